//! Regenerates the tables of `docs/failure-study.md`: every case of the study characterized, selected by the thesis
//! policy and measured by the oracle, plus hit counts at extreme scales and the explosion's refit table.
//!
//! ```text
//! cargo run --release --example failure_study -- [--out DIR] [--backend vulkan|cpu|naive] [--resolution N]
//!     [--repeats R] [--large-n-max N] [--no-oracle] [--conference FILE]
//! ```

use meshchar::characterize::{Backend, Characterizer, Params};
use meshchar::eval::failure_study::{self, Case, CaseStats};
use meshchar::eval::{evaluate_scene, OracleConfig, Rebuild, SceneEvaluation};
use meshchar::mesh::load_mesh;
use std::path::PathBuf;
use std::process::ExitCode;

#[path = "support/cli.rs"]
mod cli;

const USAGE: &str = "\
usage: failure_study [options]

Characterizes every case of docs/failure-study.md, lets the thesis policy select, runs the oracle, and prints the
study's tables in markdown.

options:
  --out DIR           also write DIR/failure-study.json (DIR is created)
  --backend B         vulkan, cpu or naive (default: vulkan when a device is found, else cpu)
  --resolution N      oracle image side (default 128)
  --repeats R         oracle repeats (default 3)
  --large-n-max N     largest size of the large-n case (default 1000000)
  --no-oracle         statistics and selection only
  --conference FILE   also characterize this mesh (the conference room: real zero-area triangles)
  -h, --help          this text";

struct Args {
    out: Option<PathBuf>,
    backend: Option<Backend>,
    resolution: u32,
    repeats: usize,
    large_n_max: usize,
    oracle: bool,
    conference: Option<PathBuf>,
}

fn parse_args(argv: Vec<String>) -> Result<Option<Args>, String> {
    let mut a = Args {
        out: None,
        backend: None,
        resolution: 128,
        repeats: 3,
        large_n_max: 1_000_000,
        oracle: true,
        conference: None,
    };
    let mut it = argv.into_iter();
    while let Some(arg) = it.next() {
        let mut value = |name: &str| it.next().ok_or_else(|| format!("{name} needs a value"));
        match arg.as_str() {
            "-h" | "--help" => return Ok(None),
            "--out" => a.out = Some(PathBuf::from(value("--out")?)),
            "--backend" => a.backend = Some(value("--backend")?.parse().map_err(|e| format!("{e}"))?),
            "--resolution" => {
                a.resolution = value("--resolution")?
                    .parse()
                    .ok()
                    .filter(|&r| (1..=4096).contains(&r))
                    .ok_or("--resolution must be an integer in 1..=4096")?
            }
            "--repeats" => {
                a.repeats = value("--repeats")?
                    .parse()
                    .ok()
                    .filter(|&r| (1..=100).contains(&r))
                    .ok_or("--repeats must be an integer in 1..=100")?
            }
            "--large-n-max" => {
                a.large_n_max = value("--large-n-max")?.parse().map_err(|_| "--large-n-max must be an integer")?
            }
            "--no-oracle" => a.oracle = false,
            "--conference" => a.conference = Some(PathBuf::from(value("--conference")?)),
            other => return Err(format!("unknown argument {other:?}")),
        }
    }
    Ok(Some(a))
}

fn oracle(case: &Case, stats: &CaseStats, a: &Args) -> Result<SceneEvaluation, String> {
    let anim = case.animation().map_err(|e| e.to_string())?;
    let dynamic = anim.frames.len() > 1;
    let config = OracleConfig {
        resolution: a.resolution,
        repeats: a.repeats,
        rebuild: if dynamic { Rebuild::PerFrame } else { Rebuild::Once },
        ..OracleConfig::default()
    };
    let selected = Some(stats.selected);
    evaluate_scene(&anim, &config, selected, &|_| {}).map_err(|e| format!("{}: oracle: {e}", case.name))
}

fn fmt_p(p: f64) -> String {
    if p == 0.0 {
        "0".into()
    } else if p >= 0.01 {
        format!("{p:.3}")
    } else {
        format!("{p:.1e}")
    }
}

