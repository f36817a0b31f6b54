//! The offline study's CSV: its columns, each row's cells, the text and the file name.

use std::fmt::Write as _;

use super::rows::{Fit, Row};
use crate::{GaExclusion, Method};

/// A CSV field, quoted when it holds a separator, a quote or a line break.
pub fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// The CSV's `excluded` value of a GA exclusion (empty for none).
pub fn exclusion_name(e: Option<GaExclusion>) -> &'static str {
    match e {
        None => "",
        Some(GaExclusion::AbsolutelyCertain) => "absolutely_certain",
        Some(GaExclusion::AbsolutelyUncertain) => "absolutely_uncertain",
    }
}

/// A column of the offline study's CSV after `split`, `index` and `file_path`: its name and
/// whether it holds text or numbers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Column {
    pub name: &'static str,
    pub text: bool,
}

const fn number(name: &'static str) -> Column {
    Column { name, text: false }
}

const fn text(name: &'static str) -> Column {
    Column { name, text: true }
}

/// GA's columns, in the CSV's order.
const GA_COLUMNS: [Column; 8] = [
    number("mu_d"),
    number("sigma_d"),
    text("excluded"),
    number("objective"),
    number("rays"),
    number("rays_without_samples"),
    number("floored_mu_d"),
    number("floored_sigma_d"),
];

/// BLA's columns, in the CSV's order.
const BLA_COLUMNS: [Column; 10] = [
    number("normalized_trace"),
    number("rmv"),
    number("information_gain"),
    number("map_loss"),
    number("initial_loss"),
    number("perturbation"),
    number("prior_precision"),
    number("log_evidence"),
    number("rays"),
    text("note"),
];

/// The method's columns after `split`, `index` and `file_path`, in the CSV's order.
pub fn columns(method: Method) -> &'static [Column] {
    match method {
        Method::Ga => &GA_COLUMNS,
        Method::Bla => &BLA_COLUMNS,
    }
}

/// One value of a row, in a [`Column`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Cell {
    /// A text column's value (`""` for none).
    Text(&'static str),
    Number(f64),
    /// A number column of an image whose rays all miss.
    Empty,
}

impl Fit {
    /// The row's values, one per column of [`columns`] for its method. An image whose rays all
    /// miss has empty numbers and `all_rays_miss` in GA's `excluded` or BLA's `note`.
    pub fn cells(&self) -> Vec<Cell> {
        use Cell::{Empty, Number, Text};
        match self {
            Fit::Ga(Some(g)) => vec![
                Number(g.mu_d),
                Number(g.sigma_d),
                Text(exclusion_name(g.excluded)),
                Number(g.objective),
                Number(g.rays as f64),
                Number(g.rays_without_samples as f64),
                Number(g.floored_mu_d),
                Number(g.floored_sigma_d),
            ],
            Fit::Ga(None) => GA_COLUMNS.iter().map(|c| if c.text { Text(ALL_RAYS_MISS) } else { Empty }).collect(),
            Fit::Bla(Some(b)) => vec![
                Number(b.normalized_trace),
                Number(b.rmv),
                Number(b.information_gain),
                Number(b.map_loss),
                Number(b.initial_loss),
                Number(b.perturbation as f64),
                Number(b.prior_precision),
                Number(b.log_evidence),
                Number(b.rays as f64),
                Text(""),
            ],
            Fit::Bla(None) => BLA_COLUMNS.iter().map(|c| if c.text { Text(ALL_RAYS_MISS) } else { Empty }).collect(),
        }
    }
}

/// The text value of an image whose rays all miss the model.
pub const ALL_RAYS_MISS: &str = "all_rays_miss";

/// One row per image under [`columns`]. An image whose rays all miss has empty values (GA:
/// `excluded` is `all_rays_miss`; BLA: `note` is).
pub fn csv(rows: &[Row], method: Method) -> String {
    let mut out = String::from("split,index,file_path");
    for c in columns(method) {
        let _ = write!(out, ",{}", c.name);
    }
    out.push('\n');
    for r in rows {
        let _ = write!(out, "{},{},{}", r.split, r.index, csv_field(&r.file_path));
        for cell in r.fit.cells() {
            let _ = match cell {
                Cell::Text(t) => write!(out, ",{}", csv_field(t)),
                Cell::Number(v) => write!(out, ",{v}"),
                Cell::Empty => write!(out, ","),
            };
        }
        out.push('\n');
    }
    out
}

/// `uq_{method}.csv`: a method's rows ([`csv`]), as `nerfsv uq offline` and the run's `uq/`
/// name them.
pub const fn csv_name(method: Method) -> &'static str {
    match method {
        Method::Ga => "uq_ga.csv",
        Method::Bla => "uq_bla.csv",
    }
}
