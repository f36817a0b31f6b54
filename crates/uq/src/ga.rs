//! Gaussian approximation (GA), the paper's eq. 2–3, summed over every ray and colour channel
//! of an image.
//!
//! A ray's colour is modelled as the composite of its samples with a density scale drawn per
//! image, `r ~ N(μ_d·m, σ_d²·s)` with `m = Σ_i c_i d_i` and `s = Σ_i c_i² d_i²` (`c_i` the
//! sample colours, `d_i` their compositing weights, per channel; over a background, colours
//! relative to it: see the end of these docs). The negative log-likelihood
//! of an image, up to constants, is eq. 2 summed over its `N` (ray, channel) terms with `s > 0`:
//!
//!   `f(μ, σ) = Σ_k [ log(s_k σ²) + (r_k − μ m_k)² / (s_k σ²) ]`
//!
//! The paper minimises one ray's term, which has no finite optimum (`σ → 0` drives it to −∞
//! whenever `r = μ m` can be met). Summed over the image it is a weighted least-squares problem
//! with the closed-form optimum
//!
//!   `μ̂ = Σ(r m / s) / Σ(m² / s)`,   `σ̂² = (1/N)·Σ (r − μ̂ m)² / s`
//!
//! (`∂f/∂μ = 0` is linear in μ for any σ; then `∂f/∂σ² = 0`). [`GaFit`] reports σ_d = σ̂ and
//! μ_d = μ̂, the paper's exclusions (σ_d ≤ 0: "absolutely certain", σ_d ≥ 3: "absolutely
//! uncertain") and the standardised residual `z_k = (r_k − μ̂ m_k)/(σ̂ √s_k)` of every pixel and
//! channel (mean square 1 over the image by construction).
//!
//! **Noise floor.** Eq. 2 has no term for the pixel noise, so a ray with tiny `s` (nearly
//! transparent) makes `(r − μm)²/s` huge for any noise in `r`, and such rays drive σ̂ (on an
//! exact model with 0.02 pixel noise and a tenth of the rays at opacity 0.02, σ̂ = 1.27, almost
//! all of it from those rays). Beside the paper's form, [`GaFit::floored`] fits
//! `r ~ N(μ·m, σ²·s + σ_n²)` with σ_n the pixel noise ([`crate::UqConfig::noise_std`]): μ in
//! closed form for each σ (weighted least squares), σ the lowest minimum of the profile
//! objective (a scan of its slope, each sign change refined by root finding); σ_d is then ≈ 0
//! when the model explains the image up to the noise.
//!
//! Rays that composite no sample (they miss the box or cross only empty occupancy cells) have
//! `s = 0` and no information about the density scale: they are left out of the fit, counted,
//! and get a NaN residual.
//!
//! **Background.** A render is `Σ_i d_i c_i + (1 − Σ_i d_i)·bg`. Scaling the weights by μ
//! scales the opacity with them, so the background seen through the remaining transmittance
//! changes too: the render is `bg + μ·Σ_i d_i (c_i − bg)`. The paper writes eq. 2 without a
//! background (black, where both agree); over any background nerfsv uses colours relative to
//! it, `c_i − bg` in `m` and `s` and `r = reference − bg`, so μ = 1 is the render and every μ is
//! the render of the weights scaled by μ. (Subtracting the background at the model's own
//! transmittance, `reference − (1 − Σ d_i)·bg`, would hold the occlusion fixed while the
//! density scales: on a white background that leaves a bias of `(μ − 1)·Σ d_i` per ray.)

use nerfsv_nerf::{Nerf, RayInput, RaySamples};
use rayon::prelude::*;

use crate::UqError;

/// One ray's GA inputs, per colour channel.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GaRay {
    /// `m = Σ_i (c_i − bg) d_i`.
    pub m: [f64; 3],
    /// `s = Σ_i (c_i − bg)² d_i²` (0 for a ray without samples).
    pub s: [f64; 3],
    /// The colour the samples must explain: `reference − bg`.
    pub r: [f64; 3],
}

