//! The scene-feature pass on lavapipe equals the CPU reference exactly (occupancy per depth, size histogram, zero
//! extents, vertex bounds bit for bit) on real meshes, generated and degenerate ones, for 30- and 63-bit codes and
//! sampled runs, with the validation layer silent.

use crate::common;
use crate::gpu_support;

use meshchar::characterize::vulkan::VulkanBackend;
use meshchar::characterize::{features_cpu, Features, MortonBits, Params};
use meshchar::mesh::{generate, load_mesh, Mesh};

fn bits(f: &Features) -> (Features, [u32; 3], [u32; 3]) {
    (f.clone(), f.lo.map(f32::to_bits), f.hi.map(f32::to_bits))
}

fn check(vk: &mut VulkanBackend, mesh: &Mesh, params: &Params) -> Features {
    let cpu = features_cpu(mesh, params).unwrap_or_else(|e| panic!("{}: cpu features: {e}", mesh.name));
    let (c, gpu) =
        vk.characterize_with_features(mesh, params).unwrap_or_else(|e| panic!("{}: gpu features: {e}", mesh.name));
    assert_eq!(bits(&gpu), bits(&cpu), "{} with {params:?}", mesh.name);
    assert_eq!(gpu.triangles, c.triangles, "{}", mesh.name);
    assert!(c.timings.iter().any(|t| t.name == "features"), "{}: the pass reports its GPU time", mesh.name);
    cpu
}

fn params(b: MortonBits, stride: u32) -> Params {
    Params { morton_bits: b, sample_stride: stride, ..Params::default() }
}

#[test]
fn gpu_features_equal_cpu_on_generated_and_degenerate_meshes() {
    let Some(ctx) = gpu_support::context() else { return };
    let mut vk = VulkanBackend::new(&ctx).expect("backend");
    let soup = generate::random_soup(20_000, 3);
    let meshes = vec![
        soup.clone(),
        generate::clustered(30_000, 5, 4),
        generate::flat(5_000, 5),
        generate::all_equal(100),
        generate::single_triangle(),
        generate::two_triangles(),
        generate::collinear_centroids(1_000),
        generate::teapot_in_stadium(6),
        generate::long_thin_triangle(),
        generate::overlapping_large(500, 7),
        generate::zero_area(2_000, 8),
        generate::scaled(&soup, 1e30).expect("huge"),
        generate::scaled(&soup, 1e-30).expect("tiny"),
    ];
    for m in &meshes {
        for b in [MortonBits::Bits30, MortonBits::Bits63] {
            for stride in [1, 3] {
                if m.triangle_count().div_ceil(stride as usize) == 0 {
                    continue;
                }
                check(&mut vk, m, &params(b, stride));
            }
        }
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn gpu_features_equal_cpu_on_shared_meshes() {
    let Some(ctx) = gpu_support::context() else { return };
    let mut vk = VulkanBackend::new(&ctx).expect("backend");
    for rel in [
        "stanford-bunny/bun_zipper.ply",
        "dabrovic-sponza/sponza.obj",
        "conference/conference.obj",
        "sibenik/sibenik.obj",
        "bart/museum5/museum5_f0000.obj",
    ] {
        let mesh = load_mesh(&common::shared_mesh(rel)).expect("load");
        let f = check(&mut vk, &mesh, &Params::default());
        // Sanity of the definitions on real data: occupancy never falls with depth and never exceeds 8^d or n.
        for d in 1..f.occupied_cells.len() {
            assert!(f.occupied_cells[d] >= f.occupied_cells[d - 1], "{rel}: occupancy falls at depth {}", d + 1);
        }
        for (d, &o) in f.occupied_cells.iter().enumerate() {
            assert!(o <= 8u64.pow(d as u32 + 1) && o <= f.triangles, "{rel}: depth {} has {o} cells", d + 1);
        }
        let sized: u64 = f.size_histogram.iter().sum::<u64>() + f.zero_extent;
        assert_eq!(sized, f.triangles, "{rel}: every triangle in one size bin");
        check(&mut vk, &mesh, &params(MortonBits::Bits63, 7));
    }
    gpu_support::assert_no_validation_messages(&ctx);
}
