//! Property tests: whatever bytes a dataset folder holds, [`load_split`], [`Image::read_png`]
//! and [`DepthImage::read_png`] return (never panic, never abort on a crafted size) with either
//! an error that names the file or a split whose every value is usable.
//!
//! Inputs start from a valid tiny dataset (4×4 views of the monolith scene) and are mutated:
//! JSON keys deleted, replaced or added with values of any type (huge, negative and non-finite
//! numbers included), the text truncated or overwritten, and PNGs truncated, flipped, replaced
//! or given new IHDR fields (huge dimensions, odd bit depths) with a valid CRC.
//!
//! Deterministic: a fixed seed, no persistence files.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use nerfsv_dataset::{generate, load_split, DatasetError, DepthImage, GenerateOptions, Image, LoadOptions, Split};
use nerfsv_scene::validate::MemoryBudget;
use nerfsv_scene::Scene;
use nerfsv_testkit::{config, flip, flips, garbage, truncate};
use proptest::prelude::*;
use proptest::sample::Index;
use serde_json::Value;

/// A budget far below any machine's, so that a crafted size is refused the same way everywhere
/// (the valid tiny dataset needs a few KiB).
const BUDGET: u64 = 256 << 20;

/// The files of a valid tiny dataset, as (path relative to the folder, bytes).
fn fixture() -> &'static [(PathBuf, Vec<u8>)] {
    static FILES: OnceLock<Vec<(PathBuf, Vec<u8>)>> = OnceLock::new();
    FILES.get_or_init(|| {
        MemoryBudget::set(BUDGET);
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("ds");
        let opts =
            GenerateOptions { width: 4, height: 4, train: 2, val: 1, test: 1, supersample: 1, ..Default::default() };
        generate(&Scene::builtin("monolith").unwrap(), &out, &opts, &|_, _| {}).unwrap();
        let mut files = Vec::new();
        collect(&out, &out, &mut files);
        files.sort();
        files
    })
}

fn collect(root: &Path, dir: &Path, files: &mut Vec<(PathBuf, Vec<u8>)>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            collect(root, &p, files);
        } else {
            files.push((p.strip_prefix(root).unwrap().to_path_buf(), std::fs::read(&p).unwrap()));
        }
    }
}

fn names_ending(suffix: &str) -> Vec<PathBuf> {
    fixture().iter().filter(|(p, _)| p.to_string_lossy().ends_with(suffix)).map(|(p, _)| p.clone()).collect()
}

// ---------------------------------------------------------------- random JSON

/// A JSON value as text, of any type; numbers include the non-JSON tokens Python writes
/// (`NaN`, `Infinity`), values beyond f32 and f64, and integers beyond u64.
fn raw_json() -> impl Strategy<Value = String> {
    let tokens = [
        "null",
        "true",
        "false",
        "NaN",
        "-NaN",
        "Infinity",
        "-Infinity",
        "1e999",
        "-1e999",
        "1e300",
        "-1e300",
        "3.5e38",
        "1e-300",
        "1e-45",
        "0",
        "-0.0",
        "-1",
        "0.5",
        "4",
        "3.2",
        "6.3",
        "1000000000000000",
        "4294967295",
        "4294967296",
        "65536",
        "18446744073709551615",
        "18446744073709551616",
        "-9223372036854775809",
        "\"NaN\"",
        "\"Infinity\"",
        "\"\"",
        "\".\"",
        "\"..\"",
        "\"/\"",
        "\"./train/r_0\"",
        "\"./train/r_1.png\"",
        "\"./train/r_0_depth.png\"",
        "\"./val/r_0\"",
        "\"transforms_train.json\"",
        "\"train\"",
        "\"scene.json\"",
        "\"./train/r_0_depth\"",
        "[]",
        "{}",
        "[[]]",
    ];
    let leaf = prop_oneof![
        4 => proptest::sample::select(tokens.to_vec()).prop_map(String::from),
        1 => any::<i64>().prop_map(|v| v.to_string()),
        1 => any::<u64>().prop_map(|v| v.to_string()),
        1 => any::<f64>().prop_map(|v| format!("{v:e}")),
        1 => "[ -~]{0,10}".prop_map(|s| serde_json::to_string(&s).unwrap()),
    ];
    leaf.prop_recursive(3, 24, 5, |inner| {
        prop_oneof![
            proptest::collection::vec(inner.clone(), 0..6).prop_map(|v| format!("[{}]", v.join(","))),
            proptest::collection::vec((key(), inner), 0..4).prop_map(|kv| {
                let members: Vec<String> =
                    kv.into_iter().map(|(k, v)| format!("{}:{v}", serde_json::to_string(&k).unwrap())).collect();
                format!("{{{}}}", members.join(","))
            }),
        ]
    })
}

