//! Output folders and files that know who wrote them: nerfsv clears or replaces only what it
//! wrote itself.
//!
//! Every folder a command writes (a run folder, a dataset, a training, renders, a flight, a
//! stress test, an uncertainty study, a replication) carries [`MARKER`], a small JSON file that
//! says nerfsv wrote it, for which command ([`OutputKind`]) and in which format version. Before
//! any work, [`check_folder`] admits an output folder only if it is absent, empty, marked by
//! nerfsv for the same kind of output, or an earlier version's folder of that kind recognised by
//! its file names ([`OutputKind::legacy`]). Anything else is refused with a message that names
//! the flag or key, the path as given, what is wrong and what to do: a folder holding a user's
//! files, a regular file, an empty path, the current folder, the home folder and the filesystem
//! root. [`claim_folder`] then creates the folder and writes its marker.
//!
//! An output *file* (a collision field, a mesh, an uncertainty field) is replaced only if it is
//! absent or nerfsv wrote it ([`check_file`]): its own header says so (a safetensors file whose
//! metadata `format` starts with `nerfsv`, a PLY file with a `comment nerfsv` line).

use std::io::Read;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// The marker file in every folder nerfsv writes.
pub const MARKER: &str = "nerfsv-folder.json";

/// The marker's format version.
pub const MARKER_FORMAT: u32 = 1;

/// What a folder nerfsv writes holds, and so which command may write into it again.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OutputKind {
    /// `nerfsv run`'s run folder (one folder per stage, `summary.json`, the report).
    Run,
    /// `nerfsv replicate`'s folder (`seed_S/` run folders and the figures side by side).
    Replication,
    /// A rendered dataset (`nerfsv scene`).
    Dataset,
    /// A training's checkpoint (`nerfsv train`).
    Training,
    /// A split rendered by a NeRF (`nerfsv render`).
    Renders,
    /// One flight (`nerfsv fly`).
    Flight,
    /// A stress test (`nerfsv stress`).
    Stress,
    /// An uncertainty study of a dataset (`nerfsv uq offline`, `nerfsv uq ause`).
    Uncertainty,
}

impl OutputKind {
    /// The kind's name in the marker and in messages.
    pub fn name(self) -> &'static str {
        match self {
            Self::Run => "run",
            Self::Replication => "replication",
            Self::Dataset => "dataset",
            Self::Training => "training",
            Self::Renders => "renders",
            Self::Flight => "flight",
            Self::Stress => "stress",
            Self::Uncertainty => "uncertainty",
        }
    }

    /// Whether `dir`, which has no marker, is this kind's folder as an earlier nerfsv (before
    /// markers) wrote it, told by records only nerfsv writes: a run folder holds `summary.json`
    /// and stage folders, each with its record (`stage.json` with a key and figures) or a
    /// resumable stage's mark (`started.json` with a key); a replication holds such run folders
    /// (`seed_S/`) and its figures; a dataset holds the `scene.json` nerfsv writes; a training
    /// holds a checkpoint whose header says nerfsv wrote it. Every entry must be such (hidden
    /// temporaries of a killed writer aside). The other kinds' folders (renders, flights, stress
    /// tests, uncertainty studies) carry nothing that tells them from a user's files: without a
    /// marker they are refused, and the command writes into a new folder.
    pub fn legacy(self, dir: &Path) -> bool {
        let Ok(entries) = std::fs::read_dir(dir) else { return false };
        let (mut any, mut seeds) = (false, false);
        for entry in entries.flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            if name.starts_with('.') && name.contains(".tmp-") {
                continue;
            }
            any = true;
            let path = entry.path();
            if !self.writes(&name, &path) {
                return false;
            }
            seeds |= path.is_dir() && name.starts_with("seed_");
        }
        any && (self != Self::Replication || seeds)
    }

    /// Whether `name` (at `path`, inside a folder of this kind without a marker) is an entry
    /// only nerfsv writes there.
    fn writes(self, name: &str, path: &Path) -> bool {
        let file = path.is_file();
        let json =
            |p: &Path| std::fs::read_to_string(p).ok().and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok());
        let record = |dir: &Path| {
            json(&dir.join("stage.json")).is_some_and(|v| v.get("key").is_some() && v.get("figures").is_some())
                || json(&dir.join("started.json")).is_some_and(|v| v.get("key").is_some())
        };
        match self {
            Self::Run => (file && name == "summary.json") || (path.is_dir() && record(path)),
            Self::Replication => {
                (file && matches!(name, "replicate.csv" | "replicate.json" | "index.html"))
                    || (path.is_dir() && name.starts_with("seed_") && Self::Run.legacy(path))
            }
            Self::Dataset => {
                // Only nerfsv's own renders: a user's capture has no scene.json written by nerfsv.
                let ours = json(&path.with_file_name("scene.json")).is_some_and(|v| v["generator"] == "nerfsv");
                ours && (file || matches!(name, "train" | "val" | "test"))
            }
            Self::Training => file && name == "checkpoint.safetensors" && written_by_nerfsv(path),
            Self::Renders | Self::Flight | Self::Stress | Self::Uncertainty => false,
        }
    }
}

