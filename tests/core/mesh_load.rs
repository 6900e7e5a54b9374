//! Loaders (OBJ, PLY, animations), their errors, the embedded scenes and the generators.

use crate::common;

use common::{shared_mesh, shared_meshes, temp_dir, temp_file};
use meshchar::mesh::generate;
use meshchar::mesh::{
    default_scene, default_teapot, load_animation, load_mesh, load_path, parse_mesh, Mesh, MeshError, MeshFormat,
};
use std::path::Path;

// ------------------------------------------------------------------------------------------------------------------
// Shared meshes: exact counts (../shared/meshes/README.md, checked with shared/tools/meshstat.py)
// ------------------------------------------------------------------------------------------------------------------

fn load(rel: &str) -> Mesh {
    let p = shared_mesh(rel);
    load_mesh(&p).unwrap_or_else(|e| panic!("{e}"))
}

fn bbox(m: &Mesh) -> ([f32; 3], [f32; 3]) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in &m.positions {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    (lo, hi)
}

fn assert_close(a: [f32; 3], b: [f64; 3]) {
    for k in 0..3 {
        assert!((f64::from(a[k]) - b[k]).abs() < 1e-5, "{a:?} vs {b:?}");
    }
}

#[test]
fn stanford_bunny_ply_ascii_with_extra_vertex_properties() {
    let m = load("stanford-bunny/bun_zipper.ply");
    assert_eq!(m.triangle_count(), 69_451);
    assert_eq!(m.positions.len(), 35_947);
    assert_eq!(m.object_ids, None);
    let (lo, hi) = bbox(&m);
    assert_close(lo, [-0.09469, 0.032987, -0.061874]);
    assert_close(hi, [0.061009, 0.187321, 0.0588]);
    for (rel, n) in [
        ("stanford-bunny/bun_zipper_res2.ply", 16_301),
        ("stanford-bunny/bun_zipper_res3.ply", 3_851),
        ("stanford-bunny/bun_zipper_res4.ply", 948),
    ] {
        assert_eq!(load(rel).triangle_count(), n, "{rel}");
    }
}

#[test]
fn stanford_dragon_ply_ascii_871k() {
    let m = load("stanford-dragon/dragon_vrip.ply");
    assert_eq!(m.triangle_count(), 871_414);
    assert_eq!(m.positions.len(), 437_645);
}

#[test]
fn igea_ply_triangle_strips() {
    let m = load("scans/igea.ply");
    assert_eq!(m.triangle_count(), 268_686);
    assert_eq!(m.positions.len(), 134_345);
    assert_eq!(m.zero_area_count(), 0);
    let (lo, hi) = bbox(&m);
    assert_close(lo, [-0.034556, -0.049669, -0.049538]);
    assert_close(hi, [0.034556, 0.049669, 0.049538]);
}

#[test]
fn sponza_obj_groups_become_objects() {
    let m = load("dabrovic-sponza/sponza.obj");
    assert_eq!(m.triangle_count(), 66_454);
    let ids = m.object_ids.as_ref().expect("sponza has several groups");
    assert_eq!(ids.len(), m.triangle_count());
    assert!(ids.windows(2).all(|w| w[0] <= w[1]), "object ids follow file order");
    assert!(*ids.last().unwrap() > 10);
    let (lo, hi) = bbox(&m);
    assert_close(lo, [-17.40276, -0.906689, -7.798512]);
    assert_close(hi, [17.41724, 15.653312, 7.801489]);
}

#[test]
fn conference_obj_331k_with_zero_area_triangles() {
    let m = load("conference/conference.obj");
    assert_eq!(m.triangle_count(), 331_179);
    assert_eq!(m.zero_area_count(), 53_627);
}

#[test]
fn other_obj_scans_and_small_meshes() {
    for (rel, n) in [
        ("sibenik/sibenik.obj", 75_284),
        ("scans/nefertiti.obj", 99_938),
        ("scans/happy-buddha-100k.obj", 100_000),
        ("scans/lucy-52k.obj", 52_591),
        ("scans/horse.obj", 96_966),
        ("small/suzanne.obj", 968), // quads
        ("small/cow.obj", 5_804),
        ("small/spot.obj", 5_856),
        ("small/fandisk.obj", 12_946),
        ("small/homer.obj", 12_000),
        ("small/rocker-arm.obj", 20_088),
        ("small/teapot-pd.obj", 992),
        ("small/bunny-lowres-pd.obj", 3_674),
    ] {
        assert_eq!(load(rel).triangle_count(), n, "{rel}");
    }
    let ogre = load("scans/ogre.obj");
    assert_eq!(ogre.triangle_count(), 124_008);
    assert_eq!(ogre.zero_area_count(), 4);
}

#[test]
fn dragon_lower_resolutions() {
    for (rel, n) in [
        ("stanford-dragon/dragon_vrip_res2.ply", 202_520),
        ("stanford-dragon/dragon_vrip_res3.ply", 47_794),
        ("stanford-dragon/dragon_vrip_res4.ply", 11_102),
    ] {
        assert_eq!(load(rel).triangle_count(), n, "{rel}");
    }
}

#[test]
fn bart_museum5_directory_is_a_31_frame_animation() {
    let dir = shared_meshes().join("bart/museum5");
    let anim = load_path(&dir).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(anim.frames.len(), 31);
    assert!(anim.is_dynamic());
    assert_eq!(anim.name, dir.display().to_string());
    for f in &anim.frames {
        assert_eq!(f.triangle_count(), 11_308, "{}", f.name);
    }
    assert!(anim.frames[0].name.ends_with("museum5_f0000.obj"));
    assert!(anim.frames[30].name.ends_with("museum5_f0299.obj"));
    assert_ne!(anim.frames[0].positions, anim.frames[30].positions, "the scene moves");
}

#[test]
fn single_file_is_a_one_frame_animation() {
    let p = shared_mesh("small/teapot-pd.obj");
    let anim = load_path(&p).unwrap();
    assert_eq!(anim.frames.len(), 1);
    assert!(!anim.is_dynamic());
    assert_eq!(anim.frames[0].triangle_count(), 992);
}

// ------------------------------------------------------------------------------------------------------------------
// Embedded scenes
// ------------------------------------------------------------------------------------------------------------------

#[test]
fn embedded_scenes_match_the_shared_files() {
    let bunny = default_scene();
    assert_eq!(bunny.triangle_count(), 3_674);
    assert_eq!(bunny.positions.len(), 1_839);
    let teapot = default_teapot();
    assert_eq!(teapot.triangle_count(), 992);
    assert_eq!(teapot.positions.len(), 792);
    let file = load("small/bunny-lowres-pd.obj");
    assert_eq!(file.positions, bunny.positions);
    assert_eq!(file.indices, bunny.indices);
}

// ------------------------------------------------------------------------------------------------------------------
// OBJ details
// ------------------------------------------------------------------------------------------------------------------

#[test]
fn obj_polygons_fan_relative_indices_polylines_and_objects() {
    let text = "# test\n\
                v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0.5 0.5 1\n\
                o first\n\
                f 1/1/1 2 3 4\n\
                l 1 2 3\n\
                p 1\n\
                f 1 2\n\
                o second\n\
                f -5 -4 -1\n";
    let p = temp_file("fan.obj", text.as_bytes());
    let m = load_mesh(&p).unwrap();
    assert_eq!(m.name, p.display().to_string());
    assert_eq!(m.triangle_count(), 3, "quad -> 2, polyline, point and segment -> 0, triangle -> 1");
    let tris: Vec<[[f32; 3]; 3]> = (0..3).map(|i| m.triangle(i).map(|v| v.to_array())).collect();
    assert_eq!(tris[0], [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]]);
    assert_eq!(tris[1], [[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]]);
    assert_eq!(tris[2], [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 0.5, 1.0]]);
    assert_eq!(m.object_ids, Some(vec![0, 0, 1]));
}

/// A file without triangles used to load as an empty mesh; it is now refused by the loader, naming the file.
#[test]
fn empty_obj_is_refused() {
    let p = temp_file("empty.obj", b"# nothing here\n");
    let (e, msg) = err_of(&p);
    assert!(matches!(e, MeshError::NoTriangles { .. }), "{e:?}");
    assert!(msg.contains("no triangles"), "{msg}");
    // A mesh without triangles is still a valid value (the generators and tests build them); only loading refuses.
    assert!(Mesh::new("empty", vec![[0.0; 3]], vec![]).is_ok());
}

