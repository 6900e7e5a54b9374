//! The PLY loader on arbitrary bytes: `parse_mesh(.., MeshFormat::Ply)` (the header checks, `ply-rs-bw`, the
//! item-by-item payload reader, faces and triangle strips) and the content sniffer. See `meshchar_fuzz` for the
//! checks.
#![no_main]

use libfuzzer_sys::fuzz_target;
use meshchar::mesh::MeshFormat;

#[global_allocator]
static ALLOC: meshchar_fuzz::Counting = meshchar_fuzz::Counting;

fuzz_target!(|data: &[u8]| {
    meshchar_fuzz::fuzz_parse(data, MeshFormat::Ply);
});
