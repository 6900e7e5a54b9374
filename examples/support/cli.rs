//! What the example binaries share: the parse-then-run main with its exit codes, and loading the cost model.
//! Included by `#[path = "support/cli.rs"] mod cli;` (Cargo does not build this folder as an
//! example of its own).
#![allow(dead_code)]

use meshchar::cost::CostModel;
use std::path::Path;
use std::process::ExitCode;

/// Exit code 0 after `--help` (`Ok(None)`: `usage` printed) or a successful `run`; 2 with the usage for bad
/// arguments; 1 when `run` fails. Every message is prefixed with the binary's `name`.
pub fn main_with<A>(
    name: &str,
    usage: &str,
    parsed: Result<Option<A>, String>,
    run: impl FnOnce(&A) -> Result<(), String>,
) -> ExitCode {
    let args = match parsed {
        Ok(Some(a)) => a,
        Ok(None) => {
            println!("{}", usage.trim_end());
            return ExitCode::SUCCESS;
        }
        Err(e) => {
            eprintln!("{name}: {e}\n\n{}", usage.trim_end());
            return ExitCode::from(2);
        }
    };
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("{name}: {e}");
            ExitCode::FAILURE
        }
    }
}

/// The calibration file at `path` (an error when it is missing or invalid), the shipped defaults without one.
/// `_name` is unused since loading has no fallback warning left to print.
pub fn cost_model(_name: &str, path: Option<&Path>) -> Result<CostModel, String> {
    CostModel::load(path).map_err(|e| format!("cost model: {e}"))
}

/// Makes a closed standard output (`example | head`) end the program quietly with status 141, as a shell tool
/// would, instead of a panic message: Rust ignores SIGPIPE, so `println!` panics on a closed pipe.
pub fn exit_quietly_on_broken_pipe() {
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
        default(info);
    }));
}

/// The value of `--policy`: `thesis` or `calibrated`.
pub fn policy_arg(v: String) -> Result<String, String> {
    if v == "thesis" || v == "calibrated" {
        Ok(v)
    } else {
        Err(format!("--policy: {v:?} is not thesis or calibrated"))
    }
}

/// The value of `--tie-margin`: a share of the best predicted total in `0..=1`.
pub fn tie_margin_arg(v: &str) -> Result<f64, String> {
    v.parse()
        .ok()
        .filter(|x: &f64| (0.0..=1.0).contains(x))
        .ok_or_else(|| "--tie-margin needs a number in 0..=1".into())
}
