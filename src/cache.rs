//! Content-keyed stage cache for `nerfsv run`: a stage's folder holds `stage.json` with the key
//! of everything it was computed from (its configuration and its inputs' keys). A re-run skips
//! a stage whose key is unchanged and whose outputs exist, and redoes it otherwise.

use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::Serialize;

/// FNV-1a, 64 bit: stable across platforms and Rust versions, unlike `DefaultHasher`.
pub fn fnv1a(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// The key of a stage: its name, its configuration (as JSON) and the keys of its inputs.
pub fn stage_key<C: Serialize>(name: &str, config: &C, inputs: &[&str]) -> anyhow::Result<String> {
    let text = serde_json::to_string(&(name, config, inputs))?;
    Ok(format!("{:016x}", fnv1a(text.as_bytes())))
}

/// One stage's folder and key.
pub struct Stage {
    pub dir: PathBuf,
    pub key: String,
}

impl Stage {
    pub fn new(dir: PathBuf, key: String) -> Self {
        Self { dir, key }
    }

    fn record(&self) -> PathBuf {
        self.dir.join("stage.json")
    }

    /// The figures recorded when this stage last completed with the same key, if its
    /// `outputs` (relative to the stage folder) all still exist.
    pub fn cached(&self, outputs: &[&str]) -> Option<serde_json::Value> {
        let text = std::fs::read_to_string(self.record()).ok()?;
        let v: serde_json::Value = serde_json::from_str(&text).ok()?;
        let fresh = v["key"] == self.key.as_str() && outputs.iter().all(|o| self.dir.join(o).exists());
        fresh.then(|| v["figures"].clone())
    }

    /// Marks the stage complete with its figures (written atomically, after the outputs).
    pub fn complete(&self, figures: &serde_json::Value) -> anyhow::Result<()> {
        let doc = serde_json::json!({ "key": self.key, "figures": figures });
        let path = self.record();
        nerfsv_scene::io::atomic_write(&path, |w| serde_json::to_writer_pretty(w, &doc).map_err(std::io::Error::other))
            .with_context(|| format!("writing {}", path.display()))
    }

    /// Starts (or restarts) the stage. Returns `true` when an interrupted run of the same key
    /// left its partial outputs here to resume from; otherwise the folder is emptied first so
    /// nothing computed from other inputs can leak into this run.
    pub fn begin(&self) -> anyhow::Result<bool> {
        let marker = self.dir.join("started.json");
        let resumable = std::fs::read_to_string(&marker)
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .is_some_and(|v| v["key"] == self.key.as_str());
        if !resumable && self.dir.exists() {
            std::fs::remove_dir_all(&self.dir).with_context(|| format!("clearing {}", self.dir.display()))?;
        }
        ensure_dir(&self.dir)?;
        self.invalidate()?;
        let doc = serde_json::json!({ "key": self.key });
        nerfsv_scene::io::atomic_write(&marker, |w| serde_json::to_writer(w, &doc).map_err(std::io::Error::other))
            .with_context(|| format!("writing {}", marker.display()))?;
        Ok(resumable)
    }

    /// Forgets a previous completion (before recomputing).
    pub fn invalidate(&self) -> anyhow::Result<()> {
        match std::fs::remove_file(self.record()) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                Err(e).context(format!("{}", self.record().display()))
            }
            _ => Ok(()),
        }
    }
}

/// Creates `dir` (and parents), naming it in the error.
pub fn ensure_dir(dir: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating folder {}", dir.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fnv1a_matches_reference_values() {
        // Published FNV-1a 64 test vectors.
        assert_eq!(fnv1a(b""), 0xcbf29ce484222325);
        assert_eq!(fnv1a(b"a"), 0xaf63dc4c8601ec8c);
        assert_eq!(fnv1a(b"foobar"), 0x85944171f73967e8);
    }

    #[test]
    fn a_stage_is_cached_only_with_the_same_key_and_its_outputs() {
        let dir = tempfile::tempdir().unwrap();
        let key = stage_key("dataset", &("stonehenge", 100), &[]).unwrap();
        let stage = Stage::new(dir.path().to_path_buf(), key.clone());
        assert!(stage.cached(&["out.bin"]).is_none());
        std::fs::write(dir.path().join("out.bin"), b"x").unwrap();
        stage.complete(&serde_json::json!({ "views": 3 })).unwrap();
        assert_eq!(stage.cached(&["out.bin"]).unwrap()["views"], 3);
        let other = Stage::new(dir.path().to_path_buf(), stage_key("dataset", &("stonehenge", 101), &[]).unwrap());
        assert!(other.cached(&["out.bin"]).is_none());
        std::fs::remove_file(dir.path().join("out.bin")).unwrap();
        assert!(stage.cached(&["out.bin"]).is_none());
    }

    #[test]
    fn begin_keeps_partial_outputs_of_the_same_key_only() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("train");
        let a = Stage::new(dir.clone(), "a".into());
        assert!(!a.begin().unwrap());
        std::fs::write(dir.join("checkpoint"), b"partial").unwrap();
        assert!(a.begin().unwrap(), "same key: resume");
        assert!(dir.join("checkpoint").exists());
        let b = Stage::new(dir.clone(), "b".into());
        assert!(!b.begin().unwrap(), "other key: start afresh");
        assert!(!dir.join("checkpoint").exists());
    }
}
