//! The one guard against writing over an input or a user's files: every command and `nerfsv
//! run` name what they will read and what they will write, and [`Guard::check`] refuses, before
//! anything is written, any output that is, contains or lies inside an input, any two outputs
//! that coincide or nest, an output folder that is not nerfsv's to write (a folder holding a
//! user's files, a regular file, the current or home folder, the root: see
//! [`nerfsv_scene::folder`]) and an output file nerfsv did not write (its header says who did:
//! [`folder::written_by_nerfsv`] for safetensors and PLY, [`glb_written_by_nerfsv`] for a binary
//! glTF). [`Guard::claim`] then creates and marks the output folders.
//!
//! Paths are compared by identity, not by their text: each is made absolute and resolved
//! through symbolic links as far as it exists (`./a`, `a/../a`, a link to `a` and `a` are one
//! path). A dataset folder counts with every file its transforms files or COLMAP model name,
//! each resolved on its own, so a split folder that is a link into another dataset guards that
//! dataset's images.

use std::path::{Path, PathBuf};

use nerfsv_scene::folder::{self, resolve, OutputKind};

use crate::PipelineError;

/// Extensions of the files a mesh reads beside itself (OBJ materials and textures, glTF buffers).
const MESH_COMPANIONS: [&str; 7] = ["mtl", "png", "jpg", "jpeg", "bin", "tga", "bmp"];

/// What a command reads and writes, each under the name the user gave it (a flag or a config
/// key).
#[derive(Debug, Default)]
pub struct Guard {
    /// Folders read: nothing may be written inside them, at them, or over a folder holding them.
    folders: Vec<Named>,
    /// Files read: nothing may be written at them or over a folder holding them.
    files: Vec<Named>,
    outputs: Vec<Output>,
}

#[derive(Debug)]
struct Named {
    what: String,
    given: PathBuf,
    real: PathBuf,
}

impl Named {
    fn new(what: &str, path: &Path) -> Self {
        Self { what: what.to_string(), given: path.to_path_buf(), real: resolve(path) }
    }
}

/// An output: a folder of one kind (claimed and marked), a file, or a file beside another.
#[derive(Debug)]
struct Output {
    named: Named,
    form: Form,
}

#[derive(Debug)]
enum Form {
    Folder(OutputKind),
    File,
    /// A file without a header of its own (a picture), written beside this main output file:
    /// replaced only if the main file is nerfsv's.
    Beside(PathBuf),
}

impl Guard {
    pub fn new() -> Self {
        Self::default()
    }

    /// An input read as it is: a folder if it is one now, else a file.
    pub fn input(mut self, what: &str, path: &Path) -> Self {
        let named = Named::new(what, path);
        if named.real.is_dir() {
            self.folders.push(named);
        } else {
            self.files.push(named);
        }
        self
    }

    /// A dataset folder: the folder, and every file its transforms files or COLMAP model name
    /// (each resolved through links on its own).
    pub fn dataset(mut self, what: &str, dir: &Path) -> Self {
        self.folders.push(Named::new(what, dir));
        for file in nerfsv_dataset::dataset_files(dir) {
            self.files.push(Named::new(what, &file));
        }
        self
    }

    /// A mesh file and the materials, textures and buffers beside it that its reader may open.
    pub fn mesh(mut self, what: &str, path: &Path) -> Self {
        self.files.push(Named::new(what, path));
        let folder = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        let companions = std::fs::read_dir(folder).into_iter().flatten().flatten().map(|e| e.path()).filter(|p| {
            p.is_file()
                && p.extension()
                    .and_then(|e| e.to_str())
                    .is_some_and(|e| MESH_COMPANIONS.contains(&e.to_ascii_lowercase().as_str()))
        });
        for file in companions {
            self.files.push(Named::new(&format!("{what}'s companion"), &file));
        }
        self
    }

    /// An input that may be absent (`None` adds nothing).
    pub fn input_opt(self, what: &str, path: Option<&Path>) -> Self {
        match path {
            Some(p) => self.input(what, p),
            None => self,
        }
    }

