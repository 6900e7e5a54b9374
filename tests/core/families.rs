//! Scene families (`mesh::families`) and camera presets (`trace::views`): determinism, counts, validity, bounds and
//! cameras.

use meshchar::mesh::generate::{generate, Family, MAX_FAMILY_TRIANGLES};
use meshchar::mesh::Mesh;
use meshchar::trace::views::{presets, View};
use meshchar::trace::workload::mesh_bounds;

fn bits(m: &Mesh) -> (Vec<[u32; 3]>, &[[u32; 3]]) {
    (m.positions.iter().map(|p| p.map(f32::to_bits)).collect(), &m.indices)
}

fn check(family: Family, n: usize, seed: u64) -> Mesh {
    let m = generate(family, n, seed).unwrap_or_else(|e| panic!("{family} {n}: {e}"));
    m.validate().unwrap_or_else(|e| panic!("{family} {n}: {e}"));
    let got = m.triangle_count();
    assert!(got.abs_diff(n) * 10 <= n, "{family}: {got} triangles for {n} requested");
    let b = mesh_bounds(&m);
    assert!(b.min.is_finite() && b.max.is_finite() && !b.is_empty(), "{family} {n}: bounds {b:?}");
    assert!(b.extent().max_element() > 0.0, "{family} {n}: a point");
    for (v, c) in presets(&b) {
        assert!(c.eye.is_finite() && c.forward.is_finite() && c.right.is_finite(), "{family} {n} {v}: {c:?}");
        if v == View::Inside {
            assert!(c.eye.cmpge(b.min).all() && c.eye.cmple(b.max).all(), "{family} {n}: eye {} outside {b:?}", c.eye);
        }
        if v == View::Framing {
            assert_eq!(c, meshchar::geom::Camera::frame(&b), "{family}: framing is Camera::frame");
        }
    }
    m
}

#[test]
fn every_family_is_deterministic_and_seeds_differ() {
    for family in Family::ALL {
        let a = check(family, 3000, 7);
        let b = generate(family, 3000, 7).expect("same request");
        assert_eq!(bits(&a), bits(&b), "{family}: same seed, same bits");
        assert_eq!(a.name, b.name);
        let c = generate(family, 3000, 8).expect("other seed");
        assert_ne!(bits(&a), bits(&c), "{family}: another seed, another scene");
    }
}

#[test]
fn counts_are_as_requested_at_1k_10k_100k() {
    for family in Family::ALL {
        for n in [1_000, 10_000, 100_000] {
            let m = check(family, n, 1);
            // The generators cut the last object short, so the count is exact.
            assert_eq!(m.triangle_count(), n, "{family}");
        }
    }
}

#[test]
fn tiny_and_absurd_requests() {
    for family in Family::ALL {
        let empty = generate(family, 0, 3).expect("0 triangles");
        assert_eq!(empty.triangle_count(), 0, "{family}");
        for n in [1, 2, 5, 13] {
            let m = generate(family, n, 3).expect("a few triangles");
            m.validate().expect("valid");
            assert_eq!(m.triangle_count(), n, "{family}");
        }
        let err = generate(family, MAX_FAMILY_TRIANGLES + 1, 3).expect_err("too many");
        assert!(err.to_string().contains("67108864"), "{family}: {err}");
    }
}

