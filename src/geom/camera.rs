//! Pinhole cameras: given explicitly, or framing a scene automatically.

use super::Aabb;
use super::Ray;
use glam::Vec3;

/// A pinhole camera with a vertical field of view; pixel `(x, y)` of a `w x h` image maps to a ray through the
/// pixel centre, `y` growing downwards.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position.
    pub eye: Vec3,
    /// Unit viewing direction.
    pub forward: Vec3,
    /// Unit right vector.
    pub right: Vec3,
    /// Unit up vector (orthogonal to `forward` and `right`).
    pub up: Vec3,
    /// `tan(fov_y / 2)`.
    pub tan_half_fov: f32,
}

/// Direction from the scene centre towards the automatic camera: in front (+z), a little to the right (+x) and
/// above (+y), so that no default ray is parallel to an axis.
pub const AUTO_VIEW_DIRECTION: [f32; 3] = [0.45, 0.35, 1.0];

/// Vertical field of view of the automatic camera, in degrees.
pub const AUTO_FOV_DEGREES: f32 = 45.0;

impl Camera {
    /// A camera at `eye` looking at `target` with `up` as the approximate up direction and a vertical field of view
    /// in degrees. `None` when `eye == target`, when `up` is parallel to the view direction, when a value is not
    /// finite, or when the field of view is not in `(0, 180)`.
    pub fn look_at(eye: Vec3, target: Vec3, up: Vec3, fov_y_degrees: f32) -> Option<Self> {
        if !(eye.is_finite() && target.is_finite() && up.is_finite()) {
            return None;
        }
        if !(fov_y_degrees > 0.0 && fov_y_degrees < 180.0) {
            return None;
        }
        let forward = (target - eye).try_normalize()?;
        let right = forward.cross(up).try_normalize()?;
        let up = right.cross(forward);
        Some(Camera { eye, forward, right, up, tan_half_fov: (fov_y_degrees.to_radians() * 0.5).tan() })
    }

    /// A camera that sees the whole box: it looks at the centre from [`AUTO_VIEW_DIRECTION`], far enough that the
    /// bounding sphere fits in a [`AUTO_FOV_DEGREES`] field of view, with +y up. A point-like or empty box gets a
    /// unit radius.
    pub fn frame(bounds: &Aabb) -> Self {
        let (center, mut radius) =
            if bounds.is_empty() { (Vec3::ZERO, 1.0) } else { (bounds.center(), bounds.extent().length() * 0.5) };
        if !(radius > 0.0 && radius.is_finite()) {
            radius = 1.0;
        }
        let dir = Vec3::from_array(AUTO_VIEW_DIRECTION).normalize();
        let half = (AUTO_FOV_DEGREES.to_radians() * 0.5).sin();
        let dist = radius / half * 1.05;
        let eye = center + dir * dist;
        // The view direction is not parallel to +y, so look_at cannot fail for finite inputs.
        Camera::look_at(eye, center, Vec3::Y, AUTO_FOV_DEGREES).unwrap_or(Camera {
            eye,
            forward: -dir,
            right: Vec3::X,
            up: Vec3::Y,
            tan_half_fov: (AUTO_FOV_DEGREES.to_radians() * 0.5).tan(),
        })
    }

    /// The ray through the centre of pixel `(x, y)` of a `width x height` image (`tmin = 0`, `tmax = inf`,
    /// unit direction).
    pub fn ray(&self, x: u32, y: u32, width: u32, height: u32) -> Ray {
        let w = width.max(1) as f32;
        let h = height.max(1) as f32;
        let aspect = w / h;
        let sx = ((x as f32 + 0.5) / w * 2.0 - 1.0) * self.tan_half_fov * aspect;
        let sy = (1.0 - (y as f32 + 0.5) / h * 2.0) * self.tan_half_fov;
        let dir = (self.forward + self.right * sx + self.up * sy).normalize();
        Ray::new(self.eye, dir)
    }
}

/// Offset that moves a secondary ray's origin off its surface, along the normal facing the incoming ray: `1e-5` of
/// the scene diagonal plus `1e-6` of the point's magnitude (so that it stays above f32 rounding far from the
/// origin). The shadow and diffuse workloads (`trace::workload`) start their rays there, and
/// [`crate::cost::near_crossings`] counts the boxes holding those origins.
pub(crate) fn surface_offset(bounds: &Aabb, p: Vec3) -> f32 {
    1e-5 * bounds.extent().length() + 1e-6 * p.abs().max_element()
}

/// Where the secondary ray of a primary hit starts: the hit point `p` of the ray along `dir` on `tri`, moved off the
/// surface by [`surface_offset`] along the triangle's unit normal facing the incoming ray; the origin and that
/// normal, or `None` for a zero-area triangle (never hit). The shadow and diffuse workloads (`trace::workload`) and
/// [`crate::cost::near_crossings`] both place their origins with it, so that the two agree to the bit.
pub(crate) fn secondary_start(tri: &super::Triangle, p: Vec3, dir: Vec3, bounds: &Aabb) -> Option<(Vec3, Vec3)> {
    let n = tri.e1.cross(tri.e2).try_normalize()?;
    let facing = if n.dot(dir) > 0.0 { -n } else { n };
    Some((p + facing * surface_offset(bounds, p), facing))
}

/// The shadow ray from `origin` to `light`: unit direction, `tmax` just short of the light (so that the light itself
/// never occludes); `None` when the two coincide or the distance is not finite.
pub(crate) fn shadow_ray(origin: Vec3, light: Vec3) -> Option<super::Ray> {
    let to = light - origin;
    let dist = to.length();
    (dist > 0.0 && dist.is_finite()).then(|| super::Ray {
        origin,
        dir: to / dist,
        tmin: 0.0,
        tmax: dist * (1.0 - 1e-5),
    })
}

/// The default point light of the shadow workload: above the scene (+y), towards the front-left, at one scene
/// diagonal from the centre (`(0, 10, 0)` for an empty box).
pub fn default_light(bounds: &Aabb) -> Vec3 {
    if bounds.is_empty() {
        return Vec3::new(0.0, 10.0, 0.0);
    }
    let diag = bounds.extent().length().max(1e-3);
    bounds.center() + Vec3::new(-0.3, 1.0, 0.4).normalize() * diag
}
