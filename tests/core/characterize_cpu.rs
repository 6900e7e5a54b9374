//! The CPU characterization: the naive reference and the rayon path agree bit for bit; moments agree with an f64
//! two-pass; docs/spec.md's degenerate cases; sampling; 63-bit codes; the JSON report.

use crate::common;

use meshchar::characterize::{cpu, run, Backend, CharError, Characterization, ClassRule, MortonBits, Params};
use meshchar::mesh::{Mesh, MeshError};
use meshchar::rng::SplitMix64 as Rng;
use meshchar::select::{Policy, Report, SceneSummary, ThesisPolicy};
use std::path::{Path, PathBuf};

// ---------------------------------------------------------------------------------------------------------------
// Helpers

fn soup(name: &str, tris: Vec<[[f32; 3]; 3]>) -> Mesh {
    let positions: Vec<[f32; 3]> = tris.iter().flat_map(|t| t.iter().copied()).collect();
    let indices = (0..tris.len() as u32).map(|i| [3 * i, 3 * i + 1, 3 * i + 2]).collect();
    Mesh::new(name, positions, indices).expect("valid generated mesh")
}

/// `n` random small triangles in the box `[0, s)^3`.
fn random_mesh(n: usize, s: f32, seed: u64) -> Mesh {
    let mut g = Rng(seed);
    let tris = (0..n)
        .map(|_| {
            let c = [g.next_f32() * s, g.next_f32() * s, g.next_f32() * s];
            let mut t = [[0.0; 3]; 3];
            for v in &mut t {
                for a in 0..3 {
                    v[a] = c[a] + (g.next_f32() - 0.5) * s * 0.01;
                }
            }
            t
        })
        .collect();
    soup(&format!("random-{n}-{s}"), tris)
}

/// Three tight clusters and a sparse background.
fn clustered_mesh(n: usize, seed: u64) -> Mesh {
    let mut g = Rng(seed);
    let centers = [[0.1f32, 0.2, 0.3], [0.8, 0.8, 0.1], [0.5, 0.1, 0.9]];
    let tris = (0..n)
        .map(|i| {
            let (c, r) = if i % 10 == 0 { ([0.5f32; 3], 0.5f32) } else { (centers[i % 3], 0.02) };
            let mut t = [[0.0; 3]; 3];
            for v in &mut t {
                for a in 0..3 {
                    v[a] = c[a] + (g.next_f32() - 0.5) * 2.0 * r;
                }
            }
            t
        })
        .collect();
    soup("clustered", tris)
}

fn scaled(mesh: &Mesh, f: f32, name: &str) -> Mesh {
    let positions = mesh.positions.iter().map(|p| [p[0] * f, p[1] * f, p[2] * f]).collect();
    Mesh::new(name, positions, mesh.indices.clone()).expect("valid scaled mesh")
}

fn load(path: &Path) -> Mesh {
    meshchar::mesh::load_mesh(path).unwrap_or_else(|e| panic!("cannot load {}: {e}", path.display()))
}

fn params(bits: MortonBits) -> Params {
    Params { morton_bits: bits, keep_per_triangle: true, ..Params::default() }
}

/// Every reported float of a characterization, as bits.
fn float_bits(c: &Characterization) -> Vec<u64> {
    let s = &c.stats;
    let mut v = vec![
        c.moments.mean.to_bits(),
        c.moments.std_dev.to_bits(),
        c.moments.skewness.to_bits(),
        s.chi_square.to_bits(),
        s.p_value.to_bits(),
        s.critical_value.to_bits(),
        s.cramers_v.to_bits(),
        s.concentrated_share.to_bits(),
    ];
    v.extend(c.lo.iter().chain(&c.hi).map(|x| x.to_bits() as u64));
    v
}