impl GaRay {
    /// From a ray's composited samples (`colours: [k, 3]`, `weights: [k]`), its reference colour
    /// and its background (see the [module docs](self) for why colours are taken relative to it).
    pub fn from_samples(colours: &[[f32; 3]], weights: &[f32], reference: [f32; 3], background: [f32; 3]) -> Self {
        let mut out = Self::default();
        for (c, &w) in colours.iter().zip(weights) {
            let w = w as f64;
            for (ch, &cc) in c.iter().enumerate() {
                let cw = (cc as f64 - background[ch] as f64) * w;
                out.m[ch] += cw;
                out.s[ch] += cw * cw;
            }
        }
        for ch in 0..3 {
            out.r[ch] = reference[ch] as f64 - background[ch] as f64;
        }
        out
    }
}

/// Why an image is left out of the paper's statistics.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum GaExclusion {
    /// σ_d ≤ 0: the samples explain the image exactly.
    AbsolutelyCertain,
    /// σ_d ≥ the bound (3 by default).
    AbsolutelyUncertain,
}

/// The noise-floored GA optimum of one image: `r ~ N(μ_d·m, σ_d²·s + σ_n²)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GaFloored {
    pub mu_d: f64,
    /// σ_d ≥ 0.
    pub sigma_d: f64,
    /// σ_n, the pixel noise it was fitted with.
    pub noise_std: f64,
    /// `Σ_k [ln(σ_d² s_k + σ_n²) + (r_k − μ_d m_k)²/(σ_d² s_k + σ_n²)]`.
    pub objective: f64,
}

/// The GA optimum of one image.
#[derive(Clone, Debug, PartialEq)]
pub struct GaFit {
    /// μ_d: the density scale that best explains the image (1 when the render matches).
    pub mu_d: f64,
    /// σ_d ≥ 0: its standard deviation.
    pub sigma_d: f64,
    /// `f(μ_d, σ_d)`, eq. 2 summed over the terms (−∞ when σ_d = 0).
    pub objective: f64,
    /// `N`, the (ray, channel) terms with `s > 0`.
    pub terms: usize,
    /// Rays without any composited sample, left out.
    pub rays_without_samples: usize,
    /// The paper's exclusion, if any.
    pub excluded: Option<GaExclusion>,
    /// `[r]` standardised residuals `(r − μ_d m)/(σ_d √s)` per ray and channel; NaN where
    /// `s = 0`, 0 everywhere when σ_d = 0.
    pub standardized: Vec<[f32; 3]>,
    /// The same image with the pixel noise in the model (see the module docs).
    pub floored: GaFloored,
}

impl GaFit {
    /// `[r]` the per-pixel uncertainty map: the root mean square of the standardised residuals
    /// over the pixel's channels with `s > 0` (NaN for a pixel without samples).
    pub fn pixel_rms(&self) -> Vec<f32> {
        self.standardized
            .iter()
            .map(|z| {
                let (sum, n) = z.iter().filter(|v| !v.is_nan()).fold((0.0f32, 0u32), |(s, n), &v| (s + v * v, n + 1));
                if n == 0 {
                    f32::NAN
                } else {
                    (sum / n as f32).sqrt()
                }
            })
            .collect()
    }
}

/// Eq. 2 summed over every term with `s > 0`, at `(μ, σ)`.
pub fn ga_objective(rays: &[GaRay], mu: f64, sigma: f64) -> f64 {
    let v = sigma * sigma;
    let mut f = 0.0;
    for ray in rays {
        for ch in 0..3 {
            let s = ray.s[ch];
            if s > 0.0 {
                let e = ray.r[ch] - mu * ray.m[ch];
                f += (s * v).ln() + e * e / (s * v);
            }
        }
    }
    f
}

/// The noise-floored objective `Σ_k [ln V_k + (r_k − μ m_k)²/V_k]`, `V_k = σ² s_k + σ_n²`, over
/// the terms with `s > 0`, at `(μ, σ)`.
pub fn ga_floored_objective(rays: &[GaRay], mu: f64, sigma: f64, noise_std: f64) -> f64 {
    let (v, n2) = (sigma * sigma, noise_std * noise_std);
    let mut f = 0.0;
    for ray in rays {
        for ch in 0..3 {
            let s = ray.s[ch];
            if s > 0.0 {
                let (e, var) = (ray.r[ch] - mu * ray.m[ch], v * s + n2);
                f += var.ln() + e * e / var;
            }
        }
    }
    f
}

