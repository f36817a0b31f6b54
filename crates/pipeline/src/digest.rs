//! Digests of the workspace's source code, so that a stage's cache key changes exactly when the
//! code it runs does. The build script computes them over `crates/` (this file and
//! [`crate::modules`] are compiled into it as well as into the crate) and [`crate::stage`] folds
//! the digest of a stage's module into its key.
//!
//! A pipeline module's digest ([`module_digests`]) covers the code it reaches: its own file,
//! every pipeline module it imports (transitively, [`crate::modules`]) and every workspace crate
//! those name. Nothing is listed per stage: a stage that starts calling another module's code is
//! keyed by it from that build on. Two kinds of module are set apart, by name:
//! - presentation ([`PRESENTATION_MODULE`]: a stage's section of the report and its one-line
//!   description) is neither covered nor followed;
//! - the runner's own modules ([`RUNNER_MODULES`]: errors, settings, the runner, the folder
//!   layout), and the modules reached only through them (a stage's settings module the config
//!   imports), are covered by their own code, but the crates they name are not followed: they
//!   name every crate's error and settings types, which would key every stage by every crate (a
//!   line in the uncertainty crate would retrain the NeRF). Code that calls a crate does not
//!   belong in them.
//!
//! A crate's digest covers its `Cargo.toml` and every file under its `src/`, in sorted path
//! order, and folds in the digests of the workspace crates it depends on, so that a change to
//! `nerfsv-nerf` also changes `nerfsv-sim`'s.
//!
//! What does not change a computation is left out: a Rust file is digested without its comments
//! (doc comments included) and with every run of whitespace as one space ([`code_text`]), and a
//! crate whose manifest marks it as presentation (`[package.metadata.nerfsv] presentation =
//! true`: pictures and their styling) is left out of its dependents' digests.

use std::collections::{BTreeMap, BTreeSet};
use std::io;
use std::path::Path;

/// FNV-1a, 64 bit, continuing from `hash`.
fn fnv1a_from(mut hash: u64, bytes: &[u8]) -> u64 {
    for &b in bytes {
        hash ^= u64::from(b);
        hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
    }
    hash
}

/// FNV-1a's offset basis.
const BASIS: u64 = 0xcbf2_9ce4_8422_2325;

/// Every file under `dir` (recursively), as paths relative to it with `/` separators, sorted.
fn files(dir: &Path) -> io::Result<Vec<String>> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d)? {
            let path = entry?.path();
            if path.is_dir() {
                stack.push(path);
            } else if let Ok(rel) = path.strip_prefix(dir) {
                out.push(rel.components().map(|c| c.as_os_str().to_string_lossy()).collect::<Vec<_>>().join("/"));
            }
        }
    }
    out.sort();
    Ok(out)
}

/// Rust source without what cannot change what it computes: comments (`//…`, `/*…*/` nested,
/// doc comments included) and the amount of whitespace (each run of whitespace and comments
/// becomes one space). String, raw-string and character literals are kept as written.
pub fn code_text(source: &str) -> String {
    let chars: Vec<char> = source.chars().collect();
    let mut out = String::with_capacity(source.len());
    let mut space = false;
    let mut i = 0;
    let ident = |c: char| c.is_alphanumeric() || c == '_';
    while i < chars.len() {
        let c = chars[i];
        let next = chars.get(i + 1).copied();
        // Whitespace and comments: one space.
        if c.is_whitespace() || (c == '/' && (next == Some('/') || next == Some('*'))) {
            if c == '/' && next == Some('/') {
                while i < chars.len() && chars[i] != '\n' {
                    i += 1;
                }
            } else if c == '/' {
                let mut depth = 0;
                while i < chars.len() {
                    if chars[i] == '/' && chars.get(i + 1) == Some(&'*') {
                        depth += 1;
                        i += 2;
                    } else if chars[i] == '*' && chars.get(i + 1) == Some(&'/') {
                        depth -= 1;
                        i += 2;
                        if depth == 0 {
                            break;
                        }
                    } else {
                        i += 1;
                    }
                }
            } else {
                i += 1;
            }
            space = true;
            continue;
        }
        if space && !out.is_empty() {
            out.push(' ');
        }
        space = false;
        let start = i;
        let after_ident = start > 0 && ident(chars[start - 1]);
        // A raw string: r"…", r#"…"#, br#"…"# (not the tail of an identifier such as `for`).
        let raw_at = match (c, next) {
            ('r', Some('"' | '#')) if !after_ident => Some(i + 1),
            ('b', Some('r')) if !after_ident && matches!(chars.get(i + 2), Some('"' | '#')) => Some(i + 2),
            _ => None,
        };
        if let Some(mut j) = raw_at {
            let hashes = chars[j..].iter().take_while(|&&h| h == '#').count();
            j += hashes;
            if chars.get(j) == Some(&'"') {
                j += 1;
                while j < chars.len()
                    && !(chars[j] == '"' && chars[j + 1..].iter().take(hashes).filter(|&&h| h == '#').count() == hashes)
                {
                    j += 1;
                }
                i = (j + 1 + hashes).min(chars.len());
                out.extend(&chars[start..i]);
                continue;
            }
        }
        if c == '"' {
            i += 1;
            while i < chars.len() && chars[i] != '"' {
                i += if chars[i] == '\\' { 2 } else { 1 };
            }
            i = (i + 1).min(chars.len());
            out.extend(&chars[start..i]);
            continue;
        }
        // A character literal ('a', '\n', '\''), not a lifetime ('a).
        if c == '\'' {
            let end = if next == Some('\\') {
                chars.get(i + 3..).and_then(|rest| rest.iter().position(|&q| q == '\'')).map(|k| i + 3 + k + 1)
            } else if chars.get(i + 2) == Some(&'\'') {
                Some(i + 3)
            } else {
                None
            };
            i = end.unwrap_or(i + 1).min(chars.len());
            out.extend(&chars[start..i]);
            continue;
        }
        out.push(c);
        i += 1;
    }
    out
}

