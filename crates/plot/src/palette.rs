//! The colours every nerfsv figure shares, so that "true track" is the same blue in the
//! trajectory plot, the histograms and the HTML report.
//!
//! Track and marker colours follow the Okabe–Ito palette (distinguishable with the common
//! colour-vision deficiencies); the signed-distance map is a warm grey ramp that stays behind
//! the data.

use plotters::style::RGBColor;

/// An sRGB colour, 8 bits per channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Rgb(pub u8, pub u8, pub u8);

impl Rgb {
    /// The channels as `[r, g, b]` (the layout of a decoded RGB8 PNG pixel).
    pub const fn to_array(self) -> [u8; 3] {
        [self.0, self.1, self.2]
    }

    /// CSS notation, e.g. `#0072b2`, for the HTML report.
    pub fn hex(self) -> String {
        format!("#{:02x}{:02x}{:02x}", self.0, self.1, self.2)
    }

    /// Linear blend in sRGB: `t = 0` gives `self`, `t = 1` gives `other` (`t` is clamped).
    pub fn lerp(self, other: Rgb, t: f64) -> Rgb {
        let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
        let mix = |a: u8, b: u8| (f64::from(a) + (f64::from(b) - f64::from(a)) * t).round() as u8;
        Rgb(mix(self.0, other.0), mix(self.1, other.1), mix(self.2, other.2))
    }
}

impl From<Rgb> for RGBColor {
    fn from(c: Rgb) -> Self {
        RGBColor(c.0, c.1, c.2)
    }
}

/// Figure background.
pub const WHITE: Rgb = Rgb(255, 255, 255);
/// Text, axes and the planned path.
pub const INK: Rgb = Rgb(0x1f, 0x1f, 0x1f);
/// Secondary text (panel captions, legend labels).
pub const INK_SOFT: Rgb = Rgb(0x4a, 0x4a, 0x4a);
/// Grid lines.
pub const GRID: Rgb = Rgb(0xdc, 0xdc, 0xdc);

/// The planned path (drawn dashed).
pub const PLANNED: Rgb = INK;
/// The true (simulated ground-truth) track: Okabe–Ito blue.
pub const TRUE_TRACK: Rgb = Rgb(0x00, 0x72, 0xb2);
/// The state estimator's track: Okabe–Ito orange.
pub const ESTIMATED: Rgb = Rgb(0xe6, 0x9f, 0x00);
/// Further tracks, cycled by index: Okabe–Ito reddish purple, sky blue, vermillion, bluish
/// green, then a brown and a grey.
pub const CATEGORICAL: [Rgb; 6] = [
    Rgb(0xcc, 0x79, 0xa7),
    Rgb(0x56, 0xb4, 0xe9),
    Rgb(0xd5, 0x5e, 0x00),
    Rgb(0x00, 0x9e, 0x73),
    Rgb(0x8c, 0x56, 0x4b),
    Rgb(0x7f, 0x7f, 0x7f),
];

/// Start marker: Okabe–Ito bluish green.
pub const START: Rgb = Rgb(0x00, 0x9e, 0x73);
/// Goal marker.
pub const GOAL: Rgb = Rgb(0xc6, 0x28, 0x28);
/// Collision marker: a saturated red, drawn with a white halo.
pub const COLLISION: Rgb = Rgb(0xe0, 0x00, 0x00);

/// Inside geometry (signed distance < 0).
pub const SOLID: Rgb = Rgb(0x6b, 0x5e, 0x53);
/// The zero level set (the obstacle surface).
pub const SURFACE: Rgb = Rgb(0x24, 0x1e, 0x1a);
/// Free space right at the surface; the shade lightens to [`WHITE`] with clearance.
pub const CLEARANCE_NEAR: Rgb = Rgb(0xd9, 0xcd, 0xbd);
/// Where the signed-distance slice has no data.
pub const NO_DATA: Rgb = Rgb(0xee, 0xef, 0xf2);
/// Below ground in the side view.
pub const GROUND: Rgb = Rgb(0xe8, 0xdf, 0xd2);
/// The allowed altitude band.
pub const BAND: Rgb = Rgb(0x2e, 0x7d, 0x32);
/// Inside the altitude band (a 7 % tint of [`BAND`] on white).
pub const BAND_TINT: Rgb = Rgb(0xee, 0xf5, 0xee);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lerp_hits_both_ends_and_clamps() {
        assert_eq!(INK.lerp(WHITE, 0.0), INK);
        assert_eq!(INK.lerp(WHITE, 1.0), WHITE);
        assert_eq!(INK.lerp(WHITE, 7.0), WHITE);
        assert_eq!(Rgb(0, 0, 0).lerp(Rgb(200, 100, 50), 0.5), Rgb(100, 50, 25));
    }

    #[test]
    fn hex_is_lowercase_css() {
        assert_eq!(TRUE_TRACK.hex(), "#0072b2");
    }
}
