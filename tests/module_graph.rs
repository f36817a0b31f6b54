//! The modules of every crate (the library crates, the binary and the Python package) form a
//! line: no module file imports one that (directly or through others) imports it back. Every
//! file is a node, nested modules included (`a/b.rs` and `a/b/mod.rs` are `a::b`; the crate root
//! is none). A module's imports are the module paths its code names, resolved to the deepest
//! module file they reach: `crate::…`, `super::…`, `self::…` and a child module's name
//! (comments and its `#[cfg(test)]` module left out); a name the crate root re-exports
//! (`pub use module::{A, B}`) counts as an import of that module.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// A module's path below the crate root (`["field_components", "hash_encoding"]`).
type ModPath = Vec<String>;

/// Module → the modules it imports, for the crate whose `src/` is `src`.
fn module_graph(src: &Path) -> BTreeMap<String, BTreeSet<String>> {
    let mut sources: BTreeMap<ModPath, String> = BTreeMap::new();
    let mut root = String::new();
    let mut stack = vec![src.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap().flatten() {
            let path = entry.path();
            if path.is_dir() {
                stack.push(path);
            } else if path.extension().is_some_and(|e| e == "rs") {
                let rel = path.strip_prefix(src).unwrap().with_extension("");
                let mut module: ModPath =
                    rel.components().map(|c| c.as_os_str().to_string_lossy().into_owned()).collect();
                if module.last().is_some_and(|m| m == "mod") {
                    module.pop();
                }
                let code = code_of(&std::fs::read_to_string(&path).unwrap());
                if module == ["lib"] || module == ["main"] {
                    root.push_str(&code);
                } else {
                    sources.entry(module).or_default().push_str(&code);
                }
            }
        }
    }
    let modules: BTreeSet<ModPath> = sources.keys().cloned().collect();
    let reexports = root_reexports(&root, &modules);
    sources
        .iter()
        .map(|(m, code)| {
            let deps =
                imports(m, code, &modules, &reexports).into_iter().filter(|d| d != m).map(|d| d.join("::")).collect();
            (m.join("::"), deps)
        })
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

/// Every circle of the graph, as the modules of each strongly connected component of more than
/// one module (Tarjan).
fn circles(graph: &BTreeMap<String, BTreeSet<String>>) -> Vec<Vec<String>> {
    struct Tarjan<'a> {
        graph: &'a BTreeMap<String, BTreeSet<String>>,
        index: BTreeMap<&'a str, usize>,
        low: BTreeMap<&'a str, usize>,
        stack: Vec<&'a str>,
        found: Vec<Vec<String>>,
    }
    impl<'a> Tarjan<'a> {
        fn visit(&mut self, v: &'a str) {
            let i = self.index.len();
            self.index.insert(v, i);
            self.low.insert(v, i);
            self.stack.push(v);
            for w in self.graph.get(v).into_iter().flatten() {
                let w = w.as_str();
                if !self.index.contains_key(w) {
                    self.visit(w);
                    let lw = self.low[w];
                    let lv = self.low.get_mut(v).unwrap();
                    *lv = (*lv).min(lw);
                } else if self.stack.contains(&w) {
                    let iw = self.index[w];
                    let lv = self.low.get_mut(v).unwrap();
                    *lv = (*lv).min(iw);
                }
            }
            if self.low[v] == self.index[v] {
                let mut component = Vec::new();
                while let Some(w) = self.stack.pop() {
                    component.push(w.to_string());
                    if w == v {
                        break;
                    }
                }
                if component.len() > 1 {
                    component.sort();
                    self.found.push(component);
                }
            }
        }
    }
    let mut t = Tarjan { graph, index: BTreeMap::new(), low: BTreeMap::new(), stack: Vec::new(), found: Vec::new() };
    for v in graph.keys() {
        if !t.index.contains_key(v.as_str()) {
            t.visit(v);
        }
    }
    t.found
}

