//! Which vector width the NeRF's kernels run at: AVX-512, AVX2 + FMA, or the portable code.
//!
//! Every kernel has a portable form (plain Rust, the reference) and, on x86-64, forms for
//! 256-bit AVX2 + FMA and 512-bit AVX-512 vectors. All of them compute the same operations in
//! the same order, so they give the same bits: a checkpoint, a render or a trajectory does not
//! depend on the host it was made on. Where a sum is a fused multiply-add chain (the layer
//! products and the weight gradients) every form computes exactly that chain, the portable one
//! with [`f32::mul_add`]; nowhere else is a multiply and an add fused.
//!
//! The kernels run at [`active`]'s width: the widest the host has, unless the program chose
//! another with [`set_active`] (the `nerfsv` binary reads `NERFSV_KERNELS`, see
//! [`Kernels::from_env`]). Forcing the portable kernels on a fast host is how a test shows that
//! the paths agree.

use std::sync::atomic::{AtomicU8, Ordering};

/// A kernel width.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Kernels {
    /// Plain Rust, whatever the compiler's baseline target vectorises it to.
    Portable,
    /// 256-bit vectors with fused multiply-add (x86-64-v3: Intel since Haswell, AMD since Zen 1).
    Avx2,
    /// 512-bit vectors (AVX-512F: Intel server parts, AMD since Zen 4).
    Avx512,
}

/// The environment variable the `nerfsv` binary and the Python package read: `portable`,
/// `avx2`, `avx512` or `native` (the widest the host has, as when it is unset).
pub const ENV: &str = "NERFSV_KERNELS";

impl Kernels {
    /// Every width, narrowest first.
    pub const ALL: [Kernels; 3] = [Kernels::Portable, Kernels::Avx2, Kernels::Avx512];

    /// The name `NERFSV_KERNELS` takes.
    pub fn name(self) -> &'static str {
        match self {
            Kernels::Portable => "portable",
            Kernels::Avx2 => "avx2",
            Kernels::Avx512 => "avx512",
        }
    }

    /// Whether this host can run these kernels.
    pub fn available(self) -> bool {
        match self {
            Kernels::Portable => true,
            #[cfg(target_arch = "x86_64")]
            Kernels::Avx2 => std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma"),
            #[cfg(target_arch = "x86_64")]
            Kernels::Avx512 => std::arch::is_x86_feature_detected!("avx512f"),
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// The widths this host runs, narrowest (portable) first.
    pub fn on_this_host() -> impl Iterator<Item = Kernels> {
        Self::ALL.into_iter().filter(|k| k.available())
    }

    /// The widest kernels this host runs.
    pub fn widest() -> Kernels {
        Self::on_this_host().last().unwrap_or(Kernels::Portable)
    }

    /// The width `NERFSV_KERNELS` asks for: unset or `native` is [`Kernels::widest`]; a width
    /// this host lacks, or a name that is none of the four, is an error that says which.
    pub fn from_env() -> Result<Kernels, KernelsError> {
        match std::env::var(ENV) {
            Err(std::env::VarError::NotPresent) => Ok(Self::widest()),
            Err(std::env::VarError::NotUnicode(v)) => Err(KernelsError::Unknown(v.to_string_lossy().into_owned())),
            Ok(v) => Self::parse(&v),
        }
    }

    /// [`Kernels::from_env`] of one value.
    pub fn parse(value: &str) -> Result<Kernels, KernelsError> {
        if value == "native" {
            return Ok(Self::widest());
        }
        let k = Self::ALL
            .into_iter()
            .find(|k| k.name() == value)
            .ok_or_else(|| KernelsError::Unknown(value.to_string()))?;
        if k.available() {
            Ok(k)
        } else {
            Err(KernelsError::Unavailable { asked: k.name(), widest: Self::widest().name() })
        }
    }
}

/// A `NERFSV_KERNELS` value that cannot be honoured.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum KernelsError {
    #[error("{ENV}={0:?}: expected one of portable, avx2, avx512, native")]
    Unknown(String),
    #[error("{ENV}={asked}: this host has no {asked} (its widest kernels are {widest})")]
    Unavailable { asked: &'static str, widest: &'static str },
}

/// 0: not chosen yet (the first [`active`] picks the widest); else 1 + the index in `ALL`.
static ACTIVE: AtomicU8 = AtomicU8::new(0);

/// The kernels the NeRF runs now.
#[inline]
pub fn active() -> Kernels {
    match ACTIVE.load(Ordering::Relaxed) {
        0 => {
            let k = Kernels::widest();
            ACTIVE.store(code(k), Ordering::Relaxed);
            k
        }
        c => Kernels::ALL[c as usize - 1],
    }
}

/// Runs every later kernel at `k`'s width (for the whole process). Refuses a width the host
/// lacks.
pub fn set_active(k: Kernels) -> Result<(), KernelsError> {
    if !k.available() {
        return Err(KernelsError::Unavailable { asked: k.name(), widest: Kernels::widest().name() });
    }
    ACTIVE.store(code(k), Ordering::Relaxed);
    Ok(())
}

/// Runs `body` compiled for [`active`]'s width: element-wise loops (activations, compositing,
/// Adam) in the width's vectors. `body` must be a closure marked `#[inline(always)]` that calls
/// `#[inline(always)]` functions (no closures of its own around the hot loops), so that all of
/// it is compiled inside the width's entry point: an unmarked closure is compiled once, for the
/// baseline, and the entry point only calls it. The compiler fuses no multiply and add that the
/// source does not and reorders no floating-point operation, so every width gives the same
/// bits.
#[inline(always)]
pub(crate) fn dispatch<R>(body: impl FnOnce() -> R) -> R {
    match active() {
        // SAFETY: `active` runs only widths the host has.
        #[cfg(target_arch = "x86_64")]
        Kernels::Avx512 => unsafe { on_avx512(body) },
        #[cfg(target_arch = "x86_64")]
        Kernels::Avx2 => unsafe { on_avx2(body) },
        _ => body(),
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn on_avx512<R>(body: impl FnOnce() -> R) -> R {
    body()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn on_avx2<R>(body: impl FnOnce() -> R) -> R {
    body()
}

fn code(k: Kernels) -> u8 {
    Kernels::ALL.iter().position(|&a| a == k).map_or(0, |i| i as u8 + 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_back_and_a_missing_width_is_refused_by_name() {
        for k in Kernels::ALL {
            match Kernels::parse(k.name()) {
                Ok(parsed) => assert_eq!(parsed, k),
                Err(e) => {
                    assert!(!k.available());
                    assert!(e.to_string().contains(k.name()), "{e}");
                }
            }
        }
        assert_eq!(Kernels::parse("native"), Ok(Kernels::widest()));
        assert!(Kernels::parse("sse9").unwrap_err().to_string().contains("portable, avx2, avx512"));
        assert!(Kernels::Portable.available());
    }
}
