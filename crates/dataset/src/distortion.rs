//! OpenCV's radial-tangential lens model (COLMAP's and nerfstudio's `OPENCV` camera: `k1`, `k2`,
//! `p1`, `p2`) and the undistortion of an image into the pinhole camera with the same `fx`, `fy`,
//! `cx`, `cy`.
//!
//! Pixel coordinates are continuous, pixel `(i, j)` covering `[i, i+1) × [j, j+1)` with its
//! centre at `(i + 0.5, j + 0.5)` (nerfsv's, COLMAP's and nerfstudio's convention); normalised
//! coordinates are `x = (u − cx)/fx`, `y = (v − cy)/fy`, y pointing down the image.

use nerfsv_scene::image::{DepthImage, Image};
use nerfsv_scene::Intrinsics;

/// OpenCV's distortion of normalised image coordinates (OpenCV's `projectPoints`, COLMAP's
/// `OpenCVCameraModel`), dimensionless coefficients:
///
/// `r² = x² + y²`, `R = 1 + k1·r² + k2·r⁴`,
/// `x_d = x·R + 2·p1·x·y + p2·(r² + 2x²)`, `y_d = y·R + p1·(r² + 2y²) + 2·p2·x·y`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct OpenCvDistortion {
    pub k1: f64,
    pub k2: f64,
    pub p1: f64,
    pub p2: f64,
}

impl OpenCvDistortion {
    /// No distortion at all: the camera is a pinhole.
    pub fn is_zero(&self) -> bool {
        [self.k1, self.k2, self.p1, self.p2].iter().all(|&c| c == 0.0)
    }

