//! Cache keys come from the code: a change to one crate's source changes the digest of exactly
//! the crates that depend on it, and so the keys of exactly the stages that run them.

use std::path::Path;

use nerfsv_pipeline::digest::{workspace_dependencies, workspace_digests};
use nerfsv_pipeline::stage::code_digest_in;

fn write(path: &Path, text: &str) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, text).unwrap();
}

/// A workspace of four crates: `low` ← `mid` ← `top`, and `apart` on its own.
fn workspace(root: &Path) {
    let manifest = |name: &str, deps: &[&str]| {
        let mut m =
            format!("[package]\nname = \"{name}\"\nversion = \"0.1.0\"\n\n[dependencies]\nserde.workspace = true\n");
        for d in deps {
            m.push_str(&format!("{d}.workspace = true\n"));
        }
        m.push_str("\n[dev-dependencies]\nnerfsv-apart.workspace = true\n");
        m
    };
    for (dir, name, deps) in [
        ("low", "nerfsv-low", &[][..]),
        ("mid", "nerfsv-mid", &["nerfsv-low"][..]),
        ("top", "nerfsv-top", &["nerfsv-mid"][..]),
        ("apart", "nerfsv-apart", &[][..]),
    ] {
        write(&root.join(dir).join("Cargo.toml"), &manifest(name, deps));
        write(&root.join(dir).join("src/lib.rs"), &format!("//! {name}\npub fn f() -> u32 {{ 1 }}\n"));
    }
    write(&root.join("low/src/inner/deep.rs"), "pub const X: u32 = 1;\n");
    // Not a crate: skipped.
    write(&root.join("notes/readme.txt"), "hello");
}

#[test]
fn the_manifest_parser_reads_workspace_dependencies_only() {
    let m = "[package]\nname = \"nerfsv-x\"\n[dependencies]\nnerfsv-scene.workspace = true\nnerfsv-nerf = { path = \"../nerf\" }\nrayon.workspace = true\n[dev-dependencies]\nnerfsv-testkit.workspace = true\n[build-dependencies]\nnerfsv-plot.workspace = true\n";
    assert_eq!(workspace_dependencies(m), ["nerfsv-scene", "nerfsv-nerf"]);
}

#[test]
fn a_change_to_one_crate_changes_the_digests_of_exactly_it_and_its_dependents() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    workspace(root);
    let before = workspace_digests(root).unwrap();
    assert_eq!(before.keys().collect::<Vec<_>>(), ["nerfsv-apart", "nerfsv-low", "nerfsv-mid", "nerfsv-top"]);
    assert_eq!(workspace_digests(root).unwrap(), before, "digests are not deterministic");

    // One line in a nested module of the lowest crate.
    write(&root.join("low/src/inner/deep.rs"), "pub const X: u32 = 2;\n");
    let after = workspace_digests(root).unwrap();
    for name in ["nerfsv-low", "nerfsv-mid", "nerfsv-top"] {
        assert_ne!(before[name], after[name], "{name} did not change");
    }
    assert_eq!(before["nerfsv-apart"], after["nerfsv-apart"]);

    // The middle crate's manifest: it and its dependent, not the crate below.
    let again = workspace_digests(root).unwrap();
    let m = std::fs::read_to_string(root.join("mid/Cargo.toml")).unwrap();
    write(&root.join("mid/Cargo.toml"), &m.replace("version = \"0.1.0\"", "version = \"0.2.0\""));
    let third = workspace_digests(root).unwrap();
    assert_eq!(again["nerfsv-low"], third["nerfsv-low"]);
    assert_ne!(again["nerfsv-mid"], third["nerfsv-mid"]);
    assert_ne!(again["nerfsv-top"], third["nerfsv-top"]);
    assert_eq!(again["nerfsv-apart"], third["nerfsv-apart"]);

    // A file renamed with the same bytes is a change; a file outside src/ is not.
    std::fs::rename(root.join("apart/src/lib.rs"), root.join("apart/src/main.rs")).unwrap();
    let fourth = workspace_digests(root).unwrap();
    assert_ne!(third["nerfsv-apart"], fourth["nerfsv-apart"]);
    write(&root.join("apart/tests/t.rs"), "#[test] fn t() {}\n");
    assert_eq!(workspace_digests(root).unwrap(), fourth);
}