/// The bytes of a file as digested: a Rust file's [`code_text`], any other file's bytes.
fn digested_bytes(path: &Path) -> io::Result<Vec<u8>> {
    let bytes = std::fs::read(path)?;
    if path.extension().is_some_and(|e| e == "rs") {
        if let Ok(text) = std::str::from_utf8(&bytes) {
            return Ok(code_text(text).into_bytes());
        }
    }
    Ok(bytes)
}

/// The digest of one file: a Rust file's [`code_text`], any other file's bytes.
pub fn file_digest(path: &Path) -> io::Result<u64> {
    Ok(fnv1a_from(BASIS, &digested_bytes(path)?))
}

/// The digest of every file under `dir` (relative names and digested bytes, in sorted path
/// order).
pub fn folder_digest(dir: &Path) -> io::Result<u64> {
    files_digest(dir, &files(dir)?, digested_bytes)
}

/// The digest of the files `rels` of `dir` (names relative to it with `/` separators, digested
/// in the order given: each name, then the bytes `read` gives for the file).
pub fn files_digest(dir: &Path, rels: &[String], read: impl Fn(&Path) -> io::Result<Vec<u8>>) -> io::Result<u64> {
    let mut hash = BASIS;
    for rel in rels {
        hash = fnv1a_from(hash, rel.as_bytes());
        hash = fnv1a_from(hash, &[0]);
        hash = fnv1a_from(hash, &read(&dir.join(rel))?);
        hash = fnv1a_from(hash, &[0xff]);
    }
    Ok(hash)
}

/// The digest of a crate's own code: its `Cargo.toml` and every file under `src/` (names and
/// bytes, [`folder_digest`]), without its dependencies.
pub fn crate_digest(dir: &Path) -> io::Result<u64> {
    let manifest = fnv1a_from(BASIS, &std::fs::read(dir.join("Cargo.toml"))?);
    Ok(fnv1a_from(manifest, &folder_digest(&dir.join("src"))?.to_le_bytes()))
}

/// The workspace crates (`nerfsv-…`) a `Cargo.toml` lists under `[dependencies]` (not dev- or
/// build-dependencies), by package name.
pub fn workspace_dependencies(manifest: &str) -> Vec<String> {
    let mut section = "";
    let mut deps = Vec::new();
    for line in manifest.lines().map(str::trim) {
        if line.starts_with('[') {
            section = line;
            continue;
        }
        if section == "[dependencies]" {
            let name = line.split(['.', '=', ' ']).next().unwrap_or("");
            if name.starts_with("nerfsv-") {
                deps.push(name.to_owned());
            }
        }
    }
    deps
}

/// A manifest's package name (its first `name = "…"` line).
fn package_name(manifest: &str) -> Option<String> {
    manifest.lines().find_map(|l| l.trim().strip_prefix("name = ").map(|n| n.trim_matches('"').to_owned()))
}

/// Whether a manifest marks its crate as presentation (`presentation = true` under
/// `[package.metadata.nerfsv]`).
pub fn is_presentation(manifest: &str) -> bool {
    let mut section = "";
    for line in manifest.lines().map(str::trim) {
        if line.starts_with('[') {
            section = line;
        } else if section == "[package.metadata.nerfsv]" && line.replace(' ', "") == "presentation=true" {
            return true;
        }
    }
    false
}