/// A 4×4 matrix as text: a rotation with a (possibly absurd) translation, or random entries.
fn raw_matrix() -> impl Strategy<Value = String> {
    let entry = prop_oneof![
        (-2.0f64..2.0).prop_map(|v| v.to_string()),
        proptest::sample::select(vec!["0", "1", "-1", "1e300", "-1e300", "3.5e38", "1e-40", "NaN", "Infinity"])
            .prop_map(String::from),
    ];
    prop_oneof![
        (entry.clone(), entry.clone(), entry.clone())
            .prop_map(|(x, y, z)| { format!("[[1,0,0,{x}],[0,1,0,{y}],[0,0,1,{z}],[0,0,0,1]]") }),
        proptest::collection::vec(proptest::collection::vec(entry, 3..=5), 3..=5).prop_map(|rows| {
            let rows: Vec<String> = rows.iter().map(|r| format!("[{}]", r.join(","))).collect();
            format!("[{}]", rows.join(","))
        }),
    ]
}

/// Keys the reader looks at (and a few it does not).
fn key() -> impl Strategy<Value = String> {
    let keys = vec![
        "w",
        "h",
        "fl_x",
        "fl_y",
        "cx",
        "cy",
        "camera_angle_x",
        "camera_angle_y",
        "aabb_scale",
        "depth_unit_scale_factor",
        "depth_file_path",
        "file_path",
        "transform_matrix",
        "frames",
        "",
        "unknown",
    ];
    proptest::sample::select(keys).prop_map(String::from)
}

#[derive(Clone, Debug)]
enum JsonEdit {
    /// Removes the value at a node (the whole text at the root).
    Delete(Index),
    /// Replaces the value at a node with raw JSON text.
    Replace(Index, String),
    /// Adds `key: value` to the object at (or enclosing) a node.
    Insert(Index, String, String),
}

fn json_edit() -> impl Strategy<Value = JsonEdit> {
    prop_oneof![
        2 => any::<Index>().prop_map(JsonEdit::Delete),
        3 => (any::<Index>(), prop_oneof![3 => raw_json(), 1 => raw_matrix()]).prop_map(|(i, v)| JsonEdit::Replace(i, v)),
        3 => (any::<Index>(), key(), prop_oneof![3 => raw_json(), 1 => raw_matrix()])
            .prop_map(|(i, k, v)| JsonEdit::Insert(i, k, v)),
    ]
}

#[derive(Clone, Debug)]
enum ByteEdit {
    Truncate(Index),
    /// XORs bytes at random offsets with non-zero masks.
    Flip(Vec<(Index, u8)>),
    /// Overwrites a slice at a random offset.
    Splice(Index, Vec<u8>),
    /// Replaces the whole file.
    Garbage(Vec<u8>),
    Delete,
}

fn byte_edit() -> impl Strategy<Value = ByteEdit> {
    prop_oneof![
        any::<Index>().prop_map(ByteEdit::Truncate),
        flips(8).prop_map(ByteEdit::Flip),
        (any::<Index>(), proptest::collection::vec(any::<u8>(), 1..16)).prop_map(|(i, b)| ByteEdit::Splice(i, b)),
        garbage().prop_map(ByteEdit::Garbage),
        Just(ByteEdit::Delete),
    ]
}

/// New IHDR fields (written with a valid CRC, so the decoder trusts them).
#[derive(Clone, Debug)]
struct Ihdr {
    width: u32,
    height: u32,
    /// Bit depth and colour type; `None` keeps the file's.
    format: Option<(u8, u8)>,
    interlace: bool,
}

fn dimension() -> impl Strategy<Value = u32> {
    prop_oneof![
        1..=8u32,
        proptest::sample::select(vec![0, 30_000, 65_536, 100_000, 1 << 24, 0x7fff_ffff, 0x8000_0000, u32::MAX]),
        any::<u32>(),
    ]
}

