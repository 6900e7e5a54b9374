//! The Vulkan characterization agrees exactly with both CPU paths: every code, every class, the histogram, `k`, the
//! exact code sums and therefore every reported float bit for bit, on every shared mesh (every stored BART frame
//! included) and on generated meshes, degenerate ones included. Runs on lavapipe with the validation layer on.

use crate::common;
use crate::gpu_support;

use meshchar::characterize::vulkan::VulkanBackend;
use meshchar::characterize::{cpu, CharError, Characterization, ClassRule, MortonBits, Params};
use meshchar::mesh::{generate, load_mesh, load_path, Mesh};
use meshchar::select::Report;
use std::path::Path;

/// Everything a report carries, compared exactly (floats by their bits), plus the per-triangle arrays.
fn assert_same(a: &Characterization, b: &Characterization, what: &str) {
    assert_eq!(a.triangles, b.triangles, "{what}: n");
    assert_eq!(a.lo.map(f32::to_bits), b.lo.map(f32::to_bits), "{what}: lo");
    assert_eq!(a.hi.map(f32::to_bits), b.hi.map(f32::to_bits), "{what}: hi");
    assert_eq!(a.code_stats, b.code_stats, "{what}: code sums");
    assert_eq!(a.moments.mean.to_bits(), b.moments.mean.to_bits(), "{what}: mean");
    assert_eq!(a.moments.std_dev.to_bits(), b.moments.std_dev.to_bits(), "{what}: std_dev");
    assert_eq!(a.moments.skewness.to_bits(), b.moments.skewness.to_bits(), "{what}: skewness");
    assert_eq!(a.classes, b.classes, "{what}: k");
    assert_eq!(a.histogram, b.histogram, "{what}: histogram");
    let (sa, sb) = (&a.stats, &b.stats);
    assert_eq!(sa.chi_square.to_bits(), sb.chi_square.to_bits(), "{what}: chi2");
    assert_eq!(sa.p_value.to_bits(), sb.p_value.to_bits(), "{what}: p");
    assert_eq!(sa.critical_value.to_bits(), sb.critical_value.to_bits(), "{what}: critical");
    assert_eq!(sa.cramers_v.to_bits(), sb.cramers_v.to_bits(), "{what}: V");
    assert_eq!(
        (sa.empty_classes, sa.concentrated_classes, sa.uniform),
        (sb.empty_classes, sb.concentrated_classes, sb.uniform),
        "{what}: classes"
    );
    assert_eq!(sa.concentrated_share.to_bits(), sb.concentrated_share.to_bits(), "{what}: share");
    match (&a.per_triangle, &b.per_triangle) {
        (Some(x), Some(y)) => {
            assert_eq!(x.codes, y.codes, "{what}: codes");
            assert_eq!(x.classes, y.classes, "{what}: classes of triangles");
        }
        _ => panic!("{what}: per-triangle arrays were asked for"),
    }
}

fn params(bits: MortonBits) -> Params {
    Params { morton_bits: bits, keep_per_triangle: true, ..Params::default() }
}

fn check_all(vk: &mut VulkanBackend, mesh: &Mesh, p: &Params, naive_too: bool) {
    let what = format!("{} ({:?}, stride {})", mesh.name, p.morton_bits, p.sample_stride);
    let fast = cpu::fast(mesh, p).unwrap_or_else(|e| panic!("{what}: cpu: {e}"));
    let gpu = vk.characterize(mesh, p).unwrap_or_else(|e| panic!("{what}: vulkan: {e}"));
    assert_same(&gpu, &fast, &what);
    assert_eq!(gpu.backend, "vulkan");
    if naive_too {
        let naive = cpu::naive(mesh, p).unwrap_or_else(|e| panic!("{what}: naive: {e}"));
        assert_same(&naive, &fast, &what);
    }
}

fn backend() -> Option<VulkanBackend> {
    let ctx = gpu_support::context()?;
    Some(VulkanBackend::new(&ctx).expect("pipelines"))
}

#[test]
fn vulkan_equals_cpu_on_generated_and_degenerate_meshes() {
    let Some(mut vk) = backend() else { return };
    let teapot = meshchar::mesh::default_teapot();
    let meshes = vec![
        generate::random_soup(20_000, 1),
        generate::clustered(20_000, 5, 2),
        generate::flat(5_000, 3),
        generate::all_equal(1_000),
        generate::single_triangle(),
        generate::two_triangles(),
        generate::collinear_centroids(2_000),
        generate::zero_area(3_000, 4),
        generate::teapot_in_stadium(5),
        generate::long_thin_triangle(),
        generate::overlapping_large(2_000, 6),
        generate::scaled(&teapot, 1e30).expect("huge"),
        generate::scaled(&teapot, 1e-30).expect("tiny"),
        generate::duplicated(&teapot, 3).expect("duplicated"),
    ];
    for mesh in &meshes {
        for bits in [MortonBits::Bits30, MortonBits::Bits63] {
            check_all(&mut vk, mesh, &params(bits), true);
        }
        let sampled = Params { sample_stride: 3, class_rule: ClassRule::Sturges, ..params(MortonBits::Bits30) };
        if mesh.triangle_count() >= 3 {
            check_all(&mut vk, mesh, &sampled, true);
        }
    }
    gpu_support::assert_no_validation_messages(vk.context());
}