#[test]
fn families_have_their_character() {
    // Interiors: the eye of `inside` is within a room and the walls are large: some triangle spans a room's side.
    let m = generate(Family::Interior, 20_000, 2).expect("interior");
    let largest = (0..m.triangle_count())
        .map(|i| {
            let [a, b, c] = m.triangle(i);
            (b - a).max(c - a).max(b - c).abs().max_element()
        })
        .fold(0.0f32, f32::max);
    assert!(largest >= 3.0, "interior: largest triangle {largest} m");
    // Vegetation and particles: small triangles almost everywhere (median longest edge under 1% of the scene).
    for family in [Family::Vegetation, Family::Particles] {
        let m = generate(family, 20_000, 2).expect("soup");
        let diag = mesh_bounds(&m).extent().length();
        let mut edges: Vec<f32> = (0..m.triangle_count())
            .map(|i| {
                let [a, b, c] = m.triangle(i);
                (b - a).length().max((c - a).length()).max((c - b).length())
            })
            .collect();
        edges.sort_by(f32::total_cmp);
        assert!(edges[edges.len() / 2] < 0.01 * diag, "{family}: median edge {} of {diag}", edges[edges.len() / 2]);
    }
    // Engineering: slivers, triangles whose longest edge is 20 times their height.
    let m = generate(Family::Engineering, 20_000, 2).expect("engineering");
    let slivers = (0..m.triangle_count())
        .filter(|&i| {
            let [a, b, c] = m.triangle(i).map(|v| v.as_dvec3());
            let longest = (b - a).length().max((c - a).length()).max((c - b).length());
            let area2 = (b - a).cross(c - a).length();
            longest > 0.0 && area2 / longest < longest / 20.0
        })
        .count();
    assert!(slivers * 4 > m.triangle_count(), "engineering: {slivers} slivers of {}", m.triangle_count());
}

#[test]
#[ignore = "2M triangles per family: 1.5 s for all seven in release, much longer in debug"]
fn counts_at_2m() {
    for family in Family::ALL {
        let m = check(family, 2_000_000, 1);
        assert_eq!(m.triangle_count(), 2_000_000, "{family}");
    }
}

#[test]
fn a_family_spec_names_a_generated_scene_wherever_a_path_is_taken() {
    use meshchar::mesh::families::parse_spec;
    assert_eq!(parse_spec("family:city:1000:5"), Some(Ok((Family::City, 1000, 5))));
    assert_eq!(parse_spec("family:Terrain:100k"), Some(Ok((Family::Terrain, 100_000, 0))));
    assert_eq!(parse_spec("family:particles:2m:1"), Some(Ok((Family::Particles, 2_000_000, 1))));
    assert_eq!(parse_spec("family:stadium:10_000:9"), Some(Ok((Family::Stadium, 10_000, 9))));
    assert_eq!(parse_spec("bunny.obj"), None);
    for bad in
        ["family:", "family:city", "family:forest:10", "family:city:ten", "family:city:10:x", "family:city:1:2:3"]
    {
        let e = parse_spec(bad).unwrap().unwrap_err();
        assert!(e.contains("family:NAME:TRIANGLES") || e.contains("unknown scene family"), "{bad}: {e}");
    }
    // Loading the spec gives the generator's mesh bit for bit, named by the spec.
    let anim = meshchar::eval::load_scene(std::path::Path::new("family:city:1000:5")).unwrap();
    assert_eq!(anim.name, "family:city:1000:5");
    let want = generate(Family::City, 1000, 5).unwrap();
    assert_eq!(anim.frames.len(), 1);
    assert_eq!(bits(&anim.frames[0]), bits(&want));
    // A bad spec is an error naming it, and a count over the limit is refused.
    let e = meshchar::eval::load_scene(std::path::Path::new("family:city:lots")).unwrap_err().to_string();
    assert!(e.contains("family:city:lots"), "{e}");
    assert!(meshchar::eval::load_scene(std::path::Path::new("family:city:100m")).is_err());
    // The file loaders read files only: a spec is a missing file to them.
    let e = meshchar::mesh::load_path(std::path::Path::new("family:city:1000:5")).unwrap_err();
    assert!(matches!(e, meshchar::mesh::MeshError::Io { .. }), "{e}");
}

