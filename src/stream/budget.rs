//! The frame-time budget (seed 000 §6): keep a requested frame time by feedback on the pixel-error
//! threshold, one step when the measured time leaves a dead band, and a larger predicted step when
//! newly visible nodes bring faces that would overrun the target.

/// Relative dead band around the target inside which the threshold is left alone.
pub const DEAD_BAND: f32 = 0.1;
/// Factor of one feedback step on the threshold.
pub const STEP: f32 = 1.25;
/// Range the threshold is clamped to, in pixels.
pub const MIN_PIXELS: f32 = 0.25;
pub const MAX_PIXELS: f32 = 512.0;

/// A pixel-error threshold steered toward a target frame time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameTime {
    pub target_ms: f32,
    threshold: f32,
    /// Milliseconds per displayed face, from the last measurement.
    ms_per_face: Option<f32>,
}

impl FrameTime {
    pub fn new(target_ms: f32, initial_pixels: f32) -> FrameTime {
        FrameTime { target_ms, threshold: initial_pixels.clamp(MIN_PIXELS, MAX_PIXELS), ms_per_face: None }
    }

    /// The pixel-error threshold to refine with.
    pub fn threshold(&self) -> f32 {
        self.threshold
    }

    /// Feedback: the last frame took `ms` with `faces` displayed. Coarser by one step when it was
    /// slower than the band, finer when faster. A frame that displayed nothing says nothing about
    /// what geometry costs, so it leaves the threshold alone (else looking away from the model
    /// would drift it to the finest, and the model would come back into view far over the target).
    pub fn measured(&mut self, ms: f32, faces: u64) {
        if !ms.is_finite() || ms < 0.0 || faces == 0 {
            return;
        }
        if ms > 0.0 {
            self.ms_per_face = Some(ms / faces as f32);
        }
        if ms > self.target_ms * (1.0 + DEAD_BAND) {
            self.threshold *= STEP;
        } else if ms < self.target_ms * (1.0 - DEAD_BAND) {
            self.threshold /= STEP;
        }
        self.threshold = self.threshold.clamp(MIN_PIXELS, MAX_PIXELS);
    }

    /// Prediction: `new_faces` of the `faces` about to be displayed belong to nodes not displayed
    /// last frame. When the time predicted for `faces` overruns the band, coarsen at once by the
    /// factor that brings it back (faces scale with 1/threshold², so by the square root).
    pub fn predict(&mut self, faces: u64, new_faces: u64) {
        let Some(k) = self.ms_per_face else { return };
        let predicted = k * faces as f32;
        if new_faces > 0 && predicted > self.target_ms * (1.0 + DEAD_BAND) && self.target_ms > 0.0 {
            self.threshold = (self.threshold * (predicted / self.target_ms).sqrt().max(STEP)).clamp(MIN_PIXELS, MAX_PIXELS);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn feedback_steps_outside_the_dead_band_only_and_clamps() {
        let mut f = FrameTime::new(10.0, 1.0);
        f.measured(10.5, 1000);
        assert_eq!(f.threshold(), 1.0);
        f.measured(20.0, 1000);
        assert_eq!(f.threshold(), STEP);
        f.measured(5.0, 1000);
        assert_eq!(f.threshold(), 1.0);
        for _ in 0..100 {
            f.measured(1.0, 1000);
        }
        assert_eq!(f.threshold(), MIN_PIXELS);
        for _ in 0..100 {
            f.measured(1000.0, 1000);
        }
        assert_eq!(f.threshold(), MAX_PIXELS);
        f.measured(1.0, 0);
        assert_eq!(f.threshold(), MAX_PIXELS, "an empty frame is no evidence");
    }

    #[test]
    fn newly_visible_faces_take_a_larger_predicted_step() {
        let mut f = FrameTime::new(10.0, 1.0);
        f.measured(10.0, 1000);
        f.predict(4000, 0);
        assert_eq!(f.threshold(), 1.0);
        f.predict(4000, 3000);
        assert!((f.threshold() - 2.0).abs() < 1e-5, "{}", f.threshold());
    }
}
