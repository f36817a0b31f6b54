//! The scatter of the calibration's fits: the filter's model error per unit of a fit's colour
//! RMSE ([`filter_model_error`]) and the scatter of one real fit beyond an ensemble member's
//! own ([`within_view_excess`]).

use serde::{Deserialize, Serialize};

use nerfsv_scene::seed::mix;

use super::record::CalibrationRecord;

/// The scatter of one fit around its view's error that the real images have beyond a member's
/// (`member`: the member's fits of the same views with the same pixels and starts), per axis
/// ([`AXES`](nerfsv_sim::perception::AXES)): `√max(0, s²_real − s²_member)`, `s²` the variance of a view's fits about their
/// mean pooled over views. Over the route capture's views (the flight's own views), or every
/// view where there is no route capture; fits the filter would refuse as lost (variance factor
/// above `lost_variance_factor`, in either) are left out with their pair. The error model's
/// draw is a smooth function of the view, so without this a member's images scatter from image
/// to image only as much as the member's own fits do.
pub fn within_view_excess(
    real: &[CalibrationRecord],
    member: &[CalibrationRecord],
    lost_variance_factor: f64,
) -> [f64; 6] {
    use std::collections::BTreeMap;
    let on_route = real.iter().any(|r| r.route_fraction.is_some());
    let theirs: BTreeMap<(usize, usize), &CalibrationRecord> = member.iter().map(|m| ((m.view, m.fit), m)).collect();
    // Per view, each pair's errors: [real, member].
    let mut views: BTreeMap<usize, Vec<[[f64; 6]; 2]>> = BTreeMap::new();
    for r in real.iter().filter(|r| !on_route || r.route_fraction.is_some()) {
        let Some(m) = theirs.get(&(r.view, r.fit)) else { continue };
        if r.variance_factor > lost_variance_factor || m.variance_factor > lost_variance_factor {
            continue;
        }
        views.entry(r.view).or_default().push([r.error, m.error]);
    }
    // The sums of squares about each view's mean, [real, member] per axis.
    let mut sums = [[0.0; 6]; 2];
    let mut dof = 0usize;
    for fits in views.values().filter(|f| f.len() > 1) {
        let n = fits.len() as f64;
        for (k, sum) in sums.iter_mut().enumerate() {
            for (a, s) in sum.iter_mut().enumerate() {
                let mean = fits.iter().map(|p| p[k][a]).sum::<f64>() / n;
                *s += fits.iter().map(|p| (p[k][a] - mean).powi(2)).sum::<f64>();
            }
        }
        dof += fits.len() - 1;
    }
    if dof == 0 {
        return [0.0; 6];
    }
    std::array::from_fn(|a| ((sums[0][a] - sums[1][a]) / dof as f64).max(0.0).sqrt())
}

/// The filter's model error measured on calibration fits: the standard deviation per axis of a
/// fit's error per unit of its colour RMSE (`sim.vision.model_error_per_rmse`'s meaning), with a
/// 95 % interval from a bootstrap over views.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ModelError {
    /// `[metres, degrees]` per unit of RMSE.
    pub per_rmse: [f64; 2],
    pub position_ci95: [f64; 2],
    pub rotation_ci95: [f64; 2],
    /// The fits it rests on (those the filter would take) and their views.
    pub fits: usize,
    pub views: usize,
}

/// Bootstrap resamples of [`filter_model_error`]'s interval.
const MODEL_ERROR_RESAMPLES: usize = 1000;

/// The filter's model error of the fits `records` (one view's fits share its `view`): per unit
/// of each fit's colour RMSE, the root mean square of its error over the position axes (metres)
/// and over the rotation axes (degrees), `sqrt(mean(e² / rmse²))`, the maximum-likelihood scale
/// of an error that is normal with standard deviation `k · rmse` per axis. Fits the filter
/// refuses as lost (variance factor above `lost_variance_factor`) and fits without a residual
/// are left out. The interval resamples views (a view's fits share its bias), seeded by `seed`.
/// None without a fit left.
pub fn filter_model_error(records: &[CalibrationRecord], lost_variance_factor: f64, seed: u64) -> Option<ModelError> {
    // Per view: the sums of e²/rmse² over its fits' position and rotation axes, and its fits.
    let mut per_view: std::collections::BTreeMap<(&str, usize), ([f64; 2], usize)> = Default::default();
    for r in records.iter().filter(|r| r.variance_factor <= lost_variance_factor && r.rmse > 0.0) {
        let entry = per_view.entry((r.source.name(), r.view)).or_default();
        let w = 1.0 / (r.rmse * r.rmse);
        entry.0[0] += w * r.error[..3].iter().map(|e| e * e).sum::<f64>();
        entry.0[1] += w * r.error[3..].iter().map(|e| e.to_degrees().powi(2)).sum::<f64>();
        entry.1 += 1;
    }
    let views: Vec<([f64; 2], usize)> = per_view.into_values().collect();
    let scale = |picked: &mut dyn Iterator<Item = &([f64; 2], usize)>| -> [f64; 2] {
        let (mut sum, mut n) = ([0.0; 2], 0);
        for (s, k) in picked {
            sum = [sum[0] + s[0], sum[1] + s[1]];
            n += k;
        }
        sum.map(|s| (s / (3 * n.max(1)) as f64).sqrt())
    };
    let fits: usize = views.iter().map(|v| v.1).sum();
    if fits == 0 {
        return None;
    }
    let per_rmse = scale(&mut views.iter());
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(mix(seed, 0x30de1, 0));
    let mut draws: [Vec<f64>; 2] = Default::default();
    for _ in 0..MODEL_ERROR_RESAMPLES {
        let k = scale(&mut (0..views.len()).map(|_| &views[rng.random_range(0..views.len())]));
        draws[0].push(k[0]);
        draws[1].push(k[1]);
    }
    let ci = |mut v: Vec<f64>| -> [f64; 2] {
        v.sort_by(f64::total_cmp);
        [nerfsv_scene::stats::quantile_sorted(&v, 0.025), nerfsv_scene::stats::quantile_sorted(&v, 0.975)]
    };
    let [p, r] = draws;
    Some(ModelError { per_rmse, position_ci95: ci(p), rotation_ci95: ci(r), fits, views: views.len() })
}

