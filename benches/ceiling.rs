//! The machine's ceilings for the NeRF kernels' two kinds of work, so that BENCHMARKS.md can
//! state each kernel's share of them: f32 fused multiply-adds (the layer products) and 64-bit
//! table gathers (the hash encoding's lookups), on one core and on every core at once.
//!
//! - `ceiling/fma_*`: independent accumulator registers (sixteen of AVX-512's 32 where the host
//!   has it, else twelve of 256-bit AVX2's 16), nothing but FMAs; the throughput counts 2 flops
//!   per lane.
//! - `ceiling/small_gemm_512x64x64`: the layer kernel (`mlp::small_gemm`) on a hidden layer's
//!   shape, in the same units, for its share of the first.
//! - `ceiling/gather_l1_*`, `ceiling/gather_levels_*`: 8-lane 64-bit gathers (as the hash
//!   encoding makes them at the host's width) of random rows from one 4 KiB table (L1) and from sixteen tables of the
//!   default model's level size (2¹⁵ rows of two f32 features, 256 KiB each, 4 MiB in all:
//!   L2/L3), with the row arithmetic of a hash (a multiply and a mask per lane); the throughput
//!   counts lookups.
//!
//! - `ceiling/hash_encode_4096_points_1_core`: the hash encoding (`HashEncoding::encode_batch`,
//!   the default model's levels) at the host's widest kernels, in lookups (8 corners per level
//!   and point), for its share of the `gather_levels` ceiling.
//!
//! `cargo bench --bench ceiling`; the gathers run as AVX-512 `vgatherdpd` where the host has it,
//! else as the AVX2 hash kernel's eight 64-bit loads.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use rayon::prelude::*;

/// FMA iterations per call: long enough that the loop's set-up is noise.
const FMA_ITERS: usize = 1 << 16;
/// Gathers per call.
const GATHERS: usize = 1 << 16;
/// Rows of one level's table in the default model (`log2_hashmap_size` 15).
const LEVEL_ROWS: usize = 1 << 15;
const LEVELS: usize = 16;