fn ihdr() -> impl Strategy<Value = Ihdr> {
    let format = proptest::option::of((
        proptest::sample::select(vec![1u8, 2, 4, 8, 16, 3]),
        proptest::sample::select(vec![0u8, 2, 3, 4, 6, 1, 7]),
    ));
    (dimension(), dimension(), format, any::<bool>()).prop_map(|(width, height, format, interlace)| Ihdr {
        width,
        height,
        format,
        interlace,
    })
}

#[derive(Clone, Debug)]
enum PngEdit {
    Bytes(ByteEdit),
    Ihdr(Ihdr),
    /// Replaces the file with a valid PNG of huge declared size whose pixels are all zero
    /// (deflate squeezes them to a small file): a decompression bomb.
    Bomb {
        width: u32,
        height: u32,
    },
    /// Copies another PNG of the dataset over this one (an RGBA image where a 16-bit depth is
    /// expected, or the reverse).
    CopyFrom(Index),
}

fn png_edit() -> impl Strategy<Value = PngEdit> {
    prop_oneof![
        3 => byte_edit().prop_map(PngEdit::Bytes),
        3 => ihdr().prop_map(PngEdit::Ihdr),
        1 => (prop_oneof![Just(4096u32), 1..=64u32], prop_oneof![Just(4096u32), 1..=64u32])
            .prop_map(|(width, height)| PngEdit::Bomb { width, height }),
        1 => any::<Index>().prop_map(PngEdit::CopyFrom),
    ]
}

/// The file a mutation edits: mostly one of the split being loaded, sometimes any.
#[derive(Clone, Debug)]
struct Target {
    index: Index,
    anywhere: bool,
}

fn target() -> impl Strategy<Value = Target> {
    (any::<Index>(), proptest::bool::weighted(0.15)).prop_map(|(index, anywhere)| Target { index, anywhere })
}

#[derive(Clone, Debug)]
enum Mutation {
    /// Structural edits of one transforms file.
    Json(Target, Vec<JsonEdit>),
    /// Byte edits of one transforms file.
    JsonBytes(Target, ByteEdit),
    Png(Target, PngEdit),
    /// Renames `transforms_train.json` to the instant-ngp `transforms.json` (every 8th frame
    /// goes to val/test) and removes the other splits.
    SingleTransformsFile,
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        5 => (target(), proptest::collection::vec(json_edit(), 1..4)).prop_map(|(f, e)| Mutation::Json(f, e)),
        1 => (target(), byte_edit()).prop_map(|(f, e)| Mutation::JsonBytes(f, e)),
        3 => (target(), png_edit()).prop_map(|(f, e)| Mutation::Png(f, e)),
        1 => Just(Mutation::SingleTransformsFile),
    ]
}

// ---------------------------------------------------------------- applying mutations

/// JSON pointers of every node, root first.
fn pointers(v: &Value, at: String, out: &mut Vec<String>) {
    out.push(at.clone());
    match v {
        Value::Object(m) => {
            for (k, c) in m {
                pointers(c, format!("{at}/{}", k.replace('~', "~0").replace('/', "~1")), out);
            }
        }
        Value::Array(a) => {
            for (i, c) in a.iter().enumerate() {
                pointers(c, format!("{at}/{i}"), out);
            }
        }
        _ => {}
    }
}