/// Naive and fast agree on everything but timings, backend and device; returns the fast result.
fn assert_agree(mesh: &Mesh, p: &Params) -> Characterization {
    let a = cpu::naive(mesh, p).unwrap_or_else(|e| panic!("naive on {}: {e}", mesh.name));
    let b = cpu::fast(mesh, p).unwrap_or_else(|e| panic!("fast on {}: {e}", mesh.name));
    assert_eq!(float_bits(&a), float_bits(&b), "{}: floats differ", mesh.name);
    assert_eq!(a.code_stats, b.code_stats, "{}", mesh.name);
    assert_eq!(a.classes, b.classes, "{}", mesh.name);
    assert_eq!(a.histogram, b.histogram, "{}", mesh.name);
    assert_eq!(a.per_triangle, b.per_triangle, "{}", mesh.name);
    assert_eq!((a.triangles, a.total_triangles), (b.triangles, b.total_triangles));
    assert_eq!(a.stats.dof, b.stats.dof);
    assert_eq!(
        (a.stats.uniform, a.stats.empty_classes, a.stats.concentrated_classes),
        (b.stats.uniform, b.stats.empty_classes, b.stats.concentrated_classes)
    );
    assert_eq!((a.backend.as_str(), b.backend.as_str()), ("naive", "cpu"));
    // The JSON reports are identical but for timings, backend and device.
    let strip = |c: &Characterization| {
        let mut r = Report::new(&mesh.name, c);
        r.timings_ms.0.clear();
        r.backend.clear();
        r.device.clear();
        r.to_json()
    };
    assert_eq!(strip(&a), strip(&b));
    check_invariants(mesh, &b);
    b
}

/// Class of a code, docs/spec.md step 7, transcribed: `min(((m - m_min) k) div (m_max - m_min), k - 1)` in `u128`, 0
/// when `m_max == m_min` or `k <= 1`.
fn class_of(code: u64, code_min: u64, code_max: u64, k: u32) -> u32 {
    if code_max <= code_min || k <= 1 {
        return 0;
    }
    let c = (code.clamp(code_min, code_max) - code_min) as u128 * k as u128 / (code_max - code_min) as u128;
    c.min(k as u128 - 1) as u32
}

/// Properties every result has, checked from its own per-triangle data.
fn check_invariants(mesh: &Mesh, c: &Characterization) {
    let pt = c.per_triangle.as_ref().expect("per-triangle data was requested");
    assert_eq!(pt.codes.len() as u64, c.triangles);
    assert_eq!(c.histogram.len() as u32, c.classes);
    assert_eq!(c.histogram.iter().sum::<u64>(), c.triangles);
    let (mn, mx) = (c.code_stats.code_min, c.code_stats.code_max);
    assert_eq!(pt.codes.iter().min(), Some(&mn));
    assert_eq!(pt.codes.iter().max(), Some(&mx));
    assert!(mx < 1u64 << c.params.morton_bits.total());
    let mut h = vec![0u64; c.classes as usize];
    for (&code, &cl) in pt.codes.iter().zip(&pt.classes) {
        assert_eq!(cl, class_of(code, mn, mx, c.classes));
        h[cl as usize] += 1;
    }
    assert_eq!(h, c.histogram);
    // Moments within 1e-9 of an f64 two-pass computation over the codes.
    let n = pt.codes.len() as f64;
    let mean = pt.codes.iter().map(|&m| m as f64).sum::<f64>() / n;
    let var = pt.codes.iter().map(|&m| (m as f64 - mean).powi(2)).sum::<f64>() / n;
    let sd = var.sqrt();
    let skew = if sd > 0.0 { pt.codes.iter().map(|&m| ((m as f64 - mean) / sd).powi(3)).sum::<f64>() / n } else { 0.0 };
    let close = |x: f64, y: f64, scale: f64| (x - y).abs() <= 1e-9 * scale;
    assert!(close(c.moments.mean, mean, mean.abs().max(1.0)), "{}: mean {} vs {mean}", mesh.name, c.moments.mean);
    assert!(close(c.moments.std_dev, sd, sd.max(1.0)), "{}: sd {} vs {sd}", mesh.name, c.moments.std_dev);
    assert!(
        close(c.moments.skewness, skew, skew.abs().max(1.0)),
        "{}: skew {} vs {skew}",
        mesh.name,
        c.moments.skewness
    );
    // No NaN or infinity anywhere in the report.
    let json: serde_json::Value = serde_json::from_str(&Report::new(&mesh.name, c).to_json()).expect("valid JSON");
    assert_no_null(&json, &mesh.name);
}