/// The marker's contents.
#[derive(Debug, Serialize, Deserialize)]
struct Marker {
    written_by: String,
    kind: OutputKind,
    format: u32,
    version: String,
}

/// Why an output path is refused. Each message names the flag or key, the path as the user
/// gave it, what is wrong with it, and what to do instead.
#[derive(Debug, thiserror::Error)]
pub enum FolderError {
    #[error("{what}: the path is empty; give the name of a new folder")]
    EmptyPath { what: String },
    #[error(
        "{what} {}: is {place}, and nerfsv never writes its outputs there; give the name of a new folder \
         (e.g. {what} {})",
        .given.display(), .example.display()
    )]
    Forbidden { what: String, given: PathBuf, place: &'static str, example: PathBuf },
    #[error("{what} {}: is a file, not a folder; give the name of a new folder", .given.display())]
    NotAFolder { what: String, given: PathBuf },
    #[error(
        "{what} {}: the folder already holds files nerfsv did not write ({entry}; no {MARKER}); \
         nerfsv writes only into a new or empty folder or one it made, so nothing of yours is cleared: give \
         the name of a new folder, or empty this one",
        .given.display()
    )]
    Foreign { what: String, given: PathBuf, entry: String },
    #[error(
        "{what} {}: holds nerfsv's {found} folder, not a {wanted} folder (see its {MARKER}); give the name \
         of a new folder",
        .given.display()
    )]
    OtherKind { what: String, given: PathBuf, found: String, wanted: &'static str },
    #[error(
        "{what} {}: the file already exists and nerfsv did not write it (its header does not say so); \
         nerfsv replaces only its own files: give a new file name, or move this file away",
        .given.display()
    )]
    ForeignFile { what: String, given: PathBuf },
    #[error("{what} {}: is a folder, not a file; give a file name", .given.display())]
    NotAFile { what: String, given: PathBuf },
    #[error("{what} {}: cannot be read or written: {error}", .given.display())]
    Io { what: String, given: PathBuf, error: std::io::Error },
}

/// What [`check_folder`] found at an admissible output folder.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Found {
    /// Nothing there yet.
    Absent,
    /// An empty folder.
    Empty,
    /// A folder nerfsv marked as this kind's.
    Marked,
    /// An earlier version's folder of this kind, recognised by its file names.
    Legacy,
}

/// Whether `given` may be `what`'s output folder of `kind` (see the module docs). Reads only.
pub fn check_folder(what: &str, given: &Path, kind: OutputKind) -> Result<Found, FolderError> {
    let named = || (what.to_string(), given.to_path_buf());
    if given.as_os_str().is_empty() {
        return Err(FolderError::EmptyPath { what: what.to_string() });
    }
    check_place(what, given, kind)?;
    let meta = match std::fs::metadata(given) {
        Ok(meta) => meta,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            // A dangling link or a path through a file is not a folder nerfsv can make.
            return match std::fs::symlink_metadata(given) {
                Ok(_) => Err(FolderError::NotAFolder { what: what.to_string(), given: given.to_path_buf() }),
                Err(_) => Ok(Found::Absent),
            };
        }
        Err(error) => {
            let (what, given) = named();
            return Err(FolderError::Io { what, given, error });
        }
    };
    if !meta.is_dir() {
        let (what, given) = named();
        return Err(FolderError::NotAFolder { what, given });
    }
    let marker = given.join(MARKER);
    if marker.exists() {
        return match read_marker(&marker) {
            Some(m) if m.kind == kind => Ok(Found::Marked),
            Some(m) => {
                let (what, given) = named();
                Err(FolderError::OtherKind { what, given, found: m.kind.name().to_string(), wanted: kind.name() })
            }
            None => {
                let (what, given) = named();
                Err(FolderError::Foreign { what, given, entry: format!("{MARKER}, not nerfsv's marker") })
            }
        };
    }
    let mut entries: Vec<String> = std::fs::read_dir(given)
        .map_err(|error| FolderError::Io { what: what.to_string(), given: given.to_path_buf(), error })?
        .flatten()
        .map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            if e.path().is_dir() {
                format!("{name}/")
            } else {
                name
            }
        })
        .collect();
    if entries.is_empty() {
        return Ok(Found::Empty);
    }
    if kind.legacy(given) {
        return Ok(Found::Legacy);
    }
    entries.sort();
    let (what, given) = named();
    let mut shown = entries.iter().take(3).cloned().collect::<Vec<_>>().join(", ");
    if entries.len() > 3 {
        shown.push_str(&format!(" and {} more", entries.len() - 3));
    }
    Err(FolderError::Foreign { what, given, entry: shown })
}

