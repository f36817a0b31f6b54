//! A run only ever clears what it wrote: output folders carry nerfsv's marker, a folder holding
//! a user's files is refused before any work, and the check opens every input. Each message
//! names the key or flag, the path as given, what is wrong and what to do.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{nerfsv, nerfsv_with, s, tiny_ensemble_run_config};
use proptest::prelude::*;

/// Every file below `root` (not following links) with its bytes, and every folder.
fn snapshot(root: &Path) -> Vec<(PathBuf, Option<Vec<u8>>)> {
    let mut out = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for e in std::fs::read_dir(&dir).unwrap().flatten() {
            let p = e.path();
            let kind = e.file_type().unwrap();
            let rel = p.strip_prefix(root).unwrap().to_path_buf();
            if kind.is_dir() {
                stack.push(p);
                out.push((rel, None));
            } else if kind.is_file() {
                out.push((rel, Some(std::fs::read(&p).unwrap())));
            }
        }
    }
    out.sort();
    out
}

/// Asserts that everything in `before` is still there with the same bytes (new files may have
/// appeared beside them).
fn assert_kept(root: &Path, before: &[(PathBuf, Option<Vec<u8>>)], what: &str) {
    let now = snapshot(root);
    for (path, bytes) in before {
        let found = now.iter().find(|(p, _)| p == path);
        assert!(found.is_some(), "{what}: {} is gone", path.display());
        assert!(found.unwrap().1 == *bytes, "{what}: {} changed", path.display());
    }
}

fn write(path: &Path, bytes: &[u8]) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn a_users_folder_sharing_stage_names_is_refused_untouched_and_a_folder_nerfsv_made_is_reused() {
    let dir = tempfile::tempdir().unwrap();
    let foreign = dir.path().join("foreign");
    write(&foreign.join("dataset/notes.txt"), b"mine");
    write(&foreign.join("nerf/notes.txt"), b"mine too");
    let before = snapshot(dir.path());
    let cfg = tiny_ensemble_run_config(dir.path());
    for check in [true, false] {
        let mut args = vec!["run", s(&cfg), "--out", s(&foreign)];
        if check {
            args.push("--check");
        }
        let (ok, _, err) = nerfsv(&args);
        assert!(!ok, "{err}");
        assert!(
            err.contains(&format!(
                "--out {}: the folder already holds files nerfsv did not write (dataset/, nerf/",
                s(&foreign)
            )),
            "{err}"
        );
        assert!(err.contains("give the name of a new folder"), "{err}");
        assert_kept(dir.path(), &before, "a refused run");
    }
    // A dataset nerfsv made is its own to replace; the folder carries its marker.
    let ds = dir.path().join("ds");
    let scene = |out: &Path| {
        nerfsv(&[
            "scene",
            "--scene",
            "monolith",
            "--out",
            s(out),
            "--width",
            "4",
            "--height",
            "4",
            "--train",
            "1",
            "--val",
            "1",
            "--test",
            "1",
            "--supersample",
            "1",
        ])
    };
    for _ in 0..2 {
        let (ok, _, err) = scene(&ds);
        assert!(ok, "{err}");
        let marker = std::fs::read_to_string(ds.join("nerfsv-folder.json")).unwrap();
        assert!(marker.contains("\"written_by\": \"nerfsv\"") && marker.contains("\"kind\": \"dataset\""), "{marker}");
    }
    // …but not a run folder's place, nor a user's capture.
    let (ok, _, err) = scene(&foreign);
    assert!(!ok && err.contains("nerfsv did not write"), "{err}");
    assert_kept(dir.path(), &before, "a refused scene");
}

#[test]
fn an_earlier_versions_run_folder_is_recognised_by_its_records_and_marked() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    write(&run.join("summary.json"), b"{}");
    write(&run.join("dataset/stage.json"), br#"{"key": "old", "seconds": 1.0, "figures": {}}"#);
    let (ok, _, err) = nerfsv(&["run", "--check", "--out", s(&run), "--set", "scene=monolith"]);
    assert!(ok, "{err}");
    assert!(err.contains(&format!("ready to run into {}", s(&run))), "{err}");
    // A stage folder without its record (or a user's folder of that name) is not recognised.
    write(&run.join("nerf/notes.txt"), b"mine");
    let (ok, _, err) = nerfsv(&["run", "--check", "--out", s(&run)]);
    assert!(!ok && err.contains("nerf/"), "{err}");
}

