//! The modules of every crate (the library crates, the binary and the Python package) form a
//! line: no module file imports one that (directly or through others) imports it back. The graph
//! is the one the stage keys are derived from (`nerfsv_pipeline::modules`: every file a node, its
//! imports the module paths its code names).

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Module → the modules it imports, for the crate whose `src/` is `src`.
fn module_graph(src: &Path) -> BTreeMap<String, BTreeSet<String>> {
    nerfsv_pipeline::modules::module_graph(src).unwrap()
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
