//! `nerfsv config [CONFIG] [--set TABLE.KEY=VALUE …]`: the run config `nerfsv run` would use (the
//! embedded default without a file) as TOML, every key preceded by its documentation (what it
//! is, its unit) taken from the doc comments of the config structs themselves
//! (`#[derive(FieldDocs)]`, `nerfsv-derive`), so the file and the code cannot drift apart. Saved
//! to a file, it is a starting point for `nerfsv run my.toml` and loads back to exactly the same
//! config.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use nerfsv_pipeline::RunConfig;

use crate::config_file::{run_config, Sets};

#[derive(Args)]
pub struct ConfigArgs {
    /// A run config (TOML): print the config `nerfsv run CONFIG` would use with it and the
    /// overrides, every key. Without it, the embedded default with the overrides.
    #[arg(conflicts_with = "default")]
    pub config: Option<PathBuf>,
    /// Print the embedded default run config (what `nerfsv run` uses without a file), whatever
    /// else is given.
    #[arg(long)]
    pub default: bool,
    #[command(flatten)]
    pub sets: Sets,
}

/// Comment lines are wrapped at this width.
const WIDTH: usize = 96;

pub fn run(args: ConfigArgs) -> anyhow::Result<()> {
    if args.default || (args.config.is_none() && args.sets.sets.is_empty()) {
        print!("{}", default_toml()?);
    } else {
        let cfg = run_config(args.config.as_deref(), &args.sets)?;
        let source = match &args.config {
            Some(path) => format!("`nerfsv run {}`", path.display()),
            None => "`nerfsv run`".to_owned(),
        };
        let sets = match args.sets.sets.len() {
            0 => String::new(),
            n => format!(" with {n} override(s) ({})", args.sets.sets.join(", ")),
        };
        let header = format!(
            "The run config {source}{sets} uses, every key with its documentation. It loads back to the same \
             config: `nerfsv run` with this file and no overrides."
        );
        print!("{}", config_toml(&cfg, &header)?);
    }
    Ok(())
}

/// `text` as `# ` comment lines of at most [`WIDTH`] characters.
fn comment(text: &str, out: &mut String) {
    let mut line = String::from("#");
    for word in text.split_whitespace() {
        if line.len() + 1 + word.len() > WIDTH && line.len() > 1 {
            out.push_str(&line);
            out.push('\n');
            line = String::from("#");
        }
        line.push(' ');
        line.push_str(word);
    }
    out.push_str(&line);
    out.push('\n');
}

/// The default config as commented TOML.
pub fn default_toml() -> anyhow::Result<String> {
    config_toml(
        &RunConfig::default(),
        "The default nerfsv run config (`nerfsv config --default`): what `nerfsv run` uses without a file. \
         Every key is optional; a file that sets some of them keeps the defaults below for the rest. Values \
         are the defaults.",
    )
}

/// `cfg` as commented TOML under the comment `header`: every key, subset simulation's too.
pub fn config_toml(cfg: &RunConfig, header: &str) -> anyhow::Result<String> {
    let mut value = toml::Table::try_from(cfg).context("serialising the config")?;
    // `[stress.subset]` is left out of the serialised config while it holds the defaults
    // (the cache keys of results from before it existed); printed all the same.
    if let Some(toml::Value::Table(v)) = value.get_mut("stress") {
        if !v.contains_key("subset") {
            let subset = toml::Table::try_from(&cfg.stress.subset).context("serialising stress.subset")?;
            v.insert("subset".to_owned(), toml::Value::Table(subset));
        }
    }
    let mut out = String::new();
    comment(header, &mut out);
    table("", &value, None, &mut out)?;
    Ok(out)
}

/// Writes the table at `path` (its header after a blank line, unless it is the top level; its
/// own documentation `doc` above the header), its keys in declaration order, then its
/// sub-tables.
fn table(path: &str, value: &toml::Table, doc: Option<&str>, out: &mut String) -> anyhow::Result<()> {
    // Each table of the run config, the struct behind it and its fields' doc comments
    // (`#[derive(FieldDocs)]`; a field marked `#[docs(table)]` is a sub-table).
    let mut tables = Vec::new();
    RunConfig::tables("", &mut tables);
    let (name, fields) = tables
        .iter()
        .find(|(p, ..)| p == path)
        .map(|&(_, n, f)| (n, f))
        .with_context(|| format!("no struct is known for the table [{path}] (a field without #[docs(table)]?)"))?;
    if !path.is_empty() {
        out.push('\n');
        if let Some(d) = doc.filter(|d| !d.is_empty()) {
            comment(d, out);
        }
        out.push_str(&format!("[{path}]\n"));
    }
    let mut tables = Vec::new();
    for &(field, text) in fields {
        match value.get(field) {
            Some(toml::Value::Table(t)) => tables.push((field, text, t)),
            Some(v) => {
                comment(text, out);
                let mut one = toml::Table::new();
                one.insert(field.to_owned(), shortest(v));
                out.push_str(&toml::to_string(&one).with_context(|| format!("formatting {path}.{field}"))?);
            }
            None => {
                comment(&format!("{text} Optional, unset by default: `{field} = …`."), out);
            }
        }
    }
    if let Some(extra) = value.keys().find(|k| !fields.iter().any(|(f, _)| f == *k)) {
        anyhow::bail!("[{path}] {extra}: a key of the default config that struct {name} does not declare");
    }
    for (field, text, t) in tables {
        let sub = if path.is_empty() { field.to_owned() } else { format!("{path}.{field}") };
        table(&sub, t, Some(text), out)?;
    }
    Ok(())
}

