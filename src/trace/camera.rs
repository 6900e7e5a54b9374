//! Pinhole cameras: given explicitly, or framing a scene automatically (defined in [`crate::geom::camera`], where
//! the selection reads them without the evaluation layer; re-exported here).

pub use crate::geom::camera::*;

impl From<&Camera> for crate::accel::device::Pinhole {
    fn from(c: &Camera) -> Self {
        crate::accel::device::Pinhole {
            eye: c.eye,
            forward: c.forward,
            right: c.right,
            up: c.up,
            tan_half_fov: c.tan_half_fov,
        }
    }
}