fn assert_no_null(v: &serde_json::Value, what: &str) {
    match v {
        serde_json::Value::Null => panic!("{what}: null (NaN or infinity) in the report"),
        serde_json::Value::Number(n) => assert!(n.as_f64().is_some_and(f64::is_finite), "{what}: {n}"),
        serde_json::Value::Array(a) => a.iter().for_each(|x| assert_no_null(x, what)),
        serde_json::Value::Object(o) => o.values().for_each(|x| assert_no_null(x, what)),
        _ => {}
    }
}

// ---------------------------------------------------------------------------------------------------------------
// Agreement on generated and real meshes

#[test]
fn agree_on_generated_meshes() {
    let random = random_mesh(20_000, 10.0, 1);
    let clustered = clustered_mesh(30_000, 2);
    let meshes = vec![
        random_mesh(1, 1.0, 3),
        random_mesh(2, 1.0, 4),
        random_mesh(3, 1.0, 5),
        random_mesh(100_003, 1.0, 6),
        scaled(&random, 1e30 / 10.0, "huge 1e30"),
        scaled(&random, 1e-30 / 10.0, "tiny 1e-30"),
        scaled(&random, -3.0, "mirrored"),
        random,
        clustered,
    ];
    for bits in [MortonBits::Bits30, MortonBits::Bits63] {
        for m in &meshes {
            let c = assert_agree(m, &params(bits));
            assert_eq!(c.triangles, m.triangle_count() as u64);
        }
    }
}

#[test]
fn agree_on_the_scene_generators() {
    use meshchar::mesh::generate as g;
    let teapot = meshchar::mesh::default_teapot();
    let meshes = vec![
        g::random_soup(5000, 1),
        g::clustered(5000, 4, 2),
        g::flat(3000, 3),
        g::all_equal(100),
        g::single_triangle(),
        g::two_triangles(),
        g::collinear_centroids(500),
        g::teapot_in_stadium(4),
        g::long_thin_triangle(),
        g::overlapping_large(1000, 5),
        g::zero_area(999, 6),
        g::scaled(&teapot, 1e30).expect("scaled up"),
        g::scaled(&teapot, 1e-30).expect("scaled down"),
        g::duplicated(&teapot, 3).expect("duplicated"),
    ];
    for bits in [MortonBits::Bits30, MortonBits::Bits63] {
        for m in &meshes {
            assert_agree(m, &params(bits));
        }
    }
    let zero = g::zero_area(999, 6);
    assert_eq!(cpu::zero_area_triangles(&zero, 1), 999);
    for f in g::explode(&teapot, 4, 7).expect("exploded").frames {
        assert_agree(&f, &params(MortonBits::Bits30));
    }
}

#[test]
fn agree_on_flat_and_zero_area_meshes() {
    let mut g = Rng(11);
    // Flat: z = 0 everywhere (one axis of zero extent): codes still vary in x and y.
    let flat = soup(
        "flat",
        (0..5000)
            .map(|_| {
                let (x, y) = (g.next_f32(), g.next_f32());
                [[x, y, 0.0], [x + 0.01, y, 0.0], [x, y + 0.01, 0.0]]
            })
            .collect(),
    );
    // Zero-area: degenerate slivers along a line and collapsed points, mixed with normal triangles.
    let zero = soup(
        "zero-area",
        (0..3000)
            .map(|i| {
                let x = g.next_f32();
                match i % 3 {
                    0 => [[x, x, x]; 3],
                    1 => [[x, 0.0, 0.0], [x + 0.1, 0.0, 0.0], [x + 0.2, 0.0, 0.0]],
                    _ => [[x, 0.0, 0.0], [x, 1.0, 0.0], [x, 0.0, 1.0]],
                }
            })
            .collect(),
    );
    for bits in [MortonBits::Bits30, MortonBits::Bits63] {
        let c = assert_agree(&flat, &params(bits));
        assert_eq!(c.lo[2], 0.0);
        assert_eq!(c.hi[2], 0.0);
        assert!(c.classes > 1, "a flat scene still has distinct codes");
        let c = assert_agree(&zero, &params(bits));
        assert!(c.classes > 1);
    }
    assert_eq!(cpu::zero_area_triangles(&zero, 1), 2000);
    assert_eq!(cpu::zero_area_triangles(&zero, 1) as usize, zero.zero_area_count());
    assert_eq!(cpu::zero_area_triangles(&flat, 1), 0);
    // Every third triangle from 0 is a collapsed point.
    assert_eq!(cpu::zero_area_triangles(&zero, 3), 1000);
}

