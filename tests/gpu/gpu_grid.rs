//! The device grid builder (`meshchar::accel::gpu::grid`) against the host grid: the resolution, every cell's list
//! (its triangles and their order) and the reference count equal the host grid's on the shared meshes, the
//! degenerate generators and random soups, with default and other options; budgets fail as on the host; a recorded
//! build with too small a reference array says how many it needs; the device-built grid traces like the host
//! grid, ray by ray and count by count. With the validation layer on; fails (never skips) under `REQUIRE_GPU=1`.

use crate::common;
use crate::gpu_support;

use meshchar::accel::device_trace::{DeviceLayout, DeviceTracer, TraceRay};
use meshchar::accel::gpu::grid::{triangle_bounds, GridBuildError, GridBuilder, GridPlan};
use meshchar::accel::grid::{Grid, GridOptions};
use meshchar::accel::{AccelError, AccelStructure};
use meshchar::geom::{Ray, TraceCounters};
use meshchar::gpu::{Context, MeshBuffers};
use meshchar::mesh::{generate, load::load_mesh, Mesh};

/// The host grid's resolution, cell starts and references.
fn host_lists(grid: &Grid) -> ([u32; 3], Vec<u32>, Vec<u32>) {
    match grid.device_layout() {
        DeviceLayout::Grid { res, cell_start, refs, .. } => (res, cell_start.to_vec(), refs.to_vec()),
        _ => unreachable!("a grid's layout is a grid"),
    }
}

/// Builds `mesh`'s grid on the device and on the host with `o` and compares them; returns the references, or the
/// error both gave.
fn compare(ctx: &Context, builder: &GridBuilder, what: &str, mesh: &Mesh, o: &GridOptions) -> Result<u64, String> {
    let buffers = MeshBuffers::upload(ctx, &mesh.positions, &mesh.indices).unwrap();
    let host = Grid::build_with(mesh, o);
    // The host finds the coincident copies; the device build skips them (tested without copies too: the flags are
    // then all zero, and a build without them must give the same lists).
    let flags = meshchar::accel::grid::copy_flags(mesh).expect("copy flags");
    let device = if flags.contains(&1) {
        let copies = ctx.upload("copy flags", &flags).unwrap();
        builder.build_with_copies(&buffers.view(), &triangle_bounds(mesh), o, &copies)
    } else {
        builder.build(&buffers.view(), &triangle_bounds(mesh), o)
    };
    match (host, device) {
        (Ok(h), Ok(d)) => {
            let (res, starts, refs) = host_lists(&h);
            assert_eq!(d.plan().frame().res, res, "{what}: resolution");
            let (dstarts, drefs) = d.read_back(ctx).unwrap();
            assert_eq!(d.reference_count(), Some(refs.len() as u64), "{what}: references");
            if let Some(c) = (0..starts.len()).find(|&c| starts[c] != dstarts[c]) {
                panic!("{what}: cell start {c}: host {}, device {}", starts[c], dstarts[c]);
            }
            if let Some(k) = (0..refs.len()).find(|&k| refs[k] != drefs[k]) {
                panic!("{what}: reference {k}: host {}, device {}", refs[k], drefs[k]);
            }
            Ok(refs.len() as u64)
        }
        (
            Err(AccelError::OverBudget { what: hw, budget: hb, .. }),
            Err(GridBuildError::Accel(AccelError::OverBudget { what: dw, budget: db, needed, .. })),
        ) => {
            assert_eq!((hw, hb), (dw, db), "{what}: budget errors");
            assert!(needed > db, "{what}: needs {needed} over a budget of {db}");
            Err(format!("over budget: {needed}"))
        }
        (h, d) => panic!("{what}: host {:?}, device {:?}", h.map(|g| g.references()), d.map(|g| g.reference_count())),
    }
}

trait References {
    fn references(&self) -> usize;
}
impl References for Grid {
    fn references(&self) -> usize {
        host_lists(self).2.len()
    }
}