#[test]
fn out_is_refused_when_empty_a_file_the_current_home_or_root_folder() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("a_regular_file");
    write(&file, b"x");
    let cfg = dir.path().join("empty_out.toml");
    write(&cfg, b"out = \"\"\n");
    let (ok, _, err) = nerfsv(&["run", s(&cfg), "--check"]);
    assert!(!ok, "{err}");
    assert!(err.contains("out: the path is empty; give the name of a new folder"), "{err}");
    let (ok, _, err) = nerfsv(&["run", "--check", "--out", s(&file)]);
    assert!(!ok && err.contains(&format!("--out {}: is a file, not a folder", s(&file))), "{err}");
    for (out, place) in [(".", "the current folder"), ("/", "the filesystem root")] {
        let out = Command::new(env!("CARGO_BIN_EXE_nerfsv"))
            .args(["run", "--check", "--out", out])
            .current_dir(dir.path())
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(place) && err.contains("--out runs/my_study"), "{err}");
    }
    let (ok, _, err) = nerfsv_with(&["run", "--check", "--out", s(dir.path())], &[("HOME", s(dir.path()))]);
    assert!(!ok && err.contains("is your home folder"), "{err}");
    // The other commands' output folders too.
    let (ok, _, err) = nerfsv(&["scene", "--out", s(&file)]);
    assert!(!ok && err.contains("is a file, not a folder"), "{err}");
}

#[test]
fn environment_variables_are_checked_like_flags() {
    for bad in ["abc", "-3", "0", "nan"] {
        let (ok, _, err) = nerfsv_with(&["config"], &[("NERFSV_MEMORY_BUDGET_GIB", bad)]);
        assert!(!ok, "{bad}");
        assert!(err.contains("NERFSV_MEMORY_BUDGET_GIB") && err.contains("must be a positive number of GiB"), "{err}");
        assert!(err.contains(&format!("found \"{bad}\"")), "{err}");
    }
    let (ok, _, err) = nerfsv_with(&["run", "--check"], &[("NERFSV_MEMORY_BUDGET_GIB", "4")]);
    assert!(ok, "{err}");
}

#[test]
fn the_check_opens_a_dataset_world_without_a_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n);
    let check = |dataset: &Path| {
        nerfsv(&["run", "--check", "--out", s(&p("out")), "--set", &format!("world.dataset={}", s(dataset))])
    };
    let (ok, _, err) = check(&p("nowhere"));
    assert!(!ok, "{err}");
    assert!(
        err.contains(&format!(
            "world.dataset: {}: no such file or folder; give the folder of a capture",
            s(&p("nowhere"))
        )),
        "{err}"
    );
    std::fs::create_dir(p("empty")).unwrap();
    let (ok, _, err) = check(&p("empty"));
    assert!(!ok && err.contains("is not a dataset folder") && err.contains("transforms_train.json"), "{err}");
    // A capture whose frames hold text.
    write(&p("text/a.jpg"), b"this is not an image");
    write(
        &p("text/transforms_train.json"),
        br#"{"camera_angle_x": 0.8, "frames": [{"file_path": "a.jpg", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,2],[0,0,0,1]]}]}"#,
    );
    let (ok, _, err) = check(&p("text"));
    assert!(!ok, "{err}");
    assert!(
        err.contains("world.dataset") && err.contains("cannot be read as a dataset") && err.contains("a.jpg"),
        "{err}"
    );
    // A one-image COLMAP capture: its single image is held out, and the message says so.
    let col = p("colmap");
    write(&col.join("sparse/0/cameras.txt"), b"1 PINHOLE 4 4 4 4 2 2\n");
    write(&col.join("sparse/0/images.txt"), b"1 1 0 0 0 0 0 2 1 a.png\n\n");
    let mut png = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut png, 4, 4);
        enc.set_color(png::ColorType::Rgb);
        enc.write_header().unwrap().write_image_data(&[128u8; 48]).unwrap();
    }
    write(&col.join("images/a.png"), &png);
    let (ok, _, err) = check(&col);
    assert!(!ok, "{err}");
    assert!(
        err.contains("the train split has no frames") && err.contains("held out") && err.contains("1 registered image"),
        "{err}"
    );
}

