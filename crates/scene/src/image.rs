//! RGBA and depth images: PNG decoding/encoding and downscaling.

use std::io::{BufReader, Write};
use std::path::Path;

use crate::validate::{bytes_for, MemoryBudget};

/// A straight (not premultiplied) RGBA image, `rgba: [height, width, 4]` in `[0, 1]`,
/// row-major from the top row.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<f32>,
}

/// A depth image in metres, `[height, width]`; 0 marks pixels without depth (background).
/// Depth is z-depth: distance along the camera's optical axis (nerfstudio's convention).
#[derive(Clone, Debug, PartialEq)]
pub struct DepthImage {
    pub width: u32,
    pub height: u32,
    pub metres: Vec<f32>,
}

impl Image {
    pub fn new(width: u32, height: u32) -> Self {
        Self { width, height, rgba: vec![0.0; width as usize * height as usize * 4] }
    }

    pub fn pixel(&self, x: u32, y: u32) -> [f32; 4] {
        let i = 4 * (y as usize * self.width as usize + x as usize);
        [self.rgba[i], self.rgba[i + 1], self.rgba[i + 2], self.rgba[i + 3]]
    }

    /// Decodes an 8- or 16-bit grey, grey+alpha, RGB or RGBA PNG. Missing alpha is opaque.
    pub fn read_png(path: &Path) -> Result<Self, String> {
        let file = std::fs::File::open(path).map_err(|e| e.to_string())?;
        let mut decoder = png::Decoder::new(BufReader::new(file));
        decoder.set_transformations(png::Transformations::EXPAND);
        let mut reader = decoder.read_info().map_err(|e| e.to_string())?;
        let size = reader.output_buffer_size().ok_or("image too large")?;
        check_decoded_size(reader.info(), size, 16)?;
        let mut buf = vec![0; size];
        let info = reader.next_frame(&mut buf).map_err(|e| format!("cannot decode PNG: {e}"))?;
        let (w, h) = (info.width, info.height);
        let channels = info.color_type.samples();
        let sixteen = info.bit_depth == png::BitDepth::Sixteen;
        let n = w as usize * h as usize;
        let sample = |k: usize| -> f32 {
            if sixteen {
                u16::from_be_bytes([buf[2 * k], buf[2 * k + 1]]) as f32 / 65535.0
            } else {
                buf[k] as f32 / 255.0
            }
        };
        let mut rgba = Vec::with_capacity(4 * n);
        for p in 0..n {
            let b = p * channels;
            let px = match channels {
                1 => [sample(b), sample(b), sample(b), 1.0],
                2 => [sample(b), sample(b), sample(b), sample(b + 1)],
                3 => [sample(b), sample(b + 1), sample(b + 2), 1.0],
                4 => [sample(b), sample(b + 1), sample(b + 2), sample(b + 3)],
                c => return Err(format!("unsupported PNG with {c} channels")),
            };
            rgba.extend_from_slice(&px);
        }
        Ok(Self { width: w, height: h, rgba })
    }

    /// Encodes as an 8-bit RGBA PNG.
    pub fn write_png<W: Write>(&self, w: W) -> std::io::Result<()> {
        let bytes: Vec<u8> = self.rgba.iter().map(|&v| (v.clamp(0.0, 1.0) * 255.0).round() as u8).collect();
        write_png_bytes(w, self.width, self.height, png::ColorType::Rgba, png::BitDepth::Eight, &bytes)
    }

    /// Box-filters by an integer `factor`, averaging colour weighted by alpha so that
    /// transparent background does not bleed into edges.
    pub fn downscaled(&self, factor: u32) -> Self {
        if factor <= 1 {
            return self.clone();
        }
        let (w, h) = (self.width / factor, self.height / factor);
        let mut out = Image::new(w, h);
        let inv = 1.0 / (factor * factor) as f32;
        for y in 0..h {
            for x in 0..w {
                let mut acc = [0.0f32; 4];
                for dy in 0..factor {
                    for dx in 0..factor {
                        let p = self.pixel(x * factor + dx, y * factor + dy);
                        for c in 0..3 {
                            acc[c] += p[c] * p[3];
                        }
                        acc[3] += p[3];
                    }
                }
                let o = 4 * (y as usize * w as usize + x as usize);
                for c in 0..3 {
                    out.rgba[o + c] = if acc[3] > 0.0 { acc[c] / acc[3] } else { 0.0 };
                }
                out.rgba[o + 3] = acc[3] * inv;
            }
        }
        out
    }
}