#[test]
fn format_is_sniffed_without_extension() {
    let obj = temp_file("noext_obj", b"# a triangle\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    assert_eq!(load_mesh(&obj).unwrap().triangle_count(), 1);
    let ply = temp_file("noext_ply.dat", &ply_bytes(&PlySpec::new(Enc::Le)));
    assert_eq!(load_mesh(&ply).unwrap().triangle_count(), 7);
    let upper = temp_file("UPPER.OBJ", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    assert_eq!(load_mesh(&upper).unwrap().triangle_count(), 1);
}

// ------------------------------------------------------------------------------------------------------------------
// Errors: every message names the file and the place
// ------------------------------------------------------------------------------------------------------------------

fn err_of(p: &Path) -> (MeshError, String) {
    match load_mesh(p) {
        Ok(m) => panic!("{} loaded ({} triangles) but should fail", p.display(), m.triangle_count()),
        Err(e) => {
            let msg = e.to_string();
            assert!(msg.contains(&p.display().to_string()), "message does not name the file: {msg}");
            (e, msg)
        }
    }
}

#[test]
fn obj_index_out_of_range_names_line_and_triangle() {
    let p = temp_file("oob.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\n");
    let (e, msg) = err_of(&p);
    match e {
        MeshError::IndexOutOfRange { triangle, index, vertices, .. } => {
            assert_eq!((triangle, index, vertices), (1, 9, 3));
        }
        other => panic!("wrong error {other:?}"),
    }
    assert!(msg.contains(&format!("{}:5", p.display())), "{msg}");
    assert!(msg.contains("triangle 1"), "{msg}");

    let p = temp_file("zero.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n");
    let (e, msg) = err_of(&p);
    assert!(matches!(e, MeshError::Parse { .. }), "{e:?}");
    assert!(msg.contains("line 4"), "{msg}");
}

#[test]
fn ply_index_out_of_range_names_triangle() {
    for enc in [Enc::Ascii, Enc::Le, Enc::Be] {
        let mut spec = PlySpec::new(enc);
        spec.faces[4] = vec![3, 4, 6]; // 6 vertices: index 6 is one past the end
        let p = temp_file("oob.ply", &ply_bytes(&spec));
        let (e, msg) = err_of(&p);
        match e {
            MeshError::IndexOutOfRange { triangle, index, vertices, .. } => {
                assert_eq!((triangle, index, vertices), (6, 6, 6));
            }
            other => panic!("wrong error {other:?}"),
        }
        assert!(msg.contains("triangle 6"), "{msg}");
        if enc == Enc::Ascii {
            // 18 header lines, 6 vertex lines, face 4 is the 5th face line.
            assert!(msg.contains(&format!("{}:29", p.display())), "{msg}");
        }
    }
    let mut spec = PlySpec::new(Enc::Le);
    spec.faces[0] = vec![0, -2, 1];
    let (e, msg) = err_of(&temp_file("neg.ply", &ply_bytes(&spec)));
    assert!(matches!(e, MeshError::Parse { .. }), "{e:?}");
    assert!(msg.contains("element 'face' 0"), "{msg}");
}

#[test]
fn obj_nan_and_infinite_coordinates() {
    for (name, text, vertex, line) in [
        ("nan.obj", "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n", 1, 2),
        ("inf.obj", "# c\nv 0 0 0\nv 1 0 0\nv 0 1 -inf\nf 1 2 3\n", 2, 4),
        ("big.obj", "v 1e39 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", 0, 1),
    ] {
        let p = temp_file(name, text.as_bytes());
        let (e, msg) = err_of(&p);
        match e {
            MeshError::NonFinite { vertex: v, .. } => assert_eq!(v, vertex, "{msg}"),
            other => panic!("wrong error {other:?}"),
        }
        assert!(msg.contains(&format!("{}:{line}", p.display())), "{msg}");
        assert!(msg.contains(&format!("vertex {vertex}")), "{msg}");
    }
}

#[test]
fn ply_nan_and_infinite_coordinates() {
    let mut spec = PlySpec::new(Enc::Le);
    spec.verts[2][1] = f64::NAN;
    let (e, msg) = err_of(&temp_file("nan.ply", &ply_bytes(&spec)));
    assert!(matches!(e, MeshError::NonFinite { vertex: 2, .. }), "{e:?}");
    assert!(msg.contains("vertex 2"), "{msg}");

    let mut spec = PlySpec::new(Enc::Be);
    spec.verts[5][0] = f64::NEG_INFINITY;
    let (e, _) = err_of(&temp_file("inf.ply", &ply_bytes(&spec)));
    assert!(matches!(e, MeshError::NonFinite { vertex: 5, .. }), "{e:?}");

    // Ascii PLY cannot spell NaN or inf, but a literal beyond the f32 range reads as infinity, whether the property
    // is a float or a double.
    let text = String::from_utf8(ply_bytes(&PlySpec::new(Enc::Ascii))).unwrap();
    assert!(text.contains("\n0 1 0 7\n"));
    let p = temp_file("inf_ascii.ply", text.replace("\n0 1 0 7\n", "\n0 1 1e39 7\n").as_bytes());
    let (e, msg) = err_of(&p);
    assert!(matches!(e, MeshError::NonFinite { vertex: 3, .. }), "{e:?}");
    assert!(msg.contains(&format!("{}:22", p.display())), "{msg}");
    let mut spec = PlySpec::new(Enc::Ascii);
    spec.coord = Ty::Double;
    spec.verts[3][2] = -1e39;
    let (e, _) = err_of(&temp_file("inf_double.ply", &ply_bytes(&spec)));
    assert!(matches!(e, MeshError::NonFinite { vertex: 3, .. }), "{e:?}");
}

#[test]
fn missing_and_unreadable_files() {
    let dir = temp_dir("missing");
    let p = dir.join("does-not-exist.obj");
    let (e, _) = err_of(&p);
    assert!(matches!(e, MeshError::Io { .. }), "{e:?}");
    // A directory is not a readable mesh file.
    let d = dir.join("a-dir.ply");
    std::fs::create_dir(&d).unwrap();
    let (e, _) = err_of(&d);
    assert!(matches!(e, MeshError::Io { .. }), "{e:?}");
    assert!(load_path(&dir.join("nope")).is_err());
}

#[test]
fn unknown_format() {
    let p = temp_file("mesh.stl", b"solid cube\n  facet normal 0 0 1\n");
    let (e, _) = err_of(&p);
    assert!(matches!(e, MeshError::UnknownFormat { .. }), "{e:?}");
    let p = temp_file("notes.txt", b"hello world\nthis is not a mesh\n");
    assert!(matches!(err_of(&p).0, MeshError::UnknownFormat { .. }));
    let p = temp_file("empty.bin", b"");
    assert!(matches!(err_of(&p).0, MeshError::UnknownFormat { .. }));
}

/// Deterministic junk bytes.
fn junk(len: usize, mut x: u64) -> Vec<u8> {
    (0..len)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 24) as u8
        })
        .collect()
}

#[test]
fn garbage_is_an_error_not_a_panic() {
    let g = junk(4096, 0x1234_5678);
    let (e, msg) = err_of(&temp_file("garbage.ply", &g));
    assert!(matches!(e, MeshError::Parse { .. }), "{e:?}");
    assert!(msg.contains("header"), "{msg}");
    let (e, msg) = err_of(&temp_file("garbage.obj", &g));
    assert!(matches!(e, MeshError::Parse { .. }), "{e:?}");
    assert!(msg.contains("line 1"), "{msg}");
    assert!(matches!(err_of(&temp_file("garbage", &g)).0, MeshError::UnknownFormat { .. }));
    let mut after_magic = b"ply\n".to_vec();
    after_magic.extend_from_slice(&g);
    assert!(matches!(err_of(&temp_file("garbage2.ply", &after_magic)).0, MeshError::Parse { .. }));
    let mut header_then_junk = b"ply\nformat binary_little_endian 1.0\nelement vertex 1000\nproperty float x\n\
                                  property float y\nproperty float z\nend_header\n"
        .to_vec();
    header_then_junk.extend_from_slice(&g);
    let (e, msg) = err_of(&temp_file("short.ply", &header_then_junk));
    assert!(matches!(e, MeshError::Parse { .. }), "{e:?}");
    assert!(msg.contains("element 'vertex' 341"), "4096 bytes hold 341 vertices and a bit: {msg}");
}

#[test]
fn mutated_files_never_panic() {
    let ply = ply_bytes(&PlySpec::new(Enc::Le));
    let ascii = ply_bytes(&PlySpec::new(Enc::Ascii));
    let obj = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 1\nf 1 2 3\nf 2/1 3/1 4/1\ng x\nf -1 -2 -3 1\n".to_vec();
    for (k, (bytes, format)) in
        [(ply, MeshFormat::Ply), (ascii, MeshFormat::Ply), (obj, MeshFormat::Obj)].into_iter().enumerate()
    {
        let mut x = 0x9e37_79b9_7f4a_7c15u64 ^ k as u64;
        for _ in 0..400 {
            let mut b = bytes.clone();
            for _ in 0..3 {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                let at = (x % b.len() as u64) as usize;
                b[at] = (x >> 40) as u8;
            }
            if let Ok(m) = parse_mesh("mutant", &b, format) {
                assert!(m.validate().is_ok());
            }
        }
    }
}

