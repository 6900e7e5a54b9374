//! Regenerates the tables of `docs/failure-study.md`: every case of the study characterized, selected by the thesis
//! policy and measured by the oracle, plus hit counts at extreme scales and the explosion's refit table.
//!
//! ```text
//! cargo run --release --example failure_study -- [--out DIR] [--backend vulkan|cpu|naive] [--resolution N]
//!     [--repeats R] [--large-n-max N] [--no-oracle] [--conference FILE]
//! ```

use anyhow::Context as _;
use clap::Parser;
use cli::args::{self, BackendArg};
use cli::Progress;
use meshchar::characterize::{Characterizer, Params};
use meshchar::eval::failure_study::{self, Case, CaseStats};
use meshchar::eval::{evaluate_scene, OracleConfig, Rebuild, SceneEvaluation};
use std::path::PathBuf;
use std::process::ExitCode;

#[path = "support/cli.rs"]
mod cli;

/// Characterizes every case of docs/failure-study.md, lets the thesis policy select, runs the oracle, and prints
/// the study's tables in markdown.
#[derive(Parser, Debug)]
#[command(name = "failure_study", args_override_self = true)]
struct Args {
    /// Also write DIR/failure-study.json (DIR is created)
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    #[command(flatten)]
    backend: BackendArg,
    /// Oracle image side
    #[arg(long, value_name = "N", default_value_t = 128, value_parser = args::resolution(1, 4096))]
    resolution: u32,
    /// Oracle repeats, 1..=100
    #[arg(long, value_name = "R", default_value_t = 3, value_parser = args::positive_max(100))]
    repeats: usize,
    /// Largest size of the large-n case
    #[arg(long, value_name = "N", default_value_t = 1_000_000)]
    large_n_max: usize,
    /// Statistics and selection only
    #[arg(long)]
    no_oracle: bool,
    /// Also characterize this mesh (the conference room: real zero-area triangles)
    #[arg(long, value_name = "FILE")]
    conference: Option<PathBuf>,
}

/// The oracle's configuration for a case of `frames` frames.
fn oracle_config(a: &Args, frames: usize) -> OracleConfig {
    OracleConfig {
        resolution: a.resolution,
        repeats: a.repeats,
        rebuild: if frames > 1 { Rebuild::PerFrame } else { Rebuild::Once },
        ..OracleConfig::default()
    }
}

fn oracle(case: &Case, stats: &CaseStats, a: &Args, bar: &Progress) -> anyhow::Result<SceneEvaluation> {
    let anim = case.animation()?;
    let config = oracle_config(a, anim.frames.len());
    let selected = Some(stats.selected);
    evaluate_scene(&anim, &config, selected, &|m| bar.step(m)).with_context(|| format!("{}: oracle", case.name))
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

fn run(args: Args) -> anyhow::Result<()> {
    let a = &args;
    let mut engine = Characterizer::new(a.backend.backend)?;
    let params = Params::default();
    let mut cases = failure_study::generated_cases(a.large_n_max)?;
    if let Some(path) = &a.conference {
        let mesh = cli::load_mesh_checked(path, cli::BYTES_PER_TRIANGLE)?;
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
    // One item per case (its characterization, then the oracle's steps), then the hit counts and the refit study.
    let bar = Progress::new("failure study", Some(cases.len() + 2), false);
    for (i, case) in cases.iter().enumerate() {
        let measured = !a.no_oracle && case.name != "conference";
        let config = oracle_config(a, case.frames.len());
        let oracle_steps = case.frames.len() * (1 + config.repeats * config.structures.len());
        bar.item(i, 1 + if measured { oracle_steps } else { 0 }, "");
        bar.step(&format!("{}: characterization", case.name));
        let stats = failure_study::characterize_case(case, &mut engine, &params).with_context(|| case.name.clone())?;
        let eval = if measured { Some(oracle(case, &stats, a, &bar)?) } else { None };
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
        bar.suspend(|| {
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
            )
        });
        json_cases.push(serde_json::json!({
            "case": case.name,
            "description": case.description,
            "stats": stats,
            "oracle": eval.as_ref().map(|e| e.to_json()),
        }));
    }

    let hit_cases: Vec<&Case> =
        cases.iter().filter(|c| ["soup_5000", "huge_1e30", "tiny_1e-30"].contains(&c.name.as_str())).collect();
    bar.item(cases.len(), hit_cases.len(), "hit counts");
    bar.suspend(|| {
        println!("\nPrimary rays hitting a triangle (automatic camera, {r}x{r}):\n", r = a.resolution);
        println!("| case | rays | BVH hits | brute-force hits |");
        println!("|---|---:|---:|---:|");
    });
    let mut json_hits = Vec::new();
    for case in hit_cases {
        bar.step(&format!("{}: hit counts", case.name));
        let h = failure_study::primary_hits(&case.frames[0], a.resolution)?;
        bar.suspend(|| println!("| {} | {} | {} | {} |", case.name, h.rays, h.bvh_hits, h.brute_hits));
        json_hits.push(serde_json::json!({"case": case.name, "hits": h}));
    }

    let mut json_refit = serde_json::Value::Null;
    bar.item(cases.len() + 1, 1, "explosion: refit study");
    if let Some(case) = cases.iter().find(|c| c.name == "explosion") {
        let anim = case.animation()?;
        let rows = failure_study::refit_study(&anim, a.resolution)?;
        bar.finish();
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
        json_refit = serde_json::to_value(&rows)?;
    }
    bar.finish();

    if let Some(dir) = &a.out {
        std::fs::create_dir_all(dir).with_context(|| dir.display().to_string())?;
        let path = dir.join("failure-study.json");
        let doc = serde_json::json!({
            "backend": backend,
            "resolution": a.resolution,
            "repeats": a.repeats,
            "cases": json_cases,
            "hits": json_hits,
            "explosion_refit": json_refit,
        });
        let text = serde_json::to_string_pretty(&doc)?;
        std::fs::write(&path, text).with_context(|| path.display().to_string())?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

fn main() -> ExitCode {
    cli::main_with(run)
}