#[test]
fn agree_on_real_meshes() {
    let dir = common::shared_meshes();
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir.join("small"))
        .unwrap_or_else(|e| panic!("{}: {e}", dir.join("small").display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "obj"))
        .collect();
    files.sort();
    assert!(files.len() >= 5, "expected the small OBJ meshes in {}", dir.join("small").display());
    for f in [
        "dabrovic-sponza/sponza.obj",
        "sibenik/sibenik.obj",
        "stanford-bunny/bun_zipper.ply",
        "stanford-bunny/bun_zipper_res4.ply",
        "stanford-dragon/dragon_vrip_res3.ply",
    ] {
        files.push(dir.join(f));
    }
    for f in &files {
        let mesh = load(f);
        assert!(mesh.triangle_count() > 0, "{}", f.display());
        let c = assert_agree(&mesh, &params(MortonBits::Bits30));
        assert!(c.classes > 1);
    }
    // 63-bit codes on real meshes.
    assert_agree(&load(&dir.join("small/teapot-pd.obj")), &params(MortonBits::Bits63));
    assert_agree(&load(&dir.join("stanford-bunny/bun_zipper_res2.ply")), &params(MortonBits::Bits63));
    // The embedded default scene.
    assert_agree(&meshchar::mesh::default_scene(), &params(MortonBits::Bits30));
}

#[test]
fn animation_frames_and_policy() {
    let dir = common::shared_meshes().join("bart/museum5");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "obj"))
        .collect();
    files.sort();
    assert!(files.len() >= 3, "expected museum5 frames in {}", dir.display());
    let frames: Vec<Characterization> = files
        .iter()
        .step_by(files.len() / 3)
        .take(3)
        .map(|f| assert_agree(&load(f), &params(MortonBits::Bits30)))
        .collect();
    let scene = SceneSummary::new(dir.display().to_string(), &frames);
    let sel = ThesisPolicy::default().select(&scene);
    assert!(sel.reasons.iter().any(|r| r.text.contains("dynamic scene: 3 frames")), "{:?}", sel.reasons);
    let r = Report::new(dir.display().to_string(), &frames[1])
        .frame(1, files[1].display().to_string())
        .selection(scene.kind, "thesis", &sel);
    let v: serde_json::Value = serde_json::from_str(&r.to_json()).expect("valid JSON");
    assert_eq!(v["kind"], "dynamic");
    assert_eq!(v["frame"], 1);
}

// ---------------------------------------------------------------------------------------------------------------
// docs/spec.md's degenerate cases

#[test]
fn one_two_and_equal_triangles_have_one_class() {
    let t = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let u = [[5.0f32, 5.0, 5.0], [6.0, 5.0, 5.0], [5.0, 7.0, 5.0]];
    let all_rules = [ClassRule::Doane, ClassRule::Sturges, ClassRule::Sqrt, ClassRule::Fixed(9)];
    // Step 6 gives k = 1 for n <= 2 (Doane's rule) and for equal codes (every rule: one value, one class).
    for (name, tris, rules) in [
        ("one", vec![t], &all_rules[..3]),
        ("two", vec![t, u], &all_rules[..1]),
        ("equal", vec![u; 1000], &all_rules[..]),
    ] {
        let mesh = soup(name, tris);
        for bits in [MortonBits::Bits30, MortonBits::Bits63] {
            for &rule in rules {
                let p = Params { class_rule: rule, ..params(bits) };
                let c = assert_agree(&mesh, &p);
                assert_eq!(c.classes, 1, "{name} {rule:?}");
                assert_eq!(c.histogram, vec![c.triangles]);
                assert_eq!((c.stats.chi_square, c.stats.p_value, c.stats.uniform), (0.0, 1.0, true));
                assert_eq!(c.moments.skewness, 0.0);
            }
        }
    }
    // All centroids equal although the triangles differ.
    let a = [[0.0f32, 0.0, 0.0], [3.0, 0.0, 0.0], [0.0, 3.0, 0.0]];
    let b = [[3.0f32, 3.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]];
    let c = assert_agree(&soup("same centroid", vec![a, b, a]), &params(MortonBits::Bits30));
    assert_eq!(c.lo, c.hi);
    assert_eq!(c.classes, 1);
    assert_eq!(c.moments.std_dev, 0.0);
}