#[test]
fn vulkan_equals_cpu_on_every_shared_static_mesh() {
    let Some(mut vk) = backend() else { return };
    let root = common::shared_meshes();
    let mut files: Vec<_> =
        ["stanford-bunny", "stanford-dragon", "dabrovic-sponza", "sibenik", "conference", "scans", "small"]
            .iter()
            .flat_map(|d| std::fs::read_dir(root.join(d)).unwrap_or_else(|e| panic!("{d}: {e}")))
            .map(|e| e.expect("dir entry").path())
            .filter(|p| p.extension().is_some_and(|e| e == "obj" || e == "ply"))
            .collect();
    files.sort();
    assert!(files.len() >= 20, "expected the shared meshes, found {files:?}");
    for f in &files {
        let mesh = load_mesh(f).unwrap_or_else(|e| panic!("{e}"));
        check_all(&mut vk, &mesh, &params(MortonBits::Bits30), true);
        if mesh.triangle_count() < 300_000 {
            check_all(&mut vk, &mesh, &params(MortonBits::Bits63), false);
        }
    }
    gpu_support::assert_no_validation_messages(vk.context());
}

#[test]
fn vulkan_equals_cpu_on_every_stored_bart_frame() {
    let Some(mut vk) = backend() else { return };
    let root = common::shared_meshes().join("bart");
    for scene in ["museum5", "robots", "kitchen"] {
        let anim = load_path(&root.join(scene)).unwrap_or_else(|e| panic!("{e}"));
        assert!(anim.frames.len() > 10, "{scene}: {} frames", anim.frames.len());
        let p = params(MortonBits::Bits30);
        let gpu = vk.characterize_animation(&anim, &p).expect("vulkan animation");
        for (frame, g) in anim.frames.iter().zip(&gpu) {
            let fast = cpu::fast(frame, &p).expect("cpu");
            assert_same(g, &fast, &frame.name);
        }
        // The naive reference on the first and last frames of each scene.
        for frame in [&anim.frames[0], &anim.frames[anim.frames.len() - 1]] {
            assert_same(&cpu::naive(frame, &p).expect("naive"), &cpu::fast(frame, &p).expect("cpu"), &frame.name);
        }
    }
    gpu_support::assert_no_validation_messages(vk.context());
}

#[test]
fn vulkan_rejects_bad_input_like_the_cpu() {
    let Some(mut vk) = backend() else { return };
    let p = Params::default();
    for bad in [Params { alpha: 0.0, ..p.clone() }, Params { sample_stride: 0, ..p.clone() }] {
        assert!(matches!(vk.characterize(&generate::two_triangles(), &bad), Err(CharError::InvalidParams(_))));
    }
    let empty = Mesh::new("empty", vec![], vec![]).expect("empty mesh is valid");
    assert!(matches!(vk.characterize(&empty, &p), Err(CharError::Empty { .. })));
    assert!(matches!(cpu::fast(&empty, &p), Err(CharError::Empty { .. })));
    let mut nan = generate::single_triangle();
    nan.positions[1][2] = f32::NAN;
    let err = vk.characterize(&nan, &p).expect_err("NaN must be rejected");
    assert!(err.to_string().contains("vertex 1"), "{err}");
    // Coordinates whose keys overflow f32.
    let v = |x: f32| glam::Vec3::new(x, 1.0, 2.0);
    let huge = Mesh::from_triangles("huge", &[[v(2e38), v(2e38), v(2e38)], [v(0.0), v(1.0), v(2.0)]]).expect("finite");
    let (g, c) = (vk.characterize(&huge, &p), cpu::fast(&huge, &p));
    assert!(g.is_err() && c.is_err(), "overflowing keys must be an error on both: {g:?} {c:?}");
    // An extent so small (subnormal coordinates) that 2^b / extent overflows f32.
    let tiny = generate::scaled(&generate::two_triangles(), 1e-41).expect("finite");
    let (g, c) = (vk.characterize(&tiny, &p), cpu::fast(&tiny, &p));
    assert!(g.is_err() && c.is_err(), "unquantizable extents must be an error on both: {g:?} {c:?}");
    gpu_support::assert_no_validation_messages(vk.context());
}

#[test]
fn reports_are_identical_across_backends_and_runs() {
    let Some(mut vk) = backend() else { return };
    let mesh = load_mesh(Path::new(&common::shared_mesh("stanford-bunny/bun_zipper_res2.ply"))).expect("bunny");
    let p = Params::default();
    let strip = |c: &Characterization| {
        let mut v: serde_json::Value = serde_json::from_str(&Report::new("m", c).to_json()).expect("json");
        for f in ["timings_ms", "backend", "device"] {
            v.as_object_mut().expect("object").remove(f);
        }
        v
    };
    let first = strip(&vk.characterize(&mesh, &p).expect("vulkan"));
    for _ in 0..3 {
        assert_eq!(strip(&vk.characterize(&mesh, &p).expect("vulkan")), first);
    }
    assert_eq!(strip(&cpu::fast(&mesh, &p).expect("cpu")), first);
    assert_eq!(strip(&cpu::naive(&mesh, &p).expect("naive")), first);
    gpu_support::assert_no_validation_messages(vk.context());
}
