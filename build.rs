//! The shaders ship compiled: `src/gpu/generated/spv/<name>.spv` holds the optimized SPIR-V of `glsl/<name>.comp`
//! and `src/gpu/generated/shaders.rs` (included by `src/gpu/shaders.rs`) their reflection (entry point, local size,
//! push-constant block, specialization constants, structs), the Rust structs of the push-constant blocks and of the
//! GLSL structs the host shares, and the named layout constants of `glsl/include/layout.glsl` and
//! `glsl/include/bvh.glsl`. A default build compiles no GLSL: it only warns when `glsl/` no longer matches the
//! shipped files (their header records a hash of the sources).
//!
//! With the feature `compile-glsl` (shaderc and rspirv as build dependencies), this script compiles every
//! `glsl/*.comp` afresh (shaderc, optimized, Vulkan 1.2, warnings as errors), reflects it (rspirv), generates the
//! files above and compares them with the shipped ones: the build fails when they differ, unless
//! `MESHCHAR_WRITE_SHADERS=1`, which rewrites the shipped files instead. A GLSL error fails the build with the file
//! and line that shaderc reports.
//!
//! The examples' own kernels (`examples/shaders/*.comp`: an engine's shaders, not the library's) are compiled the
//! same way into `examples/shaders/generated/` (`<name>.spv` and `<name>.rs`, the push-constant struct and the
//! words), which the examples include; the library's shader table does not hold them.

use std::path::{Path, PathBuf};

/// Where the shipped files live, relative to the package root.
const GENERATED: &str = "src/gpu/generated";
/// The environment variable that makes a `compile-glsl` build rewrite the shipped files.
const WRITE_VAR: &str = "MESHCHAR_WRITE_SHADERS";
/// The header line that records the hash of the GLSL sources.
const HASH_PREFIX: &str = "// glsl sources: fnv1a64 ";
/// The examples' own shaders, relative to the package root, and where their compiled files live.
const EXAMPLE_SHADERS: &str = "examples/shaders";
const EXAMPLE_GENERATED: &str = "examples/shaders/generated";

fn main() {
    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").expect("CARGO_MANIFEST_DIR"));
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=glsl");
    println!("cargo:rerun-if-changed={GENERATED}");
    println!("cargo:rerun-if-changed={EXAMPLE_SHADERS}");
    println!("cargo:rerun-if-env-changed={WRITE_VAR}");
    #[cfg(feature = "compile-glsl")]
    compile::run(&root);
    #[cfg(not(feature = "compile-glsl"))]
    warn_if_stale(&root);
}

/// Every GLSL source (`glsl/*.comp` and `glsl/include/*`), as (path relative to the root, text), sorted by path.
fn glsl_sources(root: &Path) -> Vec<(String, String)> {
    let mut out = Vec::new();
    for dir in ["glsl", "glsl/include"] {
        let Ok(entries) = std::fs::read_dir(root.join(dir)) else { continue };
        for e in entries.flatten() {
            let p = e.path();
            if !p.is_file() {
                continue;
            }
            let Some(name) = p.file_name().and_then(|n| n.to_str()) else { continue };
            if dir == "glsl" && !name.ends_with(".comp") {
                continue;
            }
            let text = std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            out.push((format!("{dir}/{name}"), text.replace("\r\n", "\n")));
        }
    }
    out.sort();
    out
}

/// The examples' shaders (`examples/shaders/*.comp`), as (path relative to the root, text), sorted by path.
fn example_sources(root: &Path) -> Vec<(String, String)> {
    let mut out = Vec::new();
    let Ok(entries) = std::fs::read_dir(root.join(EXAMPLE_SHADERS)) else { return out };
    for e in entries.flatten() {
        let p = e.path();
        let Some(name) = p.file_name().and_then(|n| n.to_str()) else { continue };
        if p.is_file() && name.ends_with(".comp") {
            let text = std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            out.push((format!("{EXAMPLE_SHADERS}/{name}"), text.replace("\r\n", "\n")));
        }
    }
    out.sort();
    out
}

/// The hash recorded in an example shader's generated file: its own source and the library's includes.
fn example_hash(source: &(String, String), sources: &[(String, String)]) -> u64 {
    let mut all: Vec<(String, String)> =
        sources.iter().filter(|(p, _)| p.starts_with("glsl/include/")).cloned().collect();
    all.push(source.clone());
    source_hash(&all)
}