    /// A folder the command writes, of `kind`: it must be absent, empty or nerfsv's folder of that
    /// kind ([`folder::check_folder`]); it may be replaced whole.
    pub fn folder(mut self, what: &str, path: &Path, kind: OutputKind) -> Self {
        self.outputs.push(Output { named: Named::new(what, path), form: Form::Folder(kind) });
        self
    }

    /// A file the command writes: it must be absent or one nerfsv wrote ([`folder::check_file`]).
    pub fn file(mut self, what: &str, path: &Path) -> Self {
        self.outputs.push(Output { named: Named::new(what, path), form: Form::File });
        self
    }

    /// A file the command writes beside its output file `main` (a picture of it, which has no
    /// header to say who wrote it): it must be absent, or `main` must be a file nerfsv wrote.
    pub fn file_beside(mut self, what: &str, path: &Path, main: &Path) -> Self {
        self.outputs.push(Output { named: Named::new(what, path), form: Form::Beside(main.to_path_buf()) });
        self
    }

    /// An output file that may be absent (`None` adds nothing).
    pub fn file_opt(self, what: &str, path: Option<&Path>) -> Self {
        match path {
            Some(p) => self.file(what, p),
            None => self,
        }
    }

    /// The first refusal, naming the flag or key and the path as the user gave it, what is wrong
    /// and what to do. Reads only.
    pub fn check(&self) -> Result<(), PipelineError> {
        let inputs = self.folders.iter().map(|f| (f, true)).chain(self.files.iter().map(|f| (f, false)));
        for Output { named: out, .. } in &self.outputs {
            for (input, is_folder) in inputs.clone() {
                let problem = if out.real == input.real {
                    format!("is what {} reads ({})", input.what, shown(input))
                } else if is_folder && out.real.starts_with(&input.real) {
                    format!("lies inside {} {}, which nerfsv reads", input.what, shown(input))
                } else if input.real.starts_with(&out.real) {
                    format!(
                        "holds {} {}, which nerfsv reads, and an output may be replaced whole",
                        input.what,
                        shown(input)
                    )
                } else {
                    continue;
                };
                return Err(PipelineError::OutputOverInput {
                    what: out.what.clone(),
                    output: out.given.clone(),
                    problem,
                    input_what: input.what.clone(),
                });
            }
        }
        for (i, Output { named: a, .. }) in self.outputs.iter().enumerate() {
            for Output { named: b, .. } in &self.outputs[i + 1..] {
                if a.real.starts_with(&b.real) || b.real.starts_with(&a.real) {
                    return Err(PipelineError::OutputsOverlap {
                        first: format!("{} {}", a.what, a.given.display()),
                        second: format!("{} {}", b.what, b.given.display()),
                        change: b.what.clone(),
                    });
                }
            }
        }
        // Then each output on its own: a folder nerfsv may write, a file it may replace.
        for out in &self.outputs {
            let (what, given) = (&out.named.what, &out.named.given);
            match &out.form {
                Form::Folder(kind) => folder::check_folder(what, given, *kind).map(drop),
                Form::File => check_file(what, given),
                Form::Beside(main) if given.exists() && !written_by_nerfsv(main) => {
                    Err(folder::FolderError::ForeignFile { what: what.clone(), given: given.clone() })
                }
                Form::Beside(_) => check_file(what, given).or_else(|e| match e {
                    folder::FolderError::ForeignFile { .. } => Ok(()),
                    e => Err(e),
                }),
            }?;
        }
        Ok(())
    }

    /// [`Guard::check`], then creates each output folder that is not there yet and marks each as
    /// nerfsv's ([`folder::claim_folder`]). Call it right before the command writes, and
    /// [`Claimed::keep`] what it returns once the command has written: a command that fails
    /// before leaves no folder it made and no marker in a folder that was empty.
    pub fn claim(&self) -> Result<Claimed, PipelineError> {
        self.check()?;
        let mut claimed = Claimed::default();
        for out in &self.outputs {
            if let Form::Folder(kind) = out.form {
                let found = folder::claim_folder(&out.named.what, &out.named.given, kind)?;
                match found {
                    folder::Found::Absent => claimed.made.push(out.named.given.clone()),
                    folder::Found::Empty => claimed.marked.push(out.named.given.clone()),
                    folder::Found::Marked | folder::Found::Legacy => {}
                }
            }
        }
        Ok(claimed)
    }
}

