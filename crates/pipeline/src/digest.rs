//! Digests of the workspace's source code, so that a stage's cache key changes exactly when the
//! code it runs does. The build script computes them over `crates/` (this file is compiled into
//! it as well as into the crate) and [`crate::stage`] folds them into every stage key.
//!
//! A crate's digest covers its `Cargo.toml` and every file under its `src/`, in sorted path
//! order, and folds in the digests of the workspace crates it depends on, so that a change to
//! `nerfsv-nerf` also changes `nerfsv-sim`'s. A pipeline module's digest covers that one file.

use std::collections::BTreeMap;
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

/// The digest of one file's bytes.
pub fn file_digest(path: &Path) -> io::Result<u64> {
    Ok(fnv1a_from(BASIS, &std::fs::read(path)?))
}

/// The digest of every file under `dir` (relative names and bytes, in sorted path order).
pub fn folder_digest(dir: &Path) -> io::Result<u64> {
    let mut hash = BASIS;
    for rel in files(dir)? {
        hash = fnv1a_from(hash, rel.as_bytes());
        hash = fnv1a_from(hash, &[0]);
        hash = fnv1a_from(hash, &std::fs::read(dir.join(&rel))?);
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

/// Per workspace crate under `crates_dir` (package name → digest): its own code folded with its
/// workspace dependencies' digests, transitively. A folder without a `Cargo.toml` is skipped.
pub fn workspace_digests(crates_dir: &Path) -> io::Result<BTreeMap<String, u64>> {
    let mut own = BTreeMap::new();
    let mut deps = BTreeMap::new();
    for entry in std::fs::read_dir(crates_dir)? {
        let dir = entry?.path();
        let Ok(manifest) = std::fs::read_to_string(dir.join("Cargo.toml")) else { continue };
        let Some(name) =
            manifest.lines().find_map(|l| l.trim().strip_prefix("name = ").map(|n| n.trim_matches('"').to_owned()))
        else {
            continue;
        };
        own.insert(name.clone(), crate_digest(&dir)?);
        deps.insert(name, workspace_dependencies(&manifest));
    }
    let mut out = BTreeMap::new();
    for name in own.keys() {
        // The transitive closure, in name order (a BTreeMap), each crate once.
        let mut closure = BTreeMap::new();
        let mut stack = vec![name.clone()];
        while let Some(n) = stack.pop() {
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