/// FNV-1a (64 bits) of the sources' paths and texts (line ends normalized).
fn source_hash(sources: &[(String, String)]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for (path, text) in sources {
        for b in path.bytes().chain([0]).chain(text.bytes()).chain([0]) {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    h
}

#[cfg(not(feature = "compile-glsl"))]
fn warn_if_stale(root: &Path) {
    let sources = glsl_sources(root);
    if sources.is_empty() {
        return; // a package without its GLSL: nothing to compare
    }
    let shipped = std::fs::read_to_string(root.join(GENERATED).join("shaders.rs")).unwrap_or_default();
    let recorded = shipped.lines().find_map(|l| l.strip_prefix(HASH_PREFIX)).map(str::trim);
    let actual = format!("0x{:016x}", source_hash(&sources));
    if recorded != Some(actual.as_str()) {
        println!(
            "cargo:warning=glsl/ has changed since {GENERATED}/ was generated; the build uses the shipped (stale) \
             SPIR-V. Regenerate with: MESHCHAR_WRITE_SHADERS=1 cargo build --features compile-glsl"
        );
    }
    for source in example_sources(root) {
        let name = source.0.trim_start_matches(&format!("{EXAMPLE_SHADERS}/")).trim_end_matches(".comp").to_string();
        let shipped =
            std::fs::read_to_string(root.join(EXAMPLE_GENERATED).join(format!("{name}.rs"))).unwrap_or_default();
        let recorded = shipped.lines().find_map(|l| l.strip_prefix(HASH_PREFIX)).map(str::trim);
        let actual = format!("0x{:016x}", example_hash(&source, &sources));
        if recorded != Some(actual.as_str()) {
            println!(
                "cargo:warning={} has changed since {EXAMPLE_GENERATED}/{name}.rs was generated; regenerate with: \
                 MESHCHAR_WRITE_SHADERS=1 cargo build --features compile-glsl",
                source.0
            );
        }
    }
}

#[cfg(feature = "compile-glsl")]
mod compile {
    use super::{
        example_hash, example_sources, glsl_sources, source_hash, EXAMPLE_GENERATED, EXAMPLE_SHADERS, GENERATED,
        HASH_PREFIX, WRITE_VAR,
    };
    use rspirv::dr::{Instruction, Module, Operand};
    use rspirv::spirv::{BuiltIn, Decoration, ExecutionMode, Op, StorageClass};
    use std::collections::{BTreeMap, HashMap};
    use std::fmt::Write as _;
    use std::path::Path;

    /// Include files whose integer `#define`s are generated as Rust constants (`gpu::shaders::layout`).
    const LAYOUT_INCLUDES: [&str; 4] =
        ["glsl/include/bvh.glsl", "glsl/include/layout.glsl", "glsl/include/geometry.glsl", "glsl/include/trace.glsl"];

    pub fn run(root: &Path) {
        let sources = glsl_sources(root);
        let include = root.join("glsl").join("include");
        let docs = GlslDocs::parse(&sources);
        let defines = parse_defines(&sources);

        let compiler = shaderc::Compiler::new().expect("shaderc compiler");
        let mut shaders = Vec::new();
        let mut errors = Vec::new();
        for (file_name, text) in sources.iter().filter(|(p, _)| p.ends_with(".comp")) {
            let name = file_name.trim_start_matches("glsl/").trim_end_matches(".comp").to_string();
            // The optimized module is what runs; an unoptimized compile keeps the names (push-constant members,
            // specialization constants) that the optimizer strips, and is what gets reflected.
            let optimized = compile(&compiler, text, file_name, &include, true);
            let plain = compile(&compiler, text, file_name, &include, false);
            match (optimized, plain) {
                (Ok(words), Ok(plain_words)) => {
                    let module = rspirv::dr::load_words(&plain_words).unwrap_or_else(|e| panic!("{file_name}: {e}"));
                    let info = reflect(&module, file_name);
                    let opt_module = rspirv::dr::load_words(&words).unwrap_or_else(|e| panic!("{file_name}: {e}"));
                    let opt_info = reflect(&opt_module, file_name);
                    assert_eq!(
                        (opt_info.push_size, opt_info.local_size_ids, opt_info.bindings.len()),
                        (info.push_size, info.local_size_ids, info.bindings.len()),
                        "{file_name}: optimized and unoptimized reflection differ"
                    );
                    shaders.push((name, file_name.clone(), words, info));
                }
                (Err(e), _) | (_, Err(e)) => errors.push(e),
            }
        }
        if !errors.is_empty() {
            panic!("GLSL compilation failed:\n{}", errors.join("\n"));
        }

        let rust = generate(&shaders, &docs, &defines, source_hash(&sources));
        let mut files: Vec<(String, Vec<u8>)> = vec![("shaders.rs".into(), rust.into_bytes())];
        for (name, _, words, _) in &shaders {
            files.push((format!("spv/{name}.spv"), words.iter().flat_map(|w| w.to_le_bytes()).collect()));
        }
        sync(&root.join(GENERATED), &files);

        // The examples' kernels: the same compile, a file of their own each.
        let examples = example_sources(root);
        let all: Vec<(String, String)> = sources.iter().chain(&examples).cloned().collect();
        let docs = GlslDocs::parse(&all);
        let mut files: Vec<(String, Vec<u8>)> = Vec::new();
        for source in &examples {
            let (file_name, text) = source;
            let name = file_name.trim_start_matches(&format!("{EXAMPLE_SHADERS}/")).trim_end_matches(".comp");
            let words = compile(&compiler, text, file_name, &include, true).unwrap_or_else(|e| panic!("{e}"));
            let plain = compile(&compiler, text, file_name, &include, false).unwrap_or_else(|e| panic!("{e}"));
            let module = rspirv::dr::load_words(&plain).unwrap_or_else(|e| panic!("{file_name}: {e}"));
            let info = reflect(&module, file_name);
            let rust = generate_example(name, file_name, &words, &info, &docs, example_hash(source, &sources));
            files.push((format!("{name}.rs"), rust.into_bytes()));
            files.push((format!("{name}.spv"), words.iter().flat_map(|w| w.to_le_bytes()).collect()));
        }
        sync_examples(&root.join(EXAMPLE_GENERATED), &files);
    }

    /// [`sync`] for the examples' kernels in `examples/shaders/generated/`.
    fn sync_examples(dir: &Path, files: &[(String, Vec<u8>)]) {
        let differ: Vec<&String> = files
            .iter()
            .filter(|(rel, bytes)| std::fs::read(dir.join(rel)).ok().as_deref() != Some(bytes.as_slice()))
            .map(|(rel, _)| rel)
            .collect();
        let stale: Vec<String> = std::fs::read_dir(dir)
            .into_iter()
            .flatten()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| !files.iter().any(|(f, _)| f == n))
            .collect();
        if differ.is_empty() && stale.is_empty() {
            return;
        }
        let write = std::env::var(WRITE_VAR).is_ok_and(|v| !v.is_empty() && v != "0");
        if !write {
            let mut what: Vec<String> = differ.iter().map(|f| format!("{EXAMPLE_GENERATED}/{f} differs")).collect();
            what.extend(stale.iter().map(|f| format!("{EXAMPLE_GENERATED}/{f} has no shader")));
            panic!(
                "the examples' shipped shaders do not match a fresh compile of examples/shaders/:\n  {}\nRegenerate \
                 them with `{WRITE_VAR}=1 cargo build --features compile-glsl` and commit {EXAMPLE_GENERATED}/.",
                what.join("\n  ")
            );
        }
        std::fs::create_dir_all(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
        for (rel, bytes) in files {
            if differ.contains(&rel) {
                std::fs::write(dir.join(rel), bytes).unwrap_or_else(|e| panic!("{EXAMPLE_GENERATED}/{rel}: {e}"));
                println!("cargo:warning={WRITE_VAR}: wrote {EXAMPLE_GENERATED}/{rel}");
            }
        }
        for rel in &stale {
            std::fs::remove_file(dir.join(rel)).unwrap_or_else(|e| panic!("{EXAMPLE_GENERATED}/{rel}: {e}"));
            println!("cargo:warning={WRITE_VAR}: removed {EXAMPLE_GENERATED}/{rel}");
        }
    }

    /// The Rust file of an example's kernel: its push-constant struct (as the library's, without the library's
    /// layout trait), its local size's specialization id and its words.
    fn generate_example(name: &str, file: &str, words: &[u32], r: &Reflected, docs: &GlslDocs, hash: u64) -> String {
        let mut out = String::new();
        let _ = writeln!(
            out,
            "// @generated by meshchar's build.rs (feature `compile-glsl`) from {file}: do not edit.\n\
             // A build with the feature fails when this file or {name}.spv differs from a fresh compile;\n\
             // `MESHCHAR_WRITE_SHADERS=1 cargo build --features compile-glsl` rewrites them."
        );
        let _ = writeln!(out, "{HASH_PREFIX}0x{hash:016x}\n");
        if let Some(push) = &r.push {
            let mut layout =
                rust_layout(&push.members, &format!("{file}: push constants")).unwrap_or_else(|e| panic!("{e}"));
            let key = format!("{file}:{}", push.name);
            for f in layout.fields.iter_mut().filter(|f| !f.padding) {
                f.doc = field_doc(f, docs, &key);
            }
            let doc = format!("Push constants of `{file}` (`layout(push_constant) uniform {}`).", push.name);
            let mut s = String::new();
            emit_struct(&mut s, "", "Push", &doc, &layout);
            for line in s.lines().filter(|l| !l.contains("crate::push_layout!")) {
                let _ = writeln!(out, "{line}");
            }
        }
        if let Some(id) = r.local_size_ids[0] {
            let _ = writeln!(out, "/// The specialization id of the local size in x (`local_size_x_id`).");
            let _ = writeln!(out, "pub const LOCAL_SIZE_X_ID: u32 = {id};");
        }
        let _ = writeln!(
            out,
            "/// Words of the optimized SPIR-V ({} of them), shipped in `{name}.spv` beside this file.",
            words.len()
        );
        let _ = writeln!(out, "pub fn spirv() -> Vec<u32> {{");
        let _ = writeln!(out, "    include_bytes!(\"{name}.spv\").chunks_exact(4).map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]])).collect()");
        let _ = writeln!(out, "}}");
        out
    }

    /// Compares the generated files with the shipped ones; rewrites them under `MESHCHAR_WRITE_SHADERS=1`, fails
    /// otherwise.
    fn sync(dir: &Path, files: &[(String, Vec<u8>)]) {
        let mut differ = Vec::new();
        for (rel, bytes) in files {
            if std::fs::read(dir.join(rel)).ok().as_deref() != Some(bytes.as_slice()) {
                differ.push(rel.clone());
            }
        }
        // Shipped SPIR-V of shaders that no longer exist.
        let mut stale = Vec::new();
        for e in std::fs::read_dir(dir.join("spv")).into_iter().flatten().flatten() {
            let rel = format!("spv/{}", e.file_name().to_string_lossy());
            if !files.iter().any(|(f, _)| *f == rel) {
                stale.push(rel);
            }
        }
        if differ.is_empty() && stale.is_empty() {
            return;
        }
        let write = std::env::var(WRITE_VAR).is_ok_and(|v| !v.is_empty() && v != "0");
        if !write {
            let mut what: Vec<String> = differ.iter().map(|f| format!("{GENERATED}/{f} differs")).collect();
            what.extend(stale.iter().map(|f| format!("{GENERATED}/{f} has no shader")));
            panic!(
                "the shipped shaders do not match a fresh compile of glsl/:\n  {}\nRegenerate them with \
                 `{WRITE_VAR}=1 cargo build --features compile-glsl` and commit {GENERATED}/.",
                what.join("\n  ")
            );
        }
        std::fs::create_dir_all(dir.join("spv")).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
        for (rel, bytes) in files {
            if differ.contains(rel) {
                std::fs::write(dir.join(rel), bytes).unwrap_or_else(|e| panic!("{GENERATED}/{rel}: {e}"));
                println!("cargo:warning={WRITE_VAR}: wrote {GENERATED}/{rel}");
            }
        }
        for rel in &stale {
            std::fs::remove_file(dir.join(rel)).unwrap_or_else(|e| panic!("{GENERATED}/{rel}: {e}"));
            println!("cargo:warning={WRITE_VAR}: removed {GENERATED}/{rel}");
        }
    }

    fn compile(
        compiler: &shaderc::Compiler,
        text: &str,
        file_name: &str,
        include: &Path,
        optimize: bool,
    ) -> Result<Vec<u32>, String> {
        let mut options = shaderc::CompileOptions::new().map_err(|e| e.to_string())?;
        options.set_target_env(shaderc::TargetEnv::Vulkan, shaderc::EnvVersion::Vulkan1_2 as u32);
        options.set_target_spirv(shaderc::SpirvVersion::V1_5);
        options.set_optimization_level(if optimize {
            shaderc::OptimizationLevel::Performance
        } else {
            shaderc::OptimizationLevel::Zero
        });
        options.set_warnings_as_errors();
        let inc = include.to_path_buf();
        options.set_include_callback(move |requested, _ty, _from, _depth| {
            let path = inc.join(requested);
            std::fs::read_to_string(&path)
                .map(|content| shaderc::ResolvedInclude { resolved_name: path.display().to_string(), content })
                .map_err(|e| format!("{}: {e}", path.display()))
        });
        compiler
            .compile_into_spirv(text, shaderc::ShaderKind::Compute, file_name, "main", Some(&options))
            .map(|a| a.as_binary().to_vec())
            .map_err(|e| e.to_string())
    }

    // ---------------------------------------------------------------------------------------------------------
    // Reflection.

    /// The Rust type a SPIR-V type maps to in a `#[repr(C)]` mirror.
    #[derive(Clone, Debug, PartialEq)]
    struct RustType {
        /// Spelling (`u32`, `[f32; 3]`, `u64`, a struct's name).
        name: String,
        size: u32,
        align: u32,
        /// Whether `#[derive(Default)]` works (arrays up to 32 elements).
        default: bool,
    }

    #[derive(Clone, Debug, PartialEq)]
    struct Member {
        name: String,
        offset: u32,
        size: u32,
        /// The Rust type, or why there is none.
        ty: Result<RustType, String>,
    }

    struct Binding {
        name: String,
        set: u32,
        binding: u32,
        kind: &'static str,
        count: u32,
    }

    #[derive(Clone, Debug, PartialEq)]
    struct Struct {
        name: String,
        /// Decorated `Block` (a buffer or push-constant block); plain GLSL `struct`s are not.
        block: bool,
        members: Vec<Member>,
    }

    struct Reflected {
        entry: String,
        local_size: [u32; 3],
        local_size_ids: [Option<u32>; 3],
        bindings: Vec<Binding>,
        push_size: u32,
        /// GLSL name of the push-constant block's type, and its members.
        push: Option<Struct>,
        spec_constants: Vec<(String, u32)>,
        structs: Vec<Struct>,
    }

    fn lit(op: &Operand) -> u32 {
        match op {
            Operand::LiteralBit32(v) => *v,
            Operand::IdRef(v) => *v,
            other => panic!("expected a literal, found {other:?}"),
        }
    }

    struct Types<'a> {
        file: &'a str,
        defs: HashMap<u32, &'a Instruction>,
        names: HashMap<u32, String>,
        member_names: HashMap<(u32, u32), String>,
        offsets: HashMap<(u32, u32), u32>,
        strides: HashMap<u32, u32>,
        blocks: Vec<u32>,
    }

    impl Types<'_> {
        fn def(&self, id: u32) -> &Instruction {
            self.defs.get(&id).unwrap_or_else(|| panic!("{}: type {id}", self.file))
        }

        /// Size of a type in the explicit layout (offsets from decorations).
        fn size_of(&self, id: u32) -> u32 {
            let inst = self.def(id);
            match inst.class.opcode {
                Op::TypeInt | Op::TypeFloat => lit(&inst.operands[0]) / 8,
                Op::TypeBool => 4,
                Op::TypeVector | Op::TypeMatrix => lit(&inst.operands[1]) * self.size_of(lit(&inst.operands[0])),
                Op::TypePointer => 8,
                Op::TypeArray => {
                    let len = self.array_len(inst);
                    let stride = self.strides.get(&id).copied().unwrap_or_else(|| self.size_of(lit(&inst.operands[0])));
                    len * stride
                }
                Op::TypeRuntimeArray => 0,
                Op::TypeStruct => {
                    let mut end = 0;
                    for (mi, op) in inst.operands.iter().enumerate() {
                        let off = self.offsets.get(&(id, mi as u32)).copied().unwrap_or(0);
                        end = end.max(off + self.size_of(lit(op)));
                    }
                    end
                }
                other => panic!("{}: cannot size type {other:?}", self.file),
            }
        }

        fn array_len(&self, inst: &Instruction) -> u32 {
            let len = self.def(lit(&inst.operands[1]));
            len.operands.first().map(lit).unwrap_or(0)
        }

        /// The Rust mirror of a type.
        fn rust_type(&self, id: u32) -> Result<RustType, String> {
            let inst = self.def(id);
            let scalar = |name: String, size: u32| Ok(RustType { name, size, align: size, default: true });
            match inst.class.opcode {
                Op::TypeInt => {
                    let width = lit(&inst.operands[0]);
                    let signed = lit(&inst.operands[1]) != 0;
                    scalar(format!("{}{width}", if signed { "i" } else { "u" }), width / 8)
                }
                Op::TypeFloat => match lit(&inst.operands[0]) {
                    w @ (32 | 64) => scalar(format!("f{w}"), w / 8),
                    w => Err(format!("{w}-bit float")),
                },
                // A buffer reference (or any pointer in memory) is a 64-bit device address.
                Op::TypePointer => scalar("u64".into(), 8),
                Op::TypeVector => {
                    let e = self.rust_type(lit(&inst.operands[0]))?;
                    let n = lit(&inst.operands[1]);
                    Ok(RustType { name: format!("[{}; {n}]", e.name), size: n * e.size, align: e.align, default: true })
                }
                Op::TypeArray => {
                    let e = self.rust_type(lit(&inst.operands[0]))?;
                    let n = self.array_len(inst);
                    let stride = self.strides.get(&id).copied().unwrap_or(e.size);
                    if stride != e.size {
                        return Err(format!("array stride {stride} differs from the element size {}", e.size));
                    }
                    Ok(RustType {
                        name: format!("[{}; {n}]", e.name),
                        size: n * e.size,
                        align: e.align,
                        default: e.default && n <= 32,
                    })
                }
                Op::TypeRuntimeArray => {
                    let e = self.rust_type(lit(&inst.operands[0]))?;
                    Err(format!("runtime array of {}", e.name))
                }
                Op::TypeStruct => {
                    let name = self.names.get(&id).cloned().ok_or("unnamed struct")?;
                    if self.blocks.contains(&id) {
                        return Err(format!("block {name} inside a struct"));
                    }
                    let layout = rust_layout(&self.members(id), &name)?;
                    Ok(RustType { name, size: layout.size, align: layout.align, default: layout.default })
                }
                other => Err(format!("{other:?}")),
            }
        }

        fn members(&self, id: u32) -> Vec<Member> {
            self.def(id)
                .operands
                .iter()
                .enumerate()
                .map(|(mi, op)| {
                    let mi = mi as u32;
                    Member {
                        name: self.member_names.get(&(id, mi)).cloned().unwrap_or_else(|| format!("member{mi}")),
                        offset: self.offsets.get(&(id, mi)).copied().unwrap_or(0),
                        size: self.size_of(lit(op)),
                        ty: self.rust_type(lit(op)),
                    }
                })
                .collect()
        }
    }

    fn reflect(m: &Module, file: &str) -> Reflected {
        let mut names: HashMap<u32, String> = HashMap::new();
        let mut member_names: HashMap<(u32, u32), String> = HashMap::new();
        for i in &m.debug_names {
            match i.class.opcode {
                Op::Name => {
                    if let (Operand::IdRef(id), Operand::LiteralString(s)) = (&i.operands[0], &i.operands[1]) {
                        names.insert(*id, s.clone());
                    }
                }
                Op::MemberName => {
                    if let (Operand::IdRef(id), Operand::LiteralBit32(mi), Operand::LiteralString(s)) =
                        (&i.operands[0], &i.operands[1], &i.operands[2])
                    {
                        member_names.insert((*id, *mi), s.clone());
                    }
                }
                _ => {}
            }
        }
        // Decorations by target id, and member decorations by (struct, member).
        let mut decos: HashMap<u32, Vec<(Decoration, Vec<Operand>)>> = HashMap::new();
        let mut member_offsets: HashMap<(u32, u32), u32> = HashMap::new();
        let mut array_strides: HashMap<u32, u32> = HashMap::new();
        for i in &m.annotations {
            match i.class.opcode {
                Op::Decorate => {
                    let target = lit(&i.operands[0]);
                    if let Operand::Decoration(d) = i.operands[1] {
                        if d == Decoration::ArrayStride {
                            array_strides.insert(target, lit(&i.operands[2]));
                        }
                        decos.entry(target).or_default().push((d, i.operands[2..].to_vec()));
                    }
                }
                Op::MemberDecorate => {
                    let target = lit(&i.operands[0]);
                    let member = lit(&i.operands[1]);
                    if let Operand::Decoration(Decoration::Offset) = i.operands[2] {
                        member_offsets.insert((target, member), lit(&i.operands[3]));
                    }
                }
                _ => {}
            }
        }
        let deco = |id: u32, d: Decoration| -> Option<u32> {
            decos.get(&id)?.iter().find(|(x, _)| *x == d).map(|(_, ops)| ops.first().map(lit).unwrap_or(0))
        };
        let has_deco = |id: u32, d: Decoration| decos.get(&id).is_some_and(|v| v.iter().any(|(x, _)| *x == d));
        let defs: HashMap<u32, &Instruction> =
            m.types_global_values.iter().filter_map(|i| i.result_id.map(|id| (id, i))).collect();
        let blocks = defs.keys().copied().filter(|id| has_deco(*id, Decoration::Block)).collect();
        let types = Types {
            file,
            defs: defs.clone(),
            names: names.clone(),
            member_names,
            offsets: member_offsets.clone(),
            strides: array_strides,
            blocks,
        };

        // Entry point.
        let ep = m.entry_points.first().unwrap_or_else(|| panic!("{file}: no entry point"));
        let entry = match &ep.operands[2] {
            Operand::LiteralString(s) => s.clone(),
            _ => panic!("{file}: entry point name"),
        };

        // Local size: literal execution mode, LocalSizeId, or the WorkgroupSize built-in (spec constants).
        let mut local_size = [1u32; 3];
        let mut local_size_ids = [None; 3];
        let spec_value = |id: u32| -> (u32, Option<u32>) {
            let inst = defs.get(&id).unwrap_or_else(|| panic!("{file}: local size id {id}"));
            let value = inst.operands.first().map(lit).unwrap_or(1);
            (value, deco(id, Decoration::SpecId))
        };
        for i in &m.execution_modes {
            let mode = match i.operands[1] {
                Operand::ExecutionMode(mode) => mode,
                _ => continue,
            };
            match mode {
                ExecutionMode::LocalSize => {
                    for (a, size) in local_size.iter_mut().enumerate() {
                        *size = lit(&i.operands[2 + a]);
                    }
                }
                ExecutionMode::LocalSizeId => {
                    for a in 0..3 {
                        let (v, sid) = spec_value(lit(&i.operands[2 + a]));
                        local_size[a] = v;
                        local_size_ids[a] = sid;
                    }
                }
                _ => {}
            }
        }
        for i in &m.types_global_values {
            if i.class.opcode == Op::SpecConstantComposite || i.class.opcode == Op::ConstantComposite {
                let id = i.result_id.unwrap_or(0);
                let is_wg = decos.get(&id).is_some_and(|v| {
                    v.iter().any(|(d, ops)| {
                        *d == Decoration::BuiltIn && ops.first() == Some(&Operand::BuiltIn(BuiltIn::WorkgroupSize))
                    })
                });
                if is_wg {
                    for a in 0..3 {
                        let (v, sid) = spec_value(lit(&i.operands[a]));
                        local_size[a] = v;
                        local_size_ids[a] = sid;
                    }
                }
            }
        }

        let mut bindings = Vec::new();
        let mut push_size = 0;
        let mut push = None;
        for i in &m.types_global_values {
            if i.class.opcode != Op::Variable {
                continue;
            }
            let id = i.result_id.unwrap_or(0);
            let class = match i.operands[0] {
                Operand::StorageClass(c) => c,
                _ => continue,
            };
            let ptr = defs.get(&i.result_type.unwrap_or(0)).unwrap_or_else(|| panic!("{file}: variable type"));
            let pointee = lit(&ptr.operands[1]);
            match class {
                StorageClass::PushConstant => {
                    push_size = types.size_of(pointee);
                    push = Some(Struct {
                        name: names.get(&pointee).cloned().unwrap_or_else(|| "Push".into()),
                        block: true,
                        members: types.members(pointee),
                    });
                }
                StorageClass::StorageBuffer | StorageClass::Uniform | StorageClass::UniformConstant => {
                    let (Some(set), Some(binding)) =
                        (deco(id, Decoration::DescriptorSet), deco(id, Decoration::Binding))
                    else {
                        continue;
                    };
                    let mut ty = pointee;
                    let mut count = 1;
                    if let Some(t) = defs.get(&ty) {
                        if t.class.opcode == Op::TypeArray {
                            count =
                                defs.get(&lit(&t.operands[1])).and_then(|c| c.operands.first()).map(lit).unwrap_or(1);
                            ty = lit(&t.operands[0]);
                        } else if t.class.opcode == Op::TypeRuntimeArray {
                            panic!("{file}: runtime descriptor arrays are not supported");
                        }
                    }
                    let kind = match class {
                        StorageClass::StorageBuffer => "StorageBuffer",
                        StorageClass::Uniform if has_deco(ty, Decoration::BufferBlock) => "StorageBuffer",
                        StorageClass::Uniform => "UniformBuffer",
                        _ => panic!("{file}: binding {set}.{binding}: only buffer bindings are supported"),
                    };
                    bindings.push(Binding {
                        name: names.get(&id).cloned().unwrap_or_default(),
                        set,
                        binding,
                        kind,
                        count,
                    });
                }
                _ => {}
            }
        }
        bindings.sort_by_key(|b| (b.set, b.binding));

        let mut spec_constants = Vec::new();
        for i in &m.types_global_values {
            if matches!(i.class.opcode, Op::SpecConstant | Op::SpecConstantTrue | Op::SpecConstantFalse) {
                let id = i.result_id.unwrap_or(0);
                if let Some(sid) = deco(id, Decoration::SpecId) {
                    spec_constants.push((names.get(&id).cloned().unwrap_or_else(|| format!("spec{sid}")), sid));
                }
            }
        }
        spec_constants.sort_by_key(|s| s.1);
        spec_constants.dedup_by_key(|s| s.1);

        // Every named struct with explicit member offsets (buffer blocks, buffer_reference blocks and the structs
        // they contain), so host-side mirrors of GLSL structs can be checked member by member.
        let mut structs: Vec<Struct> = Vec::new();
        for i in &m.types_global_values {
            if i.class.opcode != Op::TypeStruct {
                continue;
            }
            let id = i.result_id.unwrap_or(0);
            let Some(name) = names.get(&id) else { continue };
            if i.operands.is_empty() || !member_offsets.contains_key(&(id, 0)) {
                continue;
            }
            if !structs.iter().any(|s| s.name == *name) {
                structs.push(Struct {
                    name: name.clone(),
                    block: has_deco(id, Decoration::Block),
                    members: types.members(id),
                });
            }
        }

        Reflected { entry, local_size, local_size_ids, bindings, push_size, push, spec_constants, structs }
    }

    // ---------------------------------------------------------------------------------------------------------
    // What the GLSL sources say beyond the SPIR-V: member comments and `#define`s.

    /// Member comments of push-constant blocks and structs, written after the member on its line
    /// (`uint64_t nodes; // Address of the nodes.`).
    struct GlslDocs {
        /// (block key, member) -> (GLSL type, comment). The key is `<file>:<block>` for a push-constant block,
        /// the struct name for a struct.
        members: HashMap<(String, String), (String, String)>,
        /// Struct name -> file declaring it.
        struct_files: HashMap<String, String>,
    }

    impl GlslDocs {
        fn parse(sources: &[(String, String)]) -> Self {
            let mut members = HashMap::new();
            let mut struct_files = HashMap::new();
            for (file, text) in sources {
                let mut key: Option<String> = None;
                for line in text.lines() {
                    let (code, comment) = match line.find("//") {
                        Some(i) => (line[..i].trim(), line[i + 2..].trim()),
                        None => (line.trim(), ""),
                    };
                    if let Some(k) = &key {
                        if code.starts_with('}') {
                            key = None;
                        } else if let Some(decl) = code.strip_suffix(';') {
                            let mut words = decl.split_whitespace();
                            if let (Some(ty), Some(name), None) = (words.next(), words.next(), words.next()) {
                                let name = name.split('[').next().unwrap_or(name);
                                members.insert((k.clone(), name.to_string()), (ty.to_string(), comment.to_string()));
                            }
                        }
                        continue;
                    }
                    let Some(head) = code.strip_suffix('{').map(str::trim) else { continue };
                    if let Some(name) = head.strip_prefix("struct ") {
                        struct_files.entry(name.trim().to_string()).or_insert_with(|| file.clone());
                        key = Some(name.trim().to_string());
                    } else if head.contains("push_constant") {
                        if let Some(name) = head.rsplit_once("uniform ").map(|(_, n)| n.trim()) {
                            key = Some(format!("{file}:{name}"));
                        }
                    }
                }
            }
            GlslDocs { members, struct_files }
        }
    }

    struct Define {
        name: String,
        /// Rust type and value.
        ty: &'static str,
        value: String,
        file: String,
        doc: String,
    }

    /// The integer `#define`s of [`LAYOUT_INCLUDES`], with the comment after them on their line or the comment
    /// lines right above them.
    fn parse_defines(sources: &[(String, String)]) -> Vec<Define> {
        let mut out = Vec::new();
        for (file, text) in sources.iter().filter(|(f, _)| LAYOUT_INCLUDES.contains(&f.as_str())) {
            let mut above: Vec<&str> = Vec::new();
            for line in text.lines() {
                let t = line.trim();
                if let Some(c) = t.strip_prefix("//") {
                    above.push(c.trim());
                    continue;
                }
                let taken = std::mem::take(&mut above);
                let Some(rest) = t.strip_prefix("#define ") else { continue };
                let (code, comment) = match rest.find("//") {
                    Some(i) => (rest[..i].trim(), rest[i + 2..].trim()),
                    None => (rest.trim(), ""),
                };
                let mut words = code.split_whitespace();
                let (Some(name), Some(literal), None) = (words.next(), words.next(), words.next()) else { continue };
                let Some((ty, value)) = integer_literal(literal) else { continue };
                let doc = if comment.is_empty() { taken.join(" ") } else { comment.to_string() };
                out.push(Define { name: name.to_string(), ty, value, file: file.clone(), doc });
            }
        }
        out
    }

    /// A GLSL integer literal (decimal or hex, suffix `u` or `ul`) as a Rust type and value.
    fn integer_literal(s: &str) -> Option<(&'static str, String)> {
        let lower = s.to_ascii_lowercase();
        let (digits, ty) = if let Some(d) = lower.strip_suffix("ul") {
            (d, "u64")
        } else if let Some(d) = lower.strip_suffix('u') {
            (d, "u32")
        } else {
            (lower.as_str(), "i32")
        };
        let valid = match digits.strip_prefix("0x") {
            Some(hex) => !hex.is_empty() && hex.chars().all(|c| c.is_ascii_hexdigit()),
            None => !digits.is_empty() && digits.chars().all(|c| c.is_ascii_digit()),
        };
        valid.then(|| (ty, digits.to_string()))
    }

    fn define_value(d: &Define) -> u64 {
        match d.value.strip_prefix("0x") {
            Some(hex) => u64::from_str_radix(hex, 16),
            None => d.value.parse(),
        }
        .unwrap_or_else(|e| panic!("{}: #define {} {}: {e}", d.file, d.name, d.value))
    }

    // ---------------------------------------------------------------------------------------------------------
    // Generation.

    struct Field {
        name: String,
        ty: String,
        offset: u32,
        doc: String,
        padding: bool,
    }

    struct Layout {
        fields: Vec<Field>,
        size: u32,
        align: u32,
        default: bool,
    }

    /// The `#[repr(C)]` fields of a struct with explicit offsets, with padding fields where the offsets leave gaps
    /// (and at the end, to a multiple of the alignment), so the struct has no implicit padding (`Pod`).
    fn rust_layout(members: &[Member], what: &str) -> Result<Layout, String> {
        let mut fields = Vec::new();
        let (mut end, mut align, mut default) = (0u32, 1u32, true);
        fn pad(fields: &mut Vec<Field>, at: u32, to: u32, default: &mut bool) {
            if to > at {
                fields.push(Field {
                    name: format!("_pad{at}"),
                    ty: format!("[u8; {}]", to - at),
                    offset: at,
                    doc: "Padding.".into(),
                    padding: true,
                });
                *default &= to - at <= 32;
            }
        }
        for m in members {
            let ty = m.ty.clone().map_err(|e| format!("{what}.{}: no Rust type for {e}", m.name))?;
            if m.offset < end || m.offset % ty.align != 0 || ty.size != m.size {
                return Err(format!(
                    "{what}.{}: a {} at offset {} (size {}) cannot follow byte {end} in a #[repr(C)] struct",
                    m.name, ty.name, m.offset, m.size
                ));
            }
            pad(&mut fields, end, m.offset, &mut default);
            fields.push(Field {
                name: m.name.clone(),
                ty: ty.name,
                offset: m.offset,
                doc: String::new(),
                padding: false,
            });
            end = m.offset + ty.size;
            align = align.max(ty.align);
            default &= ty.default;
        }
        let size = end.div_ceil(align) * align;
        pad(&mut fields, end, size, &mut default);
        Ok(Layout { fields, size, align, default })
    }

    fn upper_snake(camel: &str) -> String {
        let mut s = String::new();
        for (i, c) in camel.chars().enumerate() {
            if c.is_ascii_uppercase() && i > 0 {
                s.push('_');
            }
            s.push(c.to_ascii_uppercase());
        }
        s
    }

    /// Host alignments above the fields' own, by struct name: a BVH node (32 bytes) aligned to 32 never straddles
    /// two 64-byte cache lines, so a traversal step reads one line instead of two; with the allocator's 16-byte
    /// alignment half the nodes of an array straddle one (measured: 12% of the CPU trace time on Sponza, one
    /// thread). The device layout is unchanged (the size is a multiple of the alignment: no padding).
    const HOST_ALIGN: &[(&str, u32)] = &[("BvhNode", 32)];

    /// Emits a `#[repr(C)]` struct and its `PushConstants` impl.
    fn emit_struct(out: &mut String, indent: &str, rust_name: &str, doc: &str, layout: &Layout) {
        doc_lines(out, indent, doc);
        match HOST_ALIGN.iter().find(|(name, _)| *name == rust_name) {
            Some(&(_, align)) => {
                assert!(layout.size % align == 0, "{rust_name}: size {} is no multiple of {align}", layout.size);
                let _ = writeln!(out, "{indent}#[repr(C, align({align}))]");
            }
            None => {
                let _ = writeln!(out, "{indent}#[repr(C)]");
            }
        }
        let default = if layout.default { "Default, " } else { "" };
        let _ = writeln!(
            out,
            "{indent}#[derive(Clone, Copy, Debug, {default}PartialEq, bytemuck::Pod, bytemuck::Zeroable)]"
        );
        let _ = writeln!(out, "{indent}pub struct {rust_name} {{");
        for f in &layout.fields {
            doc_lines(out, &format!("{indent}    "), &f.doc);
            let _ = writeln!(out, "{indent}    pub {}: {},", f.name, f.ty);
        }
        let _ = writeln!(out, "{indent}}}");
        let names: Vec<&str> = layout.fields.iter().filter(|f| !f.padding).map(|f| f.name.as_str()).collect();
        let _ = writeln!(out, "{indent}crate::push_layout!({rust_name} {{ {} }});", names.join(", "));
        let _ = writeln!(out, "{indent}const _: () = assert!(std::mem::size_of::<{rust_name}>() == {});", layout.size);
    }

    fn field_doc(f: &Field, docs: &GlslDocs, key: &str) -> String {
        let (glsl_ty, comment) = docs.members.get(&(key.to_string(), f.name.clone())).cloned().unwrap_or_default();
        let at = if glsl_ty.is_empty() {
            format!("Byte {}.", f.offset)
        } else {
            format!("`{glsl_ty}` at byte {}.", f.offset)
        };
        if comment.is_empty() {
            format!("`{}`: {at}", f.name)
        } else {
            format!("{comment} {at}")
        }
    }

    /// Doc comment lines (`/// ...`) of `text`, wrapped at 120 columns.
    fn doc_lines(out: &mut String, indent: &str, text: &str) {
        let width = 120 - indent.len() - 4;
        let mut line = String::new();
        for word in text.split_whitespace() {
            if !line.is_empty() && line.len() + 1 + word.len() > width {
                let _ = writeln!(out, "{indent}/// {line}");
                line.clear();
            }
            if !line.is_empty() {
                line.push(' ');
            }
            line.push_str(word);
        }
        let _ = writeln!(out, "{indent}/// {line}");
    }

    fn member_infos(out: &mut String, indent: &str, members: &[Member]) {
        for m in members {
            let ty = match &m.ty {
                Ok(t) => t.name.clone(),
                Err(_) => "?".into(),
            };
            let _ = writeln!(
                out,
                "{indent}MemberInfo {{ name: {:?}, offset: {}, size: {}, ty: {:?} }},",
                m.name, m.offset, m.size, ty
            );
        }
    }

    type Shader = (String, String, Vec<u32>, Reflected);

    fn generate(shaders: &[Shader], docs: &GlslDocs, defines: &[Define], hash: u64) -> String {
        let mut out = String::new();
        out.push_str(
            "// @generated by build.rs (feature `compile-glsl`) from glsl/: do not edit. A build with the feature fails\n\
             // when this file or spv/ differs from a fresh compile; `MESHCHAR_WRITE_SHADERS=1 cargo build --features\n\
             // compile-glsl` rewrites them.\n",
        );
        let _ = writeln!(out, "{HASH_PREFIX}0x{hash:016x}\n");

        // Named layout constants.
        out.push_str(
            "/// The integer `#define`s of `glsl/include/bvh.glsl` and `glsl/include/layout.glsl`: flags, byte offsets,\n\
             /// record fields and result-buffer slots that host code and shaders share.\npub mod layout {\n",
        );
        for d in defines {
            let doc = if d.doc.is_empty() { format!("`{}` of `{}`.", d.name, d.file) } else { d.doc.clone() };
            doc_lines(&mut out, "    ", &doc);
            let _ = writeln!(out, "    pub const {}: {} = {};", d.name, d.ty, d.value);
        }
        out.push_str("}\n\n");

        // Shared GLSL structs (not blocks), once each; every shader that declares one must agree on its layout.
        let mut shared: BTreeMap<String, (Struct, Vec<String>)> = BTreeMap::new();
        for (name, file, _, r) in shaders {
            for s in r.structs.iter().filter(|s| !s.block) {
                let entry = shared.entry(s.name.clone()).or_insert_with(|| (s.clone(), Vec::new()));
                if entry.0 != *s {
                    panic!("{file}: struct {} differs from its declaration in {}", s.name, entry.1.join(", "));
                }
                entry.1.push(name.clone());
            }
        }
        for (sname, (s, users)) in &shared {
            let mut layout = rust_layout(&s.members, sname).unwrap_or_else(|e| panic!("struct {sname}: {e}"));
            let file = docs.struct_files.get(sname).cloned().unwrap_or_else(|| "glsl/".into());
            for f in layout.fields.iter_mut().filter(|f| !f.padding) {
                f.doc = field_doc(f, docs, sname);
            }
            let doc = format!("`struct {sname}` of `{file}` (in the shaders {}).", users.join(", "));
            emit_struct(&mut out, "", sname, &doc, &layout);
            // Defines named after the struct's fields must be their byte offsets (`BVH_NODE_MAX`), and
            // `<STRUCT>_BYTES` its size.
            let prefix = upper_snake(sname);
            for d in defines {
                let Some(rest) = d.name.strip_prefix(&prefix).and_then(|r| r.strip_prefix('_')) else { continue };
                let value = define_value(d);
                let expected = if rest == "BYTES" {
                    Some(layout.size)
                } else {
                    s.members.iter().find(|m| m.name.to_ascii_uppercase() == rest).map(|m| m.offset)
                };
                if let Some(expected) = expected {
                    assert_eq!(
                        value,
                        u64::from(expected),
                        "{}: #define {} is not the layout of {sname}",
                        d.file,
                        d.name
                    );
                    let what = if rest == "BYTES" {
                        format!("std::mem::size_of::<{sname}>()")
                    } else {
                        format!("std::mem::offset_of!({sname}, {})", rest.to_ascii_lowercase())
                    };
                    let cast = if d.ty == "u64" { "" } else { " as u64" };
                    let _ = writeln!(out, "const _: () = assert!({what} as u64 == layout::{}{cast});", d.name);
                }
            }
            out.push('\n');
        }

        for (name, file, words, r) in shaders {
            let _ = writeln!(out, "/// Shader `{file}`.");
            let _ = writeln!(out, "pub mod {name} {{");
            let _ = writeln!(out, "    use super::*;");
            if let Some(push) = &r.push {
                let mut layout =
                    rust_layout(&push.members, &format!("{file}: push constants")).unwrap_or_else(|e| panic!("{e}"));
                let key = format!("{file}:{}", push.name);
                for f in layout.fields.iter_mut().filter(|f| !f.padding) {
                    f.doc = field_doc(f, docs, &key);
                }
                let doc = format!("Push constants of `{file}` (`layout(push_constant) uniform {}`).", push.name);
                emit_struct(&mut out, "    ", "Push", &doc, &layout);
            }
            let _ = writeln!(out, "    /// SPIR-V words (optimized), shipped in `spv/{name}.spv`.");
            let _ = writeln!(
                out,
                "    pub static SPIRV: [u32; {}] = spirv_words(include_bytes!(\"spv/{name}.spv\"));",
                words.len()
            );
            let _ = writeln!(out, "    /// Reflection of the module.");
            let _ = writeln!(out, "    pub const INFO: ShaderInfo = ShaderInfo {{");
            let _ = writeln!(out, "        name: {name:?},");
            let _ = writeln!(out, "        entry: {:?},", r.entry);
            let _ = writeln!(out, "        spirv: &SPIRV,");
            let _ = writeln!(out, "        local_size: {:?},", r.local_size);
            let _ = writeln!(out, "        local_size_spec_ids: {:?},", r.local_size_ids);
            out.push_str("        bindings: &[\n");
            for b in &r.bindings {
                let _ = writeln!(
                    out,
                    "            BindingInfo {{ name: {:?}, set: {}, binding: {}, kind: DescriptorKind::{}, count: {} }},",
                    b.name, b.set, b.binding, b.kind, b.count
                );
            }
            out.push_str("        ],\n");
            let _ = writeln!(out, "        push_constant_size: {},", r.push_size);
            out.push_str("        push_constant_members: &[\n");
            member_infos(&mut out, "            ", r.push.as_ref().map(|p| p.members.as_slice()).unwrap_or(&[]));
            out.push_str("        ],\n        spec_constants: &[\n");
            for (n, id) in &r.spec_constants {
                let _ = writeln!(out, "            SpecConstantInfo {{ name: {n:?}, id: {id} }},");
            }
            out.push_str("        ],\n        structs: &[\n");
            for s in &r.structs {
                let _ = writeln!(out, "            StructInfo {{ name: {:?}, members: &[", s.name);
                member_infos(&mut out, "                ", &s.members);
                out.push_str("            ] },\n");
            }
            out.push_str("        ],\n    };\n}\n\n");
        }
        out.push_str("/// Every compiled shader, in file-name order.\npub const ALL: &[&ShaderInfo] = &[\n");
        for (n, ..) in shaders {
            let _ = writeln!(out, "    &{n}::INFO,");
        }
        out.push_str("];\n");
        out
    }
}
