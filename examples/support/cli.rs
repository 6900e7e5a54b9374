//! What the example binaries share: the parse-then-run main with its exit codes, the options and value parsers
//! several examples take ([`args`]), and the progress bar ([`progress`]). Included by
//! `#[path = "support/cli.rs"] mod cli;` (Cargo does not build this folder as an example of its own).
#![allow(dead_code)]

#[path = "args.rs"]
pub mod args;
#[path = "progress.rs"]
pub mod progress;

#[allow(unused_imports)] // not every example draws a bar
pub use progress::Progress;

use clap::{CommandFactory, Parser};
use std::process::ExitCode;

/// Parses the command line with clap and runs. Exit codes: 0 after `--help` or a successful `run`; 2 with a message
/// for a bad command line (clap's); 1 when `run` fails, with the error (and its causes, `: `-separated) prefixed by
/// the command's name, unless it is [`Reported`]; 141, quietly, on a closed standard output; 1, with the error, on
/// one that cannot be written.
pub fn main_with<A: Parser>(run: impl FnOnce(A) -> anyhow::Result<()>) -> ExitCode {
    let name = A::command().get_name().to_string();
    exit_on_output_errors(name.clone());
    let args = match A::try_parse() {
        Ok(args) => args,
        // clap prints `--help` and `--version` to standard output itself and ignores a failed write: print them
        // here, so that a help that cannot be written fails as any other output does.
        Err(e) if matches!(e.kind(), clap::error::ErrorKind::DisplayHelp | clap::error::ErrorKind::DisplayVersion) => {
            use std::io::Write;
            let written = e.print().and_then(|()| std::io::stdout().flush());
            return match written {
                Ok(()) => ExitCode::SUCCESS,
                Err(w) if w.kind() == std::io::ErrorKind::BrokenPipe => ExitCode::from(141),
                Err(w) => {
                    eprintln!("{name}: cannot write to standard output: {w}");
                    ExitCode::FAILURE
                }
            };
        }
        Err(e) => e.exit(),
    };
    match run(args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if e.is::<Reported>() => ExitCode::FAILURE,
        Err(e) => {
            eprintln!("{}: {}", A::command().get_name(), message(&e));
            ExitCode::FAILURE
        }
    }
}

/// An error and its causes, `: `-separated, leaving out a cause that the message before it already quotes (the
/// library's errors name their source in their own message).
pub fn message(e: &anyhow::Error) -> String {
    let mut out = e.to_string();
    let mut last = out.clone();
    for cause in e.chain().skip(1) {
        let text = cause.to_string();
        if !last.contains(&text) {
            out.push_str(": ");
            out.push_str(&text);
        }
        last = text;
    }
    out
}

/// The error of a run whose failures were printed as they happened: [`main_with`] exits 1 without a message.
#[derive(Debug)]
pub struct Reported;

impl std::fmt::Display for Reported {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("failed (reported above)")
    }
}

impl std::error::Error for Reported {}

/// Ends the program as clap does for a bad command line (the message, the usage, exit code 2): for the checks that
/// involve several options.
pub fn usage_error<A: CommandFactory>(kind: clap::error::ErrorKind, msg: impl std::fmt::Display) -> ! {
    A::command().error(kind, msg).exit()
}

/// Makes a closed standard output (`example | head`) end the program quietly with status 141, as a shell tool
/// would, and any other failure to write it (a full disk, `> /dev/full`) end it with the error on standard error and
/// status 1, prefixed by `name` as [`main_with`] prefixes every error, instead of a panic message: Rust ignores
/// SIGPIPE, and `println!` panics where it cannot write.
pub fn exit_on_output_errors(name: String) {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let msg = info
            .payload()
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| info.payload().downcast_ref::<&str>().copied())
            .unwrap_or("");
        if msg.contains("Broken pipe") {
            std::process::exit(141);
        }
        if let Some(why) = msg.strip_prefix("failed printing to stdout: ") {
            eprintln!("{name}: cannot write to standard output: {why}");
            std::process::exit(1);
        }
        if msg.starts_with("failed printing to stderr: ") {
            std::process::exit(1);
        }
        default(info);
    }));
}

/// The most memory a tool's work takes per triangle, as far as measured: `characterize` on a particle soup of 2M
/// triangles peaked at 1.05 GB resident (524 bytes per triangle, the city of 2M at 459), `build_bvh --builder sah`
/// at 299 and 242. [`check_memory`] reads it as the need of every tool but `build_bvh`, which passes
/// [`BUILD_BYTES_PER_TRIANGLE`].
pub const BYTES_PER_TRIANGLE: u64 = 512;