/// Raw JSON goes in through a placeholder string replaced in the serialised text, so values
/// serde_json cannot hold (`NaN`, `1e999`, 2^64) reach the file.
fn apply_json(text: &[u8], edits: &[JsonEdit]) -> Vec<u8> {
    let Ok(mut doc) = serde_json::from_slice::<Value>(text) else { return text.to_vec() };
    let mut raws: Vec<String> = Vec::new();
    for edit in edits {
        let mut ptrs = Vec::new();
        pointers(&doc, String::new(), &mut ptrs);
        match edit {
            JsonEdit::Delete(i) => {
                let p = i.get(&ptrs).clone();
                let Some((parent, last)) = p.rsplit_once('/') else { return Vec::new() };
                match doc.pointer_mut(parent) {
                    Some(Value::Object(m)) => {
                        m.remove(&last.replace("~1", "/").replace("~0", "~"));
                    }
                    Some(Value::Array(a)) => {
                        if let Ok(k) = last.parse::<usize>() {
                            if k < a.len() {
                                a.remove(k);
                            }
                        }
                    }
                    _ => {}
                }
            }
            JsonEdit::Replace(i, raw) => {
                let p = i.get(&ptrs).clone();
                if let Some(slot) = doc.pointer_mut(&p) {
                    *slot = Value::String(format!("\u{1}RAW{}", raws.len()));
                    raws.push(raw.clone());
                }
            }
            JsonEdit::Insert(i, k, raw) => {
                let mut p = i.get(&ptrs).clone();
                loop {
                    if let Some(Value::Object(m)) = doc.pointer_mut(&p) {
                        m.insert(k.clone(), Value::String(format!("\u{1}RAW{}", raws.len())));
                        raws.push(raw.clone());
                        break;
                    }
                    match p.rsplit_once('/') {
                        Some((parent, _)) => p = parent.to_string(),
                        None => break,
                    }
                }
            }
        }
    }
    let mut out = serde_json::to_string_pretty(&doc).unwrap();
    for (n, raw) in raws.iter().enumerate() {
        out = out.replace(&format!("\"\\u0001RAW{n}\""), raw);
    }
    out.into_bytes()
}

/// `None` deletes the file.
fn apply_bytes(bytes: &[u8], edit: &ByteEdit) -> Option<Vec<u8>> {
    let mut b = bytes.to_vec();
    match edit {
        ByteEdit::Truncate(i) => truncate(&mut b, i),
        ByteEdit::Flip(f) => flip(&mut b, f),
        ByteEdit::Splice(i, new) => {
            let at = i.index(b.len().max(1));
            for (k, &x) in new.iter().enumerate() {
                match b.get_mut(at + k) {
                    Some(slot) => *slot = x,
                    None => b.push(x),
                }
            }
        }
        ByteEdit::Garbage(g) => b = g.clone(),
        ByteEdit::Delete => return None,
    }
    Some(b)
}

/// CRC-32 (ISO 3309) of PNG chunks.
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xffff_ffffu32;
    for &b in bytes {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 == 1 { 0xedb8_8320 ^ (c >> 1) } else { c >> 1 };
        }
    }
    !c
}

/// Rewrites the IHDR chunk (always the first, at byte 8) and its CRC.
fn set_ihdr(png: &[u8], h: &Ihdr) -> Vec<u8> {
    let mut b = png.to_vec();
    if b.len() < 33 || &b[12..16] != b"IHDR" {
        return b;
    }
    b[16..20].copy_from_slice(&h.width.to_be_bytes());
    b[20..24].copy_from_slice(&h.height.to_be_bytes());
    if let Some((depth, colour)) = h.format {
        b[24] = depth;
        b[25] = colour;
    }
    b[28] = h.interlace as u8;
    let crc = crc32(&b[12..29]);
    b[29..33].copy_from_slice(&crc.to_be_bytes());
    b
}

/// A valid all-zero greyscale 8-bit PNG of `width × height` (tiny on disk when large).
fn bomb(width: u32, height: u32) -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, width, height);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    let mut w = enc.write_header().unwrap();
    let mut stream = w.stream_writer().unwrap();
    let row = vec![0u8; width as usize];
    for _ in 0..height {
        std::io::Write::write_all(&mut stream, &row).unwrap();
    }
    stream.finish().unwrap();
    drop(w);
    out
}

fn apply_png(bytes: &[u8], edit: &PngEdit, pngs: &[(PathBuf, Vec<u8>)]) -> Option<Vec<u8>> {
    match edit {
        PngEdit::Bytes(e) => apply_bytes(bytes, e),
        PngEdit::Ihdr(h) => Some(set_ihdr(bytes, h)),
        PngEdit::Bomb { width, height } => Some(bomb(*width, *height)),
        PngEdit::CopyFrom(i) => Some(i.get(pngs).1.clone()),
    }
}

