//! The animation readers on arbitrary frame files: the input is split into 1 to 3 files (see
//! `meshchar_fuzz::AnimationInput`), written into a scratch directory, and read with `load_path` (the directory
//! reader: `frame_files`, `load_animation`, `load_mesh`, format detection by extension) or, by a control bit, with
//! `load_animation` on the file list (format sniffed for `.txt` files).
#![no_main]

use libfuzzer_sys::fuzz_target;
use meshchar_fuzz::{check_animation, check_error, scratch_dir, AnimationInput};

fuzz_target!(|data: &[u8]| {
    let Some(input) = AnimationInput::split(data) else { return };
    let dir = scratch_dir();
    let paths = input.write(&dir);
    let r = if input.as_list { meshchar::mesh::load_animation(&paths) } else { meshchar::mesh::load_path(&dir) };
    meshchar_fuzz::report(&r, |a| format!("{} frames", a.frames.len()));
    match &r {
        Ok(a) => {
            check_animation(a);
            if !input.as_list {
                // The directory reader takes exactly the .obj and .ply files (any case), in name order.
                let frames = input.files.iter().filter(|(n, _)| !n.ends_with(".txt")).count();
                assert_eq!(a.frames.len(), frames, "frames read from the directory");
            }
        }
        Err(e) => check_error(e, &dir.display().to_string()),
    }
});