/// The noise-floored GA of an image's rays: the lowest of the profile objective's minima (μ in
/// closed form at each σ). They are where its slope
/// `dP/dσ² = Σ_k (s_k/V_k)·(1 − e_k²/V_k)` (`e_k = r_k − μ m_k`; by the envelope theorem μ's own
/// change does not enter) turns from negative to positive, or at σ = 0 when it starts
/// positive (the noise alone explains the image). The slope is scanned at 24 points
/// `σ_hi·(j/24)²` (dense near 0, where the profile of an image with a few poorly explained rays
/// can have a second minimum), σ_hi doubled from twice `plain_sigma` (the paper's σ̂) until the
/// slope there is positive; each sign change is refined by Brent–Dekker root finding to
/// `1e-9·σ_hi`, and the objective compared between the candidates. A slope evaluation is two
/// passes of divisions over the terms, no logarithm.
fn floored_fit(rays: &[GaRay], plain_sigma: f64, noise_std: f64) -> GaFloored {
    const SCAN: usize = 24;
    let terms = Terms::of(rays);
    let n2 = noise_std * noise_std;
    let slope = |sigma: f64| terms.slope(sigma * sigma, n2);
    let mut hi = plain_sigma.max(noise_std).max(1e-6) * 2.0;
    let mut f_hi = slope(hi);
    while f_hi < 0.0 && hi < 1e6 {
        hi *= 2.0;
        f_hi = slope(hi);
    }
    let mut candidates = Vec::new();
    let (mut a, mut fa) = (0.0, slope(0.0));
    if fa >= 0.0 || fa.is_nan() {
        candidates.push(0.0);
    }
    for j in 1..=SCAN {
        // The last point is σ_hi itself, whose slope the bracket search took.
        let (b, fb) = if j == SCAN {
            (hi, f_hi)
        } else {
            let b = hi * (j as f64 / SCAN as f64).powi(2);
            (b, slope(b))
        };
        if fa < 0.0 && fb >= 0.0 {
            candidates.push(brent_root(slope, a, b, fa, fb, 1e-9 * hi));
        }
        (a, fa) = (b, fb);
    }
    if candidates.is_empty() {
        // The slope is still negative at σ_hi = 1e6: the optimum is beyond any useful bound.
        candidates.push(hi);
    }
    candidates
        .into_iter()
        .map(|sigma| {
            let mu = terms.mu(sigma * sigma, n2);
            GaFloored {
                mu_d: mu,
                sigma_d: sigma,
                noise_std,
                objective: ga_floored_objective(rays, mu, sigma, noise_std),
            }
        })
        .min_by(|x, y| x.objective.total_cmp(&y.objective))
        .expect("at least one candidate")
}

/// The (ray, channel) terms with `s > 0`, one array per quantity (the σ search's passes run
/// over them alone).
struct Terms {
    m: Vec<f64>,
    s: Vec<f64>,
    r: Vec<f64>,
}

impl Terms {
    fn of(rays: &[GaRay]) -> Self {
        let mut t = Terms { m: Vec::new(), s: Vec::new(), r: Vec::new() };
        for ray in rays {
            for ch in 0..3 {
                if ray.s[ch] > 0.0 {
                    t.m.push(ray.m[ch]);
                    t.s.push(ray.s[ch]);
                    t.r.push(ray.r[ch]);
                }
            }
        }
        t
    }

    /// μ minimising the noise-floored objective at `u = σ²`: `Σ(r m/V) / Σ(m²/V)`,
    /// `V = u·s + n²` (0 without terms).
    fn mu(&self, u: f64, n2: f64) -> f64 {
        let (mut num, mut den) = (0.0, 0.0);
        for ((&m, &s), &r) in self.m.iter().zip(&self.s).zip(&self.r) {
            let w = 1.0 / (u * s + n2);
            num += r * m * w;
            den += m * m * w;
        }
        if den > 0.0 {
            num / den
        } else {
            0.0
        }
    }

