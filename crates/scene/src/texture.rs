//! Procedural solid textures: value-noise fBm evaluated in world space, so every view of a
//! point sees the same colour (a Lambertian world, as a NeRF assumes).

use nalgebra::Point3;

use crate::sdf::Material;

#[inline]
fn hash3(x: i32, y: i32, z: i32) -> f32 {
    let mut h = (x as u32).wrapping_mul(0x8DA6_B343)
        ^ (y as u32).wrapping_mul(0xD816_3841)
        ^ (z as u32).wrapping_mul(0xCB1A_B31F);
    h ^= h >> 15;
    h = h.wrapping_mul(0x2C1B_3C6D);
    h ^= h >> 12;
    h = h.wrapping_mul(0x297A_2D39);
    h ^= h >> 15;
    (h >> 8) as f32 / (1u32 << 24) as f32
}

/// Smooth value noise in [0, 1] with unit feature size.
pub fn value_noise(x: f32, y: f32, z: f32) -> f32 {
    let (xi, yi, zi) = (x.floor(), y.floor(), z.floor());
    let (fx, fy, fz) = (x - xi, y - yi, z - zi);
    let s = |t: f32| t * t * (3.0 - 2.0 * t);
    let (u, v, w) = (s(fx), s(fy), s(fz));
    let (xi, yi, zi) = (xi as i32, yi as i32, zi as i32);
    let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
    let c = |dx, dy, dz| hash3(xi + dx, yi + dy, zi + dz);
    let x00 = lerp(c(0, 0, 0), c(1, 0, 0), u);
    let x10 = lerp(c(0, 1, 0), c(1, 1, 0), u);
    let x01 = lerp(c(0, 0, 1), c(1, 0, 1), u);
    let x11 = lerp(c(0, 1, 1), c(1, 1, 1), u);
    lerp(lerp(x00, x10, v), lerp(x01, x11, v), w)
}

/// Fractal Brownian motion: `octaves` of value noise starting at `frequency` (cycles per metre).
pub fn fbm(p: &Point3<f32>, frequency: f32, octaves: u32) -> f32 {
    let (mut f, mut amp, mut sum, mut norm) = (frequency, 1.0, 0.0, 0.0);
    for o in 0..octaves {
        // Offset octaves so their lattices do not line up.
        let off = 17.3 * o as f32;
        sum += amp * value_noise(p.x * f + off, p.y * f - off, p.z * f + 0.5 * off);
        norm += amp;
        amp *= 0.5;
        f *= 2.0;
    }
    sum / norm
}

/// Albedo (linear RGB in [0, 1]) of `material` at world point `p`. Features are kept at or
/// above ~4 cm so that 100-pixel views of the 4 m scene resolve them instead of aliasing.
pub fn albedo(material: Material, p: &Point3<f32>) -> [f32; 3] {
    match material {
        Material::Stone => {
            let base = fbm(p, 6.0, 3);
            let lichen = fbm(&Point3::new(p.x + 3.1, p.y - 1.7, p.z * 1.5), 3.0, 2);
            let shade = 0.55 + 0.6 * base;
            let grey = [0.56 * shade, 0.54 * shade, 0.50 * shade];
            // Patches of yellow-green lichen.
            let t = ((lichen - 0.55) * 6.0).clamp(0.0, 1.0);
            [grey[0] * (1.0 - t) + 0.55 * t, grey[1] * (1.0 - t) + 0.58 * t, grey[2] * (1.0 - t) + 0.25 * t]
        }
        Material::Ground => {
            let patches = fbm(p, 1.5, 3);
            let detail = fbm(p, 10.0, 2);
            let t = ((patches - 0.42) * 4.0).clamp(0.0, 1.0);
            let grass = [0.22, 0.42, 0.13];
            let dirt = [0.48, 0.38, 0.24];
            let k = 0.75 + 0.5 * detail;
            [
                k * (grass[0] * (1.0 - t) + dirt[0] * t),
                k * (grass[1] * (1.0 - t) + dirt[1] * t),
                k * (grass[2] * (1.0 - t) + dirt[2] * t),
            ]
        }
    }
}