/// Writes the fixture into `dir` with `mutations` applied; a mutation that is not `anywhere`
/// edits a file of `split`.
fn write_mutated(dir: &Path, split: &str, mutations: &[Mutation]) {
    let mut files: Vec<(PathBuf, Option<Vec<u8>>)> =
        fixture().iter().map(|(p, b)| (p.clone(), Some(b.clone()))).collect();
    let originals: Vec<(PathBuf, Vec<u8>)> =
        fixture().iter().filter(|(p, _)| p.extension().is_some_and(|e| e == "png")).cloned().collect();
    // A file with extension `ext`: of the split unless `anywhere` (or the split has none).
    let pick = |files: &[(PathBuf, Option<Vec<u8>>)], t: &Target, ext: &str, of_split: &dyn Fn(&str) -> bool| {
        let all: Vec<usize> = (0..files.len()).filter(|&k| files[k].0.extension().is_some_and(|e| e == ext)).collect();
        let mine: Vec<usize> = all.iter().copied().filter(|&k| of_split(&files[k].0.to_string_lossy())).collect();
        *t.index.get(if t.anywhere || mine.is_empty() { &all } else { &mine })
    };
    let json_of_split = |n: &str| n == format!("transforms_{split}.json") || n == "transforms.json";
    let png_of_split = |n: &str| n.starts_with(&format!("{split}/"));
    for m in mutations {
        match m {
            Mutation::Json(t, edits) => {
                let k = pick(&files, t, "json", &json_of_split);
                files[k].1 = files[k].1.as_ref().map(|b| apply_json(b, edits));
            }
            Mutation::JsonBytes(t, e) => {
                let k = pick(&files, t, "json", &json_of_split);
                files[k].1 = files[k].1.as_ref().and_then(|b| apply_bytes(b, e));
            }
            Mutation::Png(t, e) => {
                let k = pick(&files, t, "png", &png_of_split);
                files[k].1 = files[k].1.as_ref().and_then(|b| apply_png(b, e, &originals));
            }
            Mutation::SingleTransformsFile => {
                for (p, b) in files.iter_mut() {
                    let name = p.to_string_lossy().into_owned();
                    if name == "transforms_train.json" {
                        *p = PathBuf::from("transforms.json");
                    } else if name.starts_with("transforms_") {
                        *b = None;
                    }
                }
            }
        }
    }
    for (p, b) in files {
        if let Some(b) = b {
            let path = dir.join(p);
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(path, b).unwrap();
        }
    }
}

// ---------------------------------------------------------------- properties

/// A loaded split is usable: frames, finite rigid poses, positive finite focal lengths, pixels
/// of the declared size in [0, 1], depths finite and non-negative, rays finite.
fn check_split(split: &Split, dir: &Path) -> Result<(), TestCaseError> {
    prop_assert!(split.path.starts_with(dir), "{}", split.path.display());
    // Only instant-ngp's single file can leave a split empty (its every 8th frame is val/test);
    // training and evaluation refuse an empty split themselves.
    prop_assert!(
        !split.frames.is_empty() || split.path.ends_with("transforms.json"),
        "a split without frames from {}",
        split.path.display()
    );
    prop_assert!(split.aabb_scale.is_none_or(|s| s.is_finite()));
    for (i, f) in split.frames.iter().enumerate() {
        let k = f.camera.intrinsics;
        prop_assert!(k.width > 0 && k.height > 0, "frame {i}: {k:?}");
        prop_assert!(k.fx.is_finite() && k.fx > 0.0 && k.fy.is_finite() && k.fy > 0.0, "frame {i}: {k:?}");
        prop_assert!(k.cx.is_finite() && k.cy.is_finite(), "frame {i}: {k:?}");
        prop_assert!(f.camera.c2w.iter().all(|v| v.is_finite()), "frame {i}: {}", f.camera.c2w);
        prop_assert_eq!((f.image.width, f.image.height), (k.width, k.height));
        prop_assert_eq!(f.image.rgba.len(), 4 * k.width as usize * k.height as usize);
        prop_assert!(f.image.rgba.iter().all(|v| (0.0..=1.0).contains(v)), "frame {i}: pixel out of [0, 1]");
        if let Some(d) = &f.depth {
            prop_assert_eq!((d.width, d.height), (k.width, k.height));
            prop_assert_eq!(d.metres.len(), k.width as usize * k.height as usize);
            prop_assert!(d.metres.iter().all(|v| v.is_finite() && *v >= 0.0), "frame {i}: depth not finite");
        }
        for (u, v) in [(0, 0), (k.width - 1, k.height - 1)] {
            let ray = f.camera.pixel_ray(u, v);
            prop_assert!(ray.direction.iter().all(|x| x.is_finite()), "frame {i}: ray {ray:?} from {k:?}");
        }
    }
    Ok(())
}