    /// `dP/du` at `u = σ²`: `Σ (s/V)·(1 − e²/V)`, `V = u·s + n²`, e at the profile's μ.
    fn slope(&self, u: f64, n2: f64) -> f64 {
        let mu = self.mu(u, n2);
        let mut g = 0.0;
        for ((&m, &s), &r) in self.m.iter().zip(&self.s).zip(&self.r) {
            let w = 1.0 / (u * s + n2);
            let e = r - mu * m;
            g += s * w * (1.0 - e * e * w);
        }
        g
    }
}

/// Brent–Dekker: a root of `f` in `[a, b]`, where `f(a) = fa` and `f(b) = fb` differ in sign,
/// to within `tol` (inverse quadratic interpolation, secant or bisection, whichever is safe).
fn brent_root(f: impl Fn(f64) -> f64, mut a: f64, mut b: f64, mut fa: f64, mut fb: f64, tol: f64) -> f64 {
    if fa.abs() < fb.abs() {
        (a, b, fa, fb) = (b, a, fb, fa);
    }
    let (mut c, mut fc, mut d) = (a, fa, a);
    let mut bisected = true;
    for _ in 0..200 {
        if fb == 0.0 || (b - a).abs() <= tol {
            break;
        }
        let mut s = if fa != fc && fb != fc {
            a * fb * fc / ((fa - fb) * (fa - fc))
                + b * fa * fc / ((fb - fa) * (fb - fc))
                + c * fa * fb / ((fc - fa) * (fc - fb))
        } else {
            b - fb * (b - a) / (fb - fa)
        };
        let q = (3.0 * a + b) / 4.0;
        let outside = !(s > q.min(b) && s < q.max(b));
        let slow = if bisected { (s - b).abs() >= (b - c).abs() / 2.0 } else { (s - b).abs() >= (c - d).abs() / 2.0 };
        let tiny = if bisected { (b - c).abs() < tol } else { (c - d).abs() < tol };
        bisected = outside || slow || tiny || !s.is_finite();
        if bisected {
            s = 0.5 * (a + b);
        }
        let fs = f(s);
        (d, c, fc) = (c, b, fb);
        if (fa < 0.0) != (fs < 0.0) {
            (b, fb) = (s, fs);
        } else {
            (a, fa) = (s, fs);
        }
        if fa.abs() < fb.abs() {
            (a, b, fa, fb) = (b, a, fb, fa);
        }
    }
    b
}

