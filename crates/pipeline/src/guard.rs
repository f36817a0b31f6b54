//! The one guard against writing over an input: every command and `nerfsv run` name what they
//! will read and what they will write, and [`Guard::check`] refuses, before anything is
//! written, any output that is, contains or lies inside an input, and any two outputs that
//! coincide or nest.
//!
//! Paths are compared by identity, not by their text: each is made absolute and resolved
//! through symbolic links as far as it exists (`./a`, `a/../a`, a link to `a` and `a` are one
//! path). A dataset folder counts with every file its transforms files or COLMAP model name,
//! each resolved on its own, so a split folder that is a link into another dataset guards that
//! dataset's images.

use std::path::{Path, PathBuf};

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
    outputs: Vec<Named>,
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

    /// A file or folder the command writes (a folder may be replaced whole).
    pub fn output(mut self, what: &str, path: &Path) -> Self {
        self.outputs.push(Named::new(what, path));
        self
    }

    /// An output that may be absent (`None` adds nothing).
    pub fn output_opt(self, what: &str, path: Option<&Path>) -> Self {
        match path {
            Some(p) => self.output(what, p),
            None => self,
        }
    }

    /// The first conflict, naming both paths as the user gave them and what they are.
    pub fn check(&self) -> Result<(), PipelineError> {
        let inputs = self.folders.iter().map(|f| (f, true)).chain(self.files.iter().map(|f| (f, false)));
        for out in &self.outputs {
            for (input, folder) in inputs.clone() {
                if out.real == input.real || (folder && out.real.starts_with(&input.real)) {
                    return Err(PipelineError::OutputInsideInput {
                        output: out.given.clone(),
                        option: format!("{} ({})", input.what, out.what),
                        input: shown(input),
                    });
                }
                if input.real.starts_with(&out.real) {
                    return Err(PipelineError::OutputHoldsInput {
                        output: out.given.clone(),
                        option: format!("{} ({})", input.what, out.what),
                        input: shown(input),
                    });
                }
            }
        }
        for (i, a) in self.outputs.iter().enumerate() {
            for b in &self.outputs[i + 1..] {
                if a.real.starts_with(&b.real) || b.real.starts_with(&a.real) {
                    return Err(PipelineError::OutputsOverlap {
                        first: format!("{} {}", a.what, a.given.display()),
                        second: format!("{} {}", b.what, b.given.display()),
                    });
                }
            }
        }
        Ok(())
    }
}

/// An input as the user gave it, with the file it really is where a link leads elsewhere.
fn shown(input: &Named) -> PathBuf {
    let given = std::path::absolute(&input.given).unwrap_or_else(|_| input.given.clone());
    if given == input.real {
        input.given.clone()
    } else {
        PathBuf::from(format!("{} (really {})", input.given.display(), input.real.display()))
    }
}

/// `path` made absolute with symbolic links resolved, as far as it exists (the rest appended).
fn resolve(path: &Path) -> PathBuf {
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut existing = absolute.as_path();
    let mut rest = Vec::new();
    loop {
        if let Ok(real) = existing.canonicalize() {
            return rest.iter().rev().fold(real, |p, c| p.join(c));
        }
        match (existing.parent(), existing.file_name()) {
            (Some(parent), Some(name)) => {
                rest.push(name.to_os_string());
                existing = parent;
            }
            _ => return absolute,
        }
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
            let e = guard().output("--out", &out).check().unwrap_err().to_string();
            assert!(e.contains("refusing to write over an input"), "{e}");
        }
        for out in [root.path().to_path_buf(), root.path().join("data/..")] {
            let e = guard().output("--out", &out).check().unwrap_err().to_string();
            assert!(e.contains("holds --data"), "{e}");
        }
        assert!(guard().output("--out", &root.path().join("renders")).check().is_ok());
        assert!(guard().output("--out", &root.path().join("data2")).check().is_ok());
    }

    #[test]
    fn a_file_input_guards_itself_only_and_two_outputs_must_not_meet() {
        let root = tempfile::tempdir().unwrap();
        let mesh = root.path().join("w/mesh.ply");
        std::fs::create_dir_all(mesh.parent().unwrap()).unwrap();
        std::fs::write(&mesh, b"ply").unwrap();
        // A sibling of a file input is free; the file itself and a folder holding it are not.
        assert!(Guard::new().mesh("--mesh", &mesh).output("--out", &root.path().join("w/ds")).check().is_ok());
        assert!(Guard::new().mesh("--mesh", &mesh).output("--out", &mesh).check().is_err());
        let x = root.path().join("x");
        let e = Guard::new().output("--out", &x).output("--mesh", &x).check().unwrap_err().to_string();
        assert!(e.contains("--out") && e.contains("--mesh") && e.contains("one path or one lies inside"), "{e}");
        assert!(Guard::new().output("--out", &x).output("--mesh", &root.path().join("y")).check().is_ok());
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
        let e =
            Guard::new().dataset("--data", &sym).output("--out", &other.join("test")).check().unwrap_err().to_string();
        assert!(e.contains("really") && e.contains("other/test/r_0.png"), "{e}");
    }
}
