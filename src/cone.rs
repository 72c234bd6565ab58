//! TEMPORARY local stand-in (replaced by the cone branch on merge).
use glam::Vec3;
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cone { pub axis: Vec3, pub half_angle: f32 }
impl Cone {
    pub fn from_normal(n: Vec3) -> Cone { Cone { axis: n.normalize_or(Vec3::Z), half_angle: 0.0 } }
    pub fn merge(&self, o: &Cone) -> Cone {
        let d = self.axis.dot(o.axis).clamp(-1.0, 1.0).acos();
        if d + o.half_angle <= self.half_angle { return *self; }
        if d + self.half_angle <= o.half_angle { return *o; }
        let h = (d + self.half_angle + o.half_angle) * 0.5;
        if h >= std::f32::consts::PI { return Cone { axis: self.axis, half_angle: std::f32::consts::PI }; }
        let t = h - self.half_angle;
        let perp = (o.axis - self.axis * self.axis.dot(o.axis)).normalize_or_zero();
        Cone { axis: (self.axis * t.cos() + perp * t.sin()).normalize(), half_angle: h }
    }
    pub fn contains(&self, dir: Vec3, tol: f32) -> bool { self.axis.dot(dir.normalize()).clamp(-1.0,1.0).acos() <= self.half_angle + tol }
    pub fn contains_cone(&self, o: &Cone, tol: f32) -> bool { self.axis.dot(o.axis).clamp(-1.0,1.0).acos() + o.half_angle <= self.half_angle + tol }
}
pub fn smallest_enclosing(normals: &[Vec3]) -> Cone {
    let mut c: Option<Cone> = None;
    for n in normals { if n.length_squared() == 0.0 { continue; } let k = Cone::from_normal(*n); c = Some(match c { None => k, Some(c) => c.merge(&k) }); }
    c.unwrap_or(Cone { axis: Vec3::Z, half_angle: 0.0 })
}
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Facing { Back, Front, Mixed }
pub fn facing_orthographic(cone: &Cone, to_viewer: Vec3) -> Facing {
    let a = cone.axis.dot(to_viewer).clamp(-1.0, 1.0).acos();
    if a - cone.half_angle > std::f32::consts::FRAC_PI_2 + 1e-5 { Facing::Back } else if a + cone.half_angle < std::f32::consts::FRAC_PI_2 - 1e-5 { Facing::Front } else { Facing::Mixed }
}
pub fn facing_perspective(_cone: &Cone, _center: Vec3, _radius: f32, _eye: Vec3) -> Facing { Facing::Mixed }