#[test]
fn no_triangles_is_an_error() {
    let mesh = Mesh::new("empty", vec![[0.0; 3]], vec![]).expect("valid");
    for backend in [Backend::Naive, Backend::Cpu] {
        let e = run(&mesh, &Params::default(), backend).expect_err("no triangles");
        assert!(matches!(e, CharError::Empty { .. }), "{e}");
        assert!(e.to_string().contains("empty") && e.to_string().contains("no triangles"), "{e}");
    }
}

#[test]
fn non_finite_vertex_is_an_error_naming_it() {
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let mesh = Mesh {
            name: "broken.obj".into(),
            positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, bad, 0.0]],
            indices: vec![[0, 1, 2], [1, 2, 3]],
            object_ids: None,
        };
        for backend in [Backend::Naive, Backend::Cpu] {
            let e = run(&mesh, &Params::default(), backend).expect_err("non-finite");
            assert!(matches!(e, CharError::Mesh(MeshError::NonFinite { vertex: 3, .. })), "{e}");
            let msg = e.to_string();
            assert!(msg.contains("broken.obj") && msg.contains("vertex 3"), "{msg}");
        }
    }
}

#[test]
fn overflowing_keys_and_extents_are_errors() {
    // (v0 + v1) + v2 = 6e38 overflows f32 in triangle 1.
    let ok = [[1.0f32, 1.0, 1.0], [2.0, 1.0, 1.0], [1.0, 2.0, 1.0]];
    let big = [[2e38f32, 0.0, 0.0], [2e38, 0.0, 0.0], [2e38, 1.0, 0.0]];
    let mesh = soup("big", vec![ok, big, ok, big]);
    for backend in [Backend::Naive, Backend::Cpu] {
        let e = run(&mesh, &Params::default(), backend).expect_err("key overflow");
        assert!(matches!(e, CharError::KeyOverflow { triangle: 1, .. }), "{e}");
        assert!(e.to_string().contains("big") && e.to_string().contains("triangle 1"), "{e}");
    }
    // Keys +-3e38 are finite, but hi - lo = 6e38 is not.
    let pos = [[1e38f32, 0.0, 0.0]; 3];
    let neg = [[-1e38f32, 0.0, 0.0]; 3];
    let mesh = soup("wide", vec![pos, neg]);
    for backend in [Backend::Naive, Backend::Cpu] {
        let e = run(&mesh, &Params::default(), backend).expect_err("extent overflow");
        assert!(matches!(e, CharError::Extent { .. }), "{e}");
    }
    // An extent so small that 2^b / extent overflows.
    let a = [[1e-40f32, 0.0, 0.0]; 3];
    let b = [[0.0f32, 0.0, 0.0]; 3];
    let e = run(&soup("tiny", vec![a, b]), &Params::default(), Backend::Cpu).expect_err("scale overflow");
    assert!(matches!(e, CharError::Extent { .. }), "{e}");
}

#[test]
fn invalid_params_are_errors() {
    let mesh = random_mesh(10, 1.0, 9);
    let bad = [
        Params { alpha: 0.0, ..Params::default() },
        Params { alpha: 1.0, ..Params::default() },
        Params { alpha: f64::NAN, ..Params::default() },
        Params { sample_stride: 0, ..Params::default() },
        Params { class_rule: ClassRule::Fixed(0), ..Params::default() },
    ];
    for p in &bad {
        for backend in [Backend::Naive, Backend::Cpu] {
            let e = run(&mesh, p, backend).expect_err("invalid params");
            assert!(matches!(e, CharError::InvalidParams(_)), "{e}");
        }
    }
}

// ---------------------------------------------------------------------------------------------------------------
// Sampling, class rules, 63-bit codes, the report

#[test]
fn sample_stride_equals_the_subset_mesh() {
    let mesh = clustered_mesh(10_001, 21);
    for stride in [1u32, 2, 3, 7, 10_000, 20_000] {
        let p = Params { sample_stride: stride, ..params(MortonBits::Bits30) };
        let c = assert_agree(&mesh, &p);
        // The same triangles as a mesh of their own.
        let subset = Mesh::new(
            "subset",
            mesh.positions.clone(),
            mesh.indices.iter().step_by(stride as usize).copied().collect(),
        )
        .expect("valid subset");
        let s = assert_agree(&subset, &params(MortonBits::Bits30));
        assert_eq!(c.triangles, (10_001u64).div_ceil(stride as u64));
        assert_eq!(c.total_triangles, 10_001);
        assert_eq!(float_bits(&c), float_bits(&s));
        assert_eq!((&c.code_stats, &c.histogram, &c.per_triangle), (&s.code_stats, &s.histogram, &s.per_triangle));
    }
}