/// A pipeline crate beside `workspace`'s: stage `a` imports the runner's `error` module (which
/// names `nerfsv-top` for a type) and has a report; stage `c` calls the helper module `h`, which
/// runs `nerfsv-mid`; stage `d` imports `c`.
fn pipeline(root: &Path) {
    let src = root.join("pipeline/src");
    write(&root.join("pipeline/Cargo.toml"), "[package]\nname = \"nerfsv-pipeline\"\n");
    write(
        &src.join("lib.rs"),
        "pub mod a;\nmod error;\npub mod c;\npub mod d;\nmod h;\npub use error::PipelineError;\n",
    );
    write(
        &src.join("a.rs"),
        "mod report;\npub struct A;\nimpl Stage for A {}\nfn run() -> crate::PipelineError { nerfsv_low::f() }\n",
    );
    write(&src.join("a/report.rs"), "use super::A;\nconst TITLE: &str = \"A\";\n");
    write(&src.join("error.rs"), "pub struct PipelineError(nerfsv_top::Error);\npub const K: u32 = 1;\n");
    write(&src.join("c.rs"), "pub struct C;\nimpl Stage for C {}\npub fn run() { crate::h::go(); }\n");
    write(&src.join("h.rs"), "pub fn go() { nerfsv_mid::f(); }\n");
    write(&src.join("d.rs"), "pub struct D;\nimpl Stage for D {}\nfn run() { crate::c::run(); }\n");
}

#[test]
fn a_stage_key_covers_the_modules_its_module_reaches_and_the_crates_they_name() {
    use nerfsv_pipeline::digest::{module_digests, module_reach};
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    workspace(root);
    pipeline(root);
    let reach = module_reach(&root.join("pipeline/src")).unwrap();
    let names = |m: &str| reach[m].iter().map(String::as_str).collect::<Vec<_>>();
    assert_eq!(names("a"), ["a", "error", "nerfsv-low"], "error through the root's re-export, not its crates");
    assert_eq!(names("d"), ["c", "d", "h", "nerfsv-mid"], "a helper two imports away and the crate it calls");
    assert_eq!(names("a::report"), ["a", "a::report", "error", "nerfsv-low"]);

    let before = module_digests(root).unwrap();
    assert_eq!(module_digests(root).unwrap(), before, "digests are not deterministic");
    let changed = |edit: &dyn Fn(&Path)| {
        let earlier = module_digests(root).unwrap();
        edit(root);
        let later = module_digests(root).unwrap();
        ["a", "c", "d"].into_iter().filter(|m| earlier[*m] != later[*m]).collect::<Vec<_>>()
    };
    let src = root.join("pipeline/src");
    // A module reached through another: the omission a hand-written list of modules made.
    assert_eq!(
        changed(&|_| write(&src.join("h.rs"), "pub fn go() { nerfsv_mid::f(); nerfsv_mid::f(); }\n")),
        ["c", "d"]
    );
    assert_eq!(changed(&|_| write(&src.join("error.rs"), "pub struct PipelineError(nerfsv_top::Error);\n")), ["a"]);
    assert_eq!(changed(&|r| write(&r.join("low/src/lib.rs"), "pub fn f() -> u32 { 2 }\n")), ["a", "c", "d"]);
    assert_eq!(changed(&|r| write(&r.join("mid/src/lib.rs"), "pub fn f() -> u32 { 3 }\n")), ["c", "d"]);
    assert!(changed(&|r| write(&r.join("top/src/lib.rs"), "pub fn f() -> u32 { 4 }\n")).is_empty(), "a type's crate");
    assert!(changed(&|_| write(&src.join("a/report.rs"), "const TITLE: &str = \"Stage A\";\n")).is_empty());
}

#[test]
fn a_stage_module_path_finds_its_file_module_or_is_keyed_by_its_path_outside_the_crate() {
    let modules = [("stress", 7u64), ("stress::report", 8), ("online::config", 9)];
    assert_eq!(code_digest_in("nerfsv_pipeline::stress", &modules).unwrap(), format!("{:016x}", 7));
    assert_eq!(code_digest_in("nerfsv_pipeline::stress::tests", &modules).unwrap(), format!("{:016x}", 7));
    assert_eq!(code_digest_in("nerfsv_pipeline::online::config", &modules).unwrap(), format!("{:016x}", 9));
    let e = code_digest_in("nerfsv_pipeline::gone", &modules).unwrap_err().to_string();
    assert!(e.contains("nerfsv_pipeline::gone"), "{e}");
    let outside = code_digest_in("my_study::count", &modules).unwrap();
    assert_ne!(outside, code_digest_in("my_study::other", &modules).unwrap());
}

