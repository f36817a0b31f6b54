//! The one quantile every stage's summaries use: linear between order statistics (Hyndman &
//! Fan's type 7, numpy's and R's default), so that a "median" or a "p90" means the same in every
//! table and section.

/// The `q` quantile (`q` in `[0, 1]`) of values sorted ascending, linear between the order
/// statistics at `(n − 1)·q`. Panics on an empty slice.
pub fn quantile_sorted(sorted: &[f64], q: f64) -> f64 {
    let h = (sorted.len() - 1) as f64 * q;
    let (lo, hi) = (h.floor() as usize, h.ceil() as usize);
    sorted[lo] + (h - lo as f64) * (sorted[hi] - sorted[lo])
}

/// [`quantile_sorted`]'s `q` quantile of `values` in any order, found by selection (linear time,
/// for millions of grid nodes) rather than a sort; the slice is reordered. Panics on an empty
/// slice.
pub fn quantile_select(values: &mut [f32], q: f64) -> f32 {
    let h = (values.len() - 1) as f64 * q;
    let lo = h.floor() as usize;
    let (_, below, above) = values.select_nth_unstable_by(lo, f32::total_cmp);
    let below = *below;
    let above = above.iter().copied().reduce(f32::min).unwrap_or(below);
    (below as f64 + (h - lo as f64) * (above as f64 - below as f64)) as f32
}

/// The `q` quantile of `values` in any order (sorted here, NaN last); none without values.
pub fn quantile(mut values: Vec<f64>, q: f64) -> Option<f64> {
    values.sort_by(f64::total_cmp);
    (!values.is_empty()).then(|| quantile_sorted(&values, q))
}

/// The median, [`quantile`] at one half: the middle value, or the mean of the two middle ones
/// (computed as their mean, which rounds the same on every host).
pub fn median(mut values: Vec<f64>) -> Option<f64> {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    match n {
        0 => None,
        _ if n % 2 == 1 => Some(values[n / 2]),
        _ => Some(0.5 * (values[n / 2 - 1] + values[n / 2])),
    }
}

/// erfc(x) to ~1e-14 relative: for |x| < 3 from the all-positive series
/// erf(x) = (2/√π)·e^{−x²}·Σ_n 2ⁿ x^{2n+1} / (1·3·…·(2n+1)) (no cancellation; erfc = 1 − erf
/// loses only ~1e-16/erfc(x) relative, < 1e-12 for x < 3), beyond from the continued fraction
/// erfc(x) = e^{−x²}/√π · 1/(x + ½/(x + 1/(x + 3/2/(x + …)))) evaluated bottom-up, 200 terms.
pub fn erfc(x: f64) -> f64 {
    if x < 0.0 {
        return 2.0 - erfc(-x);
    }
    let pre = (-x * x).exp() / std::f64::consts::PI.sqrt();
    if x < 3.0 {
        let (mut term, mut sum, mut n) = (x, x, 0.0);
        while term > 1e-17 * sum {
            n += 1.0;
            term *= 2.0 * x * x / (2.0 * n + 1.0);
            sum += term;
        }
        1.0 - 2.0 * pre * sum
    } else {
        let mut f = x;
        for k in (1..=200).rev() {
            f = x + (k as f64 / 2.0) / f;
        }
        pre / f
    }
}

/// The two-sided p-value of a standard normal statistic `z`: P(|Z| ≥ |z|) = erfc(|z|/√2).
pub fn normal_two_sided_p(z: f64) -> f64 {
    erfc(z.abs() / std::f64::consts::SQRT_2).min(1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_match_numpys_default() {
        // numpy.quantile([1, 2, 3, 4], [0, 0.25, 0.5, 0.9, 1]) = [1, 1.75, 2.5, 3.7, 4]
        let v = [1.0, 2.0, 3.0, 4.0];
        for (q, want) in [(0.0, 1.0), (0.25, 1.75), (0.5, 2.5), (0.9, 3.7), (1.0, 4.0)] {
            assert!((quantile_sorted(&v, q) - want).abs() < 1e-12, "{q}");
        }
        assert_eq!(median(vec![4.0, 1.0, 3.0, 2.0]), Some(2.5));
        assert_eq!(median(vec![5.0, 1.0, 3.0]), Some(3.0));
        assert_eq!(quantile(vec![7.0], 0.9), Some(7.0));
        assert_eq!(median(Vec::new()), None);
        let mut shuffled = [4.0f32, 1.0, 3.0, 2.0];
        assert!((quantile_select(&mut shuffled, 0.9) - 3.7).abs() < 1e-6);
        for n in 1..9 {
            let v: Vec<f64> = (0..n).map(|i| ((i * 7) % 5) as f64 * 0.3 + i as f64).collect();
            let q = quantile(v.clone(), 0.5).unwrap();
            assert!((median(v).unwrap() - q).abs() < 1e-12, "{n}");
        }
    }
}
