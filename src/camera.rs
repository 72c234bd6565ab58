//! A viewer's camera: where it is, what it sees, and how large a model-space length looks on screen.
//! Shared by the streamer (culling, refinement) and the software renderer.

use glam::camera::rh::{proj::opengl, view::look_at_mat4};
use glam::{Mat4, Vec3, Vec4};

/// Perspective with a vertical field of view, or orthographic with a visible height.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Projection {
    /// Vertical field of view in radians.
    Perspective { fov_y: f32 },
    /// Height of the visible region in model units.
    Orthographic { height: f32 },
}

/// A camera looking from `eye` toward `target`, drawing into a `width` × `height` viewport.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub eye: Vec3,
    pub target: Vec3,
    pub up: Vec3,
    pub projection: Projection,
    pub width: u32,
    pub height: u32,
    pub near: f32,
    pub far: f32,
}

/// A plane `n·p + d ≥ 0` on the inside.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    pub normal: Vec3,
    pub d: f32,
}

impl Camera {
    /// A perspective camera that frames a sphere (center, radius) from direction `from`
    /// (pointing from the center toward the eye), the sphere filling the view.
    pub fn framing(center: Vec3, radius: f32, from: Vec3, fov_y: f32, width: u32, height: u32) -> Camera {
        let dir = from.try_normalize().unwrap_or(Vec3::Z);
        let distance = radius / (0.5 * fov_y).sin().max(1e-3);
        let up = if dir.cross(Vec3::Y).length_squared() < 1e-6 { Vec3::Z } else { Vec3::Y };
        Camera {
            eye: center + dir * distance,
            target: center,
            up,
            projection: Projection::Perspective { fov_y },
            width,
            height,
            near: (distance - radius).max(distance * 1e-3),
            far: distance + radius,
        }
    }

    pub fn aspect(&self) -> f32 {
        self.width.max(1) as f32 / self.height.max(1) as f32
    }

    /// Unit direction the camera looks along.
    pub fn forward(&self) -> Vec3 {
        (self.target - self.eye).try_normalize().unwrap_or(Vec3::NEG_Z)
    }

    pub fn view(&self) -> Mat4 {
        look_at_mat4(self.eye, self.target, self.up)
    }

    pub fn projection_matrix(&self) -> Mat4 {
        match self.projection {
            Projection::Perspective { fov_y } => opengl::perspective(fov_y, self.aspect(), self.near, self.far),
            Projection::Orthographic { height } => {
                let (h, w) = (0.5 * height, 0.5 * height * self.aspect());
                opengl::orthographic(-w, w, -h, h, self.near, self.far)
            }
        }
    }

    /// Model space to clip space.
    pub fn view_projection(&self) -> Mat4 {
        self.projection_matrix() * self.view()
    }

    /// The six frustum planes (left, right, bottom, top, near, far), normals pointing inward
    /// (OpenGL clip space, z in [-w, w]).
    pub fn frustum(&self) -> [Plane; 6] {
        let m = self.view_projection();
        let rows = [m.row(0), m.row(1), m.row(2), m.row(3)];
        let make = |v: Vec4| {
            let n = v.truncate();
            let len = n.length().max(f32::MIN_POSITIVE);
            Plane { normal: n / len, d: v.w / len }
        };
        [
            make(rows[3] + rows[0]),
            make(rows[3] - rows[0]),
            make(rows[3] + rows[1]),
            make(rows[3] - rows[1]),
            make(rows[3] + rows[2]),
            make(rows[3] - rows[2]),
        ]
    }

    /// Whether a sphere is at least partly inside the frustum (conservative: may say yes for a
    /// sphere just outside a corner).
    pub fn sees_sphere(&self, center: Vec3, radius: f32) -> bool {
        self.frustum().iter().all(|p| p.normal.dot(center) + p.d >= -radius)
    }

