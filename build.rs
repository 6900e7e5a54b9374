fn main() {
    let _ = shaderc::Compiler::new();
}