#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    /// `iters` rounds of sixteen independent 16-lane FMAs; returns a lane so nothing is elided.
    #[target_feature(enable = "avx512f")]
    pub unsafe fn fma_avx512(iters: usize, seed: f32) -> f32 {
        let a = _mm512_set1_ps(0.999_9);
        let b = _mm512_set1_ps(1e-7);
        let mut acc = [_mm512_set1_ps(seed); 16];
        for _ in 0..iters {
            for s in acc.iter_mut() {
                *s = _mm512_fmadd_ps(*s, a, b);
            }
        }
        let mut sum = acc[0];
        for s in &acc[1..] {
            sum = _mm512_add_ps(sum, *s);
        }
        _mm512_reduce_add_ps(sum)
    }

    /// Accumulators of [`fma_avx2`]: with its two operands they fill AVX2's 16 registers (16
    /// accumulators spilled, and the loop ran at two thirds of the layer kernel's rate).
    pub const AVX2_ACCUMULATORS: usize = 12;

    /// `iters` rounds of [`AVX2_ACCUMULATORS`] independent 8-lane (256-bit) FMAs, for hosts
    /// without AVX-512.
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn fma_avx2(iters: usize, seed: f32) -> f32 {
        let a = _mm256_set1_ps(0.999_9);
        let b = _mm256_set1_ps(1e-7);
        let mut acc = [_mm256_set1_ps(seed); AVX2_ACCUMULATORS];
        for _ in 0..iters {
            for s in acc.iter_mut() {
                *s = _mm256_fmadd_ps(*s, a, b);
            }
        }
        let mut out = [0f32; 8];
        let mut sum = acc[0];
        for s in &acc[1..] {
            sum = _mm256_add_ps(sum, *s);
        }
        _mm256_storeu_ps(out.as_mut_ptr(), sum);
        out.iter().sum()
    }

    /// `gathers` 8-lane 64-bit gathers from `tables` (each `mask + 1` rows of 8 bytes), cycling
    /// through the tables; each lane's row is a hash of a counter (multiply, mask), as the
    /// encoding's rows are. Returns a sum so nothing is elided.
    #[target_feature(enable = "avx512f")]
    pub unsafe fn gather_avx512(tables: &[Vec<f64>], mask: u32, gathers: usize, seed: u32) -> f64 {
        let lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        let prime = _mm256_set1_epi32(-1_640_531_535); // 2654435761, torch-ngp's hash prime
        let m = _mm256_set1_epi32(mask as i32);
        let mut counter = _mm256_add_epi32(_mm256_set1_epi32(seed as i32), lane);
        let step = _mm256_set1_epi32(8);
        let mut acc = [_mm512_setzero_pd(); 4];
        let mut g = 0;
        while g < gathers {
            for (t, table) in tables.iter().enumerate() {
                if g >= gathers {
                    break;
                }
                let rows = _mm256_and_si256(_mm256_mullo_epi32(counter, prime), m);
                let v = _mm512_i32gather_pd::<8>(rows, table.as_ptr());
                acc[t & 3] = _mm512_add_pd(acc[t & 3], v);
                counter = _mm256_add_epi32(counter, step);
                g += 1;
            }
        }
        _mm512_reduce_add_pd(_mm512_add_pd(_mm512_add_pd(acc[0], acc[1]), _mm512_add_pd(acc[2], acc[3])))
    }

    /// The AVX2 form of [`gather_avx512`]: the same rows, read as the AVX2 hash kernel reads them,
    /// eight 64-bit loads per eight lanes (`vgatherdpd` costs more than the loads on Zen 3).
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn gather_avx2(tables: &[Vec<f64>], mask: u32, gathers: usize, seed: u32) -> f64 {
        let lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        let prime = _mm256_set1_epi32(-1_640_531_535);
        let m = _mm256_set1_epi32(mask as i32);
        let mut counter = _mm256_add_epi32(_mm256_set1_epi32(seed as i32), lane);
        let step = _mm256_set1_epi32(8);
        let mut acc = [_mm256_setzero_pd(); 4];
        let mut rows = [0u32; 8];
        let mut g = 0;
        while g < gathers {
            for (t, table) in tables.iter().enumerate() {
                if g >= gathers {
                    break;
                }
                let r = _mm256_and_si256(_mm256_mullo_epi32(counter, prime), m);
                _mm256_storeu_si256(rows.as_mut_ptr().cast(), r);
                let p = table.as_ptr();
                let lo = _mm256_setr_pd(
                    *p.add(rows[0] as usize),
                    *p.add(rows[1] as usize),
                    *p.add(rows[2] as usize),
                    *p.add(rows[3] as usize),
                );
                let hi = _mm256_setr_pd(
                    *p.add(rows[4] as usize),
                    *p.add(rows[5] as usize),
                    *p.add(rows[6] as usize),
                    *p.add(rows[7] as usize),
                );
                acc[t & 3] = _mm256_add_pd(acc[t & 3], _mm256_add_pd(lo, hi));
                counter = _mm256_add_epi32(counter, step);
                g += 1;
            }
        }
        let s = _mm256_add_pd(_mm256_add_pd(acc[0], acc[1]), _mm256_add_pd(acc[2], acc[3]));
        let mut out = [0f64; 4];
        _mm256_storeu_pd(out.as_mut_ptr(), s);
        out.iter().sum()
    }
}

