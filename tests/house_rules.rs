//! Rules a reader can rely on across the library crates, the binary, the Python package and the
//! examples (the workspace's and each crate's): no function longer than [`MAX_LINES`] lines and
//! no `too_many_arguments` allowance, outside the NeRF's fused kernels (one pass over a chunk of
//! rays each, kept whole for speed) and the Python functions (whose arguments are Python's
//! keyword arguments: each such allowance sits under its `#[pyo3(signature = …)]`).

use std::path::{Path, PathBuf};

/// The longest a function may be, in lines from its `fn` to its closing brace.
const MAX_LINES: usize = 120;

/// The longest a module may be, in lines before its inline tests (`#[cfg(test)]` at the start of
/// a line): what a reader can take in as one concern.
const MAX_MODULE_LINES: usize = 800;

/// The longest a stage's `run` may be: it loads its inputs, calls one request → figures function
/// of a library crate and returns the figures.
const MAX_STAGE_RUN_LINES: usize = 30;

/// Modules allowed to be longer: the NeRF crate's (fused kernels kept whole for speed).
const LONG_MODULES: &str = "crates/nerf/";

/// Functions allowed to be longer: the NeRF's fused kernels (file, function).
const LONG_KERNELS: &[(&str, &str)] = &[
    ("crates/nerf/src/jacobian.rs", "backward_body"),
    ("crates/nerf/src/fields.rs", "forward_body"),
    ("crates/nerf/src/train.rs", "step"),
];

/// Files allowed `#[allow(clippy::too_many_arguments)]`: the NeRF's kernels and the Python
/// functions.
const MANY_ARGUMENTS: &[&str] = &[
    "crates/nerf/src/model_components/ray_samplers.rs",
    "crates/nerf/src/field_components/mlp.rs",
    "python/src/model.rs",
    "python/src/drone.rs",
    "python/src/data.rs",
    "python/src/uq.rs",
];

/// Every `.rs` file under `dir`, relative to `root`, sorted.
fn sources(root: &Path, dir: &str) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![root.join(dir)];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            let path = entry.path();
            if path.is_dir() {
                stack.push(path);
            } else if path.extension().is_some_and(|e| e == "rs") {
                out.push(path.strip_prefix(root).unwrap().to_path_buf());
            }
        }
    }
    out.sort();
    out
}

/// The functions of `text` longer than `max` lines: (name, first line, lines). A function runs
/// from its `fn` line to the line where the braces it opened close again (braces in strings,
/// character literals and comments are rare enough in this code base to be counted as they
/// come; a false length would show up as a failure to look at, not a silent pass).
fn long_functions(text: &str, max: usize) -> Vec<(String, usize, usize)> {
    let lines: Vec<&str> = text.lines().collect();
    let mut found = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        let code = line.split("//").next().unwrap_or("");
        let Some(at) = code.find("fn ") else { continue };
        if at > 0 && !code[..at].ends_with([' ', '(', '\t']) {
            continue;
        }
        let name: String = code[at + 3..].chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
        if name.is_empty() {
            continue;
        }
        let (mut depth, mut opened) = (0i64, false);
        for (j, l) in lines[i..].iter().enumerate() {
            let l = l.split("//").next().unwrap_or("");
            if !opened && l.trim_end().ends_with(';') && !l.contains('{') {
                break; // a declaration without a body
            }
            for c in l.chars() {
                match c {
                    '{' => (depth, opened) = (depth + 1, true),
                    '}' => depth -= 1,
                    _ => {}
                }
            }
            if opened && depth <= 0 {
                if j + 1 > max {
                    found.push((name.clone(), i + 1, j + 1));
                }
                break;
            }
        }
    }
    found
}

/// The workspace's sources the rules cover, relative to `root`: the binary's, the Python
/// package's, and each crate's library and examples.
fn workspace_sources(root: &Path) -> Vec<PathBuf> {
    let mut files = sources(root, "src");
    files.extend(sources(root, "examples"));
    files.extend(sources(root, "python/src"));
    for entry in std::fs::read_dir(root.join("crates")).unwrap().flatten() {
        let krate = entry.file_name().to_string_lossy().into_owned();
        files.extend(sources(root, &format!("crates/{krate}/src")));
        files.extend(sources(root, &format!("crates/{krate}/examples")));
    }
    assert!(files.len() > 100, "only {} source files found", files.len());
    files
}