/// Per workspace crate under `crates_dir` (package name → digest): its own code folded with its
/// workspace dependencies' digests, transitively, presentation crates ([`is_presentation`]) left
/// out of every other crate's. A folder without a `Cargo.toml` is skipped.
pub fn workspace_digests(crates_dir: &Path) -> io::Result<BTreeMap<String, u64>> {
    let mut own = BTreeMap::new();
    let mut deps = BTreeMap::new();
    let mut presentation = Vec::new();
    for entry in std::fs::read_dir(crates_dir)? {
        let dir = entry?.path();
        let Ok(manifest) = std::fs::read_to_string(dir.join("Cargo.toml")) else { continue };
        let Some(name) = package_name(&manifest) else { continue };
        if is_presentation(&manifest) {
            presentation.push(name.clone());
        }
        own.insert(name.clone(), crate_digest(&dir)?);
        deps.insert(name, workspace_dependencies(&manifest));
    }
    let mut out = BTreeMap::new();
    for name in own.keys() {
        // The transitive closure, in name order (a BTreeMap), each crate once.
        let mut closure = BTreeMap::new();
        let mut stack = vec![name.clone()];
        while let Some(n) = stack.pop() {
            if n != *name && presentation.contains(&n) {
                continue;
            }
            if let Some(&d) = own.get(&n) {
                if closure.insert(n.clone(), d).is_none() {
                    stack.extend(deps.get(&n).into_iter().flatten().cloned());
                }
            }
        }
        let digest = closure.iter().fold(BASIS, |h, (n, d)| fnv1a_from(fnv1a_from(h, n.as_bytes()), &d.to_le_bytes()));
        out.insert(name.clone(), digest);
    }
    Ok(out)
}

/// The last segment of a presentation module's path (`stress::report`, `report`): a stage's
/// section of the report, whose changes must not redo the stage.
pub const PRESENTATION_MODULE: &str = "report";

/// The runner's own modules, by path: their code is part of every key that reaches them, the
/// crates they name (for error and settings types) are not.
pub const RUNNER_MODULES: &[&str] = &["config", "digest", "error", "guard", "layout", "modules", "stage"];

/// Whether a pipeline module is presentation ([`PRESENTATION_MODULE`]).
fn is_presentation_module(path: &str) -> bool {
    path.rsplit("::").next() == Some(PRESENTATION_MODULE)
}

/// Per module of the pipeline crate (`pipeline_src`), by `::`-joined path: the code it reaches,
/// as the names of the pipeline modules it imports, transitively, itself included, and the
/// package names of the workspace crates those name, [`RUNNER_MODULES`] apart (see the module
/// docs). Presentation modules (other than the module itself) are neither included nor
/// followed; every crate named is listed, presentation or not.
pub fn module_reach(pipeline_src: &Path) -> io::Result<BTreeMap<String, BTreeSet<String>>> {
    Ok(reach(&crate::modules::modules(pipeline_src)?))
}

/// [`module_reach`] of modules already read. A module reached only through a runner module (a
/// stage's settings type that the runner's config imports) is covered by its code, but the crates
/// it names are not followed, as the runner's own are not.
fn reach(modules: &BTreeMap<String, crate::modules::Module>) -> BTreeMap<String, BTreeSet<String>> {
    let mut out = BTreeMap::new();
    for start in modules.keys() {
        let mut reached = BTreeSet::new();
        // Modules whose crates were taken: reached other than through a runner module.
        let mut followed = BTreeSet::new();
        let mut stack = vec![(start.as_str(), false)];
        while let Some((m, through_runner)) = stack.pop() {
            if m != start && is_presentation_module(m) {
                continue;
            }
            let Some(module) = modules.get(m) else { continue };
            let runner = through_runner || RUNNER_MODULES.iter().any(|r| m == *r || m.starts_with(&format!("{r}::")));
            let new = if runner {
                !reached.contains(m)
            } else {
                let new = followed.insert(m);
                reached.extend(module.crates.iter().cloned());
                new
            };
            if new {
                reached.insert(m.to_owned());
                stack.extend(module.imports.iter().map(|i| (i.as_str(), runner)));
            }
        }
        out.insert(start.clone(), reached);
    }
    out
}

/// Per module of the pipeline crate (`crates_dir/pipeline/src`), by `::`-joined path: the
/// digest of the code it reaches ([`module_reach`]): each pipeline module's file and each
/// workspace crate's [`workspace_digests`] (presentation crates left out), by name and digest in
/// name order.
pub fn module_digests(crates_dir: &Path) -> io::Result<BTreeMap<String, u64>> {
    let crates = workspace_digests(crates_dir)?;
    let mut presentation = Vec::new();
    for entry in std::fs::read_dir(crates_dir)? {
        let dir = entry?.path();
        let Ok(manifest) = std::fs::read_to_string(dir.join("Cargo.toml")) else { continue };
        if is_presentation(&manifest) {
            presentation.extend(package_name(&manifest));
        }
    }
    let modules = crate::modules::modules(&crates_dir.join("pipeline/src"))?;
    let mut files = BTreeMap::new();
    for (name, module) in &modules {
        files.insert(name.as_str(), file_digest(&module.file)?);
    }
    let mut out = BTreeMap::new();
    for (start, reached) in reach(&modules) {
        let mut hash = BASIS;
        for name in &reached {
            let digest = match files.get(name.as_str()) {
                Some(&d) => d,
                None if presentation.contains(name) => continue,
                None => match crates.get(name) {
                    Some(&d) => d,
                    None => continue, // a name like `nerfsv_…` that is no workspace crate
                },
            };
            hash = fnv1a_from(fnv1a_from(hash, name.as_bytes()), &digest.to_le_bytes());
        }
        out.insert(start, hash);
    }
    Ok(out)
}