#[test]
fn truncated_binary_ply_names_the_element() {
    for enc in [Enc::Le, Enc::Be] {
        let full = ply_bytes(&PlySpec::new(enc));
        assert!(parse_mesh("full", &full, MeshFormat::Ply).is_ok());
        for len in 0..full.len() {
            let r = parse_mesh("cut.ply", &full[..len], MeshFormat::Ply);
            let e = r.err().unwrap_or_else(|| panic!("a file cut at {len} of {} bytes loaded", full.len()));
            assert!(e.to_string().starts_with("cut.ply"), "{e}");
        }
        let header_len = full.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        // Cut in the middle of the first face (6 vertices of 3 floats and a uchar each come first).
        let p = temp_file("truncated.ply", &full[..header_len + 6 * 13 + 3]);
        let (e, msg) = err_of(&p);
        assert!(matches!(e, MeshError::Parse { .. }), "{e:?}");
        assert!(msg.contains("element 'face' 0"), "{msg}");
    }
}

#[test]
fn topology_mismatch_names_both_frames() {
    let dir = temp_dir("anim");
    let a = dir.join("f0.obj");
    let b = dir.join("f1.obj");
    std::fs::write(&a, "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\n").unwrap();
    std::fs::write(&b, "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n").unwrap();
    std::fs::write(dir.join("notes.txt"), "not a frame").unwrap();
    for r in [load_path(&dir), load_animation(&[a.clone(), b.clone()])] {
        let e = r.unwrap_err();
        assert!(matches!(e, MeshError::TopologyMismatch { .. }), "{e:?}");
        let msg = e.to_string();
        assert!(msg.contains(&a.display().to_string()) && msg.contains(&b.display().to_string()), "{msg}");
    }
    // Same topology, moved vertices: fine, and the text file is not a frame.
    std::fs::write(&b, "v 0 0 1\nv 1 0 1\nv 0 1 1\nv 1 1 1\nf 1 2 3\n").unwrap();
    let anim = load_path(&dir).unwrap();
    assert_eq!(anim.frames.len(), 2);
    // A frame that fails to load names its file.
    std::fs::write(&b, "v 0 0 1\nv 1 0 1\nf 1 2 3\n").unwrap();
    assert!(load_path(&dir).unwrap_err().to_string().contains(&b.display().to_string()));

    let empty = temp_dir("empty-anim");
    std::fs::write(empty.join("readme.md"), "nothing").unwrap();
    let e = load_path(&empty).unwrap_err();
    assert!(e.to_string().contains(&empty.display().to_string()), "{e}");
}

// ------------------------------------------------------------------------------------------------------------------
// PLY encodings and types
// ------------------------------------------------------------------------------------------------------------------

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Enc {
    Ascii,
    Le,
    Be,
}

#[derive(Clone, Copy, Debug)]
enum Ty {
    UChar,
    UShort,
    Int,
    UInt,
    Float,
    Double,
}

impl Ty {
    fn name(self) -> &'static str {
        match self {
            Ty::UChar => "uchar",
            Ty::UShort => "ushort",
            Ty::Int => "int",
            Ty::UInt => "uint",
            Ty::Float => "float",
            Ty::Double => "double",
        }
    }

    fn put(self, enc: Enc, v: f64, out: &mut Vec<u8>) {
        if enc == Enc::Ascii {
            let s = match self {
                Ty::Float => format!("{}", v as f32),
                Ty::Double => format!("{v}"),
                _ => format!("{}", v as i64),
            };
            out.extend_from_slice(s.as_bytes());
            out.push(b' ');
            return;
        }
        macro_rules! bytes {
            ($x:expr) => {
                if enc == Enc::Le {
                    out.extend_from_slice(&$x.to_le_bytes())
                } else {
                    out.extend_from_slice(&$x.to_be_bytes())
                }
            };
        }
        match self {
            Ty::UChar => bytes!(v as u8),
            Ty::UShort => bytes!(v as u16),
            Ty::Int => bytes!(v as i32),
            Ty::UInt => bytes!(v as u32),
            Ty::Float => bytes!(v as f32),
            Ty::Double => bytes!(v),
        }
    }
}

struct PlySpec {
    enc: Enc,
    coord: Ty,
    count: Ty,
    index: Ty,
    element: &'static str,
    verts: Vec<[f64; 3]>,
    faces: Vec<Vec<i64>>,
}

impl PlySpec {
    /// 6 vertices; a triangle, a quad, a pentagon, a segment (no triangle) and a triangle: 7 triangles.
    fn new(enc: Enc) -> Self {
        PlySpec {
            enc,
            coord: Ty::Float,
            count: Ty::UChar,
            index: Ty::Int,
            element: "face",
            verts: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [1.0, 1.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.5, 2.0, 0.25],
                [-1.25, 0.5, 3.0],
            ],
            faces: vec![vec![0, 1, 2], vec![0, 1, 2, 3], vec![1, 2, 4, 5, 3], vec![0, 5], vec![3, 4, 5]],
        }
    }
}

/// A PLY file with an extra vertex property, an extra face property after the index list and an extra element, so
/// that the loader must skip all three. Header: 18 lines.
fn ply_bytes(s: &PlySpec) -> Vec<u8> {
    let format = match s.enc {
        Enc::Ascii => "ascii",
        Enc::Le => "binary_little_endian",
        Enc::Be => "binary_big_endian",
    };
    let c = s.coord.name();
    let mut out = format!(
        "ply\nformat {format} 1.0\ncomment written by the meshchar tests\nelement vertex {}\nproperty {c} x\n\
         property {c} y\nproperty {c} z\nproperty uchar quality\nelement {} {}\n\
         property list {} {} vertex_indices\nproperty int flags\nelement edge 2\nproperty int vertex1\n\
         property int vertex2\nobj_info nothing\ncomment the end\ncomment of the header\nend_header\n",
        s.verts.len(),
        s.element,
        s.faces.len(),
        s.count.name(),
        s.index.name()
    )
    .into_bytes();
    let newline = |out: &mut Vec<u8>| {
        if s.enc == Enc::Ascii {
            out.pop();
            out.push(b'\n');
        }
    };
    for v in &s.verts {
        for &x in v {
            s.coord.put(s.enc, x, &mut out);
        }
        Ty::UChar.put(s.enc, 7.0, &mut out);
        newline(&mut out);
    }
    for f in &s.faces {
        s.count.put(s.enc, f.len() as f64, &mut out);
        for &i in f {
            s.index.put(s.enc, i as f64, &mut out);
        }
        Ty::Int.put(s.enc, -3.0, &mut out);
        newline(&mut out);
    }
    for e in [[0.0, 1.0], [1.0, 2.0]] {
        for x in e {
            Ty::Int.put(s.enc, x, &mut out);
        }
        newline(&mut out);
    }
    out
}

#[test]
fn ply_ascii_and_binary_encodings_give_identical_meshes() {
    let expected_tris: Vec<[u32; 3]> =
        vec![[0, 1, 2], [0, 1, 2], [0, 2, 3], [1, 2, 4], [1, 4, 5], [1, 5, 3], [3, 4, 5]];
    let mut reference: Option<Mesh> = None;
    let mut cases = 0;
    for coord in [Ty::Float, Ty::Double] {
        for count in [Ty::UChar, Ty::Int, Ty::UInt] {
            for index in [Ty::UShort, Ty::Int, Ty::UInt] {
                for enc in [Enc::Ascii, Enc::Le, Enc::Be] {
                    let mut spec = PlySpec::new(enc);
                    spec.coord = coord;
                    spec.count = count;
                    spec.index = index;
                    let bytes = ply_bytes(&spec);
                    let label = format!("{enc:?} {coord:?} list {count:?} {index:?}");
                    let mut m =
                        parse_mesh("enc.ply", &bytes, MeshFormat::Ply).unwrap_or_else(|e| panic!("{label}: {e}"));
                    assert_eq!(m.indices, expected_tris, "{label}");
                    m.name.clear();
                    match &reference {
                        None => reference = Some(m),
                        Some(r) => assert_eq!(&m, r, "{label}"),
                    }
                    cases += 1;
                }
            }
        }
    }
    assert_eq!(cases, 54);
    let r = reference.unwrap();
    assert_eq!(r.positions[5], [-1.25, 0.5, 3.0]);
    // Through a file as well.
    let p = temp_file("enc_be.ply", &ply_bytes(&PlySpec::new(Enc::Be)));
    assert_eq!(load_mesh(&p).unwrap().indices, r.indices);
}

#[test]
fn ply_tristrips_decode_with_restarts_and_alternating_winding() {
    for enc in [Enc::Ascii, Enc::Le, Enc::Be] {
        let mut spec = PlySpec::new(enc);
        spec.element = "tristrips";
        spec.count = Ty::Int;
        spec.index = Ty::Int;
        spec.verts = (0..8).map(|i| [i as f64, (i * i) as f64, 1.0]).collect();
        spec.faces = vec![vec![0, 1, 2, 3, 4, -1, 5, 6, 7, -1, 0, 1], vec![7, 6, 5, 4]];
        let m = parse_mesh("strips.ply", &ply_bytes(&spec), MeshFormat::Ply).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(m.indices, vec![[0, 1, 2], [2, 1, 3], [2, 3, 4], [5, 6, 7], [7, 6, 5], [5, 6, 4]], "{enc:?}");
    }
}