#[test]
fn the_modules_of_every_crate_form_a_line() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let (mut checked, mut bad) = (Vec::new(), Vec::new());
    let crates = std::fs::read_dir(root.join("crates")).unwrap().flatten().map(|e| e.path().join("src"));
    for src in crates.chain([root.join("src"), root.join("python/src")]) {
        if !src.join("lib.rs").exists() && !src.join("main.rs").exists() {
            continue;
        }
        let graph = module_graph(&src);
        for circle in circles(&graph) {
            bad.push(format!("{}: {circle:?}", src.display()));
        }
        checked.push(src.strip_prefix(root).unwrap().display().to_string());
    }
    assert!(bad.is_empty(), "modules importing each other:\n{}", bad.join("\n"));
    for name in ["crates/nerf/src", "crates/pipeline/src", "crates/validation/src", "src", "python/src"] {
        assert!(checked.iter().any(|c| c == name), "{name} not checked: {checked:?}");
    }
}

#[test]
fn a_circle_through_a_group_import_or_a_root_reexport_is_found() {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path();
    let write = |name: &str, text: &str| std::fs::write(src.join(name), text).unwrap();
    write("lib.rs", "mod a;\nmod b;\nmod c;\npub use c::{Gamma, Delta as D};\n");
    write("a.rs", "use crate::{b::Beta, d};\n// crate::c in a comment is no import\npub struct Alpha;\n");
    write("b.rs", "pub struct Beta(crate::Gamma);\n#[cfg(test)]\nmod tests { use crate::a::Alpha; }\n");
    write("c.rs", "pub struct Gamma;\npub struct Delta;\n");
    let graph = module_graph(src);
    assert_eq!(graph["a"], BTreeSet::from(["b".to_string()]));
    assert_eq!(graph["b"], BTreeSet::from(["c".to_string()]), "the root's re-export of Gamma is c's");
    assert!(circles(&graph).is_empty(), "the test module's import is not the module's");
    // A `#[cfg(test)]` field ends nothing: what follows it is still read.
    write(
        "b.rs",
        "pub struct Beta {\n    #[cfg(test)]\n    x: u8,\n    g: crate::Gamma,\n}\n#[cfg(test)]\nmod tests {}\n",
    );
    assert_eq!(module_graph(src)["b"], BTreeSet::from(["c".to_string()]));
    write("c.rs", "pub struct Gamma(nerfsv_crate::X);\npub struct Delta(Vec<crate::a::Alpha>);\n");
    assert_eq!(circles(&module_graph(src)), [["a", "b", "c"]]);
}

#[test]
fn a_circle_between_nested_modules_is_found() {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path();
    std::fs::create_dir_all(src.join("f")).unwrap();
    let write = |name: &str, text: &str| std::fs::write(src.join(name), text).unwrap();
    write("lib.rs", "mod f;\nmod g;\n");
    write("f/mod.rs", "mod enc;\nmod simd;\npub use enc::Level;\n");
    write("f/enc.rs", "pub struct Level;\nfn run() { other::simd::go(); }\n");
    write("f/simd.rs", "use super::{enc::Level, super::g};\nfn go(_: crate::f::enc::Level) {}\n");
    write("g.rs", "pub fn h() {}\n");
    let graph = module_graph(src);
    assert_eq!(graph["f"], BTreeSet::from(["f::enc".to_string()]), "a child named by its bare name");
    assert_eq!(graph["f::simd"], BTreeSet::from(["f::enc".to_string(), "g".to_string()]), "super:: and nested groups");
    assert!(graph["f::enc"].is_empty(), "`other::simd` is another crate's path: {:?}", graph["f::enc"]);
    assert!(circles(&graph).is_empty());
    write("f/enc.rs", "pub struct Level;\nfn run() { super::simd::go(); }\n");
    assert_eq!(circles(&module_graph(src)), [["f::enc", "f::simd"]]);
    // A child that uses its parent's helper while the parent calls the child is a circle too.
    write("f/enc.rs", "pub struct Level;\nfn run() { super::helper(); }\n");
    write("f/mod.rs", "mod enc;\nmod simd;\npub use enc::Level;\npub fn helper() {}\n");
    assert_eq!(circles(&module_graph(src)), [["f", "f::enc"]]);
}