    /// The distorted normalised coordinates of the undistorted ones `(x, y)`.
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let radial = 1.0 + self.k1 * r2 + self.k2 * r2 * r2;
        (
            x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// Whether the model is one-to-one at `(x, y)`: the radial factor is positive and still
    /// growing with the radius (`d(r·R)/dr = 1 + 3·k1·r² + 5·k2·r⁴ > 0`). Beyond that radius a
    /// strongly distorted lens folds the image back on itself and the model means nothing.
    pub fn is_valid_at(&self, x: f64, y: f64) -> bool {
        let r2 = x * x + y * y;
        1.0 + self.k1 * r2 + self.k2 * r2 * r2 > 0.0 && 1.0 + 3.0 * self.k1 * r2 + 5.0 * self.k2 * r2 * r2 > 0.0
    }

    /// The Jacobian `∂(x_d, y_d)/∂(x, y)`, row-major.
    fn jacobian(&self, x: f64, y: f64) -> [[f64; 2]; 2] {
        let r2 = x * x + y * y;
        let radial = 1.0 + self.k1 * r2 + self.k2 * r2 * r2;
        // ∂R/∂x = 2x·(k1 + 2·k2·r²), likewise for y.
        let d_r2 = self.k1 + 2.0 * self.k2 * r2;
        let (dr_dx, dr_dy) = (2.0 * x * d_r2, 2.0 * y * d_r2);
        [
            [
                radial + x * dr_dx + 2.0 * self.p1 * y + 6.0 * self.p2 * x,
                x * dr_dy + 2.0 * self.p1 * x + 2.0 * self.p2 * y,
            ],
            [
                y * dr_dx + 2.0 * self.p1 * x + 2.0 * self.p2 * y,
                radial + y * dr_dy + 6.0 * self.p1 * y + 2.0 * self.p2 * x,
            ],
        ]
    }

    /// The undistorted normalised coordinates whose distortion is `(xd, yd)`, by Newton's
    /// method from `(xd, yd)`; `None` where it does not converge to 1e-12 within 50 steps or
    /// lands where the model is not one-to-one ([`Self::is_valid_at`]).
    pub fn undistort(&self, xd: f64, yd: f64) -> Option<(f64, f64)> {
        let (mut x, mut y) = (xd, yd);
        for _ in 0..50 {
            let (fx, fy) = self.distort(x, y);
            let (ex, ey) = (fx - xd, fy - yd);
            if ex.hypot(ey) < 1e-12 {
                return self.is_valid_at(x, y).then_some((x, y));
            }
            let [[a, b], [c, d]] = self.jacobian(x, y);
            let det = a * d - b * c;
            if !(det.is_finite() && det.abs() > 1e-300) {
                return None;
            }
            x -= (d * ex - b * ey) / det;
            y -= (a * ey - c * ex) / det;
        }
        None
    }

    /// Where the undistorted pixel position `(u, v)` of camera `k` lies in the distorted image
    /// (pixels), `None` where the model is not one-to-one.
    pub fn distort_pixel(&self, k: &Intrinsics, u: f64, v: f64) -> Option<(f64, f64)> {
        let (fx, fy, cx, cy) = (k.fx as f64, k.fy as f64, k.cx as f64, k.cy as f64);
        let (x, y) = ((u - cx) / fx, (v - cy) / fy);
        if !self.is_valid_at(x, y) {
            return None;
        }
        let (xd, yd) = self.distort(x, y);
        Some((fx * xd + cx, fy * yd + cy))
    }

    /// Where the distorted pixel position `(u, v)` of camera `k` lands in the undistorted
    /// (pinhole) image, in pixels: the inverse of [`Self::distort_pixel`].
    pub fn undistort_pixel(&self, k: &Intrinsics, u: f64, v: f64) -> Option<(f64, f64)> {
        let (fx, fy, cx, cy) = (k.fx as f64, k.fy as f64, k.cx as f64, k.cy as f64);
        let (x, y) = self.undistort((u - cx) / fx, (v - cy) / fy)?;
        Some((fx * x + cx, fy * y + cy))
    }

    /// For every pixel centre of the undistorted image of camera `k`, where it lies in the
    /// distorted image, if inside it (`[0, width] × [0, height]`): `[height, width]`, row-major.
    fn source_positions(&self, k: &Intrinsics) -> Vec<Option<(f64, f64)>> {
        let (w, h) = (k.width as f64, k.height as f64);
        let mut out = Vec::with_capacity(k.pixels());
        for j in 0..k.height {
            for i in 0..k.width {
                let p = self.distort_pixel(k, i as f64 + 0.5, j as f64 + 0.5);
                out.push(p.filter(|&(u, v)| (0.0..=w).contains(&u) && (0.0..=h).contains(&v)));
            }
        }
        out
    }

    /// The pinhole image of camera `k` (same `fx`, `fy`, `cx`, `cy`) from the distorted
    /// `image`: each pixel bilinearly sampled at its distorted position (colour weighted by
    /// alpha, so transparent pixels do not bleed), transparent where that position lies
    /// outside the image. With no distortion it is `image` itself.
    pub fn undistort_image(&self, k: &Intrinsics, image: &Image) -> Image {
        if self.is_zero() {
            return image.clone();
        }
        let mut out = Image::new(image.width, image.height);
        let (w, h) = (image.width as i64, image.height as i64);
        for (o, p) in self.source_positions(k).into_iter().enumerate() {
            let Some((u, v)) = p else { continue };
            // Sample positions relative to pixel centres; neighbours clamped at the border.
            let (x, y) = (u - 0.5, v - 0.5);
            let (x0, y0) = (x.floor(), y.floor());
            let (tx, ty) = ((x - x0) as f32, (y - y0) as f32);
            let mut acc = [0.0f32; 4];
            for (dx, dy, wt) in
                [(0, 0, (1.0 - tx) * (1.0 - ty)), (1, 0, tx * (1.0 - ty)), (0, 1, (1.0 - tx) * ty), (1, 1, tx * ty)]
            {
                let xi = (x0 as i64 + dx).clamp(0, w - 1) as u32;
                let yi = (y0 as i64 + dy).clamp(0, h - 1) as u32;
                let px = image.pixel(xi, yi);
                for c in 0..3 {
                    acc[c] += wt * px[3] * px[c];
                }
                acc[3] += wt * px[3];
            }
            for c in 0..3 {
                out.rgba[4 * o + c] = if acc[3] > 0.0 { acc[c] / acc[3] } else { 0.0 };
            }
            out.rgba[4 * o + 3] = acc[3];
        }
        out
    }

    /// The pinhole depth image of camera `k` from the distorted `depth`: nearest neighbour
    /// (depths are not blended across edges), 0 (no depth) outside the image. The values, depth
    /// along the optical axis, are unchanged: both cameras share centre and axis.
    pub fn undistort_depth(&self, k: &Intrinsics, depth: &DepthImage) -> DepthImage {
        if self.is_zero() {
            return depth.clone();
        }
        let mut metres = vec![0.0; depth.metres.len()];
        for (o, p) in self.source_positions(k).into_iter().enumerate() {
            let Some((u, v)) = p else { continue };
            let xi = (u.floor() as u32).min(depth.width - 1);
            let yi = (v.floor() as u32).min(depth.height - 1);
            metres[o] = depth.metres[(yi * depth.width + xi) as usize];
        }
        DepthImage { width: depth.width, height: depth.height, metres }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LENS: OpenCvDistortion = OpenCvDistortion { k1: -0.12, k2: 0.03, p1: 0.004, p2: -0.002 };

    #[test]
    fn jacobian_matches_finite_differences() {
        let (x, y, h) = (0.31, -0.22, 1e-6);
        let j = LENS.jacobian(x, y);
        let (px, py) = (LENS.distort(x + h, y), LENS.distort(x - h, y));
        let (qx, qy) = (LENS.distort(x, y + h), LENS.distort(x, y - h));
        let fd = [
            [(px.0 - py.0) / (2.0 * h), (qx.0 - qy.0) / (2.0 * h)],
            [(px.1 - py.1) / (2.0 * h), (qx.1 - qy.1) / (2.0 * h)],
        ];
        for r in 0..2 {
            for c in 0..2 {
                assert!((j[r][c] - fd[r][c]).abs() < 1e-7, "[{r}][{c}]: {} vs {}", j[r][c], fd[r][c]);
            }
        }
    }

    #[test]
    fn undistort_inverts_distort_over_the_image() {
        for (x, y) in [(0.0, 0.0), (0.4, 0.3), (-0.5, 0.45), (0.6, -0.6)] {
            let (xd, yd) = LENS.distort(x, y);
            let (ux, uy) = LENS.undistort(xd, yd).unwrap();
            assert!((ux - x).abs() < 1e-10 && (uy - y).abs() < 1e-10, "({x}, {y}) → ({ux}, {uy})");
        }
    }
}