/// Copies every crate's `Cargo.toml` and `src/` of this workspace under `to`.
fn copy_sources(from: &Path, to: &Path) {
    for entry in std::fs::read_dir(from).unwrap().flatten() {
        let dir = entry.path();
        if !dir.join("Cargo.toml").is_file() {
            continue;
        }
        let name = dir.file_name().unwrap();
        let mut stack = vec![dir.join("src")];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).unwrap().flatten() {
                let p = e.path();
                if p.is_dir() {
                    stack.push(p);
                } else {
                    let rel = p.strip_prefix(&dir).unwrap();
                    std::fs::create_dir_all(to.join(name).join(rel).parent().unwrap()).unwrap();
                    std::fs::copy(&p, to.join(name).join(rel)).unwrap();
                }
            }
        }
        std::fs::copy(dir.join("Cargo.toml"), to.join(name).join("Cargo.toml")).unwrap();
    }
}

/// The stages whose code digest changes when `edit` changes a copy of this workspace's
/// sources (every crate's manifest and `src/`), in the run's order.
fn redone_by(edit: impl FnOnce(&Path)) -> Vec<&'static str> {
    use nerfsv_pipeline::calibration::CalibrationStage;
    use nerfsv_pipeline::ensemble::EnsembleStage;
    use nerfsv_pipeline::flight::FlightStage;
    use nerfsv_pipeline::online::OnlineStage;
    use nerfsv_pipeline::stages::{CollisionStage, DatasetStage, EvalStage, NerfCollisionStage, NerfStage};
    use nerfsv_pipeline::stress::StressStage;
    use nerfsv_pipeline::uq::UqStage;
    use nerfsv_pipeline::Stage;

    let stages: [(&'static str, &str); 11] = [
        (DatasetStage::NAME, DatasetStage::MODULE),
        (CollisionStage::NAME, CollisionStage::MODULE),
        (NerfStage::NAME, NerfStage::MODULE),
        (EvalStage::NAME, EvalStage::MODULE),
        (EnsembleStage::NAME, EnsembleStage::MODULE),
        (UqStage::NAME, UqStage::MODULE),
        (NerfCollisionStage::NAME, NerfCollisionStage::MODULE),
        (FlightStage::NAME, FlightStage::MODULE),
        (CalibrationStage::NAME, CalibrationStage::MODULE),
        (StressStage::NAME, StressStage::MODULE),
        (OnlineStage::NAME, OnlineStage::MODULE),
    ];
    let dir = tempfile::tempdir().unwrap();
    let crates_dir = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    copy_sources(crates_dir, dir.path());
    let keys = || {
        let digests = nerfsv_pipeline::digest::module_digests(dir.path()).unwrap();
        let table: Vec<(&str, u64)> = digests.iter().map(|(n, &d)| (n.as_str(), d)).collect();
        stages.map(|(name, module)| (name, code_digest_in(module, &table).unwrap()))
    };
    let before = keys();
    edit(dir.path());
    let after = keys();
    before.iter().zip(&after).filter(|(b, a)| b.1 != a.1).map(|(b, _)| b.0).collect()
}

/// `f(text)` replaces the file `rel` under `root`.
fn rewrite(root: &Path, rel: &str, f: impl FnOnce(&str) -> String) {
    let path = root.join(rel);
    let text = std::fs::read_to_string(&path).unwrap();
    let changed = f(&text);
    assert_ne!(changed, text, "{rel}: the edit changed nothing");
    std::fs::write(&path, changed).unwrap();
}

#[test]
fn a_line_changed_in_the_simulator_redoes_the_stages_that_fly_or_load_worlds_and_nothing_upstream() {
    let redone = redone_by(|root| {
        rewrite(root, "sim/src/lib.rs", |t| format!("{t}\n#[doc(hidden)]\npub const ONE_MORE_LINE: u8 = 1;\n"))
    });
    // The uncertainty stage loads the ensemble's members as the study crate's worlds.
    assert_eq!(redone, ["uq", "flight", "calibration", "stress", "online"]);
}

/// The config imports each stage's settings module (`online::config` names the uncertainty
/// crate's methods): a settings type reached through the runner's config keys no stage by its
/// crate, so a line in the uncertainty or validation crate retrains nothing.
#[test]
fn a_line_changed_in_the_uncertainty_or_validation_crate_redoes_no_training() {
    let line = |t: &str| format!("{t}\n#[doc(hidden)]\npub const ONE_MORE_LINE: u8 = 1;\n");
    let redone = redone_by(|root| rewrite(root, "uq/src/lib.rs", line));
    assert_eq!(redone, ["uq", "flight", "calibration", "stress", "online"]);
    let redone = redone_by(|root| rewrite(root, "validation/src/lib.rs", line));
    assert_eq!(redone, ["uq", "flight", "calibration", "stress", "online"]);
}

