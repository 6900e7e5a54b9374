//! The example binaries run as a user runs them: the command-line tools, the engine frame, the class render.
//!
//! One binary for the layer (each module was its own test binary, linked once per file).
#[path = "../example_binary/mod.rs"]
mod example_binary;
#[path = "../gpu_support/mod.rs"]
mod gpu_support;

mod engine_frame;
mod examples_cli;
mod render_classes;
