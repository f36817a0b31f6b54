//! Validation of values a user supplies (config keys, command-line options, values read back
//! from files), shared by every stage so that every refusal reads the same way:
//! `nerf.color_hidden: must be between 1 and 4096, found 100000000`.
//!
//! [`InvalidValue`] names the field, what was expected and the value found; the checks below
//! refuse NaN and infinities wherever a finite number is expected. [`MemoryBudget`] refuses a
//! size before it is allocated, with the estimate and the key that asked for it.
//!
//! ```
//! use nerfsv_scene::validate::{in_range, positive};
//! assert!(positive("step_size", f64::INFINITY).is_err());
//! let e = in_range("color_hidden", 100_000_000usize, 1, 4096).unwrap_err().within("nerf");
//! assert_eq!(e.to_string(), "nerf.color_hidden: must be between 1 and 4096, found 100000000");
//! ```

use std::fmt::Display;
use std::sync::atomic::{AtomicU64, Ordering};

/// A value out of range: the field (dotted path, e.g. `nerf.color_hidden`), what was expected,
/// and what was found.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{field}: {expected}, found {found}")]
pub struct InvalidValue {
    pub field: String,
    pub expected: String,
    pub found: String,
}

impl InvalidValue {
    pub fn new(field: impl Into<String>, expected: impl Into<String>, found: impl Display) -> Self {
        Self { field: field.into(), expected: expected.into(), found: found.to_string() }
    }

    /// The same error with the field placed inside a table: `within("nerf")` turns
    /// `color_hidden` into `nerf.color_hidden`.
    pub fn within(mut self, table: &str) -> Self {
        self.field = format!("{table}.{}", self.field);
        self
    }
}

/// `v` is a finite number.
pub fn finite(field: &str, v: f64) -> Result<(), InvalidValue> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(InvalidValue::new(field, "must be a finite number", v))
    }
}

/// `v` is finite and strictly positive.
pub fn positive(field: &str, v: f64) -> Result<(), InvalidValue> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(InvalidValue::new(field, "must be a positive number", v))
    }
}

/// `v` is finite and at least 0.
pub fn non_negative(field: &str, v: f64) -> Result<(), InvalidValue> {
    if v.is_finite() && v >= 0.0 {
        Ok(())
    } else {
        Err(InvalidValue::new(field, "must be a non-negative number", v))
    }
}

/// `lo ≤ v ≤ hi` (NaN is never in range).
pub fn in_range<T: PartialOrd + Display>(field: &str, v: T, lo: T, hi: T) -> Result<(), InvalidValue> {
    if lo <= v && v <= hi {
        Ok(())
    } else {
        Err(InvalidValue::new(field, format!("must be between {lo} and {hi}"), v))
    }
}

/// `lo < v < hi` (NaN is never in range).
pub fn in_open_range(field: &str, v: f64, lo: f64, hi: f64) -> Result<(), InvalidValue> {
    if lo < v && v < hi {
        Ok(())
    } else {
        Err(InvalidValue::new(field, format!("must be strictly between {lo} and {hi}"), v))
    }
}

/// Bytes as a short human-readable figure (`1.5 GiB`).
pub fn human_bytes(bytes: u64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut v = bytes as f64;
    let mut unit = 0;
    while v >= 1024.0 && unit + 1 < UNITS.len() {
        v /= 1024.0;
        unit += 1;
    }
    if unit == 0 {
        format!("{bytes} B")
    } else {
        format!("{v:.1} {}", UNITS[unit])
    }
}

/// The process-wide budget in bytes; 0 means "not set yet: use the default".
static BUDGET: AtomicU64 = AtomicU64::new(0);

/// The most memory one allocation plan (a grid, a network, a batch) may ask for. Sizes are
/// estimated before allocating and refused when over budget, so a value that passes range
/// checks can never abort the process with an allocation failure.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemoryBudget {
    pub bytes: u64,
}

impl MemoryBudget {
    /// Fraction of the machine's physical memory the default budget allows.
    pub const DEFAULT_FRACTION: f64 = 0.5;
    /// Assumed physical memory where it cannot be read (`/proc/meminfo`).
    const FALLBACK_TOTAL: u64 = 8 << 30;

