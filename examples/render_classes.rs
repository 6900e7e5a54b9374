//! Ray traces a mesh with every triangle coloured by its equivalence class (the thesis's Figures 4.6 and 5.1),
//! with a legend of class sizes, into a PNG; also writes a `.json` legend beside it.
//!
//! ```text
//! cargo run --release --example render_classes -- FILE|DIR --out FILE.png [--resolution N] [--frame K]
//!     [--backend vulkan|cpu|naive] [--morton-bits 30|63]
//! ```

use anyhow::Context as _;
use clap::Parser;
use cli::args::{self, BackendArg, MortonBitsArg};
use meshchar::characterize::{Characterizer, Params};
use meshchar::eval::render::{class_colour, interior_camera, render_classes};
use std::path::PathBuf;
use std::process::ExitCode;

#[path = "support/cli.rs"]
mod cli;

/// Ray traces a mesh with every triangle coloured by its equivalence class.
///
/// Characterizes the mesh (every triangle), ray traces it from the automatic camera with each triangle in the
/// colour of its equivalence class (Lambert-shaded), and draws a legend: a bar of the class shares and each class's
/// colour with its triangle count. Writes FILE.png and FILE.json (the legend as data).
#[derive(Parser, Debug)]
#[command(name = "render_classes", args_override_self = true)]
struct Args {
    /// A mesh (.obj, .ply), or a directory: the frames of an animation (pick one with --frame)
    #[arg(value_name = "FILE|DIR")]
    input: PathBuf,
    /// The picture to write
    #[arg(long, value_name = "FILE.png")]
    out: PathBuf,
    /// Image width and render height in pixels, 16..=4096
    #[arg(long, value_name = "N", default_value_t = 512, value_parser = args::resolution(16, 4096))]
    resolution: u32,
    /// Frame of an animation
    #[arg(long, value_name = "K", default_value_t = 0)]
    frame: usize,
    #[command(flatten)]
    backend: BackendArg,
    #[command(flatten)]
    morton: MortonBitsArg,
    /// A camera inside the scene looking along it (interiors such as Sponza) [default: outside]
    #[arg(long)]
    inside: bool,
}

fn run(a: Args) -> anyhow::Result<()> {
    let anim = cli::load_path_checked(&a.input)?;
    let count = anim.frames.len();
    let mesh = anim
        .frames
        .get(a.frame)
        .with_context(|| format!("{}: frame {} of {count} frames", a.input.display(), a.frame))?;
    let mut engine = Characterizer::new(a.backend.backend)?;
    let params = Params { morton_bits: a.morton.morton_bits, keep_per_triangle: true, ..Params::default() };
    let c = engine.characterize(mesh, &params)?;
    let per = c.per_triangle.as_ref().context("the backend returned no per-triangle classes")?;
    let camera = if a.inside {
        Some(interior_camera(mesh).context(
            "--inside: no camera fits inside the mesh's bounds (empty, too thin, too large or too far out for f32)",
        )?)
    } else {
        None
    };
    let img = render_classes(mesh, &per.classes, &c.histogram, a.resolution, camera)?;
    let bytes = img.encode_png()?;
    std::fs::write(&a.out, &bytes).with_context(|| a.out.display().to_string())?;
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
    let text = serde_json::to_string_pretty(&doc)?;
    std::fs::write(&json_path, text).with_context(|| json_path.display().to_string())?;
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
    cli::main_with(run)
}
