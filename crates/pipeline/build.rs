//! Digests the workspace's sources into `$OUT_DIR/code_digests.rs` for the stage keys (see
//! `src/digest.rs`): a stage's cached result is redone when the code it runs changes.

use std::fmt::Write as _;
use std::path::PathBuf;

#[path = "src/digest.rs"]
mod digest;

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"));
    let crates = manifest.parent().expect("the pipeline crate sits in the workspace's crates/");
    let digests = digest::workspace_digests(crates).expect("the workspace's crates are readable");
    for entry in std::fs::read_dir(crates).expect("crates/ is readable").flatten() {
        let dir = entry.path();
        if dir.join("Cargo.toml").is_file() {
            println!("cargo:rerun-if-changed={}", dir.join("Cargo.toml").display());
            println!("cargo:rerun-if-changed={}", dir.join("src").display());
        }
    }
    let src = manifest.join("src");
    let mut modules: Vec<String> = std::fs::read_dir(&src)
        .expect("src/ is readable")
        .flatten()
        .filter_map(|e| e.file_name().to_str().filter(|n| n.ends_with(".rs")).map(str::to_owned))
        .collect();
    modules.sort();
    let mut out =
        String::from("/// Workspace crates by package name: their sources' digest, dependencies folded in.\n");
    out.push_str("pub const CRATES: &[(&str, u64)] = &[\n");
    for (name, d) in &digests {
        writeln!(out, "    ({name:?}, 0x{d:016x}),").expect("writing to a String");
    }
    out.push_str("];\n/// The pipeline's own modules by file name: each file's digest.\n");
    out.push_str("pub const PIPELINE_MODULES: &[(&str, u64)] = &[\n");
    for m in &modules {
        let d = digest::file_digest(&src.join(m)).expect("a pipeline module is readable");
        writeln!(out, "    ({m:?}, 0x{d:016x}),").expect("writing to a String");
    }
    out.push_str("];\n");
    let path = PathBuf::from(std::env::var("OUT_DIR").expect("cargo sets OUT_DIR")).join("code_digests.rs");
    std::fs::write(path, out).expect("OUT_DIR is writable");
}