#[test]
fn no_function_is_longer_than_a_reader_can_hold_and_none_takes_too_many_arguments() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let files = workspace_sources(root);
    let mut bad = Vec::new();
    for file in &files {
        let name = file.to_string_lossy().replace('\\', "/");
        let text = std::fs::read_to_string(root.join(file)).unwrap();
        for (function, line, lines) in long_functions(&text, MAX_LINES) {
            if !LONG_KERNELS.contains(&(name.as_str(), function.as_str())) {
                bad.push(format!("{name}:{line}: fn {function} is {lines} lines (at most {MAX_LINES})"));
            }
        }
        if text.contains("clippy::too_many_arguments") && !MANY_ARGUMENTS.contains(&name.as_str()) {
            bad.push(format!("{name}: allows too_many_arguments; pass a request struct"));
        }
        if name.starts_with("python/") {
            for line in allowed_without_python_signature(&text) {
                bad.push(format!("{name}:{line}: allows too_many_arguments on a function Python does not call"));
            }
        }
    }
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}

/// Lines (1-based) of `text` allowing `too_many_arguments` without a `#[pyo3(signature = …)]`
/// among the four lines above: in the Python crate only a function whose arguments are Python's
/// keyword arguments may take many.
fn allowed_without_python_signature(text: &str) -> Vec<usize> {
    let lines: Vec<&str> = text.lines().collect();
    (0..lines.len())
        .filter(|&i| lines[i].contains("clippy::too_many_arguments"))
        .filter(|&i| !lines[i.saturating_sub(4)..i].iter().any(|l| l.contains("#[pyo3(signature")))
        .map(|i| i + 1)
        .collect()
}

#[test]
fn only_a_python_signature_excuses_many_arguments_in_the_python_crate() {
    let python = "#[pyfunction]\n#[pyo3(signature = (a, b = None,\n    c = None))]\n#[allow(clippy::too_many_arguments)]\nfn f() {}\n";
    assert!(allowed_without_python_signature(python).is_empty());
    let helper = "/// A helper.\n#[allow(clippy::too_many_arguments)]\nfn g() {}\n";
    assert_eq!(allowed_without_python_signature(helper), [2]);
}

#[test]
fn a_long_function_is_measured_from_its_fn_to_its_closing_brace() {
    let body = "    let x = 1;\n".repeat(5);
    let text = format!("/// doc\npub fn short() {{\n}}\n\nfn long(a: u32) -> u32 {{\n{body}    if a > 0 {{ a }} else {{ 0 }}\n}}\nfn decl();\n");
    assert_eq!(long_functions(&text, 3), [("long".to_string(), 5, 8)]);
    assert!(long_functions(&text, 8).is_empty());
}

/// The lines of `text` before its inline tests: all of them without.
fn lines_before_tests(text: &str) -> usize {
    text.lines().take_while(|l| !l.starts_with("#[cfg(test)]")).count()
}

#[test]
fn no_module_is_longer_than_one_concern() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut bad = Vec::new();
    for file in workspace_sources(root) {
        let name = file.to_string_lossy().replace('\\', "/");
        let lines = lines_before_tests(&std::fs::read_to_string(root.join(&file)).unwrap());
        if lines > MAX_MODULE_LINES && !name.starts_with(LONG_MODULES) {
            bad.push(format!(
                "{name}: {lines} lines before its tests (at most {MAX_MODULE_LINES}): split it by concern"
            ));
        }
    }
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}

#[test]
fn a_module_is_measured_up_to_its_inline_tests() {
    assert_eq!(lines_before_tests("//! doc\nfn a() {}\n\n#[cfg(test)]\nmod tests {\n}\n"), 3);
    assert_eq!(lines_before_tests("fn a() {}\n    #[cfg(test)]\nfn b() {}\n"), 3);
}

#[test]
fn every_stage_run_only_orchestrates() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut bad = Vec::new();
    let mut stages = 0;
    for file in sources(root, "crates/pipeline/src") {
        let whole = std::fs::read_to_string(root.join(&file)).unwrap();
        // The stages of the module itself, not its tests' (the runner's own `run` is not a stage's).
        let text: String = whole.lines().take(lines_before_tests(&whole)).flat_map(|l| [l, "\n"]).collect();
        if !text.contains("impl Stage for") {
            continue;
        }
        stages += 1;
        for (function, line, lines) in long_functions(&text, MAX_STAGE_RUN_LINES) {
            if function == "run" {
                bad.push(format!(
                    "{}:{line}: a stage's run is {lines} lines (at most {MAX_STAGE_RUN_LINES})",
                    file.display()
                ));
            }
        }
    }
    assert!(stages >= 10, "only {stages} stage modules found");
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}