    /// How many pixels a model-space length `size` spans at `distance` from the eye, as the
    /// largest it can appear: the basis of screen-space error (faces scale with 1/Z²).
    pub fn pixels_per_unit(&self, distance: f32) -> f32 {
        match self.projection {
            Projection::Perspective { fov_y } => self.height as f32 / (2.0 * (0.5 * fov_y).tan() * distance.max(self.near)),
            Projection::Orthographic { height } => self.height as f32 / height.max(f32::MIN_POSITIVE),
        }
    }

    /// The camera as JSON, the form golden fronts and `strata stream --print-front` use:
    /// `{eye, target, up, projection: {perspective: {fov_y}} | {orthographic: {height}}, width,
    /// height, near, far}`, each f32 written exactly.
    pub fn to_json(&self) -> serde_json::Value {
        let xyz = |p: Vec3| serde_json::json!([p.x as f64, p.y as f64, p.z as f64]);
        let projection = match self.projection {
            Projection::Perspective { fov_y } => serde_json::json!({ "perspective": { "fov_y": fov_y as f64 } }),
            Projection::Orthographic { height } => serde_json::json!({ "orthographic": { "height": height as f64 } }),
        };
        serde_json::json!({
            "eye": xyz(self.eye), "target": xyz(self.target), "up": xyz(self.up), "projection": projection,
            "width": self.width, "height": self.height, "near": self.near as f64, "far": self.far as f64,
        })
    }

    /// The camera [`to_json`](Self::to_json) wrote; `None` if a field is missing or not a number.
    pub fn from_json(v: &serde_json::Value) -> Option<Camera> {
        let f = |v: &serde_json::Value| v.as_f64().map(|x| x as f32);
        let xyz = |v: &serde_json::Value| Some(Vec3::new(f(&v[0])?, f(&v[1])?, f(&v[2])?));
        let p = &v["projection"];
        let projection = match (p.get("perspective"), p.get("orthographic")) {
            (Some(q), _) => Projection::Perspective { fov_y: f(&q["fov_y"])? },
            (_, Some(q)) => Projection::Orthographic { height: f(&q["height"])? },
            _ => return None,
        };
        Some(Camera {
            eye: xyz(&v["eye"])?,
            target: xyz(&v["target"])?,
            up: xyz(&v["up"])?,
            projection,
            width: v["width"].as_u64()? as u32,
            height: v["height"].as_u64()? as u32,
            near: f(&v["near"])?,
            far: f(&v["far"])?,
        })
    }

    /// The screen-space size in pixels of a model-space `error` for anything inside the sphere
    /// (center, radius): measured at the sphere's nearest point, so it never underestimates.
    pub fn projected_error(&self, error: f32, center: Vec3, radius: f32) -> f32 {
        let distance = (self.eye.distance(center) - radius).max(0.0);
        error * self.pixels_per_unit(distance)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn framing_camera_sees_its_sphere_and_not_behind() {
        let c = Camera::framing(Vec3::ONE, 2.0, Vec3::X, 60f32.to_radians(), 640, 480);
        assert!(c.sees_sphere(Vec3::ONE, 2.0));
        assert!(!c.sees_sphere(c.eye + (c.eye - c.target) * 3.0, 0.5));
        let clip = c.view_projection() * Vec3::ONE.extend(1.0);
        assert!(clip.x.abs() < 1e-4 && clip.y.abs() < 1e-4 && clip.w > 0.0);
    }

    #[test]
    fn projected_error_grows_as_the_camera_nears() {
        let far = Camera::framing(Vec3::ZERO, 1.0, Vec3::Z, 1.0, 512, 512);
        let mut near = far;
        near.eye = far.eye * 0.5;
        near.near = 0.01;
        let e_far = far.projected_error(0.01, Vec3::new(0.0, 0.0, 0.5), 0.1);
        let e_near = near.projected_error(0.01, Vec3::new(0.0, 0.0, 0.5), 0.1);
        assert!(e_near > e_far * 1.5);
    }
}
