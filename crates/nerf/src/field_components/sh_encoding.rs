//! Degree-4 real spherical harmonics of a unit direction (16 values), with torch-ngp's
//! `SHEncoder` constants and sign convention. Directions are inputs only: no backward.

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

#[cfg(test)]
mod tests {
    use super::*;

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
