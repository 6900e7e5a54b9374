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
/// the command's name, unless it is [`Reported`]; 141, quietly, on a closed standard output.
pub fn main_with<A: Parser>(run: impl FnOnce(A) -> anyhow::Result<()>) -> ExitCode {
    exit_quietly_on_broken_pipe();
    let args = A::parse();
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
/// status 1, instead of a panic message: Rust ignores SIGPIPE, and `println!` panics where it cannot write.
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
        if let Some(why) = msg.strip_prefix("failed printing to stdout: ") {
            let program = std::env::args().next().unwrap_or_default();
            let name = std::path::Path::new(&program).file_name().map(|n| n.to_string_lossy().into_owned());
            eprintln!("{}: cannot write to standard output: {why}", name.unwrap_or_default());
            std::process::exit(1);
        }
        if msg.starts_with("failed printing to stderr: ") {
            std::process::exit(1);
        }
        default(info);
    }));
}
