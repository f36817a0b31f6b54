//! Degree-4 real spherical harmonics of a unit direction (16 values), with torch-ngp's
//! `SHEncoder` constants and sign convention. [`sh_jacobian`] is the derivative with respect to
//! the direction (for ray Jacobians; training needs no backward here).

/// Output width of the degree-4 encoding.
pub const SH_DIM: usize = 16;

/// `d`: unit direction (world frame); `out: [16]`.
#[inline]
pub fn sh_encode(d: [f32; 3], out: &mut [f32]) {
    let [x, y, z] = d;
    let (xx, yy, zz) = (x * x, y * y, z * z);
    let (xy, yz, xz) = (x * y, y * z, x * z);
    out[0] = 0.282_094_8;
    out[1] = -0.488_602_52 * y;
    out[2] = 0.488_602_52 * z;
    out[3] = -0.488_602_52 * x;
    out[4] = 1.092_548_5 * xy;
    out[5] = -1.092_548_5 * yz;
    out[6] = 0.946_174_7 * zz - 0.315_391_57;
    out[7] = -1.092_548_5 * xz;
    out[8] = 0.546_274_2 * (xx - yy);
    out[9] = 0.590_043_6 * y * (-3.0 * xx + yy);
    out[10] = 2.890_611_4 * xy * z;
    out[11] = 0.457_045_8 * y * (1.0 - 5.0 * zz);
    out[12] = 0.373_176_33 * z * (5.0 * zz - 3.0);
    out[13] = 0.457_045_8 * x * (1.0 - 5.0 * zz);
    out[14] = 1.445_305_7 * z * (xx - yy);
    out[15] = 0.590_043_6 * x * (-xx + 3.0 * yy);
}

/// `∂out_k/∂d_a` of [`sh_encode`] at `d` (the polynomials' gradient; `d` is not renormalised):
/// `jac: [16][3]`.
#[inline]
pub fn sh_jacobian(d: [f32; 3], jac: &mut [[f32; 3]; SH_DIM]) {
    let [x, y, z] = d;
    let (xx, yy, zz) = (x * x, y * y, z * z);
    let (xy, yz, xz) = (x * y, y * z, x * z);
    let (c1, c2, c3, c4) = (0.488_602_52f32, 1.092_548_5f32, 0.946_174_7f32, 0.546_274_2f32);
    let (c5, c6, c7, c8, c9) = (0.590_043_6f32, 2.890_611_4f32, 0.457_045_8f32, 0.373_176_33f32, 1.445_305_7f32);
    *jac = [
        [0.0, 0.0, 0.0],
        [0.0, -c1, 0.0],
        [0.0, 0.0, c1],
        [-c1, 0.0, 0.0],
        [c2 * y, c2 * x, 0.0],
        [0.0, -c2 * z, -c2 * y],
        [0.0, 0.0, 2.0 * c3 * z],
        [-c2 * z, 0.0, -c2 * x],
        [2.0 * c4 * x, -2.0 * c4 * y, 0.0],
        [-6.0 * c5 * xy, 3.0 * c5 * (yy - xx), 0.0],
        [c6 * yz, c6 * xz, c6 * xy],
        [0.0, c7 * (1.0 - 5.0 * zz), -10.0 * c7 * yz],
        [0.0, 0.0, c8 * (15.0 * zz - 3.0)],
        [c7 * (1.0 - 5.0 * zz), 0.0, -10.0 * c7 * xz],
        [2.0 * c9 * xz, -2.0 * c9 * yz, c9 * (xx - yy)],
        [3.0 * c5 * (yy - xx), 6.0 * c5 * xy, 0.0],
    ];
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sh_jacobian_matches_finite_differences() {
        let mut jac = [[0.0f32; 3]; SH_DIM];
        let (mut yp, mut ym) = ([0.0f32; SH_DIM], [0.0f32; SH_DIM]);
        for d in [[0.3f32, -0.5, 0.81], [-0.9, 0.2, -0.4], [0.1, 0.95, 0.3]] {
            sh_jacobian(d, &mut jac);
            for a in 0..3 {
                let h = 1e-2f32;
                let (mut dp, mut dm) = (d, d);
                dp[a] += h;
                dm[a] -= h;
                sh_encode(dp, &mut yp);
                sh_encode(dm, &mut ym);
                for k in 0..SH_DIM {
                    // Cubic polynomials: the central difference is off by (h²/6)·∂³y ≲ 1e-3.
                    let fd = (yp[k] - ym[k]) / (2.0 * h);
                    assert!((fd - jac[k][a]).abs() < 2e-3, "Y_{k} d/d{a} at {d:?}: {} vs fd {fd}", jac[k][a]);
                }
            }
        }
    }

    #[test]
    fn sh_basis_is_orthonormal_on_the_sphere() {
        // Monte-Carlo-free check: a Fibonacci sphere quadrature of ∫ Y_i Y_j dΩ ≈ δ_ij.
        let n = 20000;
        let mut gram = [[0.0f64; SH_DIM]; SH_DIM];
        let mut y = [0.0f32; SH_DIM];
        for k in 0..n {
            let z = 1.0 - 2.0 * (k as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let phi = k as f64 * std::f64::consts::PI * (3.0 - 5f64.sqrt());
            sh_encode([(r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32], &mut y);
            for i in 0..SH_DIM {
                for j in 0..SH_DIM {
                    gram[i][j] += y[i] as f64 * y[j] as f64 * 4.0 * std::f64::consts::PI / n as f64;
                }
            }
        }
        for (i, row) in gram.iter().enumerate() {
            for (j, g) in row.iter().enumerate() {
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((g - want).abs() < 2e-3, "({i},{j}) = {g}");
            }
        }
    }
}