#[test]
fn class_rules_and_fixed_counts() {
    let mesh = random_mesh(4096, 1.0, 31);
    let n = 4096f64;
    for (rule, k) in [
        (ClassRule::Sturges, (1.0 + n.log2()).ceil() as u32),
        (ClassRule::Sqrt, 64),
        (ClassRule::Fixed(7), 7),
        (ClassRule::Fixed(100_000), 4096),
    ] {
        let c = assert_agree(&mesh, &Params { class_rule: rule, ..params(MortonBits::Bits30) });
        assert_eq!(c.classes, k, "{rule:?}");
    }
    // Doane from the reported moments.
    let c = assert_agree(&mesh, &params(MortonBits::Bits30));
    let sg1 = (6.0 * (n - 2.0) / ((n + 1.0) * (n + 3.0))).sqrt();
    let k = (1.0 + n.log2() + (1.0 + c.moments.skewness.abs() / sg1).log2()).ceil() as u32;
    assert_eq!(c.classes, k);
    // Uniform random triangles: the effect size is small.
    assert!(c.stats.cramers_v < 0.1, "V = {}", c.stats.cramers_v);
}

#[test]
fn bit63_codes_refine_bit30_codes() {
    // Quantization to 21 bits then to 10 bits is not a plain shift (f32 rounding), but the top bits of most
    // 63-bit codes equal the 30-bit code: check it holds for the overwhelming majority, and exactly for the bounds.
    let mesh = random_mesh(5000, 1.0, 41);
    let c30 = assert_agree(&mesh, &params(MortonBits::Bits30));
    let c63 = assert_agree(&mesh, &params(MortonBits::Bits63));
    assert_eq!(c30.lo, c63.lo);
    assert_eq!(c30.hi, c63.hi);
    let (a, b) = (c30.per_triangle.expect("kept"), c63.per_triangle.expect("kept"));
    let same = a.codes.iter().zip(&b.codes).filter(|(x, y)| **x == **y >> 33).count();
    assert!(same as f64 > 0.99 * a.codes.len() as f64, "{same}");
    assert!(c63.code_stats.code_max >= 1 << 60);
    assert_eq!(c63.params.morton_bits.total(), 63);
}

#[test]
fn json_report_has_every_spec_field() {
    let mesh = clustered_mesh(2000, 51);
    let c = cpu::fast(&mesh, &Params::default()).expect("characterized");
    let frames = [c];
    let summary = SceneSummary::new("clustered", &frames);
    let policy = ThesisPolicy::default();
    let sel = policy.select(&summary);
    let r = Report::new("clustered", &frames[0])
        .selection(summary.kind, policy.name(), &sel)
        .zero_area(cpu::zero_area_triangles(&mesh, 1));
    let line = r.to_json();
    assert!(!line.contains('\n'));
    let v: serde_json::Value = serde_json::from_str(&line).expect("valid JSON");
    for field in [
        "mesh",
        "triangles",
        "morton_bits",
        "bounds",
        "mean",
        "std_dev",
        "skewness",
        "classes",
        "histogram",
        "chi_square",
        "dof",
        "p_value",
        "critical_value",
        "uniform",
        "empty_classes",
        "concentrated_classes",
        "kind",
        "selected",
        "reasons",
        "backend",
        "device",
        "timings_ms",
        "effect_size",
        "concentrated_share",
        "zero_area_triangles",
        "sampled_triangles",
        "sample_stride",
        "class_rule",
    ] {
        assert!(v.get(field).is_some(), "missing {field} in {line}");
    }
    assert_eq!(v["bounds"]["lo"].as_array().map(Vec::len), Some(3));
    assert_eq!(v["bounds"]["hi"].as_array().map(Vec::len), Some(3));
    assert_eq!(v["triangles"], 2000);
    assert_eq!(v["morton_bits"], 30);
    assert_eq!(v["kind"], "static");
    assert_eq!(v["backend"], "cpu");
    assert_eq!(v["histogram"].as_array().map(Vec::len), Some(frames[0].classes as usize));
    assert!(v["reasons"].as_array().is_some_and(|r| !r.is_empty()));
    assert!(v.get("frame").is_none());
    let t = v["timings_ms"].as_object().expect("timings object");
    let ms = |pass: &str| t.get(pass).and_then(|x| x.as_f64()).unwrap_or_else(|| panic!("timing {pass}"));
    let passes = ["keys_bounds", "morton_moments", "classes_histogram", "chi_square"];
    assert_eq!(t.len(), passes.len() + 1, "{t:?}");
    // The passes run one after the other inside the total's interval: their sum cannot exceed it (1 ns of rounding
    // slack), and characterizing 2000 triangles takes time.
    let sum: f64 = passes.iter().map(|p| ms(p)).sum();
    assert!(ms("total") > 0.0 && sum <= ms("total") + 1e-6, "passes {sum} ms, total {} ms", ms("total"));
    assert_no_null(&v, "clustered");
    // The text rendering mentions the essentials.
    let text = r.to_text();
    for s in ["k = ", "chi-square", "Cramér's V", "selected", "timings"] {
        assert!(text.contains(s), "{s} missing from\n{text}");
    }
    assert_eq!(text.lines().filter(|l| l.contains('|')).count(), frames[0].classes as usize);
}