#[test]
fn device_grid_equals_the_host_grid_on_shared_meshes() {
    let Some(ctx) = gpu_support::context() else { return };
    let builder = GridBuilder::new(&ctx).expect("builder");
    let o = GridOptions::default();
    for rel in [
        "small/bunny-lowres-pd.obj",
        "small/teapot-pd.obj",
        "small/suzanne.obj",
        "small/cow.obj",
        "small/fandisk.obj",
        "small/homer.obj",
        "small/spot.obj",
        "small/rocker-arm.obj",
        "stanford-bunny/bun_zipper.ply",
        "dabrovic-sponza/sponza.obj",
        "sibenik/sibenik.obj",
        "conference/conference.obj",
        "bart/robots/robots_f0000.obj",
        "stanford-dragon/dragon_vrip.ply",
    ] {
        let mesh = load_mesh(&common::shared_mesh(rel)).unwrap();
        let refs = compare(&ctx, &builder, rel, &mesh, &o).unwrap_or_else(|e| panic!("{rel}: {e}"));
        assert!(refs >= mesh.triangle_count() as u64, "{rel}: {refs} references");
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn device_grid_equals_the_host_grid_on_degenerate_and_random_scenes() {
    let Some(ctx) = gpu_support::context() else { return };
    let builder = GridBuilder::new(&ctx).expect("builder");
    let coarse = GridOptions { density: 0.5, max_resolution: 16, ..Default::default() };
    let fine = GridOptions { density: 16.0, max_resolution: 200, ..Default::default() };
    let mut scenes = common::degenerate_scenes();
    for (k, n) in [1usize, 2, 3, 17, 255, 1000, 4099].into_iter().enumerate() {
        scenes.push(("random soup", generate::random_soup(n, 100 + k as u64)));
    }
    // Coincident copies over vertices of their own: 5,000 of one large triangle (each would cover about half the
    // cells), and a soup with every 5th triangle copied at the end; both grids store each group once.
    let mut stack = Mesh { name: "copies".into(), ..Default::default() };
    for k in 0..5_000u32 {
        stack.positions.extend([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        stack.indices.push([3 * k, 3 * k + 1, 3 * k + 2]);
    }
    scenes.push(("copies of one triangle", stack));
    let mut soup = generate::random_soup(600, 9);
    for t in soup.indices.clone().into_iter().step_by(5) {
        let base = soup.positions.len() as u32;
        let v: Vec<[f32; 3]> = t.iter().map(|&i| soup.positions[i as usize]).collect();
        soup.positions.extend(v);
        soup.indices.push([base, base + 1, base + 2]);
    }
    scenes.push(("soup with copies", soup));
    for (name, mesh) in &scenes {
        for (label, o) in [("default", GridOptions::default()), ("coarse", coarse), ("fine", fine)] {
            let what = format!("{name} ({} triangles, {label})", mesh.triangle_count());
            if let Err(e) = compare(&ctx, &builder, &what, mesh, &o) {
                // Only the quadratic scenes may run over the default budget or (on a CPU driver) its loop limit.
                assert!(matches!(*name, "all equal" | "overlapping large" | "fan"), "{what}: {e}");
            }
        }
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

/// Budgets: a tight reference budget and a tight byte budget fail on the device as on the host, with the budget
/// the host names and a count above it; the cells are left untouched.
#[test]
fn device_grid_budgets_fail_like_the_host() {
    let Some(ctx) = gpu_support::context() else { return };
    let builder = GridBuilder::new(&ctx).expect("builder");
    let refs = GridOptions { max_references_per_triangle: 2, min_reference_budget: 0, ..Default::default() };
    let bytes = GridOptions { max_bytes: 100_000, ..Default::default() };
    for (name, mesh) in [("fan", generate::fan_polygon(2000)), ("all equal", generate::all_equal(1000))] {
        for (label, o) in [("references", refs), ("bytes", bytes)] {
            let e = compare(&ctx, &builder, &format!("{name} {label}"), &mesh, &o).expect_err("over budget");
            assert!(e.starts_with("over budget"), "{name} {label}: {e}");
        }
    }
    let empty = Mesh::default();
    let buffers = MeshBuffers::upload(&ctx, &empty.positions, &empty.indices).unwrap();
    let e = builder.build(&buffers.view(), &triangle_bounds(&empty), &GridOptions::default()).unwrap_err();
    assert!(matches!(e, GridBuildError::Input(_)), "{e}");
    gpu_support::assert_no_validation_messages(&ctx);
}

/// A build recorded into the caller's command buffer with a reference array too small reports how many references
/// it needs and writes no cell; recorded again with that capacity, it equals the host grid.
#[test]
fn recorded_device_grid_reports_its_capacity_and_then_fits() {
    let Some(ctx) = gpu_support::context() else { return };
    let builder = GridBuilder::new(&ctx).expect("builder");
    let mesh = load_mesh(&common::shared_mesh("small/teapot-pd.obj")).unwrap();
    let o = GridOptions::default();
    let host = Grid::build_with(&mesh, &o).unwrap();
    let (_, starts, refs) = host_lists(&host);
    let buffers = MeshBuffers::upload(&ctx, &mesh.positions, &mesh.indices).unwrap();
    let view = buffers.view();
    let plan = GridPlan::new(&triangle_bounds(&mesh), view.triangle_count(), &o).unwrap();
    let small = plan.with_capacity(mesh.triangle_count() as u64);
    let mut g = gpu_support::in_caller_command_buffer(&ctx, |rec| builder.record(rec, &view, &small)).unwrap();
    assert!(g.is_pending());
    match g.finish() {
        Err(GridBuildError::Capacity { needed, capacity }) => {
            assert_eq!((needed, capacity), (refs.len() as u64, mesh.triangle_count() as u64));
        }
        other => panic!("expected a capacity error, got {other:?}"),
    }
    let fits = plan.with_capacity(refs.len() as u64);
    let mut g = gpu_support::in_caller_command_buffer(&ctx, |rec| builder.record(rec, &view, &fits)).unwrap();
    g.finish().unwrap();
    let (dstarts, drefs) = g.read_back(&ctx).unwrap();
    assert_eq!((dstarts, drefs), (starts, refs));
    assert!(g.timings().iter().any(|(n, _)| n == "grid_sort"), "{:?}", g.timings());
    // Recorded with the copies' flags, a mesh of copies gives the host grid's lists, one triangle's references.
    let mut copies = Mesh { name: "copies".into(), ..Default::default() };
    for k in 0..2_000u32 {
        copies.positions.extend([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        copies.indices.push([3 * k, 3 * k + 1, 3 * k + 2]);
    }
    let host = Grid::build_with(&copies, &o).unwrap();
    let (_, starts, refs) = host_lists(&host);
    assert!(refs.iter().all(|&r| r == 0), "only the first copy is in a cell");
    let flags = ctx.upload("copy flags", &meshchar::accel::grid::copy_flags(&copies).unwrap()).unwrap();
    let buffers = MeshBuffers::upload(&ctx, &copies.positions, &copies.indices).unwrap();
    let view = buffers.view();
    let plan =
        GridPlan::new(&triangle_bounds(&copies), view.triangle_count(), &o).unwrap().with_capacity(refs.len() as u64);
    let mut g =
        gpu_support::in_caller_command_buffer(&ctx, |rec| builder.record_with_copies(rec, &view, &plan, &flags))
            .unwrap();
    g.finish().unwrap();
    assert_eq!(g.read_back(&ctx).unwrap(), (starts, refs));
    gpu_support::assert_no_validation_messages(&ctx);
}

/// The device-built grid, handed to the traversal kernel without a read-back, gives the host grid's hits and counts
/// on every ray.
#[test]
fn device_built_grid_traces_like_the_host_grid() {
    let Some(ctx) = gpu_support::context() else { return };
    let builder = GridBuilder::new(&ctx).expect("builder");
    let tracer = DeviceTracer::new(&ctx).expect("tracer");
    for (name, mesh) in [
        ("bunny", load_mesh(&common::shared_mesh("stanford-bunny/bun_zipper.ply")).unwrap()),
        ("flat", generate::flat(2000, 6)),
        ("stadium", generate::teapot_in_stadium(5)),
    ] {
        let host = Grid::build_with(&mesh, &GridOptions::default()).unwrap();
        let buffers = MeshBuffers::upload(&ctx, &mesh.positions, &mesh.indices).unwrap();
        let g = builder.build(&buffers.view(), &triangle_bounds(&mesh), &GridOptions::default()).unwrap();
        let mut s = g.into_device_structure(&ctx).unwrap();
        let b = triangle_bounds(&mesh);
        let camera = meshchar::geom::Camera::frame(&b);
        let mut rays: Vec<Ray> = Vec::new();
        for y in 0..48 {
            for x in 0..48 {
                rays.push(camera.ray(x, y, 48, 48));
            }
        }
        for any in [false, true] {
            let dev: Vec<TraceRay> = rays.iter().map(TraceRay::from).collect();
            let out = tracer.trace(&ctx, &mut s, &dev, any).unwrap();
            for (i, (r, h)) in rays.iter().zip(&out.hits).enumerate() {
                let mut c = TraceCounters::default();
                let want = if any {
                    host.occluded(r, &mut c).then_some(u32::MAX)
                } else {
                    host.intersect(r, &mut c).map(|h| h.triangle)
                };
                let got = h.hit().map(|h| if any { u32::MAX } else { h.triangle });
                assert_eq!(want, got, "{name} any={any} ray {i}");
                assert_eq!((c.box_tests, c.prim_tests), (h.box_tests as u64, h.prim_tests as u64), "{name} ray {i}");
            }
        }
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

/// Two triangles over a 1024 x 1024 plane of cells (a floor under a dense soup): each needs half a million cells.
/// A device without a loop limit builds the host's grid; lavapipe, which stops a loop after 65,535 iterations, must
/// report it ([`GridBuildError::LoopLimit`]) rather than return a wrong grid (without the check it returned one).
#[test]
fn a_cut_loop_fails_the_build_instead_of_lying() {
    let Some(ctx) = gpu_support::context() else { return };
    let builder = GridBuilder::new(&ctx).expect("builder");
    let mut mesh = generate::random_soup(20_000, 3);
    for p in mesh.positions.iter_mut() {
        p[1] *= 1e-3;
    }
    let base = mesh.positions.len() as u32;
    mesh.positions.extend([[-1.0, 0.0, -1.0], [2.0, 0.0, -1.0], [2.0, 0.0, 2.0], [-1.0, 0.0, 2.0]]);
    mesh.indices.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
    let o = GridOptions { density: 64.0, ..Default::default() };
    let host = Grid::build_with(&mesh, &o).unwrap();
    let buffers = MeshBuffers::upload(&ctx, &mesh.positions, &mesh.indices).unwrap();
    let got = builder.build(&buffers.view(), &triangle_bounds(&mesh), &o);
    let (res, starts, refs) = host_lists(&host);
    assert!(res[0] * res[2] >= 1 << 19, "resolution {res:?}: the floor must cover many cells");
    match got {
        Ok(g) => {
            assert_ne!(ctx.caps().device_type, meshchar::gpu::DeviceType::Cpu, "lavapipe must reach its loop limit");
            assert_eq!(g.read_back(&ctx).unwrap(), (starts, refs));
        }
        Err(GridBuildError::LoopLimit { .. }) => {
            assert_eq!(ctx.caps().device_type, meshchar::gpu::DeviceType::Cpu, "only a CPU driver cuts loops");
        }
        Err(e) => panic!("unexpected error: {e}"),
    }
    gpu_support::assert_no_validation_messages(&ctx);
}