fn run(a: &Args) -> Result<(), String> {
    let mut engine = Characterizer::new(a.backend).map_err(|e| e.to_string())?;
    let params = Params::default();
    let mut cases = failure_study::generated_cases(a.large_n_max).map_err(|e| e.to_string())?;
    if let Some(path) = &a.conference {
        let mesh = load_mesh(path).map_err(|e| e.to_string())?;
        cases.push(Case::fixed("conference", "the conference room (real zero-area triangles)", mesh));
    }
    let backend = engine.backend().name();
    println!(
        "backend {backend}; oracle: primary rays {r}x{r}, {} repeats, structures built once (per frame for the \
         explosion)\n",
        a.repeats,
        r = a.resolution
    );
    println!(
        "| case | n | k | chi-square | p | V | empty | conc. share | zero-area | selected | oracle best | regret |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---|---:|");
    let mut json_cases = Vec::new();
    for case in &cases {
        let stats =
            failure_study::characterize_case(case, &mut engine, &params).map_err(|e| format!("{}: {e}", case.name))?;
        let eval = if a.oracle && case.name != "conference" { Some(oracle(case, &stats, a)?) } else { None };
        let f = &stats.frames[0];
        let (vmin, vmax) = stats
            .frames
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), f| (lo.min(f.effect_size), hi.max(f.effect_size)));
        let v = if stats.frames.len() > 1 { format!("{vmin:.4}-{vmax:.4}") } else { format!("{:.4}", f.effect_size) };
        let best = eval.as_ref().and_then(|e| e.oracle_best).map_or("-".into(), |b| b.as_str().to_string());
        let regret = eval
            .as_ref()
            .and_then(|e| e.regret.map(|r| (r, e.regret_within_noise == Some(true))))
            .map_or("-".into(), |(r, noise)| format!("{:.0}%{}", 100.0 * r, if noise { " (noise)" } else { "" }));
        println!(
            "| {} | {} | {} | {:.1} | {} | {} | {} | {:.0}% | {} | {} | {} | {} |",
            case.name,
            f.triangles,
            f.classes,
            f.chi_square,
            fmt_p(f.p_value),
            v,
            f.empty_classes,
            100.0 * f.concentrated_share,
            f.zero_area,
            stats.selected.name(),
            best,
            regret
        );
        json_cases.push(serde_json::json!({
            "case": case.name,
            "description": case.description,
            "stats": stats,
            "oracle": eval.as_ref().map(|e| e.to_json()),
        }));
    }

    println!("\nPrimary rays hitting a triangle (automatic camera, {r}x{r}):\n", r = a.resolution);
    println!("| case | rays | BVH hits | brute-force hits |");
    println!("|---|---:|---:|---:|");
    let mut json_hits = Vec::new();
    for case in cases.iter().filter(|c| ["soup_5000", "huge_1e30", "tiny_1e-30"].contains(&c.name.as_str())) {
        let h = failure_study::primary_hits(&case.frames[0], a.resolution).map_err(|e| e.to_string())?;
        println!("| {} | {} | {} | {} |", case.name, h.rays, h.bvh_hits, h.brute_hits);
        json_hits.push(serde_json::json!({"case": case.name, "hits": h}));
    }

    let mut json_refit = serde_json::Value::Null;
    if let Some(case) = cases.iter().find(|c| c.name == "explosion") {
        let anim = case.animation().map_err(|e| e.to_string())?;
        let rows = failure_study::refit_study(&anim, a.resolution).map_err(|e| e.to_string())?;
        println!(
            "\nExplosion: frame-0 trees refitted against trees rebuilt per frame ({r}x{r} primary rays):\n",
            r = a.resolution
        );
        println!(
            "| frame | BVH SAH rebuild / refit | LBVH SAH rebuild / refit | tri tests/ray rebuild / refit | BVH build \
             / refit ms | trace ms rebuild / refit |"
        );
        println!("|---:|---|---|---|---|---|");
        for r in &rows {
            println!(
                "| {} | {:.1} / {:.1} | {:.1} / {:.1} | {:.1} / {:.1} | {:.2} / {:.3} | {:.2} / {:.2} |",
                r.frame,
                r.bvh_rebuild_sah,
                r.bvh_refit_sah,
                r.lbvh_rebuild_sah,
                r.lbvh_refit_sah,
                r.bvh_rebuild_prim_tests,
                r.bvh_refit_prim_tests,
                r.bvh_build_ms,
                r.bvh_refit_ms,
                r.bvh_rebuild_trace_ms,
                r.bvh_refit_trace_ms
            );
        }
        json_refit = serde_json::to_value(&rows).map_err(|e| e.to_string())?;
    }

    if let Some(dir) = &a.out {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        let path = dir.join("failure-study.json");
        let doc = serde_json::json!({
            "backend": backend,
            "resolution": a.resolution,
            "repeats": a.repeats,
            "cases": json_cases,
            "hits": json_hits,
            "explosion_refit": json_refit,
        });
        let text = serde_json::to_string_pretty(&doc).map_err(|e| e.to_string())?;
        std::fs::write(&path, text).map_err(|e| format!("{}: {e}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

fn main() -> ExitCode {
    cli::exit_quietly_on_broken_pipe();
    cli::main_with("failure_study", USAGE, parse_args(std::env::args().skip(1).collect()), run)
}