// ------------------------------------------------------------------------------------------------------------------
// Generators
// ------------------------------------------------------------------------------------------------------------------

fn centroid_keys(m: &Mesh) -> Vec<[f32; 3]> {
    (0..m.triangle_count())
        .map(|i| {
            let [a, b, c] = m.triangle(i);
            ((a + b) + c).to_array()
        })
        .collect()
}

#[test]
fn generators_are_valid_and_deterministic() {
    let all = [
        generate::random_soup(500, 1),
        generate::clustered(500, 7, 2),
        generate::flat(500, 3),
        generate::all_equal(50),
        generate::single_triangle(),
        generate::two_triangles(),
        generate::collinear_centroids(100),
        generate::teapot_in_stadium(4),
        generate::long_thin_triangle(),
        generate::overlapping_large(200, 5),
        generate::zero_area(99, 6),
    ];
    for m in &all {
        assert!(m.validate().is_ok(), "{}", m.name);
        assert!(m.triangle_count() > 0, "{}", m.name);
        assert!(m.positions.iter().flatten().all(|c| c.is_finite()), "{}", m.name);
    }
    assert_eq!(generate::random_soup(500, 1), all[0]);
    assert_ne!(generate::random_soup(500, 99).positions, all[0].positions);
    assert_eq!(generate::clustered(500, 7, 2), all[1]);
    assert_eq!(generate::teapot_in_stadium(4), all[7]);
    assert_eq!(generate::zero_area(99, 6), all[10]);
}

#[test]
fn generator_properties() {
    let soup = generate::random_soup(1000, 11);
    assert_eq!(soup.triangle_count(), 1000);
    assert!(soup.positions.iter().flatten().all(|&c| (0.0..=1.0).contains(&c)));

    let flat = generate::flat(1000, 12);
    assert!(flat.positions.iter().all(|p| p[2].to_bits() == 0), "z is +0.0 everywhere");
    let (lo, hi) = bbox(&flat);
    assert!(hi[0] > lo[0] && hi[1] > lo[1] && hi[2] == lo[2]);

    let eq = generate::all_equal(64);
    let keys = centroid_keys(&eq);
    assert_eq!(keys.len(), 64);
    assert!(keys.iter().all(|k| *k == keys[0]));

    assert_eq!(generate::single_triangle().triangle_count(), 1);
    let two = generate::two_triangles();
    assert_eq!(two.triangle_count(), 2);
    let keys = centroid_keys(&two);
    assert_ne!(keys[0], keys[1]);

    let col = generate::collinear_centroids(50);
    assert!(centroid_keys(&col).iter().all(|k| k[1] == 0.0 && k[2] == 0.0));
    assert_eq!(col.zero_area_count(), 0);

    let za = generate::zero_area(300, 13);
    assert_eq!(za.zero_area_count(), 300);

    let big = generate::scaled(&soup, 1e30).unwrap();
    let tiny = generate::scaled(&soup, 1e-30).unwrap();
    assert!(bbox(&big).1[0] > 1e29 && bbox(&tiny).1[0] < 1e-29 && bbox(&tiny).1[0] > 0.0);
    assert_eq!(big.indices, soup.indices);
    assert!(matches!(generate::scaled(&soup, 1e39), Err(MeshError::NonFinite { .. })));

    let dup = generate::duplicated(&default_teapot(), 3).unwrap();
    assert_eq!(dup.triangle_count(), 3 * 992);
    assert_eq!(dup.triangle(992), dup.triangle(0));
    assert_eq!(generate::duplicated(&soup, 0).unwrap().triangle_count(), 0);

    let stadium = generate::teapot_in_stadium(7);
    assert_eq!(stadium.triangle_count(), 992 + 12);
    let (lo, hi) = bbox(&stadium);
    assert_eq!((lo, hi), ([-1e4; 3], [1e4; 3]));
    let ids = stadium.object_ids.as_ref().unwrap();
    assert_eq!(ids.iter().filter(|&&i| i == 1).count(), 12);
    let teapot_box = bbox(&Mesh { positions: stadium.positions[..792].to_vec(), ..Default::default() });
    let d: f32 = (0..3).map(|a| (teapot_box.1[a] - teapot_box.0[a]).powi(2)).sum::<f32>().sqrt();
    assert!((d - 1.0).abs() < 1e-3, "teapot diagonal {d}");

    let thin = generate::long_thin_triangle();
    assert_eq!(thin.triangle_count(), 1001);
    let [a, b, _] = thin.triangle(0);
    assert!((b - a).length() > 1.7);

    let ov = generate::overlapping_large(100, 14);
    let mean_edge: f32 = (0..100).map(|i| (ov.triangle(i)[1] - ov.triangle(i)[0]).length()).sum::<f32>() / 100.0;
    assert!(mean_edge > 0.4, "{mean_edge}");

    let cl = generate::clustered(1000, 4, 15);
    assert_eq!(cl.triangle_count(), 1000);
    assert_eq!(generate::clustered(10, 0, 1).triangle_count(), 10);
}

#[test]
fn subdivide_multiplies_triangles_by_four_per_level() {
    let teapot = default_teapot();
    for levels in 0..3u32 {
        let s = generate::subdivide(&teapot, levels).unwrap();
        assert_eq!(s.triangle_count(), 992 * 4usize.pow(levels));
        assert!(s.validate().is_ok());
        assert_eq!(bbox(&s), bbox(&teapot), "midpoints stay inside");
    }
    let one = generate::subdivide(&generate::single_triangle(), 1).unwrap();
    assert_eq!(one.positions.len(), 6, "midpoints are shared");
    let sponza_like = Mesh { object_ids: Some(vec![5]), ..generate::single_triangle() };
    assert_eq!(generate::subdivide(&sponza_like, 2).unwrap().object_ids, Some(vec![5; 16]));
}

#[test]
fn explode_starts_at_the_input_and_moves_along_normals() {
    let bunny = default_scene();
    let anim = generate::explode(&bunny, 5, 42).unwrap();
    assert_eq!(anim.frames.len(), 5);
    let f0 = &anim.frames[0];
    assert_eq!(f0.triangle_count(), bunny.triangle_count());
    for i in 0..bunny.triangle_count() {
        assert_eq!(f0.triangle(i), bunny.triangle(i));
    }
    for f in &anim.frames {
        assert_eq!(f.indices, f0.indices);
        assert!(f.validate().is_ok());
    }
    for i in (0..bunny.triangle_count()).step_by(97) {
        let [a, b, c] = bunny.triangle(i);
        let n = (b - a).cross(c - a).normalize();
        let d = anim.frames[4].triangle(i)[0] - a;
        assert!(d.length() > 0.0);
        assert!(d.normalize().dot(n) > 0.999, "triangle {i} moves along its normal");
    }
    assert_eq!(generate::explode(&bunny, 5, 42).unwrap(), anim);
    assert_eq!(generate::explode(&bunny, 0, 1).unwrap().frames.len(), 1);
    let za = generate::explode(&generate::zero_area(30, 1), 3, 2).unwrap();
    assert!(za.frames[2].positions.iter().flatten().all(|c| c.is_finite()));
}

// ------------------------------------------------------------------------------------------------------------------
// Hostile input: no panic, no hang, no success on nothing, bounded memory, bounded messages
// ------------------------------------------------------------------------------------------------------------------

/// Runs `f` on another thread and fails the test if it takes longer than `secs` (a hang fails instead of blocking
/// the test run; the stuck thread is left behind).
fn within<T: Send + 'static>(secs: u64, what: &str, f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    match rx.recv_timeout(std::time::Duration::from_secs(secs)) {
        Ok(v) => v,
        Err(_) => panic!("{what}: no answer within {secs} s"),
    }
}

/// `err_of` under a time bound.
fn err_within(p: &Path) -> (MeshError, String) {
    let q = p.to_path_buf();
    let r = within(20, &p.display().to_string(), move || load_mesh(&q));
    match r {
        Ok(m) => panic!("{} loaded ({} triangles) but should fail", p.display(), m.triangle_count()),
        Err(e) => {
            let msg = e.to_string();
            assert!(msg.contains(&p.display().to_string()), "message does not name the file: {msg}");
            assert!(!matches!(e, MeshError::ParserPanic { .. }), "a parser panicked: {msg}");
            (e, msg)
        }
    }
}

const TRIANGLE: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";