/// An error names the folder's file it is about.
fn check_error(e: &DatasetError, dir: &Path) -> Result<(), TestCaseError> {
    let msg = e.to_string();
    prop_assert!(!msg.trim().is_empty());
    match e {
        // Options are not in a file; everything else is.
        DatasetError::Invalid(_) => prop_assert!(msg.contains("downscale") || msg.contains("memory budget"), "{msg}"),
        _ => prop_assert!(msg.contains(&*dir.to_string_lossy()), "the error names no file of {}: {msg}", dir.display()),
    }
    Ok(())
}

fn check_load(dir: &Path, split: &str, opts: LoadOptions) -> Result<(), TestCaseError> {
    match load_split(dir, split, opts) {
        Ok(s) => check_split(&s, dir),
        Err(e) => check_error(&e, dir),
    }
}

fn load_options() -> impl Strategy<Value = LoadOptions> {
    let downscale =
        prop_oneof![24 => Just(1u32), 4 => 2..=3u32, 1 => Just(0u32), 1 => Just(u32::MAX), 1 => Just(65_536u32)];
    (downscale, any::<bool>()).prop_map(|(downscale, load_depth)| LoadOptions {
        downscale,
        load_depth,
        ..Default::default()
    })
}

#[test]
fn the_unmutated_fixture_loads_and_is_valid() {
    let dir = tempfile::tempdir().unwrap();
    write_mutated(dir.path(), "train", &[]);
    for split in ["train", "val", "test"] {
        let s = load_split(dir.path(), split, LoadOptions::default()).unwrap();
        check_split(&s, dir.path()).unwrap();
        assert!(s.frames.iter().all(|f| f.depth.is_some()));
    }
    assert!(!names_ending("_depth.png").is_empty() && !names_ending(".json").is_empty());
}

proptest! {
    #![proptest_config(config(1024))]

    /// JSON and PNG mutations of a dataset folder: an error naming a file, or a valid split.
    #[test]
    fn load_split_of_a_mutated_dataset_errs_naming_the_file_or_is_valid(
        mutations in proptest::collection::vec(mutation(), 1..4),
        split in proptest::sample::select(vec!["train", "val", "test"]),
        opts in load_options(),
    ) {
        let dir = tempfile::tempdir().unwrap();
        write_mutated(dir.path(), split, &mutations);
        check_load(dir.path(), split, opts)?;
    }
}

