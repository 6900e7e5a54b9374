//! The diffuse bounce direction: the CPU diffuse workload (`trace::workload`) and the probes' secondary rays
//! ([`crate::cost::probe()`]) draw their bounces with it, and the device tracer reproduces it to the bit; and the
//! secondary rays primary hits start ([`secondary_from_hits`]), for the workloads and the timed and measured probes.

use glam::Vec3;

/// `(sin, cos)` of `2 pi u` for `u` in `[0, 1)`, from additions and multiplications only, so that a device
/// reproduces it to the bit (`turn_sin_cos` of `glsl/include/trace.glsl`, with the same constants): the quadrant
/// from `4u`, then Taylor polynomials of degree 11 and 12 in Horner form on `[0, pi / 2)` (error below `1e-7`).
/// The library `sin` and `cos` differ between platforms in the last bit.
pub(crate) fn turn_sin_cos(u: f32) -> (f32, f32) {
    use crate::gpu::shaders::layout as l;
    let c = f32::from_bits;
    let t = u * 4.0;
    let q = t.floor();
    let x = (t - q) * c(l::TRACE_HALF_PI_BITS);
    let x2 = x * x;
    let mut sp = c(l::TRACE_SIN11_BITS);
    for k in [l::TRACE_SIN9_BITS, l::TRACE_SIN7_BITS, l::TRACE_SIN5_BITS, l::TRACE_SIN3_BITS] {
        sp = c(k) + x2 * sp;
    }
    let sn = x * (1.0 + x2 * sp);
    let mut cp = c(l::TRACE_COS12_BITS);
    for k in [l::TRACE_COS10_BITS, l::TRACE_COS8_BITS, l::TRACE_COS6_BITS, l::TRACE_COS4_BITS, l::TRACE_COS2_BITS] {
        cp = c(k) + x2 * cp;
    }
    let cs = 1.0 + x2 * cp;
    match (q as i32) & 3 {
        0 => (sn, cs),
        1 => (cs, -sn),
        2 => (-sn, -cs),
        _ => (-cs, sn),
    }
}

/// Cosine-distributed unit direction about the unit normal `n`: the diffuse workload's (`trace::workload`) and
/// [`crate::cost::probe()`]'s, two draws of `rng` each.
pub(crate) fn cosine_direction(n: Vec3, rng: &mut crate::rng::SplitMix64) -> Vec3 {
    let u1 = rng.next_f32();
    let u2 = rng.next_f32();
    let r = u1.sqrt();
    let (sn, cs) = turn_sin_cos(u2);
    let (x, y) = (r * cs, r * sn);
    let z = (1.0 - u1).max(0.0).sqrt();
    let (t, b) = n.any_orthonormal_pair();
    (t * x + b * y + n * z).try_normalize().unwrap_or(n)
}

/// The diffuse bounce of the `index`-th primary ray of a sample seeded with `seed`: [`cosine_direction`] about `n`
/// from a generator mixed from the two, as the diffuse workload (`trace::workload`) and the probes
/// ([`crate::cost::probe()`]) both draw it.
pub(crate) fn diffuse_direction(n: Vec3, seed: u64, index: usize) -> Vec3 {
    let mut rng = crate::rng::SplitMix64(seed ^ (index as u64).wrapping_mul(0x2545_f491_4f6c_dd1d));
    cosine_direction(n, &mut rng)
}

/// The shadow or diffuse rays that the hits `hits` of the primary rays `primary` start, in the primary rays' order:
/// per hit on a triangle of `mesh`, the start off the surface (`geom::camera::secondary_start`, within `bounds`),
/// then a shadow ray to `light` (`geom::camera::shadow_ray`) or a diffuse ray drawn with `seed` and the primary
/// ray's index ([`diffuse_direction`]); a primary workload gives the primary rays that hit. Misses, hits on no
/// triangle of the mesh and starts that fail make no ray.
pub(crate) fn secondary_from_hits(
    kind: crate::geom::WorkloadKind,
    mesh: &crate::mesh::Mesh,
    primary: &[crate::geom::Ray],
    hits: &[Option<crate::geom::Hit>],
    bounds: &crate::geom::Aabb,
    light: Vec3,
    seed: u64,
) -> Vec<crate::geom::Ray> {
    use crate::geom::camera::{secondary_start, shadow_ray};
    use crate::geom::{Ray, Triangle, WorkloadKind};
    let mut rays = Vec::new();
    for (k, (r, h)) in primary.iter().zip(hits).enumerate() {
        let Some(h) = h else { continue };
        let i = h.triangle as usize;
        if i >= mesh.triangle_count() {
            continue;
        }
        let p = r.origin + r.dir * h.t;
        let Some((origin, n)) = secondary_start(&Triangle::new(&mesh.triangle(i)), p, r.dir, bounds) else {
            continue;
        };
        match kind {
            WorkloadKind::Shadow => rays.extend(shadow_ray(origin, light)),
            WorkloadKind::Diffuse => rays.push(Ray::new(origin, diffuse_direction(n, seed, k))),
            WorkloadKind::Primary => rays.push(*r),
        }
    }
    rays
}