#[test]
fn a_doc_comment_in_the_config_a_colour_in_the_plot_crate_or_a_report_section_redoes_no_stage() {
    let redone = redone_by(|root| {
        rewrite(root, "pipeline/src/config.rs", |t| {
            t.replacen("\n/// ", "\n/// Reworded for a reader, as documentation changes do.\n/// ", 1)
        });
        rewrite(root, "pipeline/src/config.rs", |t| format!("{t}\n// A comment at the end.\n"));
    });
    assert!(redone.is_empty(), "a doc comment redid {redone:?}");
    let redone = redone_by(|root| {
        rewrite(root, "plot/src/palette.rs", |t| t.replace("Rgb(0x1f, 0x1f, 0x1f)", "Rgb(0x20, 0x20, 0x20)"))
    });
    assert!(redone.is_empty(), "a colour redid {redone:?}");
    // A stage's section and its one-line description live in its module's child report.rs.
    let redone = redone_by(|root| {
        rewrite(root, "pipeline/src/stress/report.rs", |t| t.replacen("Monte Carlo", "Plain Monte Carlo", 1));
        rewrite(root, "pipeline/src/dataset/report.rs", |t| {
            t.replacen("views of {}×{} in", "views, {}×{} pixels, in", 1)
        });
    });
    assert!(redone.is_empty(), "a report section redid {redone:?}");
}

#[test]
fn a_change_in_the_nerf_kernels_redoes_training_and_what_uses_the_model() {
    let redone = redone_by(|root| {
        rewrite(root, "nerf/src/kernels.rs", |t| format!("{t}\n#[doc(hidden)]\npub const ONE_MORE_LINE: u8 = 1;\n"))
    });
    assert_eq!(
        redone,
        ["nerf", "eval", "ensemble", "uq", "nerf_collision", "flight", "calibration", "stress", "online"]
    );
}

#[test]
fn code_text_drops_comments_and_spacing_but_keeps_literals() {
    use nerfsv_pipeline::digest::code_text;
    let a = "/// Doc.\nfn f(x: u32) -> u32 {\n    // note\n    x /* inline /* nested */ */ + 1\n}\n";
    let b = "fn f(x: u32) -> u32 { x + 1 }";
    assert_eq!(code_text(a), code_text(b));
    assert_eq!(code_text(b), "fn f(x: u32) -> u32 { x + 1 }");
    // What a literal holds is code, however it looks.
    for (x, y) in [
        (r#"let s = "a // b";"#, r#"let s = "a // c";"#),
        (r#"let s = "a  b";"#, r#"let s = "a b";"#),
        (r##"let s = r#"x " // y"#;"##, r##"let s = r#"x " // z"#;"##),
        ("let c = '/'; let d = 1;", "let c = '/'; let d = 2;"),
        ("let c = '\\''; // q\nlet d = 1;", "let c = '\\''; // q\nlet d = 2;"),
        ("let s = \"\\\" // x\";", "let s = \"\\\" // y\";"),
    ] {
        assert_ne!(code_text(x), code_text(y), "{x} / {y}");
    }
    // A lifetime is not a character literal: the comment after it is still a comment.
    assert_eq!(code_text("fn f<'a>(x: &'a u8) {} // c"), code_text("fn f<'a>(x: &'a u8) {}"));
}

#[test]
fn a_presentation_crate_is_left_out_of_its_dependents_digests() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    workspace(root);
    let m = std::fs::read_to_string(root.join("low/Cargo.toml")).unwrap();
    write(&root.join("low/Cargo.toml"), &format!("{m}\n[package.metadata.nerfsv]\npresentation = true\n"));
    let before = workspace_digests(root).unwrap();
    write(&root.join("low/src/inner/deep.rs"), "pub const X: u32 = 2;\n");
    let after = workspace_digests(root).unwrap();
    assert_ne!(before["nerfsv-low"], after["nerfsv-low"], "its own digest follows its code");
    assert_eq!(before["nerfsv-mid"], after["nerfsv-mid"]);
    assert_eq!(before["nerfsv-top"], after["nerfsv-top"]);
}

#[test]
fn a_line_changed_in_the_ensemble_stage_redoes_every_stage_that_loads_its_members() {
    let redone = redone_by(|root| {
        rewrite(root, "pipeline/src/ensemble.rs", |t| {
            format!("{t}\n#[doc(hidden)]\npub const ONE_MORE_LINE: u8 = 1;\n")
        })
    });
    assert_eq!(redone, ["ensemble", "uq", "calibration", "stress", "online"]);
}