/// Checks `given` ([`check_folder`]), then creates it if needed and marks it as `kind`'s.
pub fn claim_folder(what: &str, given: &Path, kind: OutputKind) -> Result<Found, FolderError> {
    let found = check_folder(what, given, kind)?;
    let io = |error| FolderError::Io { what: what.to_string(), given: given.to_path_buf(), error };
    std::fs::create_dir_all(given).map_err(io)?;
    if found != Found::Marked {
        let marker = Marker {
            written_by: "nerfsv".into(),
            kind,
            format: MARKER_FORMAT,
            version: env!("CARGO_PKG_VERSION").into(),
        };
        let bytes = serde_json::to_vec_pretty(&marker).map_err(|e| io(std::io::Error::other(e)))?;
        crate::io::atomic_write_bytes(&given.join(MARKER), &bytes).map_err(io)?;
    }
    Ok(found)
}

/// Whether `dir` is a folder nerfsv marked as `kind`'s.
pub fn is_marked(dir: &Path, kind: OutputKind) -> bool {
    read_marker(&dir.join(MARKER)).is_some_and(|m| m.kind == kind)
}

fn read_marker(path: &Path) -> Option<Marker> {
    let text = std::fs::read_to_string(path).ok()?;
    serde_json::from_str::<Marker>(&text).ok().filter(|m| m.written_by == "nerfsv")
}

/// Whether `given` may be `what`'s output file: absent, or a file whose header says nerfsv wrote
/// it (see the module docs). Its folder is created when the file is written.
pub fn check_file(what: &str, given: &Path) -> Result<(), FolderError> {
    if given.as_os_str().is_empty() {
        return Err(FolderError::EmptyPath { what: what.to_string() });
    }
    match std::fs::metadata(given) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(error) => Err(FolderError::Io { what: what.to_string(), given: given.to_path_buf(), error }),
        Ok(m) if m.is_dir() => Err(FolderError::NotAFile { what: what.to_string(), given: given.to_path_buf() }),
        Ok(_) if written_by_nerfsv(given) => Ok(()),
        Ok(_) => Err(FolderError::ForeignFile { what: what.to_string(), given: given.to_path_buf() }),
    }
}

/// Whether the file at `path` says in its header that nerfsv wrote it: safetensors metadata
/// `format` starting with `nerfsv`, or a PLY `comment nerfsv` line.
pub fn written_by_nerfsv(path: &Path) -> bool {
    let Ok(mut file) = std::fs::File::open(path) else { return false };
    let mut head = Vec::new();
    if file.by_ref().take(1 << 16).read_to_end(&mut head).is_err() {
        return false;
    }
    if head.starts_with(b"ply\n") || head.starts_with(b"ply\r\n") {
        let text = String::from_utf8_lossy(&head);
        return text.lines().take_while(|l| l.trim() != "end_header").any(|l| l.starts_with("comment nerfsv"));
    }
    let Some(len) = head.get(..8).map(|b| u64::from_le_bytes(b.try_into().unwrap_or_default()) as usize) else {
        return false;
    };
    let Some(header) = head.get(8..8usize.saturating_add(len)) else { return false };
    serde_json::from_slice::<serde_json::Value>(header)
        .ok()
        .and_then(|v| v["__metadata__"]["format"].as_str().map(|f| f.starts_with("nerfsv")))
        .unwrap_or(false)
}

/// Refuses the filesystem root, the home folder and the current folder (however they are
/// spelled: `.`, `./`, `a/..`, a link to them).
fn check_place(what: &str, given: &Path, kind: OutputKind) -> Result<(), FolderError> {
    let real = resolve(given);
    let home = std::env::var_os("HOME").filter(|h| !h.is_empty()).map(|h| resolve(Path::new(&h)));
    let cwd = std::env::current_dir().ok().map(|c| resolve(&c));
    let place = if real.parent().is_none() {
        "the filesystem root"
    } else if home.as_deref() == Some(real.as_path()) {
        "your home folder"
    } else if cwd.as_deref() == Some(real.as_path()) {
        "the current folder"
    } else {
        return Ok(());
    };
    let example = PathBuf::from(match kind {
        OutputKind::Run | OutputKind::Replication => "runs/my_study",
        other => other.name(),
    });
    Err(FolderError::Forbidden { what: what.to_string(), given: given.to_path_buf(), place, example })
}