    /// The budget in force: set by [`MemoryBudget::set`] (the binary's `--memory-budget-gib`),
    /// else `NERFSV_MEMORY_BUDGET_GIB` from the environment, else half the physical memory.
    pub fn current() -> Self {
        let set = BUDGET.load(Ordering::Relaxed);
        if set > 0 {
            return Self { bytes: set };
        }
        if let Ok(Some(bytes)) = Self::from_env() {
            return Self { bytes };
        }
        Self { bytes: (physical_memory().unwrap_or(Self::FALLBACK_TOTAL) as f64 * Self::DEFAULT_FRACTION) as u64 }
    }

    /// The budget `NERFSV_MEMORY_BUDGET_GIB` sets, in bytes (`None` when it is unset), refused
    /// like the flag when it is not a positive number of GiB. The binary checks it at start, so a
    /// bad value is never silently ignored.
    pub fn from_env() -> Result<Option<u64>, InvalidValue> {
        let Some(raw) = std::env::var_os(Self::ENV) else { return Ok(None) };
        let text = raw.to_string_lossy();
        let refuse = || {
            InvalidValue::new(
                format!("the environment variable {}", Self::ENV),
                "must be a positive number of GiB (e.g. 8), or unset",
                format!("{text:?}"),
            )
        };
        let gib: f64 = text.trim().parse().map_err(|_| refuse())?;
        if !(gib.is_finite() && gib > 0.0) {
            return Err(refuse());
        }
        Ok(Some((gib * (1u64 << 30) as f64) as u64))
    }

    /// The environment variable that sets the budget in GiB.
    pub const ENV: &'static str = "NERFSV_MEMORY_BUDGET_GIB";

    /// Sets the process-wide budget (bytes, > 0).
    pub fn set(bytes: u64) {
        BUDGET.store(bytes.max(1), Ordering::Relaxed);
    }

    /// Refuses `bytes` (the estimate for what `field` asks for) when it exceeds the budget.
    pub fn check(&self, field: &str, bytes: u64) -> Result<(), InvalidValue> {
        if bytes <= self.bytes {
            Ok(())
        } else {
            Err(InvalidValue::new(
                field,
                format!(
                    "must fit the memory budget of {} (set with --memory-budget-gib or NERFSV_MEMORY_BUDGET_GIB)",
                    human_bytes(self.bytes)
                ),
                format!("a value that needs about {}", human_bytes(bytes)),
            ))
        }
    }
}

/// `count · size` in bytes, saturating (an absurd count must not wrap to a small size).
pub fn bytes_for(count: u64, size_of: u64) -> u64 {
    count.saturating_mul(size_of)
}

/// Total physical memory, from `/proc/meminfo` (Linux); `None` elsewhere.
fn physical_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checks_refuse_nan_and_infinity_and_name_field_and_value() {
        assert!(finite("x", f64::NAN).is_err());
        assert!(positive("x", f64::INFINITY).is_err());
        assert!(positive("x", 0.0).is_err());
        assert!(non_negative("x", -1e-9).is_err());
        assert!(non_negative("x", 0.0).is_ok());
        assert!(in_range("x", f64::NAN, 0.0, 1.0).is_err());
        assert!(in_open_range("x", 1.0, 0.0, 1.0).is_err());
        let e = in_range("grid_threshold", 2.5, 0.0, 1.0).unwrap_err();
        assert_eq!(e.to_string(), "grid_threshold: must be between 0 and 1, found 2.5");
    }

    #[test]
    fn memory_budget_refuses_with_the_estimate() {
        let b = MemoryBudget { bytes: 1 << 30 };
        assert!(b.check("cells_per_metre", 1 << 29).is_ok());
        let e = b.check("cells_per_metre", bytes_for(u64::MAX, 4)).unwrap_err();
        assert_eq!(e.field, "cells_per_metre");
        assert!(e.to_string().contains("1.0 GiB"), "{e}");
        assert!(e.found.contains("TiB"), "{e}");
        assert!(MemoryBudget::current().bytes > 0);
    }
}