/// `v` with every float that is exactly an `f32` written as that `f32`'s shortest decimal (the
/// `f32` fields serialise through `f64`: `0.8` would print as `0.800000011920929`). The value
/// read back into the `f32` field is the same; the test below checks the whole file loads back.
fn shortest(v: &toml::Value) -> toml::Value {
    match v {
        toml::Value::Float(x) if (*x as f32) as f64 == *x => {
            toml::Value::Float((*x as f32).to_string().parse().unwrap_or(*x))
        }
        toml::Value::Array(a) => toml::Value::Array(a.iter().map(shortest).collect()),
        other => other.clone(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_key_of_the_default_config_is_documented() {
        let mut missing = Vec::new();
        let mut tables = Vec::new();
        RunConfig::tables("", &mut tables);
        // Every table of the default config is among those found from `RunConfig` (which also
        // finds the tables unset by default, `sim.camera` and `stress.subset`): none is
        // printed without its documentation.
        let paths: Vec<String> = tables.iter().map(|(p, ..)| p.clone()).collect();
        fn table_paths(prefix: &str, t: &toml::Table, out: &mut Vec<String>) {
            out.push(prefix.to_owned());
            for (key, value) in t {
                if let toml::Value::Table(inner) = value {
                    let path = if prefix.is_empty() { key.clone() } else { format!("{prefix}.{key}") };
                    table_paths(&path, inner, out);
                }
            }
        }
        let mut in_file = Vec::new();
        table_paths("", &toml::Table::try_from(RunConfig::default()).unwrap(), &mut in_file);
        let undocumented: Vec<&String> = in_file.iter().filter(|p| !paths.contains(p)).collect();
        assert!(undocumented.is_empty(), "tables printed without documentation: {undocumented:?}");
        assert!(paths.len() > 15 && paths.iter().any(|p| p == "sim.vision"), "{paths:?}");
        for (path, name, fields) in &tables {
            assert!(!fields.is_empty(), "struct {name} has no fields");
            for &(field, doc) in *fields {
                if doc.is_empty() {
                    missing.push(format!("[{path}] {field} ({name})"));
                }
            }
        }
        assert!(missing.is_empty(), "undocumented config keys: {missing:#?}");
    }

    #[test]
    fn the_commented_default_loads_back_to_the_embedded_default() {
        let text = default_toml().unwrap();
        let back: RunConfig = toml::from_str(&text).unwrap_or_else(|e| panic!("{e}\n{text}"));
        assert_eq!(serde_json::to_value(&back).unwrap(), serde_json::to_value(RunConfig::default()).unwrap());
        // Every key line has a comment right above it (a header may sit between for tables).
        let lines: Vec<&str> = text.lines().collect();
        for (i, l) in lines.iter().enumerate() {
            if !l.is_empty() && !l.starts_with('#') && !l.starts_with('[') {
                assert!(i > 0 && lines[i - 1].starts_with('#'), "no comment above {l:?}");
            }
        }
        assert!(text.contains("[stress.cem]\n") && text.contains("[online]\n"), "{text}");
        // Subset simulation's table too, though the serialised config leaves it out at its defaults.
        assert!(text.contains("[stress.subset]\n") && text.contains("\nsamples = 200\n"), "{text}");
    }

    /// Doc comments become data: each line trimmed, the lines joined by one space, intra-doc
    /// link brackets dropped, fields in declaration order (undocumented ones empty).
    #[test]
    fn field_docs_are_the_fields_doc_comments_joined() {
        #[derive(nerfsv_derive::FieldDocs)]
        #[allow(dead_code)]
        struct Example {
            /// First line,
            ///   second line with a [`link`].
            a: u32,
            b: u32,
            /// Last.
            c: u32,
        }
        assert_eq!(Example::FIELD_DOCS, &[("a", "First line, second line with a `link`."), ("b", ""), ("c", "Last.")]);
        assert_eq!(
            nerfsv_sim::SimConfig::FIELD_DOCS[0],
            ("start", "Start position, metres (the paper's (0.39, −0.67, 0.2)).")
        );
    }

    #[test]
    fn comments_wrap_at_the_width() {
        let mut out = String::new();
        comment(&"word ".repeat(60), &mut out);
        assert!(out.lines().count() > 2 && out.lines().all(|l| l.len() <= WIDTH && l.starts_with("# ")), "{out}");
    }
}
