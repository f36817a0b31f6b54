//! Atomic file output: every file nerfsv writes goes to a temporary name in the destination
//! folder and is renamed into place, so a killed process never leaves a half-written artifact.

use std::collections::BTreeMap;
use std::fs;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Writes `path` atomically: `write` fills a buffered temporary file next to `path`, which is
/// flushed, synced and renamed over `path`. On any error the temporary file is removed.
pub fn atomic_write<F>(path: &Path, write: F) -> io::Result<()>
where
    F: FnOnce(&mut BufWriter<fs::File>) -> io::Result<()>,
{
    let tmp = temp_path(path);
    let result = (|| {
        let file = fs::File::create(&tmp)?;
        let mut w = BufWriter::new(file);
        write(&mut w)?;
        w.flush()?;
        w.get_ref().sync_all()?;
        drop(w);
        fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// Writes a byte buffer atomically.
pub fn atomic_write_bytes(path: &Path, bytes: &[u8]) -> io::Result<()> {
    atomic_write(path, |w| w.write_all(bytes))
}

/// `dir/.name.tmp-<pid>-<n>`: hidden, in the same folder (so the rename stays on one file
/// system), unique per process and call (so concurrent writers of one path never share it).
fn temp_path(path: &Path) -> PathBuf {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    path.with_file_name(format!(".{name}.tmp-{}-{n}", std::process::id()))
}

/// One tensor for [`safetensors_bytes`]: name, safetensors dtype (`"F32"`, `"U8"`, …), shape,
/// and its little-endian bytes.
pub struct TensorBytes<'a> {
    pub name: &'a str,
    pub dtype: &'a str,
    pub shape: Vec<usize>,
    pub data: &'a [u8],
}

/// A safetensors file in memory, byte-identical for identical inputs: the header's keys (the
/// metadata's and the tensors') are written in sorted order, not a hash map's, and the data
/// follows in the order the tensors are given.
pub fn safetensors_bytes(tensors: &[TensorBytes], metadata: &BTreeMap<String, String>) -> Vec<u8> {
    let mut offset = 0usize;
    let mut entries: Vec<(&str, String)> = tensors
        .iter()
        .map(|t| {
            let shape: Vec<String> = t.shape.iter().map(|d| d.to_string()).collect();
            let entry = format!(
                "{{\"dtype\":{},\"shape\":[{}],\"data_offsets\":[{},{}]}}",
                json_string(t.dtype),
                shape.join(","),
                offset,
                offset + t.data.len()
            );
            offset += t.data.len();
            (t.name, entry)
        })
        .collect();
    entries.sort_by(|a, b| a.0.cmp(b.0));
    let mut header = String::from("{");
    if !metadata.is_empty() {
        let fields: Vec<String> =
            metadata.iter().map(|(k, v)| format!("{}:{}", json_string(k), json_string(v))).collect();
        header.push_str(&format!("\"__metadata__\":{{{}}}", fields.join(",")));
    }
    for (name, entry) in &entries {
        if header.len() > 1 {
            header.push(',');
        }
        header.push_str(&format!("{}:{entry}", json_string(name)));
    }
    header.push('}');
    // The format pads the header with spaces to a multiple of 8 bytes.
    while header.len() % 8 != 0 {
        header.push(' ');
    }
    let mut out = Vec::with_capacity(8 + header.len() + offset);
    out.extend_from_slice(&(header.len() as u64).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for t in tensors {
        out.extend_from_slice(t.data);
    }
    out
}

/// `s` as a JSON string literal.
fn json_string(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if (c as u32) < 0x20 => out.push_str(&format!("\\u{:04x}", c as u32)),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// Removes the temporary files that killed writers left beside `path` (`.NAME.tmp-PID-N`
/// from [`atomic_write`]), except those of processes still running. Returns how many it removed.
pub fn remove_stale_temporaries(path: &Path) -> usize {
    let Some(name) = path.file_name().map(|n| n.to_string_lossy().into_owned()) else { return 0 };
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    remove_stale_in(dir, Some(&name))
}

/// Removes every stale temporary file of [`atomic_write`] in `dir` (see
/// [`remove_stale_temporaries`]). Returns how many it removed.
pub fn remove_stale_temporaries_in(dir: &Path) -> usize {
    remove_stale_in(dir, None)
}

fn remove_stale_in(dir: &Path, only: Option<&str>) -> usize {
    let Ok(entries) = fs::read_dir(dir) else { return 0 };
    let mut removed = 0;
    for entry in entries.flatten() {
        let file = entry.file_name().to_string_lossy().into_owned();
        let Some((target, pid)) = parse_temp_name(&file) else { continue };
        if only.is_some_and(|n| n != target) || process_alive(pid) {
            continue;
        }
        if fs::remove_file(entry.path()).is_ok() {
            removed += 1;
        }
    }
    removed
}

/// `.NAME.tmp-PID-N` → (`NAME`, PID).
fn parse_temp_name(file: &str) -> Option<(&str, u32)> {
    let rest = file.strip_prefix('.')?;
    let at = rest.rfind(".tmp-")?;
    let (target, suffix) = (&rest[..at], &rest[at + 5..]);
    let (pid, n) = suffix.split_once('-')?;
    n.parse::<u64>().ok()?;
    Some((target, pid.parse().ok()?))
}

/// Whether process `pid` is running (this one always is). Where `/proc` is missing, every
/// other process counts as gone.
fn process_alive(pid: u32) -> bool {
    pid == std::process::id() || Path::new("/proc").join(pid.to_string()).exists()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failed_write_leaves_neither_target_nor_temporary_file() {
        let dir = std::env::temp_dir().join(format!("nerfsv-io-{}", std::process::id()));
        fs::create_dir_all(&dir).unwrap();
        let target = dir.join("out.bin");
        let err = atomic_write(&target, |w| {
            w.write_all(b"partial")?;
            Err(io::Error::other("boom"))
        });
        assert!(err.is_err());
        assert!(!target.exists());
        assert_eq!(fs::read_dir(&dir).unwrap().count(), 0);
        atomic_write_bytes(&target, b"whole").unwrap();
        assert_eq!(fs::read(&target).unwrap(), b"whole");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn safetensors_bytes_are_read_by_the_safetensors_crate_and_do_not_depend_on_insertion_order() {
        let a: Vec<u8> = [1.5f32, -2.0, 3.25].iter().flat_map(|v| v.to_le_bytes()).collect();
        let b = [7u8, 8, 9, 10, 11];
        let meta: BTreeMap<String, String> = [("zeta", "1"), ("alpha", "quote \" and \\ backslash"), ("mid", "x")]
            .map(|(k, v)| (k.into(), v.into()))
            .into();
        let tensors = [
            TensorBytes { name: "w", dtype: "F32", shape: vec![3], data: &a },
            TensorBytes { name: "grid", dtype: "U8", shape: vec![5, 1], data: &b },
        ];
        let bytes = safetensors_bytes(&tensors, &meta);
        assert_eq!(bytes, safetensors_bytes(&tensors, &meta.clone().into_iter().rev().collect()));
        let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        assert_eq!(st.tensor("w").unwrap().data(), &a[..]);
        assert_eq!(st.tensor("grid").unwrap().shape(), &[5, 1]);
        assert_eq!(st.tensor("grid").unwrap().data(), &b[..]);
        let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
        let read = header.metadata().clone().unwrap();
        assert_eq!(read.len(), 3);
        assert_eq!(read["alpha"], "quote \" and \\ backslash");
    }

    #[test]
    fn stale_temporaries_of_dead_processes_are_removed_and_live_ones_kept() {
        let dir = std::env::temp_dir().join(format!("nerfsv-stale-{}", std::process::id()));
        fs::create_dir_all(&dir).unwrap();
        let target = dir.join("checkpoint.safetensors");
        // PID 4194304 is above Linux's maximum, so never a running process.
        let dead = dir.join(".checkpoint.safetensors.tmp-4194304-0");
        let live = dir.join(format!(".checkpoint.safetensors.tmp-{}-7", std::process::id()));
        let other = dir.join(".gt.safetensors.tmp-4194304-3");
        for p in [&dead, &live, &other] {
            fs::write(p, b"partial").unwrap();
        }
        assert_eq!(remove_stale_temporaries(&target), 1);
        assert!(!dead.exists() && live.exists() && other.exists());
        assert_eq!(remove_stale_temporaries_in(&dir), 1);
        assert!(!other.exists() && live.exists());
        fs::remove_dir_all(&dir).unwrap();
    }
}