impl DepthImage {
    /// Decodes a 16-bit grey PNG whose values times `unit_scale` are metres.
    pub fn read_png(path: &Path, unit_scale: f32) -> Result<Self, String> {
        let file = std::fs::File::open(path).map_err(|e| e.to_string())?;
        let decoder = png::Decoder::new(BufReader::new(file));
        let mut reader = decoder.read_info().map_err(|e| e.to_string())?;
        let size = reader.output_buffer_size().ok_or("image too large")?;
        check_decoded_size(reader.info(), size, 4)?;
        let mut buf = vec![0; size];
        let info = reader.next_frame(&mut buf).map_err(|e| format!("cannot decode PNG: {e}"))?;
        if info.color_type != png::ColorType::Grayscale || info.bit_depth != png::BitDepth::Sixteen {
            return Err(format!(
                "expected a 16-bit greyscale depth PNG, found {:?} {:?}",
                info.color_type, info.bit_depth
            ));
        }
        let n = info.width as usize * info.height as usize;
        let metres = (0..n).map(|k| u16::from_be_bytes([buf[2 * k], buf[2 * k + 1]]) as f32 * unit_scale).collect();
        Ok(Self { width: info.width, height: info.height, metres })
    }

    /// Encodes as a 16-bit greyscale PNG in millimetres (values clamp to 65.535 m).
    pub fn write_png_mm<W: Write>(&self, w: W) -> std::io::Result<()> {
        let mut bytes = Vec::with_capacity(self.metres.len() * 2);
        for &m in &self.metres {
            let mm = (m * 1000.0).round().clamp(0.0, 65535.0) as u16;
            bytes.extend_from_slice(&mm.to_be_bytes());
        }
        write_png_bytes(w, self.width, self.height, png::ColorType::Grayscale, png::BitDepth::Sixteen, &bytes)
    }

    /// Downscales by averaging the valid (non-zero) depths of each block.
    pub fn downscaled(&self, factor: u32) -> Self {
        if factor <= 1 {
            return self.clone();
        }
        let (w, h) = (self.width / factor, self.height / factor);
        let mut metres = vec![0.0; w as usize * h as usize];
        for y in 0..h {
            for x in 0..w {
                let (mut sum, mut count) = (0.0, 0);
                for dy in 0..factor {
                    for dx in 0..factor {
                        let d = self.metres[((y * factor + dy) * self.width + x * factor + dx) as usize];
                        if d > 0.0 {
                            sum += d;
                            count += 1;
                        }
                    }
                }
                if count > 0 {
                    metres[(y * w + x) as usize] = sum / count as f32;
                }
            }
        }
        Self { width: w, height: h, metres }
    }
}

/// Refuses a PNG whose decoded samples (`buffer` bytes) and result (`per_pixel` bytes a pixel)
/// would not fit the memory budget, before either is allocated: the header's size is the
/// file's claim, and a few KiB of deflate can claim gigabytes.
fn check_decoded_size(info: &png::Info, buffer: usize, per_pixel: u64) -> Result<(), String> {
    let pixels = info.width as u64 * info.height as u64;
    let bytes = (buffer as u64).saturating_add(bytes_for(pixels, per_pixel));
    MemoryBudget::current()
        .check(&format!("image of {}×{} pixels", info.width, info.height), bytes)
        .map_err(|e| e.to_string())
}

fn write_png_bytes<W: Write>(
    w: W,
    width: u32,
    height: u32,
    color: png::ColorType,
    depth: png::BitDepth,
    bytes: &[u8],
) -> std::io::Result<()> {
    let mut enc = png::Encoder::new(w, width, height);
    enc.set_color(color);
    enc.set_depth(depth);
    enc.set_compression(png::Compression::Fast);
    let mut writer = enc.write_header().map_err(std::io::Error::other)?;
    writer.write_image_data(bytes).map_err(std::io::Error::other)?;
    writer.finish().map_err(std::io::Error::other)
}