#[test]
fn obj_huge_and_out_of_range_indices_are_errors_not_panics() {
    // tobj computes 3 * index without overflow checks: 3 * (6148914691236517206 - 1) + 2 wraps to 1 and the normal
    // lookup then panicked (characterize, evaluate and build_bvh exited with 101).
    let text = format!("{TRIANGLE}vn 0 0 1\nf 1//6148914691236517206 2//1 3//1\n");
    let p = temp_file("huge-normal.obj", text.as_bytes());
    let (e, msg) = err_within(&p);
    assert!(matches!(e, MeshError::Parse { .. }), "{e:?}");
    assert!(
        msg.contains("line 5") && msg.contains("normal index 6148914691236517206 is out of range (1 defined)"),
        "{msg}"
    );

    for (name, body, line, expect) in [
        ("vt.obj", "vt 0 0\nf 1/1 2/2 3/1\n", 5, "texture coordinate index 2 is out of range (1 defined)"),
        ("vt-big.obj", "vt 0 0\nf 1/9223372036854775807 2/1 3/1\n", 5, "texture coordinate index 9223372036854775807"),
        ("vn-zero.obj", "vn 0 0 1\nf 1//0 2//1 3//1\n", 5, "normal index 0 (OBJ indices start at 1)"),
        (
            "vn-rel.obj",
            "vn 0 0 1\nf 1//-2 2//-1 3//-1\n",
            5,
            "relative normal index -2 reaches before the first normal (1 so far)",
        ),
        ("vt-rel.obj", "f 1/-1 2 3\nvt 0 0\n", 4, "relative texture coordinate index -1 reaches before the first"),
        ("v-rel.obj", "f -1 -2 -4\n", 4, "relative vertex index -4 reaches before the first vertex (3 so far)"),
        ("v-zero.obj", "f 1 2 0\n", 4, "vertex index 0 (OBJ indices start at 1)"),
        ("v-missing.obj", "f 1 2 /1\n", 4, "face corner 3 ('/1') has no vertex index"),
        ("v-overflow.obj", "f 1 2 18446744073709551616\n", 4, "cannot read the face's vertex indices"),
        ("four-slots.obj", "f 1 2 3/1/1/1\n", 4, "cannot read the face's vertex indices"),
        ("no-corner.obj", "f\n", 4, "face without vertices"),
    ] {
        let p = temp_file(name, format!("{TRIANGLE}{body}").as_bytes());
        let (e, msg) = err_within(&p);
        assert!(matches!(e, MeshError::Parse { .. }), "{name}: {e:?}");
        assert!(msg.contains(&format!("line {line}")) && msg.contains(expect), "{name}: {msg}");
    }
    // A positive vertex index past the vertices is IndexOutOfRange, naming the line and the triangle.
    let p = temp_file("v-huge.obj", format!("{TRIANGLE}f 1 2 3\nf 3 2 9223372036854775807 1\n").as_bytes());
    let (e, msg) = err_within(&p);
    match e {
        MeshError::IndexOutOfRange { triangle, index, vertices, .. } => {
            assert_eq!((triangle, index, vertices), (1, 9_223_372_036_854_775_807, 3));
        }
        other => panic!("wrong error {other:?}"),
    }
    assert!(msg.contains(&format!("{}:5", p.display())), "{msg}");

    // Still accepted: texture and normal indices when the file has none of their kind (tobj ignores them), a trailing
    // empty slot, a face before its vertices in the same group, points and segments with any index.
    let ok = "f 1/7/7 2/7 3//7/\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 9\nf 0 -7\nf -3 -2 -1\n";
    let m = parse_mesh("ok.obj", ok.as_bytes(), MeshFormat::Obj).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(m.triangle_count(), 2);
}

#[test]
fn obj_groups_of_points_and_segments_only_are_no_objects() {
    // Points and segments are hidden from tobj (they give no triangle and cost it memory), so a group holding only
    // those is no object, like an empty group.
    let text = format!("{TRIANGLE}o a\nf 1\nf 2\nf 1 2\no b\nf 1 2 3\nf 1\no c\nf 3 2 1\n");
    let m = parse_mesh("groups.obj", text.as_bytes(), MeshFormat::Obj).unwrap();
    assert_eq!(m.object_ids, Some(vec![0, 1]));
}

/// A binary little-endian PLY file: a header from its lines, then `payload`.
fn ply_with(header_lines: &[&str], payload: &[u8]) -> Vec<u8> {
    let mut out = b"ply\nformat binary_little_endian 1.0\n".to_vec();
    for l in header_lines {
        out.extend_from_slice(l.as_bytes());
        out.push(b'\n');
    }
    out.extend_from_slice(b"end_header\n");
    out.extend_from_slice(payload);
    out
}

/// Three float vertices and one uchar/int triangle, little endian.
fn triangle_payload() -> Vec<u8> {
    let mut b = Vec::new();
    for v in [[0f32, 0., 0.], [1., 0., 0.], [0., 1., 0.]] {
        for x in v {
            b.extend_from_slice(&x.to_le_bytes());
        }
    }
    b.push(3);
    for i in [0i32, 1, 2] {
        b.extend_from_slice(&i.to_le_bytes());
    }
    b
}

const VERTEX3: [&str; 4] = ["element vertex 3", "property float x", "property float y", "property float z"];
const FACE1: [&str; 2] = ["element face 1", "property list uchar int vertex_indices"];

#[test]
fn ply_element_without_properties_is_refused_before_any_item_is_read() {
    // ply-rs-bw looped 2^64 - 1 times over an element of no bytes before reading any vertex.
    let mut lines: Vec<&str> = vec!["element junk 18446744073709551615"];
    lines.extend(VERTEX3);
    lines.extend(FACE1);
    let p = temp_file("no-props.ply", &ply_with(&lines, &triangle_payload()));
    let (e, msg) = err_within(&p);
    assert!(matches!(e, MeshError::Parse { .. }), "{e:?}");
    assert!(msg.contains("header line 3"), "{msg}");
    assert!(msg.contains("element 'junk' has 18446744073709551615 items but no properties"), "{msg}");
    // Without items, an element without properties is harmless.
    lines[0] = "element junk 0";
    assert_eq!(
        parse_mesh("ok.ply", &ply_with(&lines, &triangle_payload()), MeshFormat::Ply).unwrap().triangle_count(),
        1
    );
}

#[test]
fn ply_duplicate_names_are_refused() {
    let mut lines: Vec<&str> = VERTEX3.to_vec();
    lines.extend(FACE1);
    lines.extend(["element vertex 0", "property float x"]);
    let (e, msg) = err_within(&temp_file("dup-element.ply", &ply_with(&lines, &triangle_payload())));
    assert!(matches!(e, MeshError::Parse { .. }), "{e:?}");
    assert!(
        msg.contains("header line 9") && msg.contains("element 'vertex' is declared twice (first at header line 3)"),
        "{msg}"
    );

    let mut lines: Vec<&str> = VERTEX3.to_vec();
    lines.insert(2, "property double x");
    lines.extend(FACE1);
    let (_, msg) = err_within(&temp_file("dup-property.ply", &ply_with(&lines, &triangle_payload())));
    assert!(
        msg.contains("header line 5")
            && msg.contains("element 'vertex' declares property 'x' twice (first at header line 4)"),
        "{msg}"
    );
}

#[test]
fn ply_payload_shorter_than_the_header_requires() {
    // Binary: the first item that cannot fit is named.
    let mut lines: Vec<&str> =
        vec!["element vertex 1000000", "property float x", "property float y", "property float z"];
    lines.extend(FACE1);
    let (e, msg) = err_within(&temp_file("short.ply", &ply_with(&lines, &[0u8; 100])));
    assert!(matches!(e, MeshError::Parse { .. }), "{e:?}");
    assert!(msg.contains("element 'vertex' 8") && msg.contains("1000000 items of at least 12 bytes"), "{msg}");
    // Counts whose byte size overflows 64 bits.
    lines[0] = "element vertex 18446744073709551615";
    let (_, msg) = err_within(&temp_file("huge-count.ply", &ply_with(&lines, &triangle_payload())));
    assert!(msg.contains("element 'vertex' 4"), "49 bytes hold 4 vertices and a bit: {msg}");
    // Faces after the vertices: 3 vertices fit, 1000 faces of at least 1 byte do not.
    let mut lines: Vec<&str> = VERTEX3.to_vec();
    lines.extend(["element face 1000", "property list uchar int vertex_indices"]);
    let (_, msg) = err_within(&temp_file("short-faces.ply", &ply_with(&lines, &triangle_payload())));
    assert!(msg.contains("element 'face' 13"), "36 bytes of vertices, 13 left: {msg}");
    // Ascii: the element and its header line are named.
    let text = "ply\nformat ascii 1.0\nelement vertex 1000000\nproperty float x\nproperty float y\nproperty float z\n\
                end_header\n0 0 0\n1 0 0\n0 1 0\n";
    let (e, msg) = err_within(&temp_file("short-ascii.ply", text.as_bytes()));
    assert!(matches!(e, MeshError::Parse { .. }), "{e:?}");
    assert!(msg.contains("element 'vertex' (header line 3)") && msg.contains("lines of at least 6 bytes"), "{msg}");
}

