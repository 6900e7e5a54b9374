//! The scene features against their definition (the module docs of `characterize::features`), computed one
//! triangle at a time in the plainest way: `features_cpu`, and the features a CPU `Characterizer` computes from
//! its own codes, must equal it on generated, degenerate and real meshes, for both code widths, several sample
//! strides, and with the codes kept per triangle or not.

use crate::characterize::features::{exponent, Features, OCCUPANCY_DEPTHS, SIZE_BINS};
use crate::characterize::{features_cpu, Backend, Characterizer, MortonBits, Params};
use crate::keys::{centroid_key, ordered_bits, Quantizer};
use crate::mesh::{degenerate, generate, Mesh};

/// The definition, sequentially: the sample's key bounds and quantizer, every vertex's bits for the bounds, every
/// triangle's largest box extent binned against the scene's, and the distinct code prefixes at every depth.
fn definition(mesh: &Mesh, params: &Params) -> Features {
    let stride = params.sample_stride as usize;
    let sample: Vec<[[f32; 3]; 3]> = (0..mesh.triangle_count())
        .step_by(stride)
        .map(|i| mesh.indices[i].map(|v| mesh.positions[v as usize]))
        .collect();
    let keys: Vec<[f32; 3]> = sample.iter().map(|t| centroid_key(t[0], t[1], t[2])).collect();
    let q = Quantizer::of_slice(&keys, params.morton_bits).expect("quantizer");
    let mut lo = [u32::MAX; 3];
    let mut hi = [0u32; 3];
    for v in sample.iter().flatten() {
        for a in 0..3 {
            lo[a] = lo[a].min(ordered_bits(v[a]));
            hi[a] = hi[a].max(ordered_bits(v[a]));
        }
    }
    let from = |u: u32| crate::keys::from_ordered_bits(u);
    let (lo, hi) = (lo.map(from), hi.map(from));
    let largest = |l: [f32; 3], h: [f32; 3]| (0..3).fold(0.0f32, |m, a| m.max(h[a] - l[a]));
    let scene = exponent(largest(lo, hi));
    let mut size_histogram = vec![0u64; SIZE_BINS];
    let mut zero_extent = 0;
    for t in &sample {
        let tl: [f32; 3] = std::array::from_fn(|a| t[0][a].min(t[1][a]).min(t[2][a]));
        let th: [f32; 3] = std::array::from_fn(|a| t[0][a].max(t[1][a]).max(t[2][a]));
        match (exponent(largest(tl, th)), scene) {
            (Some(e), Some(s)) => size_histogram[((s - e).max(0) as usize).min(SIZE_BINS - 1)] += 1,
            _ => zero_extent += 1,
        }
    }
    let shift = params.morton_bits.total();
    let occupied_cells = (1..=OCCUPANCY_DEPTHS as u32)
        .map(|d| {
            let mut prefixes: Vec<u64> = keys.iter().map(|&k| q.code(k) >> (shift - 3 * d)).collect();
            prefixes.sort_unstable();
            prefixes.dedup();
            prefixes.len() as u64
        })
        .collect();
    Features {
        triangles: sample.len() as u64,
        total_triangles: mesh.triangle_count() as u64,
        morton_bits: params.morton_bits.total(),
        occupied_cells,
        size_histogram,
        zero_extent,
        extent_exponents: std::array::from_fn(|a| exponent(hi[a] - lo[a]).unwrap_or(i32::MIN)),
        lo,
        hi,
    }
}

/// The bounds' bits beside the features, so that `-0.0` and `+0.0` differ.
fn bits(f: &Features) -> (Features, [u32; 3], [u32; 3]) {
    (f.clone(), f.lo.map(f32::to_bits), f.hi.map(f32::to_bits))
}

fn check(mesh: &Mesh) {
    let mut cpu = Characterizer::new(Some(Backend::Cpu)).expect("cpu");
    let mut naive = Characterizer::new(Some(Backend::Naive)).expect("naive");
    for morton_bits in [MortonBits::Bits30, MortonBits::Bits63] {
        for stride in [1u32, 3, 7] {
            for keep_per_triangle in [false, true] {
                if mesh.triangle_count().div_ceil(stride as usize) == 0 {
                    continue;
                }
                let params = Params { morton_bits, sample_stride: stride, keep_per_triangle, ..Params::default() };
                let want = bits(&definition(mesh, &params));
                let what = format!("{}: {morton_bits:?}, stride {stride}, per triangle {keep_per_triangle}", mesh.name);
                assert_eq!(bits(&features_cpu(mesh, &params).expect("features")), want, "features_cpu, {what}");
                for engine in [&mut cpu, &mut naive] {
                    let (_, f) = engine.characterize_with_features(mesh, &params).expect("characterize");
                    assert_eq!(bits(&f), want, "{:?} characterizer, {what}", engine.backend());
                }
            }
        }
    }
}

#[test]
fn the_features_equal_their_definition_on_generated_and_degenerate_meshes() {
    let soup = generate::random_soup(5_000, 3);
    let mut signed_zeros = generate::random_soup(300, 9);
    // Vertices on the coordinate planes with both signs of zero: the bounds' bits must follow the total order.
    for (i, p) in signed_zeros.positions.iter_mut().enumerate() {
        p[i % 3] = if i % 2 == 0 { 0.0 } else { -0.0 };
    }
    signed_zeros.name = "signed zeros".into();
    let mut meshes = vec![
        soup.clone(),
        signed_zeros,
        generate::clustered(7_000, 5, 4),
        generate::teapot_in_stadium(4),
        generate::scaled(&soup, 1e30).expect("huge"),
        generate::scaled(&soup, 1e-30).expect("tiny"),
        generate::single_triangle(),
    ];
    for kind in degenerate::Degenerate::ALL {
        meshes.push(degenerate::generate(kind, 1_000, 5).expect("degenerate mesh"));
    }
    for family in crate::mesh::families::Family::ALL {
        meshes.push(crate::mesh::families::generate(family, 3_000, 2).expect("family scene"));
    }
    for m in &meshes {
        check(m);
    }
}

#[test]
fn the_features_equal_their_definition_on_shared_meshes() {
    for rel in ["stanford-bunny/bun_zipper.ply", "dabrovic-sponza/sponza.obj"] {
        let mesh = crate::mesh::load_mesh(&crate::mesh::testing::shared_mesh(rel)).expect("load");
        check(&mesh);
    }
}
