//! The OBJ loader on arbitrary bytes: `parse_mesh(.., MeshFormat::Obj)` (the pre-scan, `tobj`, the error scans) and
//! the content sniffer. See `meshchar_fuzz` for the checks.
#![no_main]

use libfuzzer_sys::fuzz_target;
use meshchar::mesh::MeshFormat;

#[global_allocator]
static ALLOC: meshchar_fuzz::Counting = meshchar_fuzz::Counting;

fuzz_target!(|data: &[u8]| {
    meshchar_fuzz::fuzz_parse(data, MeshFormat::Obj);
});