#[test]
fn ply_list_counts_that_cannot_fit_are_refused() {
    let mut lines: Vec<&str> = VERTEX3.to_vec();
    lines.extend(["element face 1", "property list uint int vertex_indices"]);
    let mut payload = triangle_payload();
    payload.truncate(36);
    payload.extend_from_slice(&u32::MAX.to_le_bytes());
    payload.extend_from_slice(&[0u8; 12]);
    let (e, msg) = err_within(&temp_file("list-count.ply", &ply_with(&lines, &payload)));
    assert!(matches!(e, MeshError::Parse { .. }), "{e:?}");
    assert!(msg.contains("element 'face' 0"), "{msg}");
    assert!(
        msg.contains("list 'vertex_indices' declares 4294967295 entries of 4 bytes, but only 12 bytes are left"),
        "{msg}"
    );

    lines[5] = "property list int int vertex_indices";
    payload.truncate(36);
    payload.extend_from_slice(&(-5i32).to_le_bytes());
    payload.extend_from_slice(&[0u8; 12]);
    let (_, msg) = err_within(&temp_file("negative-count.ply", &ply_with(&lines, &payload)));
    assert!(msg.contains("element 'face' 0") && msg.contains("negative count"), "{msg}");

    // Ascii: a count beyond the line's numbers.
    let text = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                element face 1\nproperty list uint int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n\
                4294967295 0 1 2\n";
    let p = temp_file("list-count-ascii.ply", text.as_bytes());
    let (_, msg) = err_within(&p);
    assert!(msg.contains("element 'face' 0 (line 13)"), "{msg}");
}

#[test]
fn ply_unknown_formats_are_refused() {
    let body = ["element vertex 3", "property float x", "property float y", "property float z"].join("\n");
    for (name, format, expect) in [
        ("middle.ply", "format binary_middle_endian 1.0", "header line 2"),
        ("v2.ply", "format binary_little_endian 2.0", "format version 2.0 is not 1.x"),
        ("none.ply", "comment no format line", "header"),
    ] {
        let bytes =
            format!("ply\n{format}\n{body}\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n");
        let mut bytes = bytes.into_bytes();
        bytes.extend_from_slice(&triangle_payload());
        let (e, msg) = err_within(&temp_file(name, &bytes));
        assert!(matches!(e, MeshError::Parse { .. }), "{name}: {e:?}");
        assert!(msg.contains(expect), "{name}: {msg}");
    }
    let mut lines: Vec<&str> = VERTEX3.to_vec();
    lines.extend(["element face 1", "property list float int vertex_indices"]);
    let (_, msg) = err_within(&temp_file("float-count.ply", &ply_with(&lines, &triangle_payload())));
    assert!(msg.contains("header line 7") && msg.contains("floating-point count type"), "{msg}");
}

#[test]
fn files_without_triangles_are_refused() {
    for (name, text) in [
        ("text.obj", "Dear reader,\nthis is a letter, not a mesh.\n"),
        ("vertices.obj", TRIANGLE),
        ("points.obj", "v 0 0 0\nv 1 0 0\nf 1\nf 1 2\nl 1 2 1\n"),
        ("nul.obj", "\0\0\0\0"),
    ] {
        let p = temp_file(name, text.as_bytes());
        let (e, msg) = err_within(&p);
        assert!(matches!(e, MeshError::NoTriangles { .. }), "{name}: {e:?}");
        assert!(msg.starts_with(&format!("{}: no triangles", p.display())), "{msg}");
    }
    let (_, msg) = err_within(&temp_file("points2.obj", b"v 0 0 0\nv 1 0 0\nf 1\nf 1 2\nl 1 2 1\n"));
    assert!(
        msg.contains("no face of 3 or more corners (2 vertex statements, 2 faces of fewer corners, 1 polylines)"),
        "{msg}"
    );

    // Triangle strips of restart markers and runs of two: no triangle.
    for enc in [Enc::Ascii, Enc::Le, Enc::Be] {
        let mut spec = PlySpec::new(enc);
        spec.element = "tristrips";
        spec.count = Ty::Int;
        spec.index = Ty::Int;
        spec.faces = vec![vec![-1, -1, -1], vec![0, 1, -1, 2, 3]];
        let p = temp_file("restarts.ply", &ply_bytes(&spec));
        let (e, msg) = err_within(&p);
        assert!(matches!(e, MeshError::NoTriangles { .. }), "{enc:?}: {e:?}");
        assert!(msg.contains("element 'tristrips' has 2 strips, none with 3 indices between restarts (-1)"), "{msg}");
    }
    // Faces of fewer than 3 corners only; no face element at all.
    let mut spec = PlySpec::new(Enc::Le);
    spec.faces = vec![vec![0, 1], vec![2]];
    let (e, _) = err_within(&temp_file("segments.ply", &ply_bytes(&spec)));
    assert!(matches!(e, MeshError::NoTriangles { .. }), "{e:?}");
    let (e, msg) = err_within(&temp_file("cloud.ply", &ply_with(&VERTEX3, &triangle_payload()[..36])));
    assert!(matches!(e, MeshError::NoTriangles { .. }), "{e:?}");
    assert!(msg.contains("3 vertices and no 'face' or 'tristrips' element"), "{msg}");
    let empty = b"ply\nformat ascii 1.0\nend_header\n";
    assert!(matches!(parse_mesh("e.ply", empty, MeshFormat::Ply), Err(MeshError::NoTriangles { .. })));
    assert!(matches!(parse_mesh("e.obj", b"", MeshFormat::Obj), Err(MeshError::NoTriangles { .. })));
    // An animation of no frame file is refused too.
    assert!(load_animation(&[]).is_err());
}

#[cfg(unix)]
#[test]
fn non_regular_files_are_refused_before_they_are_opened() {
    let dir = temp_dir("special");
    // A device that never ends: reading it would exhaust memory.
    if Path::new("/dev/zero").exists() {
        let (e, msg) = err_within(Path::new("/dev/zero"));
        assert!(matches!(e, MeshError::Io { .. }), "{e:?}");
        assert!(msg.contains("not a regular file: a character device"), "{msg}");
        let link = dir.join("zero.obj");
        std::os::unix::fs::symlink("/dev/zero", &link).unwrap();
        let (_, msg) = err_within(&link);
        assert!(msg.contains("character device"), "{msg}");
        std::fs::remove_file(&link).unwrap();
    }
    // A FIFO without a writer: opening it would block forever.
    let fifo = dir.join("pipe.obj");
    let made = std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo runs");
    assert!(made.success());
    let (e, msg) = err_within(&fifo);
    assert!(matches!(e, MeshError::Io { .. }), "{e:?}");
    assert!(msg.contains("not a regular file: a FIFO"), "{msg}");
    // The same FIFO as a frame of an animation directory, beside a good frame: the directory reader names it.
    std::fs::write(dir.join("a.obj"), format!("{TRIANGLE}f 1 2 3\n")).unwrap();
    let d = dir.clone();
    let e = within(20, "animation with a FIFO", move || load_path(&d)).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, MeshError::Io { .. }) && msg.contains(&fifo.display().to_string()), "{msg}");
    assert!(msg.contains("FIFO"), "{msg}");
    std::fs::remove_file(&fifo).unwrap();
    // A directory named like a frame is refused too, naming it.
    let sub = dir.join("b.ply");
    std::fs::create_dir(&sub).unwrap();
    let e = load_path(&dir).unwrap_err();
    assert!(e.to_string().contains(&sub.display().to_string()) && e.to_string().contains("a directory"), "{e}");
    std::fs::remove_dir(&sub).unwrap();
    assert_eq!(load_path(&dir).unwrap().frames.len(), 1);
}

#[test]
fn messages_stay_short_on_huge_lines_and_names() {
    let long = "9".repeat(1 << 20);
    // Within `MAX_PLY_HEADER_BYTES` (two of them), so that the header parser meets the names.
    let name_long = "n".repeat(1 << 18);
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("long-corner.obj", format!("{TRIANGLE}f 1 2 3x{long}\n").into_bytes()),
        ("long-vertex.obj", format!("v 0 0 {long}x\n{TRIANGLE}f 1 2 3\n").into_bytes()),
        ("long-header.ply", format!("ply\nformat ascii 1.0\nbogus {long}\nend_header\n").into_bytes()),
        (
            "long-name.ply",
            format!("ply\nformat ascii 1.0\nelement {name_long} 5\nelement {name_long} 0\nend_header\n").into_bytes(),
        ),
        (
            "long-line.ply",
            format!(
                "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                 end_header\n0 0 0\n1 0 0 {long}x\n0 1 0\n"
            )
            .into_bytes(),
        ),
    ];
    for (name, bytes) in cases {
        let p = temp_file(name, &bytes);
        let (_, msg) = err_within(&p);
        let own = msg.len() - p.display().to_string().len();
        assert!(own < 600, "{name}: a message of {own} bytes: {}", &msg[..msg.len().min(2000)]);
        if name.contains("name") {
            assert!(msg.contains("..."), "{name}: {msg}");
        }
    }
}

// ------------------------------------------------------------------------------------------------------------------
// Memory: peak heap per input byte (counted per thread by the allocator of this test binary)
// ------------------------------------------------------------------------------------------------------------------

mod heap {
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::cell::Cell;

    /// The system allocator, counting the bytes live on each thread and their peak.
    pub struct Counting;

    thread_local! {
        static LIVE: Cell<isize> = const { Cell::new(0) };
        static PEAK: Cell<isize> = const { Cell::new(0) };
    }