// ---------------------------------------------------------------------------------------------------------------
// Property test: naive == fast on small random meshes

mod prop {
    use super::*;
    use proptest::prelude::*;

    fn coord() -> impl Strategy<Value = f32> {
        prop_oneof![
            Just(0.0f32),
            Just(-0.0f32),
            Just(1.0f32),
            -4.0f32..4.0,
            (-1e6f32..1e6).prop_map(|x| x * 1e-12),
            -1e30f32..1e30,
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
        #[test]
        fn naive_equals_fast(
            verts in proptest::collection::vec([coord(), coord(), coord()], 3..24),
            tris in proptest::collection::vec([0usize..1000, 0usize..1000, 0usize..1000], 1..40),
            bits63 in any::<bool>(),
            stride in 1u32..4,
            rule in 0u32..5,
        ) {
            let nv = verts.len();
            let indices = tris.iter().map(|t| [(t[0] % nv) as u32, (t[1] % nv) as u32, (t[2] % nv) as u32]).collect();
            let mesh = Mesh::new("prop", verts, indices).expect("valid");
            let class_rule = match rule {
                0 => ClassRule::Doane,
                1 => ClassRule::Sturges,
                2 => ClassRule::Sqrt,
                r => ClassRule::Fixed(r * 3),
            };
            let p = Params {
                morton_bits: if bits63 { MortonBits::Bits63 } else { MortonBits::Bits30 },
                sample_stride: stride,
                class_rule,
                keep_per_triangle: true,
                ..Params::default()
            };
            // Mixed 1e30 and 1e-12 coordinates may overflow an extent: then both must fail the same way.
            match (cpu::naive(&mesh, &p), cpu::fast(&mesh, &p)) {
                (Ok(_), Ok(_)) => { assert_agree(&mesh, &p); }
                (Err(a), Err(b)) => prop_assert_eq!(a.to_string(), b.to_string()),
                (a, b) => prop_assert!(false, "naive {:?} vs fast {:?}", a.map(|_| ()), b.map(|_| ())),
            }
        }
    }
}

/// `Characterization::same_result`: the naive and the rayon backends report the same result (their timings, backend
/// and device differ), and a report that differs in one count does not.
#[test]
fn same_result_ignores_timings_backend_and_device_only() {
    let mesh = random_mesh(500, 1.0, 11);
    let p = params(MortonBits::Bits30);
    let naive = cpu::naive(&mesh, &p).unwrap();
    let fast = cpu::fast(&mesh, &p).unwrap();
    assert_ne!(naive.backend, fast.backend);
    assert!(naive.same_result(&fast) && fast.same_result(&naive));
    let mut other = fast.clone();
    other.histogram[0] += 1;
    assert!(!fast.same_result(&other));
    let mut other = fast.clone();
    other.triangles += 1;
    assert!(!fast.same_result(&other));
}