#[cfg(test)]
mod tests {
    use super::super::record::ViewSource;
    use super::super::tests::{record, uniforms};
    use super::*;

    #[test]
    fn the_within_view_excess_is_the_real_fits_scatter_beyond_the_members_on_the_route() {
        // Route views whose real fits scatter by ±3 cm about a view's own offset and the member's
        // by ±1 cm (pooled variances 9 and 1 cm² over three fits a view), so the excess is √8 cm
        // on y; held-out views scattering far more and lost fits are left out.
        let fits = |sd: f64, route: bool| -> Vec<CalibrationRecord> {
            (0..40)
                .flat_map(|view| {
                    let offset = 0.05 * (view as f64).sin();
                    [-1.0, 0.0, 1.0].into_iter().enumerate().map(move |(fit, z)| CalibrationRecord {
                        route_fraction: route.then_some(view as f64 / 40.0),
                        source: if route { ViewSource::Route } else { ViewSource::HeldOut },
                        ..record(if route { view } else { 100 + view }, fit, offset + z * sd)
                    })
                })
                .collect()
        };
        let lost = |mut r: CalibrationRecord| {
            r.fit = 9;
            r.variance_factor = 50.0;
            r.error[1] = 3.0;
            r
        };
        let mut real: Vec<_> = fits(0.03, true).into_iter().chain(fits(0.3, false)).collect();
        let mut member: Vec<_> = fits(0.01, true).into_iter().chain(fits(0.01, false)).collect();
        real.push(lost(real[0]));
        member.push(CalibrationRecord { fit: 9, ..member[0] });
        let e = within_view_excess(&real, &member, 5.0);
        assert!((e[1] - 0.08f64.sqrt() * 0.1).abs() < 1e-12, "{e:?}");
        assert_eq!([e[0], e[2], e[3], e[4], e[5]], [0.0; 5]);
        // A member that scatters more than the real images adds nothing; without route views
        // every view counts.
        assert_eq!(within_view_excess(&member, &real, 5.0)[1], 0.0);
        let (real, member) = (fits(0.03, false), fits(0.01, false));
        assert!((within_view_excess(&real, &member, 5.0)[1] - 0.08f64.sqrt() * 0.1).abs() < 1e-12);
    }

    #[test]
    fn the_filter_model_error_recovers_a_known_scale_and_leaves_lost_fits_out() {
        // Errors normal per axis with sd k · rmse (k = 0.4 m and 12° per unit of RMSE), the RMSE
        // varying from fit to fit; lost fits with errors 100 times larger are left out.
        let mut uniform = uniforms(7);
        let k = [0.4, 12.0_f64.to_radians()];
        let mut records = Vec::new();
        for view in 0..200 {
            for fit in 0..3 {
                let rmse = 0.02 + 0.06 * uniform();
                let lost = fit == 2 && view % 4 == 0;
                let error = std::array::from_fn(|a| {
                    let z: f64 = (0..12).map(|_| uniform()).sum::<f64>() - 6.0;
                    k[a / 3] * rmse * z * if lost { 100.0 } else { 1.0 }
                });
                let variance_factor = if lost { 50.0 } else { 1.0 };
                records.push(CalibrationRecord { error, rmse, variance_factor, ..record(view, fit, 0.0) });
            }
        }
        let m = filter_model_error(&records, 5.0, 3).unwrap();
        assert_eq!((m.fits, m.views), (550, 200));
        assert!((m.per_rmse[0] / 0.4 - 1.0).abs() < 0.05, "{m:?}");
        assert!((m.per_rmse[1] / 12.0 - 1.0).abs() < 0.05, "{m:?}");
        assert!(m.position_ci95[0] < 0.4 && 0.4 < m.position_ci95[1], "{m:?}");
        assert!(m.rotation_ci95[0] < 12.0 && 12.0 < m.rotation_ci95[1], "{m:?}");
        assert!(m.position_ci95[1] - m.position_ci95[0] < 0.05, "{m:?}");
        // Every fit lost: nothing to measure.
        let lost: Vec<_> = records.iter().map(|r| CalibrationRecord { variance_factor: 50.0, ..*r }).collect();
        assert_eq!(filter_model_error(&lost, 5.0, 3), None);
    }
}