proptest! {
    #![proptest_config(config(512))]

    /// The PNG readers on mutated image and depth files: a non-empty message (the loader adds
    /// the file), or an image whose size matches its pixels.
    #[test]
    fn png_readers_on_mutated_files_err_or_return_consistent_images(
        file in any::<Index>(),
        edits in proptest::collection::vec(png_edit(), 1..3),
        unit_scale in prop_oneof![Just(1e-3f32), Just(1.0f32), 0.0f32..10.0],
    ) {
        MemoryBudget::set(BUDGET);
        let pngs: Vec<(PathBuf, Vec<u8>)> =
            fixture().iter().filter(|(p, _)| p.extension().is_some_and(|e| e == "png")).cloned().collect();
        let mut bytes = Some(file.get(&pngs).1.clone());
        for e in &edits {
            bytes = bytes.and_then(|b| apply_png(&b, e, &pngs));
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.png");
        if let Some(b) = bytes {
            std::fs::write(&path, b).unwrap();
        }
        match Image::read_png(&path) {
            Ok(img) => {
                prop_assert!(img.width > 0 && img.height > 0);
                prop_assert_eq!(img.rgba.len(), 4 * img.width as usize * img.height as usize);
                prop_assert!(img.rgba.iter().all(|v| (0.0..=1.0).contains(v)));
            }
            Err(m) => prop_assert!(!m.trim().is_empty()),
        }
        match DepthImage::read_png(&path, unit_scale) {
            Ok(d) => {
                prop_assert!(d.width > 0 && d.height > 0);
                prop_assert_eq!(d.metres.len(), d.width as usize * d.height as usize);
                prop_assert!(d.metres.iter().all(|v| v.is_finite() && *v >= 0.0));
            }
            Err(m) => prop_assert!(!m.trim().is_empty()),
        }
    }
}

// ---------------------------------------------------------------- regressions found above

/// A copy of the fixture whose train transforms file has `edit` applied.
fn edited_train_dir(edit: impl FnOnce(&mut Value)) -> tempfile::TempDir {
    MemoryBudget::set(BUDGET);
    let dir = tempfile::tempdir().unwrap();
    write_mutated(dir.path(), "train", &[]);
    let path = dir.path().join("transforms_train.json");
    let mut doc: Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    edit(&mut doc);
    std::fs::write(&path, serde_json::to_string(&doc).unwrap()).unwrap();
    dir
}

/// The error of loading the train split of [`edited_train_dir`].
fn edited_train_error(edit: impl FnOnce(&mut Value)) -> String {
    let dir = edited_train_dir(edit);
    load_split(dir.path(), "train", LoadOptions::default()).unwrap_err().to_string()
}

#[test]
fn a_png_header_declaring_gigapixels_is_refused_before_its_buffer_is_allocated() {
    // Was: `memory allocation of 3355443200000 bytes failed` (abort) for a 4×4 PNG whose IHDR
    // claims 100000×100000 RGBA 8-bit.
    MemoryBudget::set(BUDGET);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("huge.png");
    let png = &fixture().iter().find(|(p, _)| p.ends_with("r_0.png")).unwrap().1;
    std::fs::write(&path, set_ihdr(png, &Ihdr { width: 100_000, height: 100_000, format: None, interlace: false }))
        .unwrap();
    let e = Image::read_png(&path).unwrap_err();
    assert!(e.contains("100000×100000") && e.contains("memory budget"), "{e}");
    let e = DepthImage::read_png(&path, 1e-3).unwrap_err();
    assert!(e.contains("memory budget"), "{e}");
}

#[test]
fn a_split_whose_images_fit_one_by_one_but_not_together_is_refused_from_the_headers() {
    // Four frames naming one 2048×2048 all-zero PNG (a few KiB on disk): 80 MiB decoded each,
    // over the 256 MiB budget together.
    let dir = edited_train_dir(|doc| {
        let frame = doc["frames"][0].clone();
        doc["frames"] = Value::Array(vec![frame; 4]);
        for k in ["w", "h", "fl_x", "fl_y", "cx", "cy"] {
            doc.as_object_mut().unwrap().remove(k);
        }
    });
    std::fs::write(dir.path().join("train/r_0.png"), bomb(2048, 2048)).unwrap();
    let e = load_split(dir.path(), "train", LoadOptions::default()).unwrap_err().to_string();
    assert!(e.contains("transforms_train.json: frames: decoded images must fit the memory budget"), "{e}");
}

#[test]
fn numbers_finite_as_f64_but_infinite_as_f32_are_refused_naming_the_field() {
    // Was accepted: a camera at x = −∞ (and a principal point at +∞).
    let e = edited_train_error(|doc| doc["frames"][0]["transform_matrix"][0][3] = serde_json::json!(-1e300));
    assert!(e.contains("frame 0: transform_matrix: entry [0][3]") && e.contains("finite 32-bit"), "{e}");
    let e = edited_train_error(|doc| doc["cx"] = serde_json::json!(1e300));
    assert!(e.contains("transforms_train.json: cx: expected a finite 32-bit number"), "{e}");
}

#[test]
fn degenerate_intrinsics_and_depth_scales_are_refused_naming_the_field() {
    // Each was accepted, giving flipped images, NaN pixel rays or negative depths.
    for (key, value, says) in [
        ("camera_angle_x", 4.0, "camera_angle_x: must be below π radians"),
        ("fl_x", 1e-30, "fl_x/cx: gives a focal length of 0.000000000000000000000000000001 pixels"),
        ("cx", 3e38, "fl_x/cx: gives a focal length of"),
        ("depth_unit_scale_factor", -1e-3, "depth_unit_scale_factor: must be positive"),
    ] {
        let e = edited_train_error(|doc| doc[key] = serde_json::json!(value));
        assert!(e.contains("transforms_train.json") && e.contains(says), "{key} = {value}: {e}");
    }
    // Without explicit focal lengths the angle decides: tan(½·6.0) < 0 would give fx < 0.
    let e = edited_train_error(|doc| {
        for k in ["fl_x", "fl_y"] {
            doc.as_object_mut().unwrap().remove(k);
        }
        doc["camera_angle_x"] = serde_json::json!(6.0);
    });
    assert!(e.contains("camera_angle_x: must be below π"), "{e}");
}
