//! Ray traces a mesh with every triangle coloured by its equivalence class (the thesis's Figures 4.6 and 5.1),
//! with a legend of class sizes, into a PNG; also writes a `.json` legend beside it.
//!
//! ```text
//! cargo run --release --example render_classes -- FILE|DIR --out FILE.png [--resolution N] [--frame K]
//!     [--backend vulkan|cpu|naive] [--morton-bits 30|63]
//! ```

use meshchar::characterize::{Backend, Characterizer, MortonBits, Params};
use meshchar::eval::render::{class_colour, interior_camera, render_classes};
use meshchar::mesh::load_path;
use std::path::PathBuf;
use std::process::ExitCode;

#[path = "support/cli.rs"]
mod cli;

const USAGE: &str = "\
usage: render_classes FILE|DIR --out FILE.png [options]

Characterizes the mesh (every triangle), ray traces it from the automatic camera with each triangle in the colour
of its equivalence class (Lambert-shaded), and draws a legend: a bar of the class shares and each class's colour
with its triangle count. Writes FILE.png and FILE.json (the legend as data).

  FILE                a mesh (.obj, .ply)
  DIR                 the frames of an animation (pick one with --frame)

options:
  --out FILE.png      the picture to write (required)
  --resolution N      image width and render height in pixels, 16..=4096 (default 512)
  --frame K           frame of an animation (default 0)
  --backend B         vulkan, cpu or naive (default: vulkan when a device is found, else cpu)
  --morton-bits B     30 or 63 (default 30)
  --inside            a camera inside the scene looking along it (interiors such as Sponza; default: outside)
  -h, --help          this text";

struct Args {
    input: PathBuf,
    out: PathBuf,
    resolution: u32,
    frame: usize,
    backend: Option<Backend>,
    bits: MortonBits,
    inside: bool,
}

fn parse_args(argv: Vec<String>) -> Result<Option<Args>, String> {
    let (mut input, mut out) = (None, None);
    let (mut resolution, mut frame, mut backend, mut bits) = (512u32, 0usize, None, MortonBits::Bits30);
    let mut inside = false;
    let mut it = argv.into_iter();
    while let Some(arg) = it.next() {
        let mut value = |name: &str| it.next().ok_or_else(|| format!("{name} needs a value"));
        match arg.as_str() {
            "-h" | "--help" => return Ok(None),
            "--inside" => inside = true,
            "--out" => out = Some(PathBuf::from(value("--out")?)),
            "--resolution" => {
                resolution = value("--resolution")?
                    .parse()
                    .ok()
                    .filter(|r| (16..=4096).contains(r))
                    .ok_or("--resolution must be an integer in 16..=4096")?
            }
            "--frame" => frame = value("--frame")?.parse().map_err(|_| "--frame must be a non-negative integer")?,
            "--backend" => backend = Some(value("--backend")?.parse().map_err(|e| format!("{e}"))?),
            "--morton-bits" => {
                bits = match value("--morton-bits")?.as_str() {
                    "30" => MortonBits::Bits30,
                    "63" => MortonBits::Bits63,
                    v => return Err(format!("--morton-bits must be 30 or 63, not {v:?}")),
                }
            }
            s if s.starts_with('-') => return Err(format!("unknown option {s:?}")),
            s => {
                if input.replace(PathBuf::from(s)).is_some() {
                    return Err("give one FILE or DIR".into());
                }
            }
        }
    }
    let input = input.ok_or("missing FILE or DIR")?;
    let out = out.ok_or("missing --out FILE.png")?;
    Ok(Some(Args { input, out, resolution, frame, backend, bits, inside }))
}

fn run(a: &Args) -> Result<(), String> {
    let anim = load_path(&a.input).map_err(|e| e.to_string())?;
    let count = anim.frames.len();
    let mesh = anim
        .frames
        .get(a.frame)
        .ok_or_else(|| format!("{}: frame {} of {count} frames", a.input.display(), a.frame))?;
    let mut engine = Characterizer::new(a.backend).map_err(|e| e.to_string())?;
    let params = Params { morton_bits: a.bits, keep_per_triangle: true, ..Params::default() };
    let c = engine.characterize(mesh, &params).map_err(|e| e.to_string())?;
    let per = c.per_triangle.as_ref().ok_or("the backend returned no per-triangle classes")?;
    let camera = if a.inside {
        Some(interior_camera(mesh).ok_or("--inside: the mesh has no extent to stand in")?)
    } else {
        None
    };
    let img = render_classes(mesh, &per.classes, &c.histogram, a.resolution, camera).map_err(|e| e.to_string())?;
    let bytes = img.encode_png().map_err(|e| e.to_string())?;
    std::fs::write(&a.out, &bytes).map_err(|e| format!("{}: {e}", a.out.display()))?;
    let legend: Vec<serde_json::Value> = c
        .histogram
        .iter()
        .enumerate()
        .map(|(i, &n)| {
            let [r, g, b] = class_colour(i as u32);
            serde_json::json!({"class": i, "triangles": n, "colour": format!("#{r:02x}{g:02x}{b:02x}")})
        })
        .collect();
    let doc = serde_json::json!({
        "mesh": mesh.name,
        "frame": a.frame,
        "triangles": c.triangles,
        "classes": c.classes,
        "effect_size": c.stats.cramers_v,
        "backend": c.backend,
        "legend": legend,
    });
    let json_path = a.out.with_extension("json");
    let text = serde_json::to_string_pretty(&doc).map_err(|e| e.to_string())?;
    std::fs::write(&json_path, text).map_err(|e| format!("{}: {e}", json_path.display()))?;
    println!(
        "{}: {} triangles, k = {}, V = {:.4} [{}]; wrote {} ({} bytes, {}x{}) and {}",
        mesh.name,
        c.triangles,
        c.classes,
        c.stats.cramers_v,
        c.backend,
        a.out.display(),
        bytes.len(),
        img.width,
        img.height,
        json_path.display()
    );
    Ok(())
}

fn main() -> ExitCode {
    cli::exit_quietly_on_broken_pipe();
    cli::main_with("render_classes", USAGE, parse_args(std::env::args().skip(1).collect()), run)
}