    fn add(delta: isize) {
        let _ = LIVE.try_with(|live| {
            let v = live.get() + delta;
            live.set(v);
            let _ = PEAK.try_with(|p| {
                if v > p.get() {
                    p.set(v)
                }
            });
        });
    }

    unsafe impl GlobalAlloc for Counting {
        unsafe fn alloc(&self, l: Layout) -> *mut u8 {
            let p = unsafe { System.alloc(l) };
            if !p.is_null() {
                add(l.size() as isize);
            }
            p
        }
        unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
            let p = unsafe { System.alloc_zeroed(l) };
            if !p.is_null() {
                add(l.size() as isize);
            }
            p
        }
        unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
            unsafe { System.dealloc(p, l) };
            add(-(l.size() as isize));
        }
        unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
            let q = unsafe { System.realloc(p, l, new) };
            if !q.is_null() {
                // Counted as a move: the old and the new block are both live while the bytes are copied.
                add(new as isize);
                add(-(l.size() as isize));
            }
            q
        }
    }

    /// Runs `f` and returns its result with the peak of heap bytes it had live at once on this thread.
    pub fn peak<T>(f: impl FnOnce() -> T) -> (T, usize) {
        let start = LIVE.with(Cell::get);
        PEAK.with(|p| p.set(start));
        let r = f();
        let top = PEAK.with(Cell::get) - start;
        (r, top.max(0) as usize)
    }
}

#[global_allocator]
static HEAP: heap::Counting = heap::Counting;