/// `path` made absolute with symbolic links resolved as far as it exists, and `.` and `..`
/// taken as written beyond that (`./a`, `a/../a`, a link to `a` and `a` are one path).
pub fn resolve(path: &Path) -> PathBuf {
    use std::path::Component;
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut real = PathBuf::new();
    for component in absolute.components() {
        match component {
            Component::Prefix(_) | Component::RootDir => real.push(component.as_os_str()),
            Component::CurDir => {}
            Component::ParentDir => {
                real.pop();
            }
            Component::Normal(name) => {
                real.push(name);
                if std::fs::symlink_metadata(&real).is_ok() {
                    if let Ok(canonical) = real.canonicalize() {
                        real = canonical;
                    }
                }
            }
        }
    }
    real
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tree(files: &[&str]) -> tempfile::TempDir {
        let root = tempfile::tempdir().unwrap();
        for f in files {
            let path = root.path().join(f);
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(path, b"x").unwrap();
        }
        root
    }

    #[test]
    fn a_folder_holding_a_users_files_is_refused_and_an_empty_or_absent_one_is_claimed() {
        let root = tree(&["foreign/dataset/notes.txt", "foreign/nerf/notes.txt", "empty/.keep"]);
        let foreign = root.path().join("foreign");
        let e = check_folder("--out", &foreign, OutputKind::Run).unwrap_err().to_string();
        let start = format!(
            "--out {}: the folder already holds files nerfsv did not write (dataset/, nerf/; no",
            foreign.display()
        );
        assert!(e.starts_with(&start), "{e}");
        assert!(e.contains("give the name of a new folder"), "{e}");
        assert!(claim_folder("--out", &foreign, OutputKind::Run).is_err());
        assert!(!foreign.join(MARKER).exists());
        let new = root.path().join("a/b");
        assert_eq!(claim_folder("out", &new, OutputKind::Run).unwrap(), Found::Absent);
        assert!(is_marked(&new, OutputKind::Run));
        assert_eq!(check_folder("out", &new, OutputKind::Run).unwrap(), Found::Marked);
        // Marked for another command: refused, naming both kinds.
        let e = check_folder("--out", &new, OutputKind::Dataset).unwrap_err().to_string();
        assert!(e.contains("holds nerfsv's run folder, not a dataset folder"), "{e}");
        let empty = root.path().join("e");
        std::fs::create_dir(&empty).unwrap();
        assert_eq!(claim_folder("--out", &empty, OutputKind::Flight).unwrap(), Found::Empty);
        // A marker that is not nerfsv's counts as a user's file.
        std::fs::write(root.path().join("empty").join(MARKER), b"{}").unwrap();
        assert!(check_folder("--out", &root.path().join("empty"), OutputKind::Run).is_err());
    }

    #[test]
    fn empty_paths_files_root_home_and_the_current_folder_are_refused() {
        let root = tree(&["file.txt"]);
        let e = check_folder("out", Path::new(""), OutputKind::Run).unwrap_err().to_string();
        assert_eq!(e, "out: the path is empty; give the name of a new folder");
        let e = check_folder("--out", &root.path().join("file.txt"), OutputKind::Run).unwrap_err().to_string();
        assert!(e.ends_with("file.txt: is a file, not a folder; give the name of a new folder"), "{e}");
        let e = check_folder("--out", Path::new("/"), OutputKind::Run).unwrap_err().to_string();
        assert!(e.starts_with("--out /: is the filesystem root"), "{e}");
        for dot in [".", "./", "x/..", "./."] {
            let e = check_folder("--out", Path::new(dot), OutputKind::Run).unwrap_err().to_string();
            assert!(e.contains("is the current folder") && e.contains("--out runs/my_study"), "{dot}: {e}");
        }
        if let Some(home) = std::env::var_os("HOME").filter(|h| !h.is_empty() && Path::new(h).is_dir()) {
            let e = check_folder("--out", Path::new(&home), OutputKind::Dataset).unwrap_err().to_string();
            assert!(e.contains("is your home folder") && e.contains("--out dataset"), "{e}");
        }
    }

    #[test]
    fn earlier_versions_folders_are_recognised_by_their_records_and_only_then() {
        let root = tree(&[
            "run/summary.json",
            "run/nerf/checkpoint.safetensors",
            "killed/nerf/x",
            "killed/flight/trajectory.csv",
            "fake/nerf/stage.json",
            "renders/r_0.png",
            "data/transforms_train.json",
            "capture/transforms_train.json",
            "capture/scene.json",
            "fly/trajectory.csv",
            "train/checkpoint.safetensors",
            "rep/replicate.csv",
        ]);
        let p = |n: &str| root.path().join(n);
        std::fs::write(p("run/nerf/stage.json"), br#"{"key": "k", "seconds": 1.0, "figures": {}}"#).unwrap();
        std::fs::create_dir_all(p("run/dataset")).unwrap();
        std::fs::write(p("run/dataset/started.json"), br#"{"key": "k"}"#).unwrap();
        std::fs::write(p("killed/nerf/stage.json"), br#"{"key": "k", "seconds": 1.0, "figures": {}}"#).unwrap();
        std::fs::write(p("data/scene.json"), br#"{"generator": "nerfsv"}"#).unwrap();
        assert_eq!(check_folder("--out", &p("run"), OutputKind::Run).unwrap(), Found::Legacy);
        // A stage folder without its record (a killed stage) or with a record that is not one.
        assert!(check_folder("--out", &p("killed"), OutputKind::Run).is_err());
        assert!(check_folder("--out", &p("fake"), OutputKind::Run).is_err());
        // What carries no record of nerfsv is a user's, whatever its names.
        assert!(check_folder("--out", &p("renders"), OutputKind::Renders).is_err());
        assert!(check_folder("--out", &p("fly"), OutputKind::Flight).is_err());
        assert_eq!(check_folder("--out", &p("data"), OutputKind::Dataset).unwrap(), Found::Legacy);
        let e = check_folder("--out", &p("capture"), OutputKind::Dataset).unwrap_err().to_string();
        assert!(e.contains("scene.json, transforms_train.json"), "{e}");
        // A checkpoint whose header is not nerfsv's.
        assert!(check_folder("--out", &p("train"), OutputKind::Training).is_err());
        let mut meta = std::collections::BTreeMap::new();
        meta.insert("format".to_string(), "nerfsv-checkpoint".to_string());
        std::fs::write(p("train/checkpoint.safetensors"), crate::io::safetensors_bytes(&[], &meta)).unwrap();
        assert_eq!(check_folder("--out", &p("train"), OutputKind::Training).unwrap(), Found::Legacy);
        assert!(check_folder("--out", &p("train"), OutputKind::Run).is_err());
        // A replication needs its seeds' run folders, not only a file of its name.
        assert!(check_folder("--out", &p("rep"), OutputKind::Replication).is_err());
        std::fs::create_dir_all(p("rep/seed_0")).unwrap();
        std::fs::copy(p("run/summary.json"), p("rep/seed_0/summary.json")).unwrap();
        assert_eq!(check_folder("--out", &p("rep"), OutputKind::Replication).unwrap(), Found::Legacy);
    }

    #[test]
    fn an_output_file_is_replaced_only_if_its_header_says_nerfsv_wrote_it() {
        let root = tree(&["mine.safetensors", "dir/x"]);
        let p = |n: &str| root.path().join(n);
        assert!(check_file("--out", &p("new.safetensors")).is_ok());
        let e = check_file("--out", &p("mine.safetensors")).unwrap_err().to_string();
        assert!(e.contains("the file already exists and nerfsv did not write it"), "{e}");
        assert!(check_file("--out", &p("dir")).unwrap_err().to_string().contains("is a folder, not a file"));
        let mut meta = std::collections::BTreeMap::new();
        meta.insert("format".to_string(), "nerfsv-grid".to_string());
        std::fs::write(p("ours.safetensors"), crate::io::safetensors_bytes(&[], &meta)).unwrap();
        assert!(check_file("--out", &p("ours.safetensors")).is_ok());
        meta.insert("format".to_string(), "pt".to_string());
        std::fs::write(p("theirs.safetensors"), crate::io::safetensors_bytes(&[], &meta)).unwrap();
        assert!(check_file("--out", &p("theirs.safetensors")).is_err());
        std::fs::write(p("ours.ply"), "ply\nformat ascii 1.0\ncomment nerfsv-collision\nend_header\n").unwrap();
        std::fs::write(p("theirs.ply"), "ply\nformat ascii 1.0\ncomment blender\nend_header\n").unwrap();
        assert!(check_file("--mesh-out", &p("ours.ply")).is_ok());
        assert!(check_file("--mesh-out", &p("theirs.ply")).is_err());
    }
}
