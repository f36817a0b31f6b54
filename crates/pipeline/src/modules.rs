//! The module graph of a crate, read from its sources: which of its modules each module
//! imports and which workspace crates it names. The circle test reads every crate's graph; the
//! build script reads the pipeline's, so that a stage's key covers every module and crate its
//! module reaches ([`crate::digest::module_digests`]).
//!
//! Every file is a module, nested ones included (`a/b.rs` and `a/b/mod.rs` are `a::b`; the crate
//! root is none). A module's imports are the module paths its code names, resolved to the
//! deepest module file they reach: `crate::…`, `super::…`, `self::…` and a child module's name
//! (comments and its `#[cfg(test)]` module left out); a name the crate root re-exports
//! (`pub use module::{A, B}`) counts as an import of that module.

use std::collections::{BTreeMap, BTreeSet};
use std::io;
use std::path::{Path, PathBuf};

/// A module's path below the crate root (`["field_components", "hash_encoding"]`).
pub type ModPath = Vec<String>;

/// One module of a crate: its file and what its code names.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Module {
    /// The module's file (the crate root's modules have `lib.rs`/`main.rs` apart: not a module).
    pub file: PathBuf,
    /// The crate's modules this one imports (see the module docs), by `::`-joined path.
    pub imports: BTreeSet<String>,
    /// The workspace crates its code names (`nerfsv_sim::…` gives `nerfsv-sim`), by package name.
    pub crates: BTreeSet<String>,
}

/// The modules of the crate whose `src/` is `src`, by `::`-joined path below the crate root.
pub fn modules(src: &Path) -> io::Result<BTreeMap<String, Module>> {
    let mut sources: BTreeMap<ModPath, (PathBuf, String)> = BTreeMap::new();
    let mut root = String::new();
    let mut stack = vec![src.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir)? {
            let path = entry?.path();
            if path.is_dir() {
                stack.push(path);
            } else if path.extension().is_some_and(|e| e == "rs") {
                let Ok(rel) = path.strip_prefix(src) else { continue };
                let mut module: ModPath =
                    rel.with_extension("").components().map(|c| c.as_os_str().to_string_lossy().into_owned()).collect();
                if module.last().is_some_and(|m| m == "mod") {
                    module.pop();
                }
                let code = code_of(&std::fs::read_to_string(&path)?);
                if module == ["lib"] || module == ["main"] {
                    root.push_str(&code);
                } else {
                    sources.entry(module).or_insert_with(|| (path.clone(), String::new())).1.push_str(&code);
                }
            }
        }
    }
    let paths: BTreeSet<ModPath> = sources.keys().cloned().collect();
    let reexports = root_reexports(&root, &paths);
    Ok(sources
        .into_iter()
        .map(|(m, (file, code))| {
            let imports =
                imports(&m, &code, &paths, &reexports).into_iter().filter(|d| *d != m).map(|d| d.join("::")).collect();
            let crates = crates_named(&code);
            (m.join("::"), Module { file, imports, crates })
        })
        .collect())
}

/// Module → the modules it imports, for the crate whose `src/` is `src`.
pub fn module_graph(src: &Path) -> io::Result<BTreeMap<String, BTreeSet<String>>> {
    Ok(modules(src)?.into_iter().map(|(m, module)| (m, module.imports)).collect())
}

/// The workspace crates `code` names: each identifier `nerfsv_…` as the package `nerfsv-…`.
fn crates_named(code: &str) -> BTreeSet<String> {
    let ident = |c: char| c.is_alphanumeric() || c == '_';
    code.match_indices("nerfsv_")
        .filter(|&(i, _)| !code[..i].ends_with(ident))
        .map(|(i, _)| code[i..].chars().take_while(|&c| ident(c)).collect::<String>().replace('_', "-"))
        .collect()
}

/// The code of a file: without `//` comments and without what follows its first `#[cfg(test)]`
/// module (a `#[cfg(test)]` field or item elsewhere is code like any other).
fn code_of(text: &str) -> String {
    const TEST: &str = "#[cfg(test)]";
    let test_module = text.match_indices(TEST).map(|(i, _)| i).find(|&i| {
        let item = text[i + TEST.len()..].trim_start();
        let item = item.strip_prefix("pub(crate) ").or_else(|| item.strip_prefix("pub ")).unwrap_or(item);
        item.starts_with("mod ")
    });
    let text = &text[..test_module.unwrap_or(text.len())];
    text.lines().map(|l| l.split("//").next().unwrap_or("")).collect::<Vec<_>>().join("\n")
}