#[test]
fn the_default_run_folder_follows_the_world() {
    let dir = tempfile::tempdir().unwrap();
    let run = |args: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_nerfsv")).args(args).current_dir(dir.path()).output().unwrap();
        (out.status.success(), String::from_utf8_lossy(&out.stderr).into_owned())
    };
    for (scene, folder) in [("stonehenge", "runs/stonehenge"), ("pillars", "runs/pillars")] {
        let (ok, err) = run(&["run", "--check", "--set", &format!("scene={scene}")]);
        assert!(ok && err.contains(&format!("ready to run into {folder} ")), "{err}");
    }
    // A mesh world's folder is named after the mesh file (read through the library: the check
    // would read the mesh itself first).
    let cfg = dir.path().join("box.toml");
    write(&cfg, b"[world]\nmesh = \"arch.ply\"\n");
    let config = nerfsv_pipeline::RunConfig::load(&cfg).unwrap();
    assert_eq!(config.run_folder(), Path::new("runs/arch"));
    let cfg = dir.path().join("capture.toml");
    write(&cfg, b"[world]\ndataset = \"my_capture\"\n");
    let config = nerfsv_pipeline::RunConfig::load(&cfg).unwrap();
    assert_eq!(config.run_folder(), Path::new("runs/my_capture"));
}

#[test]
fn path_guard_and_mesh_messages_read_as_sentences() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n);
    // An output inside an input: the flag, the path, what is wrong, the fix.
    std::fs::create_dir_all(p("sub")).unwrap();
    let mesh = p("sub/world.obj");
    write(&mesh, b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let (ok, _, err) = nerfsv(&["collision", "--gt-mesh", s(&mesh), "--out", s(&mesh)]);
    assert!(!ok, "{err}");
    assert!(
        err.contains(&format!("--out {}: is what --gt-mesh reads ({})", s(&mesh), s(&mesh)))
            && err.contains("choose another path for --out, outside --gt-mesh"),
        "{err}"
    );
    // A run folder inside the capture it reads: the key, the path, where it lies, the fix.
    let cap = common::tiny_dataset(&p("sub"), "2", "1");
    let run = cap.join("run");
    let (ok, _, err) = nerfsv(&["run", "--check", "--out", s(&run), "--set", &format!("world.dataset={}", s(&cap))]);
    assert!(!ok, "{err}");
    assert!(
        err.contains(&format!("--out {}: lies inside world.dataset {}, which nerfsv reads", s(&run), s(&cap)))
            && err.contains("choose another path for --out, outside world.dataset"),
        "{err}"
    );
    assert!(!run.exists(), "the check wrote nothing");
    // One wording for a missing mesh of any format, naming the key.
    for name in ["missing.obj", "missing.glb", "missing.ply"] {
        let (ok, _, err) =
            nerfsv(&["run", "--check", "--out", s(&p("o")), "--set", &format!("world.mesh={}", s(&p(name)))]);
        assert!(!ok, "{err}");
        assert!(err.contains(&format!("world.mesh: {}: no such file or folder", s(&p(name)))), "{err}");
    }
    write(&p("text.glb"), b"hello");
    let (ok, _, err) =
        nerfsv(&["run", "--check", "--out", s(&p("o")), "--set", &format!("world.mesh={}", s(&p("text.glb")))]);
    assert!(!ok && err.contains("is not a readable glTF 2.0 file") && err.contains("export the mesh again"), "{err}");
}

/// The commands a user points at an output, each cheap on a tiny input.
#[derive(Clone, Copy, Debug)]
enum Cmd {
    Scene,
    Run,
    RunCheck,
    Collision,
    Train,
}

/// Where the command is told to write, relative to the user's tree (the command runs in it).
#[derive(Clone, Copy, Debug)]
enum Out {
    Current,
    CurrentSlash,
    UpAgain,
    UserFolder,
    UserStageFolder,
    Link,
    LinkedNew,
    NestedNew,
    UserFile,
    New,
}

impl Out {
    fn path(self) -> &'static str {
        match self {
            Out::Current => ".",
            Out::CurrentSlash => "./",
            Out::UpAgain => "u/..",
            Out::UserFolder => "u",
            Out::UserStageFolder => "u/dataset",
            Out::Link => "link",
            Out::LinkedNew => "link/fresh",
            Out::NestedNew => "u/new/deeper",
            Out::UserFile => "u/notes.txt",
            Out::New => "new",
        }
    }
}

/// Names a user's files and folders may have, stage and output names among them.
const NAMES: [&str; 12] = [
    "dataset",
    "nerf",
    "report",
    "stress",
    "summary.json",
    "checkpoint.safetensors",
    "r_0.png",
    "trajectory.csv",
    "stage.json",
    "nerfsv-folder.json",
    "scene.json",
    "notes.txt",
];

fn user_tree() -> impl Strategy<Value = Vec<(usize, usize, Vec<u8>)>> {
    prop::collection::vec((0..4usize, 0..NAMES.len(), prop::collection::vec(any::<u8>(), 0..16)), 1..10)
}

