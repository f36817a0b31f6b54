//! Digests the workspace's sources into `$OUT_DIR/code_digests.rs` for the stage keys (see
//! `src/digest.rs`): a stage's cached result is redone when the code it runs changes.

use std::fmt::Write as _;
use std::path::PathBuf;

#[path = "src/digest.rs"]
#[allow(dead_code)] // its module_reach is the tests' view of what module_digests covers
mod digest;
#[path = "src/modules.rs"]
#[allow(dead_code)] // its module_graph is the circle test's
mod modules;

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"));
    let crates = manifest.parent().expect("the pipeline crate sits in the workspace's crates/");
    for entry in std::fs::read_dir(crates).expect("crates/ is readable").flatten() {
        let dir = entry.path();
        if dir.join("Cargo.toml").is_file() {
            println!("cargo:rerun-if-changed={}", dir.join("Cargo.toml").display());
            println!("cargo:rerun-if-changed={}", dir.join("src").display());
        }
    }
    let digests = digest::module_digests(crates).expect("the workspace's crates are readable");
    let mut out =
        String::from("/// The pipeline's modules by `::`-joined path: the digest of the code each reaches.\n");
    out.push_str("pub const MODULES: &[(&str, u64)] = &[\n");
    for (name, d) in &digests {
        writeln!(out, "    ({name:?}, 0x{d:016x}),").expect("writing to a String");
    }
    out.push_str("];\n");
    let path = PathBuf::from(std::env::var("OUT_DIR").expect("cargo sets OUT_DIR")).join("code_digests.rs");
    std::fs::write(path, out).expect("OUT_DIR is writable");
}