/// Inputs built to cost the loaders the most memory per byte, each about `n` bytes, and the triangles they hold.
fn memory_hungry_inputs(n: usize) -> Vec<(&'static str, Vec<u8>, usize)> {
    let repeat = |unit: &str, head: &str| {
        let mut s = head.to_string();
        while s.len() < n {
            s.push_str(unit);
        }
        s.into_bytes()
    };
    let count = |b: &[u8], pat: &[u8]| b.windows(pat.len()).filter(|w| *w == pat).count();
    // Triangles of a file whose last face is a long polygon: its corners minus 2.
    let polygon = |b: &[u8]| {
        let last = b.split(|&c| c == b'\n').rfind(|l| l.starts_with(b"f ")).unwrap_or_default();
        last.split(|&c| c == b' ').count() - 1 - 2
    };
    let mut out = Vec::new();
    let b = repeat("v 0 0 0\n", "f 1 2 3\n");
    let nt = 1;
    out.push(("obj vertices", b, nt));
    let b = repeat("f 1 2 3\n", TRIANGLE);
    let nt = count(&b, b"f ");
    out.push(("obj triangles", b, nt));
    let b = repeat("f 1/1/1 2/1/1 3/1/1\n", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n");
    let nt = count(&b, b"f ");
    out.push(("obj triangles v/vt/vn", b, nt));
    let b = repeat("g\nf 1 2 3\n", TRIANGLE);
    let nt = count(&b, b"f ");
    out.push(("obj one-triangle groups", b, nt));
    let mut b = repeat(" 1", &format!("{TRIANGLE}f 1 2 3"));
    b.push(b'\n');
    let nt = polygon(&b);
    out.push(("obj long polygon", b, nt));
    let mut b = repeat(" 1", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\nf 1/1/1 2/1/1 3/1/1");
    b.push(b'\n');
    let nt = polygon(&b);
    out.push(("obj long polygon v/vt/vn", b, nt));
    let b = repeat("f 1\n", &format!("{TRIANGLE}f 1 2 3\n"));
    out.push(("obj points", b, 1));
    let b = repeat("g\nf 1\n", &format!("{TRIANGLE}f 1 2 3\n"));
    out.push(("obj groups of one point", b, 1));
    let b = repeat("l 1 2\n", &format!("{TRIANGLE}f 1 2 3\n"));
    out.push(("obj polylines", b, 1));

    // Binary PLY, uchar coordinates and uchar lists: 3 bytes a vertex, 4 bytes a triangle, 1 byte an empty face.
    let ply = |nv: usize, element: &str, items: usize, count: &str, index: &str, payload: &[u8]| {
        let mut b = format!(
            "ply\nformat binary_little_endian 1.0\nelement vertex {nv}\nproperty uchar x\nproperty uchar y\n\
             property uchar z\nelement {element} {items}\nproperty list {count} {index} vertex_indices\nend_header\n"
        )
        .into_bytes();
        b.extend_from_slice(payload);
        b
    };
    let nv = n / 3;
    let mut payload: Vec<u8> = (0..nv).flat_map(|i| [i as u8, (i >> 8) as u8, (i >> 16) as u8]).collect();
    payload.extend_from_slice(&[3, 0, 1, 2]);
    out.push(("ply vertices", ply(nv, "face", 1, "uchar", "uchar", &payload), 1));
    let nf = n / 4;
    let payload: Vec<u8> =
        [[0u8; 3], [1, 0, 0], [0, 1, 0]].concat().into_iter().chain((0..nf).flat_map(|_| [3u8, 0, 1, 2])).collect();
    out.push(("ply triangles", ply(3, "face", nf, "uchar", "uchar", &payload), nf));
    let payload: Vec<u8> = [[0u8; 3], [1, 0, 0], [0, 1, 0]]
        .concat()
        .into_iter()
        .chain([3u8, 0, 1, 2])
        .chain(std::iter::repeat_n(0u8, n))
        .collect();
    out.push(("ply empty faces", ply(3, "face", n + 1, "uchar", "uchar", &payload), 1));
    let strip: Vec<u8> = (0..n).map(|i| (i % 3) as u8).collect();
    let mut payload: Vec<u8> = [[0u8; 3], [1, 0, 0], [0, 1, 0]].concat();
    payload.extend_from_slice(&(n as u32).to_le_bytes());
    payload.extend_from_slice(&strip);
    out.push(("ply strip", ply(3, "tristrips", 1, "uint", "char", &payload), n - 2));
    let mut payload: Vec<u8> = [[0u8; 3], [1, 0, 0], [0, 1, 0]].concat();
    payload.extend_from_slice(&(n as u32).to_le_bytes());
    payload.extend(std::iter::repeat_n(0u8, n));
    out.push(("ply long polygon", ply(3, "face", 1, "uint", "uchar", &payload), n - 2));

    // Ascii PLY.
    let head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n";
    let b = {
        let faces = n / 8;
        let mut s = format!(
            "{head}element face {faces}\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n"
        );
        for _ in 0..faces {
            s.push_str("3 0 1 2\n");
        }
        (s.into_bytes(), faces)
    };
    out.push(("ply ascii triangles", b.0, b.1));
    let k = n / 2;
    let mut s = format!(
        "{head}element tristrips 1\nproperty list int int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n{k}"
    );
    for i in 0..k {
        s.push_str([" 0", " 1", " 2"][i % 3]);
    }
    s.push('\n');
    out.push(("ply ascii strip", s.into_bytes(), k - 2));
    out
}

#[test]
fn loading_stays_within_the_stated_memory_bound() {
    use meshchar::mesh::load::{LOAD_BYTES_FIXED, LOAD_BYTES_PER_INPUT_BYTE};
    let mut worst = (0.0f64, "");
    // Several sizes per shape, so that some land just past a power of two, where growing vectors are half empty
    // (MESHCHAR_MEMORY_SWEEP=1 tries 24 sizes from 1 to 2.5 MiB).
    let sizes: Vec<usize> = match std::env::var("MESHCHAR_MEMORY_SWEEP") {
        Ok(_) => (0..24).map(|k| (1usize << 20) + k * (1 << 16)).collect(),
        Err(_) => vec![1 << 20, 1_400_000, 1_900_000],
    };
    for (what, bytes, triangles) in sizes.iter().flat_map(|&n| memory_hungry_inputs(n)) {
        let ext = if what.starts_with("obj") { "obj" } else { "ply" };
        let p = temp_file(&format!("hungry.{ext}"), &bytes);
        let (m, peak) = heap::peak(|| load_mesh(&p));
        let m = m.unwrap_or_else(|e| panic!("{what}: {e}"));
        assert_eq!(m.triangle_count(), triangles, "{what}");
        drop(m);
        let per_byte = peak as f64 / bytes.len() as f64;
        eprintln!("{what:28} {:>9} bytes  peak {:>11} bytes  {per_byte:6.2} per byte", bytes.len(), peak);
        if per_byte > worst.0 {
            worst = (per_byte, what);
        }
        assert!(
            peak <= LOAD_BYTES_PER_INPUT_BYTE * bytes.len() + LOAD_BYTES_FIXED,
            "{what}: {peak} bytes at the peak for {} input bytes ({per_byte:.1} per byte)",
            bytes.len()
        );
        std::fs::remove_file(&p).unwrap();
    }
    eprintln!("worst: {what} at {per:.2} bytes per input byte", what = worst.1, per = worst.0);
    // Real meshes, for comparison.
    for rel in
        ["dabrovic-sponza/sponza.obj", "conference/conference.obj", "stanford-bunny/bun_zipper.ply", "scans/igea.ply"]
    {
        let p = shared_mesh(rel);
        let len = std::fs::metadata(&p).unwrap().len() as usize;
        let (m, peak) = heap::peak(|| load_mesh(&p));
        assert!(m.is_ok(), "{rel}");
        drop(m);
        eprintln!("{rel:28} {len:>9} bytes  peak {peak:>11} bytes  {:6.2} per byte", peak as f64 / len as f64);
        assert!(peak <= LOAD_BYTES_PER_INPUT_BYTE * len + LOAD_BYTES_FIXED, "{rel}: {peak}");
    }
    // Refused input costs no more: a header promising far more than the file holds allocates next to nothing.
    let lie =
        ply_with(&["element vertex 4000000000", "property float x", "property float y", "property float z"], &[0; 64]);
    let (r, peak) = heap::peak(|| parse_mesh("lie.ply", &lie, MeshFormat::Ply));
    assert!(r.is_err());
    assert!(peak < LOAD_BYTES_FIXED, "{peak}");
}

// ------------------------------------------------------------------------------------------------------------------
// Property test: random bytes and mutations of valid files give Ok or Err, never a panic, within a time bound
// ------------------------------------------------------------------------------------------------------------------

/// Loads `bytes` under a time bound and checks the outcome: a valid mesh with triangles, or an error naming the file
/// that is not a caught panic and stays short.
fn check_outcome(bytes: Vec<u8>, format: MeshFormat) -> Result<(), proptest::test_runner::TestCaseError> {
    let started = std::time::Instant::now();
    let r = within(10, "a proptest case", move || parse_mesh("case.mesh", &bytes, format));
    let took = started.elapsed();
    proptest::prop_assert!(took < std::time::Duration::from_secs(2), "a case took {took:?}");
    match r {
        Ok(m) => {
            proptest::prop_assert!(m.validate().is_ok());
            proptest::prop_assert!(m.triangle_count() > 0);
        }
        Err(e) => {
            let msg = e.to_string();
            proptest::prop_assert!(!matches!(e, MeshError::ParserPanic { .. }), "{msg}");
            proptest::prop_assert!(msg.starts_with("case.mesh"), "{msg}");
            proptest::prop_assert!(msg.len() < 800, "a message of {} bytes", msg.len());
        }
    }
    Ok(())
}

/// Valid files to mutate.
fn proptest_bases() -> Vec<(Vec<u8>, MeshFormat)> {
    let mut strips = PlySpec::new(Enc::Le);
    strips.element = "tristrips";
    strips.count = Ty::UInt;
    strips.faces = vec![vec![0, 1, 2, 3, -1, 4, 5, 0]];
    let obj = "# c\nmtllib x.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0 1\nv 1 1 1\nvt 0 0\nvt 1 0\nvn 0 0 1\no a\nusemtl m\n\
               f 1/1/1 2/2/1 3/1/1\nf 2//1 3//1 4//1\ng b\nf -1 -2 -3 1\nl 1 2\nf 1\n";
    vec![
        (ply_bytes(&PlySpec::new(Enc::Le)), MeshFormat::Ply),
        (ply_bytes(&PlySpec::new(Enc::Be)), MeshFormat::Ply),
        (ply_bytes(&PlySpec::new(Enc::Ascii)), MeshFormat::Ply),
        (ply_bytes(&strips), MeshFormat::Ply),
        (obj.as_bytes().to_vec(), MeshFormat::Obj),
    ]
}

/// Tokens that mutations insert: numbers at the edges of the integer types, OBJ and PLY keywords, separators.
const TOKENS: [&str; 30] = [
    "-1",
    "0",
    "-2147483648",
    "4294967295",
    "18446744073709551615",
    "6148914691236517206",
    "9223372036854775807",
    "-9223372036854775808",
    "1e39",
    "nan",
    "\n",
    "\r\n",
    " ",
    "/",
    "//",
    "f ",
    "v ",
    "vt ",
    "vn ",
    "o ",
    "l ",
    "element ",
    "property ",
    "list ",
    "uint ",
    "char ",
    "double ",
    "end_header\n",
    "\0",
    "\u{3000}",
];

#[derive(Clone, Debug)]
enum Edit {
    /// Set the byte at a position.
    Byte(usize, u8),
    /// Insert a token at a position.
    Insert(usize, usize),
    /// Delete a range.
    Delete(usize, usize),
    /// Duplicate a range in place.
    Repeat(usize, usize, u8),
    /// Cut the file.
    Truncate(usize),
}

fn apply(edits: &[Edit], mut b: Vec<u8>) -> Vec<u8> {
    for e in edits {
        let n = b.len().max(1);
        match *e {
            Edit::Byte(at, v) => {
                if let Some(x) = b.get_mut(at % n) {
                    *x = v;
                }
            }
            Edit::Insert(at, t) => {
                let at = (at % n).min(b.len());
                b.splice(at..at, TOKENS[t % TOKENS.len()].bytes());
            }
            Edit::Delete(at, len) => {
                let at = (at % n).min(b.len());
                let end = (at + len % 64).min(b.len());
                b.drain(at..end);
            }
            Edit::Repeat(at, len, times) => {
                let at = (at % n).min(b.len());
                let end = (at + len % 256).min(b.len());
                let piece = b[at..end].to_vec();
                for _ in 0..times % 16 {
                    b.splice(at..at, piece.iter().copied());
                }
            }
            Edit::Truncate(at) => b.truncate(at % n),
        }
    }
    b
}

fn edit_strategy() -> impl proptest::strategy::Strategy<Value = Edit> {
    use proptest::prelude::*;
    prop_oneof![
        4 => (any::<usize>(), any::<u8>()).prop_map(|(a, v)| Edit::Byte(a, v)),
        4 => (any::<usize>(), any::<usize>()).prop_map(|(a, t)| Edit::Insert(a, t)),
        1 => (any::<usize>(), any::<usize>()).prop_map(|(a, l)| Edit::Delete(a, l)),
        1 => (any::<usize>(), any::<usize>(), any::<u8>()).prop_map(|(a, l, t)| Edit::Repeat(a, l, t)),
        1 => any::<usize>().prop_map(Edit::Truncate),
    ]
}

proptest::proptest! {
    #![proptest_config(proptest::test_runner::Config { cases: 300, ..proptest::test_runner::Config::default() })]

    #[test]
    fn random_bytes_load_or_fail_cleanly(
        bytes in proptest::collection::vec(proptest::arbitrary::any::<u8>(), 0..3000),
        ply in proptest::arbitrary::any::<bool>(),
        magic in proptest::arbitrary::any::<bool>(),
    ) {
        let mut b = if magic && ply { b"ply\nformat binary_little_endian 1.0\n".to_vec() } else { Vec::new() };
        b.extend_from_slice(&bytes);
        check_outcome(b, if ply { MeshFormat::Ply } else { MeshFormat::Obj })?;
    }

    #[test]
    fn mutated_valid_files_load_or_fail_cleanly(
        base in 0..5usize,
        edits in proptest::collection::vec(edit_strategy(), 1..8),
    ) {
        let (bytes, format) = proptest_bases().swap_remove(base);
        check_outcome(apply(&edits, bytes), format)?;
    }
}

/// A PLY header that does not end within `MAX_PLY_HEADER_BYTES` is refused before the header parser copies it (a
/// file of gigabytes without a line end used to abort on memory); a long comment within the limit still parses.
#[test]
fn a_ply_header_past_the_limit_is_refused_and_one_within_it_parses() {
    use meshchar::mesh::load::MAX_PLY_HEADER_BYTES;
    let with_comment = |len: usize| {
        let mut b = b"ply\nformat ascii 1.0\ncomment ".to_vec();
        b.extend(std::iter::repeat_n(b'x', len));
        b.extend_from_slice(b"\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n");
        b.extend_from_slice(b"element face 1\nproperty list uchar int vertex_indices\nend_header\n");
        b.extend_from_slice(b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
        b
    };
    let short = with_comment(MAX_PLY_HEADER_BYTES / 2);
    let m = parse_mesh("long-comment.ply", &short, MeshFormat::Ply).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(m.triangle_count(), 1);
    let long = with_comment(MAX_PLY_HEADER_BYTES);
    match parse_mesh("endless.ply", &long, MeshFormat::Ply) {
        Err(MeshError::Parse { file, place, reason }) => {
            assert_eq!((file.as_str(), place.as_str()), ("endless.ply", "header"));
            assert!(reason.contains("end_header") && reason.contains(&MAX_PLY_HEADER_BYTES.to_string()), "{reason}");
        }
        other => panic!("expected a header error, got {other:?}"),
    }
    // No line end at all: the same.
    let mut endless = b"ply\nformat ascii 1.0\ncomment ".to_vec();
    endless.resize(MAX_PLY_HEADER_BYTES + 10, b'x');
    assert!(matches!(parse_mesh("endless.ply", &endless, MeshFormat::Ply), Err(MeshError::Parse { .. })));
}