fn ceiling(c: &mut Criterion) {
    let threads = rayon::current_num_threads();
    let mut g = c.benchmark_group("ceiling");
    g.sample_size(20);

    #[cfg(target_arch = "x86_64")]
    {
        let avx512 = std::arch::is_x86_feature_detected!("avx512f");
        let fma2 = std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma");
        // SAFETY (every call below): the features each function enables were detected here.
        let fma = |seed: f32| -> f32 {
            if avx512 {
                unsafe { x86::fma_avx512(FMA_ITERS, seed) }
            } else {
                unsafe { x86::fma_avx2(FMA_ITERS, seed) }
            }
        };
        if avx512 || fma2 {
            let (lanes, accumulators) = if avx512 { (16, 16) } else { (8, x86::AVX2_ACCUMULATORS) };
            let flops = (FMA_ITERS * accumulators * lanes * 2) as u64;
            let name = if avx512 { "avx512" } else { "avx2" };
            g.throughput(Throughput::Elements(flops));
            g.bench_function(format!("fma_{name}_1_core"), |b| b.iter(|| fma(std::hint::black_box(1.0))));
            g.throughput(Throughput::Elements(flops * threads as u64));
            g.bench_function(format!("fma_{name}_{threads}_cores"), |b| {
                b.iter(|| (0..threads).into_par_iter().map(|t| fma(std::hint::black_box(t as f32))).sum::<f32>())
            });
        }

        let (n, k, m) = (512, 64, 64);
        let a: Vec<f32> = (0..n * k).map(|i| (i % 7) as f32 * 0.1).collect();
        let w: Vec<f32> = (0..k * m).map(|i| (i % 5) as f32 * 0.1).collect();
        let mut out = vec![0f32; n * m];
        use nerfsv_nerf::field_components::mlp::{small_gemm, Right};
        if small_gemm(&a, Right::Transposed(&w), &mut out, n, k, m) {
            g.throughput(Throughput::Elements((2 * n * k * m) as u64));
            g.bench_function("small_gemm_512x64x64_1_core", |b| {
                b.iter(|| small_gemm(&a, Right::Transposed(&w), &mut out, n, k, m))
            });
        }

        if avx512 || fma2 {
            let table =
                |rows: usize, salt: usize| -> Vec<f64> { (0..rows).map(|i| ((i ^ salt) % 97) as f64).collect() };
            let l1 = vec![table(512, 0)];
            let levels: Vec<Vec<f64>> = (0..LEVELS).map(|l| table(LEVEL_ROWS, l)).collect();
            let lookups = (GATHERS * 8) as u64;
            for (name, tables, mask) in
                [("gather_l1", &l1, 511u32), ("gather_levels", &levels, (LEVEL_ROWS - 1) as u32)]
            {
                let one = |seed: u32| unsafe {
                    if avx512 {
                        x86::gather_avx512(tables, mask, GATHERS, seed)
                    } else {
                        x86::gather_avx2(tables, mask, GATHERS, seed)
                    }
                };
                g.throughput(Throughput::Elements(lookups));
                g.bench_function(format!("{name}_1_core"), |b| b.iter(|| one(std::hint::black_box(1))));
                g.throughput(Throughput::Elements(lookups * threads as u64));
                g.bench_function(format!("{name}_{threads}_cores"), |b| {
                    b.iter(|| (0..threads).into_par_iter().map(|t| one(std::hint::black_box(t as u32))).sum::<f64>())
                });
            }
        }

        // The hash encoding itself (the default model's 16 levels of at most 2¹⁵ rows), at the
        // host's widest kernels, on points spread over the box: its lookups (8 corners a level)
        // per second, for its share of the `gather_levels` ceiling.
        use nerfsv_nerf::field_components::hash_encoding::HashEncoding;
        let enc = HashEncoding::new(LEVELS, 16, 512, 15);
        let emb: Vec<f32> = (0..enc.n_params()).map(|i| ((i % 97) as f32 - 48.0) * 1e-3).collect();
        let points = 4096;
        let pos: Vec<f32> =
            (0..3 * points).map(|i| ((i as u64 * 2_654_435_761) % 1_000_003) as f32 / 1_000_003.0).collect();
        let mut out = vec![0f32; points * enc.output_dim()];
        g.throughput(Throughput::Elements((points * LEVELS * 8) as u64));
        g.bench_function("hash_encode_4096_points_1_core", |b| b.iter(|| enc.encode_batch(&emb, &pos, &mut out)));
    }
    g.finish();
}

criterion_group!(benches, ceiling);
criterion_main!(benches);