/// One name per stage: its struct is `{Folder}Stage` (`nerf_collision` → `NerfCollisionStage`),
/// its module file is named after its folder, and its report section's id is its folder.
#[test]
fn every_stage_has_one_name() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut bad = Vec::new();
    let mut stages = 0;
    for file in sources(root, "crates/pipeline/src") {
        let whole = std::fs::read_to_string(root.join(&file)).unwrap();
        // Code only: a doc example's stage is not one of the pipeline's.
        let text: String = whole
            .lines()
            .take(lines_before_tests(&whole))
            .filter(|l| !l.trim_start().starts_with("//"))
            .flat_map(|l| [l, "\n"])
            .collect();
        let Some(at) = text.find("impl Stage for ") else { continue };
        stages += 1;
        let rest = &text[at + "impl Stage for ".len()..];
        let name: String = rest.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
        let folder = match text.find("const NAME: &'static str = \"") {
            Some(i) => text[i + "const NAME: &'static str = \"".len()..].split('"').next().unwrap().to_string(),
            // A stage whose name is a library's constant (the stress stage's `STAGE`).
            None => file.file_stem().unwrap().to_string_lossy().into_owned(),
        };
        let camel: String = folder.split('_').map(|w| w[..1].to_uppercase() + &w[1..]).collect::<Vec<_>>().join("");
        let want = format!("{camel}Stage");
        if name != want {
            bad.push(format!("{}: stage `{name}` writes folder `{folder}`: name it `{want}`", file.display()));
        }
        if file.file_stem().unwrap().to_string_lossy() != folder {
            bad.push(format!(
                "{}: stage `{name}` writes folder `{folder}`: name its module `{folder}.rs`",
                file.display()
            ));
        }
        let report = file.with_extension("").join("report.rs");
        if let Ok(r) = std::fs::read_to_string(root.join(&report)) {
            for (i, _) in r.match_indices("Section::new(") {
                let id = &r[i + "Section::new(".len()..];
                if !id.trim_start().starts_with(&format!("{name}::NAME")) && !id.trim_start().starts_with("<") {
                    bad.push(format!(
                        "{}: a section of stage `{name}` is not identified by `{name}::NAME`",
                        report.display()
                    ));
                }
            }
        }
    }
    assert!(stages >= 10, "only {stages} stage modules found");
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}

/// The wheel's build (maturin builds the Python package alone) reuses the test suite's: every
/// crate the package shares with the workspace resolves to the same features both ways, or
/// maturin rebuilds every workspace crate (see `python/Cargo.toml`).
#[test]
fn the_python_package_builds_with_the_workspaces_features() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let features = |scope: &[&str]| -> std::collections::BTreeMap<String, std::collections::BTreeSet<String>> {
        let out = std::process::Command::new(&cargo)
            .args(["tree", "--offline", "--prefix", "none", "-f", "{p}|{f}"])
            .args(scope)
            .current_dir(root)
            .output()
            .unwrap();
        assert!(out.status.success(), "cargo tree: {}", String::from_utf8_lossy(&out.stderr));
        let mut map = std::collections::BTreeMap::<String, std::collections::BTreeSet<String>>::new();
        for line in String::from_utf8_lossy(&out.stdout).lines() {
            let line = line.trim_end_matches(" (*)");
            if let Some((package, features)) = line.split_once('|') {
                let entry = map.entry(package.to_string()).or_default();
                entry.extend(features.split(',').filter(|f| !f.is_empty()).map(str::to_string));
            }
        }
        map
    };
    let (python, workspace) = (features(&["-p", "nerfsv-python"]), features(&["--workspace"]));
    assert!(python.len() > 50, "only {} packages under the Python package", python.len());
    let differ: Vec<String> = python
        .iter()
        .filter_map(|(p, f)| {
            let w = workspace.get(p)?;
            (w != f).then(|| format!("{p}: the workspace's {w:?}, the Python package's alone {f:?}"))
        })
        .collect();
    assert!(differ.is_empty(), "{}", differ.join("\n"));
}