#[test]
fn a_degenerate_spec_names_a_failure_study_generator_wherever_a_path_is_taken() {
    use meshchar::eval::scene::{load_scene as load_path, load_scene_mesh as load_mesh};
    use meshchar::mesh::degenerate::{self, parse_spec, Degenerate};
    use meshchar::mesh::generate as g;
    use std::path::Path;
    assert_eq!(parse_spec("degenerate:flat:10k:5"), Some(Ok((Degenerate::Flat, 10_000, 5))));
    assert_eq!(parse_spec("degenerate:All-Equal:1000"), Some(Ok((Degenerate::AllEqual, 1000, 0))));
    assert_eq!(parse_spec("family:city:10"), None);
    for bad in ["degenerate:", "degenerate:flat", "degenerate:blob:10", "degenerate:fan:x", "degenerate:fan:1:2:3"] {
        let e = parse_spec(bad).unwrap().unwrap_err();
        assert!(e.contains("degenerate:NAME:TRIANGLES") || e.contains("unknown degenerate scene"), "{bad}: {e}");
    }
    // The same meshes as the generators the failure study calls, bit for bit.
    let same = |spec: &str, want: Mesh| {
        let got = load_mesh(Path::new(spec)).unwrap_or_else(|e| panic!("{spec}: {e}"));
        assert_eq!(got.name, spec);
        assert_eq!(bits(&got), bits(&want), "{spec}");
        let anim = load_path(Path::new(spec)).unwrap();
        assert_eq!((anim.name.as_str(), anim.frames.len()), (spec, 1));
        assert_eq!(bits(&anim.frames[0]), bits(&want), "{spec}");
    };
    same("degenerate:flat:10000:5", g::flat(10_000, 5));
    same("degenerate:collinear:1000", g::collinear_centroids(1000));
    same("degenerate:all-equal:1000", g::all_equal(1000));
    same("degenerate:zero-area:3000:13", g::zero_area(3000, 13));
    same("degenerate:overlapping:2000:19", g::overlapping_large(2000, 19));
    same("degenerate:fan:300", g::fan_polygon(300));
    same("degenerate:lattice:180400", g::lattice_with_diagonal(300, 400));
    let soup = g::random_soup(5000, 11);
    same("degenerate:duplicated:20000:11", g::duplicated(&soup, 4).unwrap());
    same("degenerate:huge:5000:11", g::scaled(&soup, 1e30).unwrap());
    same("degenerate:tiny:5000:11", g::scaled(&soup, 1e-30).unwrap());
    same("degenerate:long-thin:1001:24301", g::long_thin_triangle());
    // Counts: exact where the module says so, at most the request for the lattice and the duplicated soup.
    for kind in Degenerate::ALL {
        for n in [0usize, 1, 2, 3, 7, 451, 1000, 4097] {
            let m = degenerate::generate(kind, n, 3).unwrap_or_else(|e| panic!("{kind:?} {n}: {e}"));
            m.validate().unwrap_or_else(|e| panic!("{kind:?} {n}: {e}"));
            let got = m.triangle_count();
            match kind {
                Degenerate::Lattice => {
                    let k = ((n - n / 451) as f64 / 2.0).sqrt().floor() as usize;
                    assert_eq!(got, 2 * k * k + n / 451, "{kind:?} {n}");
                }
                Degenerate::Duplicated => assert_eq!(got, n / 4 * 4, "{kind:?} {n}"),
                _ => assert_eq!(got, n, "{kind:?} {n}"),
            }
        }
    }
    let e = load_path(Path::new("degenerate:flat:100m")).unwrap_err().to_string();
    assert!(e.contains("degenerate:flat:100m") && e.contains("more than"), "{e}");
    let e = load_mesh(Path::new("degenerate:flat:lots")).unwrap_err().to_string();
    assert!(e.contains("degenerate:flat:lots") && e.contains("not a whole number"), "{e}");
    // A count past u64 is too large, not malformed.
    for big in ["degenerate:flat:99999999999999999999", "family:city:18446744073709551615k"] {
        let e = load_mesh(Path::new(big)).unwrap_err().to_string();
        assert!(e.contains("too large"), "{big}: {e}");
    }
}