/// The closed-form GA optimum of an image's rays (see the module docs), and beside it the
/// noise-floored one with pixel noise `noise_std`. `image` names it in errors; images with
/// `σ_d ≥ sigma_max` or `σ_d ≤ 0` are flagged, not refused.
///
/// Errors: [`UqError::AllRaysMiss`] when no ray has a sample, [`UqError::NonFinite`] when the
/// inputs are not finite.
pub fn ga_fit(image: &str, rays: &[GaRay], sigma_max: f64, noise_std: f64) -> Result<GaFit, UqError> {
    // Pass 1: μ̂ = Σ(r m/s) / Σ(m²/s).
    let (mut num, mut den, mut terms, mut without) = (0.0f64, 0.0f64, 0usize, 0usize);
    for ray in rays {
        if ray.s.iter().all(|&s| s <= 0.0) {
            without += 1;
        }
        for ch in 0..3 {
            let s = ray.s[ch];
            if s > 0.0 {
                num += ray.r[ch] * ray.m[ch] / s;
                den += ray.m[ch] * ray.m[ch] / s;
                terms += 1;
            }
        }
    }
    if terms == 0 {
        return Err(UqError::AllRaysMiss { image: image.to_string(), rays: rays.len() });
    }
    let mu = num / den;
    if !mu.is_finite() {
        return Err(UqError::NonFinite { image: image.to_string(), what: "μ_d" });
    }
    // Pass 2: σ̂² = mean of (r − μ̂ m)²/s, and Σ log s for the objective.
    let (mut ss, mut log_s) = (0.0f64, 0.0f64);
    for ray in rays {
        for ch in 0..3 {
            let s = ray.s[ch];
            if s > 0.0 {
                let e = ray.r[ch] - mu * ray.m[ch];
                ss += e * e / s;
                log_s += s.ln();
            }
        }
    }
    let var = ss / terms as f64;
    let sigma = var.sqrt();
    if !sigma.is_finite() {
        return Err(UqError::NonFinite { image: image.to_string(), what: "σ_d" });
    }
    let objective = if var > 0.0 { log_s + terms as f64 * (var.ln() + 1.0) } else { f64::NEG_INFINITY };
    let standardized = rays
        .iter()
        .map(|ray| {
            [0, 1, 2].map(|ch| {
                let s = ray.s[ch];
                if s <= 0.0 {
                    f32::NAN
                } else if sigma == 0.0 {
                    0.0
                } else {
                    ((ray.r[ch] - mu * ray.m[ch]) / (sigma * s.sqrt())) as f32
                }
            })
        })
        .collect();
    let excluded = if sigma <= 0.0 {
        Some(GaExclusion::AbsolutelyCertain)
    } else if sigma >= sigma_max {
        Some(GaExclusion::AbsolutelyUncertain)
    } else {
        None
    };
    let floored = floored_fit(rays, sigma, noise_std);
    Ok(GaFit {
        mu_d: mu,
        sigma_d: sigma,
        objective,
        terms,
        rays_without_samples: without,
        excluded,
        standardized,
        floored,
    })
}

/// Renders `rays` (one per pixel, each with its background) and fits the GA to the image's
/// `reference` colours (`[r]`, straight colour already composited on the same backgrounds).
/// Rendering is parallel over rays (rayon), each ray's `(m, s, r)` taken where its samples were
/// composited (they are not kept); the fit is a few passes over the rays.
pub fn ga_image(
    nerf: &Nerf,
    image: &str,
    rays: &[RayInput],
    reference: &[[f32; 3]],
    sigma_max: f64,
    noise_std: f64,
) -> Result<GaFit, UqError> {
    check_reference(image, rays.len(), reference)?;
    let ga_rays = nerf.map_ray_samples(rays, |i, c, w| GaRay::from_samples(c, w, reference[i], rays[i].background));
    ga_fit(image, &ga_rays, sigma_max, noise_std)
}

/// [`ga_image`] on an already rendered view: `samples` of `rays` (from
/// [`Nerf::render_rays_samples`]), so a caller that needs them again (the GA maps,
/// [`crate::ga_maps_from_samples`]) renders once.
pub fn ga_fit_samples(
    image: &str,
    rays: &[RayInput],
    samples: &RaySamples,
    reference: &[[f32; 3]],
    sigma_max: f64,
    noise_std: f64,
) -> Result<GaFit, UqError> {
    check_reference(image, rays.len(), reference)?;
    if samples.len() != rays.len() {
        return Err(UqError::LengthMismatch { image: image.to_string(), rays: samples.len(), references: rays.len() });
    }
    let ga_rays: Vec<GaRay> = (0..rays.len())
        .into_par_iter()
        .map(|i| {
            let (c, w) = samples.ray(i);
            GaRay::from_samples(c, w, reference[i], rays[i].background)
        })
        .collect();
    ga_fit(image, &ga_rays, sigma_max, noise_std)
}

/// Rays and references pair up and every reference is finite.
pub(crate) fn check_reference(image: &str, rays: usize, reference: &[[f32; 3]]) -> Result<(), UqError> {
    if rays != reference.len() {
        return Err(UqError::LengthMismatch { image: image.to_string(), rays, references: reference.len() });
    }
    if let Some((pixel, value)) = reference.iter().enumerate().find(|(_, c)| c.iter().any(|v| !v.is_finite())) {
        return Err(UqError::NonFiniteReference { image: image.to_string(), pixel, value: *value });
    }
    Ok(())
}
