//! The one progress bar of the examples: on standard error, drawn only when standard error is a terminal and the
//! example was not asked for JSON; otherwise it prints nothing at all, and its methods only run what they are given.
//!
//! A bar counts items (scenes, cases, settings), each made of steps: [`Progress::item`] starts one with its number
//! of steps, and [`Progress::step`] (the callback the library's long runs take as `progress: &dyn Fn(&str)`, such
//! as `meshchar::eval::evaluate_scene`) advances it by one step and shows the step's text, which names the scene.
//! The estimated time left assumes that the steps still to come take as long as those done. Paths in the messages
//! are shown as their last component.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressFinish, ProgressStyle};
use std::cell::Cell;
use std::io::IsTerminal;
use std::time::Duration;

/// Positions per item: an item's steps are spread over this many positions of the bar.
const PER_ITEM: u64 = 1000;

/// A progress bar of `items` items, or nothing (see the module docs).
pub struct Progress {
    bar: Option<ProgressBar>,
    label: String,
    items: usize,
    item: Cell<usize>,
    steps: Cell<usize>,
    done: Cell<usize>,
}

impl Progress {
    /// A bar labelled `label` over `items` items (a spinner when `items` is `None`: the count is not known ahead);
    /// drawn when standard error is a terminal and `quiet` is false (pass `--json` as `quiet`).
    pub fn new(label: &str, items: Option<usize>, quiet: bool) -> Progress {
        let drawn = !quiet && std::io::stderr().is_terminal();
        let bar = drawn.then(|| {
            let (bar, template) = match items {
                Some(n) => (
                    ProgressBar::with_draw_target(Some(n.max(1) as u64 * PER_ITEM), ProgressDrawTarget::stderr()),
                    "{prefix:.bold} [{bar:30.cyan/blue}] {percent:>3}% {elapsed} (ETA {eta}) {wide_msg}",
                ),
                None => (
                    ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr()),
                    "{spinner} {prefix:.bold} {elapsed} {wide_msg}",
                ),
            };
            let style = ProgressStyle::with_template(template).expect("a valid template").progress_chars("=> ");
            bar.with_style(style).with_finish(ProgressFinish::AndClear)
        });
        let p = Progress {
            bar,
            label: label.to_string(),
            items: items.unwrap_or(0),
            item: Cell::new(0),
            steps: Cell::new(1),
            done: Cell::new(0),
        };
        p.set_prefix();
        if let Some(bar) = &p.bar {
            bar.enable_steady_tick(Duration::from_millis(200));
        }
        p
    }

    /// Starts item `index` (from 0), which reports `steps` steps, with `msg` shown until its first step.
    pub fn item(&self, index: usize, steps: usize, msg: &str) {
        self.item.set(index);
        self.steps.set(steps.max(1));
        self.done.set(0);
        self.set_prefix();
        if let Some(bar) = &self.bar {
            bar.set_position(index as u64 * PER_ITEM);
            bar.set_message(shorten(msg));
        }
    }

    /// One step of the current item, `msg` shown beside the bar.
    pub fn step(&self, msg: &str) {
        let done = self.done.get();
        self.done.set(done + 1);
        if let Some(bar) = &self.bar {
            if self.items > 0 {
                let within = (done.min(self.steps.get()) as u64 * PER_ITEM) / self.steps.get() as u64;
                bar.set_position(self.item.get() as u64 * PER_ITEM + within);
            }
            bar.set_message(shorten(msg));
        }
    }

    /// Runs `f` with the bar cleared from the terminal (for output to standard output or standard error), then
    /// draws it again.
    pub fn suspend<R>(&self, f: impl FnOnce() -> R) -> R {
        match &self.bar {
            Some(bar) => bar.suspend(f),
            None => f(),
        }
    }

    /// Prints `line` on standard error above the bar.
    pub fn eprintln(&self, line: &str) {
        self.suspend(|| eprintln!("{line}"));
    }

    /// Clears the bar (dropping it does too).
    pub fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }

    fn set_prefix(&self) {
        if let Some(bar) = &self.bar {
            if self.items > 1 {
                bar.set_prefix(format!("{} {}/{}", self.label, self.item.get() + 1, self.items));
            } else {
                bar.set_prefix(self.label.clone());
            }
        }
    }
}

/// `msg` with every path in it (a word with a `/` and a letter) shown as its last component, since scene names are
/// often long paths: `../meshes/bunny.ply: frame 1/2` -> `bunny.ply: frame 1/2`.
fn shorten(msg: &str) -> String {
    msg.split(' ')
        .map(|word| {
            let body = word.trim_end_matches([':', ',', ')']);
            if body.contains('/') && body.chars().any(char::is_alphabetic) {
                let name = body.trim_end_matches('/').rsplit('/').next().unwrap_or(body);
                format!("{name}{}", &word[body.len()..])
            } else {
                word.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}