/// Lays out the user's tree in `root`: files at `u/`, `u/A/`, `u/A/B/`, `other/` (the first
/// component of a deeper path is one of [`NAMES`], so stage-named folders are common).
fn lay_out(root: &Path, files: &[(usize, usize, Vec<u8>)]) {
    for (k, (depth, name, bytes)) in files.iter().enumerate() {
        let folder = match depth {
            0 => PathBuf::from("u"),
            1 => PathBuf::from("u").join(NAMES[(k + name) % 4]),
            2 => PathBuf::from("u").join(NAMES[k % 4]).join(NAMES[(k + 1) % 4]),
            _ => PathBuf::from("other"),
        };
        let path = root.join(folder).join(NAMES[*name]);
        if path.exists() {
            continue;
        }
        if std::fs::create_dir_all(path.parent().unwrap()).is_ok() {
            let _ = std::fs::write(&path, bytes);
        }
    }
    write(&root.join("u/notes.txt"), b"the user's notes");
    #[cfg(unix)]
    std::os::unix::fs::symlink(root.join("u"), root.join("link")).unwrap();
}

/// Runs `cmd` into `out` inside `root`, killed after `kill_ms` if it is still running.
fn attempt(root: &Path, inputs: &Path, cmd: Cmd, out: Out, kill_ms: u64) {
    let ds = inputs.join("ds");
    let cfg = inputs.join("run.toml");
    let args: Vec<String> = match cmd {
        Cmd::Scene => "scene --scene monolith --width 4 --height 4 --train 1 --val 1 --test 1 --supersample 1 --out"
            .split(' ')
            .map(String::from)
            .collect(),
        Cmd::Run => vec!["run".into(), s(&cfg).into(), "--out".into()],
        Cmd::RunCheck => vec!["run".into(), s(&cfg).into(), "--check".into(), "--out".into()],
        Cmd::Collision => "collision --scene monolith --cells-per-metre 5 --out".split(' ').map(String::from).collect(),
        Cmd::Train => {
            vec!["train".into(), "--data".into(), s(&ds).into(), "--steps".into(), "2".into(), "--out".into()]
        }
    };
    let out_path = match cmd {
        Cmd::Collision if matches!(out, Out::New | Out::NestedNew | Out::LinkedNew) => {
            format!("{}.safetensors", out.path())
        }
        _ => out.path().to_string(),
    };
    let mut child = Command::new(env!("CARGO_BIN_EXE_nerfsv"))
        .args(&args)
        .arg(&out_path)
        .current_dir(root)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let start = Instant::now();
    loop {
        if child.try_wait().unwrap().is_some() {
            return;
        }
        if start.elapsed() > Duration::from_millis(kill_ms) {
            let _ = child.kill();
            let _ = child.wait();
            return;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// One tiny dataset and config for every case.
fn inputs() -> &'static Path {
    static INPUTS: std::sync::OnceLock<tempfile::TempDir> = std::sync::OnceLock::new();
    INPUTS
        .get_or_init(|| {
            let dir = tempfile::tempdir().unwrap();
            common::tiny_dataset(dir.path(), "2", "1");
            tiny_ensemble_run_config(dir.path());
            dir
        })
        .path()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 40, failure_persistence: None, ..ProptestConfig::default() })]

    /// Whatever the user's tree and whichever output a command is pointed at (the current folder
    /// however spelled, a user's folder, a stage-named one inside it, a link to it, a new folder
    /// inside or through it, a user's file), every file that was there before is there after
    /// with the same bytes: whether the command succeeded, was refused or was killed mid-way.
    #[test]
    fn a_users_files_survive_every_command_and_output(
        files in user_tree(),
        cmd in prop_oneof![Just(Cmd::Scene), Just(Cmd::Run), Just(Cmd::RunCheck), Just(Cmd::Collision), Just(Cmd::Train)],
        out in prop_oneof![
            Just(Out::Current), Just(Out::CurrentSlash), Just(Out::UpAgain), Just(Out::UserFolder),
            Just(Out::UserStageFolder), Just(Out::Link), Just(Out::LinkedNew), Just(Out::NestedNew),
            Just(Out::UserFile), Just(Out::New)
        ],
        kill_ms in 20u64..2500,
    ) {
        let root = tempfile::tempdir().unwrap();
        lay_out(root.path(), &files);
        let before = snapshot(root.path());
        attempt(root.path(), inputs(), cmd, out, kill_ms);
        assert_kept(root.path(), &before, &format!("{cmd:?} --out {}", out.path()));
    }
}