/// The paths a `use`-like tail names: `a::b::{c, d::e}` gives `a::b::c` and `a::b::d::e`.
fn paths_of(tail: &str) -> Vec<ModPath> {
    let mut prefix = Vec::new();
    let mut rest = tail.trim_start();
    loop {
        if let Some(group) = rest.strip_prefix('{') {
            // The group's items, split at the commas of its own level.
            let (mut depth, mut start, mut out) = (0, 0, Vec::new());
            for (i, c) in group.char_indices() {
                match c {
                    '{' => depth += 1,
                    '}' if depth == 0 => {
                        out.push(&group[start..i]);
                        break;
                    }
                    '}' => depth -= 1,
                    ',' if depth == 0 => {
                        out.push(&group[start..i]);
                        start = i + 1;
                    }
                    _ => {}
                }
            }
            return out.into_iter().flat_map(paths_of).map(|p| prefix.iter().cloned().chain(p).collect()).collect();
        }
        let name: String = rest.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
        if name.is_empty() {
            return vec![prefix];
        }
        prefix.push(name.clone());
        rest = &rest[name.len()..];
        match rest.trim_start().strip_prefix("::") {
            Some(r) => rest = r.trim_start(),
            None => return vec![prefix],
        }
    }
}

/// The length of the path at the start of `tail` (segments, `::` and a `{…}` group).
fn path_extent(tail: &str) -> usize {
    let mut depth = 0;
    for (i, c) in tail.char_indices() {
        match c {
            '{' => depth += 1,
            '}' if depth == 1 => return i + 1,
            '}' => depth -= 1,
            c if depth == 0 && !(c.is_alphanumeric() || c == '_' || c == ':' || c.is_whitespace()) => return i,
            _ => {}
        }
    }
    tail.len()
}

/// The modules the module `m` names in `code`.
fn imports(
    m: &ModPath,
    code: &str,
    modules: &BTreeSet<ModPath>,
    reexports: &BTreeMap<String, ModPath>,
) -> BTreeSet<ModPath> {
    let parent = &m[..m.len() - 1];
    let children: Vec<&String> =
        modules.iter().filter(|c| c.len() == m.len() + 1 && c.starts_with(m)).map(|c| &c[m.len()]).collect();
    let mut found = BTreeSet::new();
    let mut read_to = 0; // the end of the last path read: its group's paths are read with it
    for (i, _) in code.match_indices("::") {
        if i < read_to {
            continue;
        }
        // The path's first segment: the identifier just before this `::`.
        let head_start = code[..i].rfind(|c: char| !(c.is_alphanumeric() || c == '_')).map_or(0, |j| j + 1);
        let head = &code[head_start..i];
        if code[..head_start].trim_end().ends_with("::") {
            continue; // a later segment of a path already read
        }
        let base: ModPath = match head {
            "crate" => Vec::new(),
            "self" => m.clone(),
            "super" => {
                // `super::super::…` walks up once per `super`.
                let mut base = parent.to_vec();
                let mut tail = &code[i + 2..];
                while let Some(t) = tail.trim_start().strip_prefix("super::") {
                    base.pop();
                    tail = t;
                }
                base
            }
            h if children.iter().any(|c| c.as_str() == h) => m.clone(),
            _ => continue,
        };
        let tail = if head == "crate" || head == "self" || head == "super" {
            let mut t = &code[i + 2..];
            while let Some(rest) = t.trim_start().strip_prefix("super::") {
                t = rest;
            }
            t.to_string()
        } else {
            code[head_start..].to_string()
        };
        read_to = code.len() - tail.len() + path_extent(&tail);
        for path in paths_of(&tail) {
            // `super` and `self` inside a group (`use super::{a, super::b}`) walk from the base.
            let mut full = base.clone();
            for seg in path {
                match seg.as_str() {
                    "super" => {
                        full.pop();
                    }
                    "self" => {}
                    _ => full.push(seg),
                }
            }
            let deepest = (1..=full.len()).rev().map(|k| full[..k].to_vec()).find(|p| modules.contains(p));
            found.extend(deepest.or_else(|| full.first().and_then(|n| reexports.get(n)).cloned()));
        }
    }
    found
}

/// Name → module for the root's `pub use module::{A, B}` and `pub use module::A`.
fn root_reexports(root: &str, modules: &BTreeSet<ModPath>) -> BTreeMap<String, ModPath> {
    let mut map = BTreeMap::new();
    for stmt in root.split(';') {
        let Some(tail) = stmt.trim().strip_prefix("pub use ") else { continue };
        for path in paths_of(tail) {
            let Some(name) = path.last() else { continue };
            let deepest = (1..path.len()).rev().map(|k| path[..k].to_vec()).find(|p| modules.contains(p));
            if let Some(module) = deepest {
                map.insert(name.clone(), module);
            }
        }
    }
    map
}