/// The output folders a [`Guard::claim`] made or marked. Dropped without [`Claimed::keep`] (the
/// command failed), each is left as it was found if the command wrote nothing into it: a folder
/// it made is removed, an empty folder it marked loses its marker.
#[derive(Debug, Default)]
#[must_use = "a claim dropped without `keep` undoes itself"]
pub struct Claimed {
    made: Vec<PathBuf>,
    marked: Vec<PathBuf>,
    kept: bool,
}

impl Claimed {
    /// The command has written its outputs: the folders stay nerfsv's.
    pub fn keep(mut self) {
        self.kept = true;
    }
}

impl Drop for Claimed {
    fn drop(&mut self) {
        if self.kept {
            return;
        }
        let only_marker = |dir: &Path| {
            std::fs::read_dir(dir)
                .is_ok_and(|entries| entries.flatten().all(|e| e.file_name().to_str() == Some(folder::MARKER)))
        };
        for dir in self.made.iter().chain(&self.marked) {
            if only_marker(dir) {
                let _ = std::fs::remove_file(dir.join(folder::MARKER));
            }
        }
        for dir in &self.made {
            let _ = std::fs::remove_dir(dir);
        }
    }
}

/// Whether `path` is a binary glTF (`.glb`) whose `asset.generator` starts with `nerfsv` (what
/// `nerfsv export` writes, [`nerfsv_plot::glb::GENERATOR`]). Reads the header and the JSON chunk
/// only (refusing a chunk over 64 MiB).
pub fn glb_written_by_nerfsv(path: &Path) -> bool {
    use std::io::Read;
    let Ok(mut file) = std::fs::File::open(path) else { return false };
    let mut head = [0u8; 20];
    if file.read_exact(&mut head).is_err() || &head[..4] != b"glTF" {
        return false;
    }
    let len = u32::from_le_bytes([head[12], head[13], head[14], head[15]]) as usize;
    if len > 64 << 20 {
        return false;
    }
    let mut bytes = head.to_vec();
    bytes.resize(20 + len, 0);
    if file.read_exact(&mut bytes[20..]).is_err() {
        return false;
    }
    nerfsv_plot::glb::glb_json(&bytes)
        .and_then(|doc| doc["asset"]["generator"].as_str().map(|g| g.starts_with("nerfsv")))
        .unwrap_or(false)
}

/// Whether the file's header says nerfsv wrote it (safetensors, PLY or binary glTF).
fn written_by_nerfsv(path: &Path) -> bool {
    folder::written_by_nerfsv(path) || glb_written_by_nerfsv(path)
}

/// [`folder::check_file`], also admitting a binary glTF nerfsv wrote.
fn check_file(what: &str, given: &Path) -> Result<(), folder::FolderError> {
    folder::check_file(what, given).or_else(|e| match e {
        folder::FolderError::ForeignFile { .. } if glb_written_by_nerfsv(given) => Ok(()),
        e => Err(e),
    })
}