/// [`BYTES_PER_TRIANGLE`] for one build (`build_bvh`).
pub const BUILD_BYTES_PER_TRIANGLE: u64 = 320;

/// Refuses a scene of `triangles` triangles (`what` names it) whose work would need more memory than this process can
/// have, `bytes_per_triangle` each: an allocation that fails ends a Rust program with an abort and no message
/// worth the name, so a small file that expands into tens of millions of triangles (one polygon of 30 million
/// corners) is stopped here instead, with the figures. What the process can have: the system's `MemAvailable`
/// and, when set, the address-space limit (`ulimit -v`) less what the process maps already; nothing is refused
/// where neither can be read.
pub fn check_memory(what: &str, triangles: usize, bytes_per_triangle: u64) -> anyhow::Result<()> {
    match memory_refusal(triangles, bytes_per_triangle) {
        Some(why) => anyhow::bail!("{what}: {why}"),
        None => Ok(()),
    }
}

/// Why [`check_memory`] refuses `triangles` triangles at `bytes_per_triangle` (the figures), or `None`.
fn memory_refusal(triangles: usize, bytes_per_triangle: u64) -> Option<String> {
    let need = (triangles as u64).saturating_mul(bytes_per_triangle);
    match available_memory() {
        Some(have) if need > have => Some(format!(
            "{triangles} triangles need about {:.2} GiB of memory here ({bytes_per_triangle} bytes each), \
             and this process can have {:.2} GiB",
            need as f64 / GIB,
            have as f64 / GIB
        )),
        _ => None,
    }
}

/// [`check_memory`] at [`BYTES_PER_TRIANGLE`] for a scene an oracle record names, as
/// [`meshchar::eval::record::load_samples_admitted`] asks (the error names the file and the mesh itself).
pub fn admit_record_scene(_mesh: &str, triangles: usize) -> Result<(), String> {
    memory_refusal(triangles, BYTES_PER_TRIANGLE).map_or(Ok(()), Err)
}

const GIB: f64 = (1u64 << 30) as f64;

/// What this process can still allocate, as far as Linux says: the least of `MemAvailable` (`/proc/meminfo`) and
/// the soft address-space limit (`/proc/self/limits`) less the process's mapped size (`/proc/self/statm`, 4 KiB
/// pages). `None` where neither is known (another system).
fn available_memory() -> Option<u64> {
    let read = |p: &str| std::fs::read_to_string(p).ok();
    let meminfo = read("/proc/meminfo").and_then(|t| {
        let line = t.lines().find_map(|l| l.strip_prefix("MemAvailable:"))?.to_owned();
        line.trim().trim_end_matches("kB").trim().parse::<u64>().ok().map(|kb| kb.saturating_mul(1024))
    });
    let limit = read("/proc/self/limits").and_then(|t| {
        let line = t.lines().find(|l| l.starts_with("Max address space"))?.to_owned();
        // "Max address space  SOFT  HARD  bytes"; "unlimited" does not parse.
        line.split_whitespace().nth(3)?.parse::<u64>().ok()
    });
    let mapped = read("/proc/self/statm")
        .and_then(|t| t.split_whitespace().next()?.parse::<u64>().ok())
        .map_or(0, |pages| pages.saturating_mul(4096));
    match (meminfo, limit.map(|l| l.saturating_sub(mapped))) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}

/// [`meshchar::eval::scene::load_scene`] (a file, a directory of frames or a generated scene's spec), then
/// [`check_memory`] at [`BYTES_PER_TRIANGLE`] for the first frame's triangles.
#[cfg(feature = "eval")]
pub fn load_path_checked(path: &std::path::Path) -> anyhow::Result<meshchar::mesh::Animation> {
    let scene = meshchar::eval::scene::load_scene(path)?;
    let triangles = scene.frames.first().map_or(0, |f| f.triangle_count());
    check_memory(&path.display().to_string(), triangles, BYTES_PER_TRIANGLE)?;
    Ok(scene)
}

/// [`meshchar::eval::scene::load_scene_mesh`] (a file or a generated scene's spec), then [`check_memory`] at
/// `bytes_per_triangle`.
#[cfg(feature = "eval")]
pub fn load_mesh_checked(path: &std::path::Path, bytes_per_triangle: u64) -> anyhow::Result<meshchar::mesh::Mesh> {
    let mesh = meshchar::eval::scene::load_scene_mesh(path)?;
    check_memory(&path.display().to_string(), mesh.triangle_count(), bytes_per_triangle)?;
    Ok(mesh)
}