/// An input as the user gave it, with the file it really is where a link leads elsewhere.
fn shown(input: &Named) -> String {
    let given = std::path::absolute(&input.given).unwrap_or_else(|_| input.given.clone());
    if given == input.real {
        input.given.display().to_string()
    } else {
        format!("{} (really {})", input.given.display(), input.real.display())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_output_inside_an_input_is_refused_however_it_is_spelled() {
        let root = tempfile::tempdir().unwrap();
        let data = root.path().join("data");
        std::fs::create_dir_all(data.join("test")).unwrap();
        let model = root.path().join("model.safetensors");
        std::fs::write(&model, b"x").unwrap();
        let guard = || Guard::new().input("--data", &data).input("--model", &model);
        for out in [data.join("test"), data.join("new/deeper"), data.join("test/../test"), data.clone(), model.clone()]
        {
            let e = guard().folder("--out", &out, OutputKind::Run).check().unwrap_err().to_string();
            assert!(e.starts_with(&format!("--out {}: ", out.display())), "{e}");
            assert!(e.contains("nerfsv never writes over what it reads"), "{e}");
        }
        for out in [root.path().to_path_buf(), root.path().join("data/..")] {
            let e = guard().folder("--out", &out, OutputKind::Run).check().unwrap_err().to_string();
            assert!(e.contains("holds --data") || e.contains("files nerfsv did not write"), "{e}");
        }
        assert!(guard().folder("--out", &root.path().join("renders"), OutputKind::Renders).check().is_ok());
        assert!(guard().folder("--out", &root.path().join("data2"), OutputKind::Run).check().is_ok());
    }

    #[test]
    fn a_file_input_guards_itself_only_and_two_outputs_must_not_meet() {
        let root = tempfile::tempdir().unwrap();
        let mesh = root.path().join("w/mesh.ply");
        std::fs::create_dir_all(mesh.parent().unwrap()).unwrap();
        std::fs::write(&mesh, b"ply").unwrap();
        // A sibling of a file input is free; the file itself and a folder holding it are not.
        assert!(Guard::new()
            .mesh("--mesh", &mesh)
            .folder("--out", &root.path().join("w/ds"), OutputKind::Dataset)
            .check()
            .is_ok());
        assert!(Guard::new().mesh("--mesh", &mesh).file("--out", &mesh).check().is_err());
        let x = root.path().join("x");
        let e = Guard::new().file("--out", &x).file("--mesh", &x).check().unwrap_err().to_string();
        assert!(e.contains("--out") && e.contains("--mesh") && e.contains("one path or one lies inside"), "{e}");
        assert!(e.ends_with("choose another path for --mesh"), "{e}");
        assert!(Guard::new().file("--out", &x).file("--mesh", &root.path().join("y")).check().is_ok());
    }

    #[test]
    fn a_glb_is_replaced_only_if_its_generator_is_nerfsv() {
        use nerfsv_plot::glb::{glb_bytes, GlbScene};
        let root = tempfile::tempdir().unwrap();
        let p = |n: &str| root.path().join(n);
        let ours = glb_bytes(&GlbScene::default()).unwrap();
        std::fs::write(p("ours.glb"), &ours).unwrap();
        assert!(Guard::new().file("--out", &p("ours.glb")).check().is_ok());
        // Another program's file: the same layout, another generator (of the same length).
        let mut theirs = ours.clone();
        let at = theirs.windows(6).position(|w| w == b"nerfsv").unwrap();
        theirs[at..at + 6].copy_from_slice(b"Kronos");
        std::fs::write(p("theirs.glb"), &theirs).unwrap();
        assert!(!glb_written_by_nerfsv(&p("theirs.glb")));
        let e = Guard::new().file("--out", &p("theirs.glb")).check().unwrap_err().to_string();
        assert!(e.contains("the file already exists and nerfsv did not write it"), "{e}");
        std::fs::write(p("short.glb"), &ours[..19]).unwrap();
        assert!(Guard::new().file("--out", &p("short.glb")).check().is_err());
        assert!(Guard::new().file("--out", &p("new.glb")).check().is_ok());
    }

    #[cfg(unix)]
    #[test]
    fn a_split_linked_into_another_dataset_guards_that_datasets_images() {
        let root = tempfile::tempdir().unwrap();
        let other = root.path().join("other");
        std::fs::create_dir_all(other.join("test")).unwrap();
        std::fs::write(other.join("test/r_0.png"), b"png").unwrap();
        let sym = root.path().join("sym");
        std::fs::create_dir_all(&sym).unwrap();
        std::os::unix::fs::symlink(other.join("test"), sym.join("test")).unwrap();
        std::fs::write(
            sym.join("transforms_test.json"),
            r#"{"camera_angle_x": 0.8, "frames": [{"file_path": "./test/r_0", "transform_matrix": []}]}"#,
        )
        .unwrap();
        let e = Guard::new()
            .dataset("--data", &sym)
            .folder("--out", &other.join("test"), OutputKind::Renders)
            .check()
            .unwrap_err()
            .to_string();
        assert!(e.contains("really") && e.contains("other/test/r_0.png"), "{e}");
    }
}
