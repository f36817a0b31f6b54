//! RGBA and depth images: PNG and JPEG decoding, PNG encoding, downscaling.

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

    /// Decodes a PNG ([`Image::read_png`]) or a JPEG ([`Image::read_jpeg`]), told apart by the
    /// file's first bytes, not by its name.
    pub fn read(path: &Path) -> Result<Self, String> {
        match sniff(path)? {
            ImageFormat::Png => Self::read_png(path),
            ImageFormat::Jpeg => Self::read_jpeg(path),
        }
    }

    /// Decodes a baseline or progressive JPEG (greyscale, YCbCr or RGB; CMYK converted to RGB).
    /// JPEG has no alpha: every pixel is opaque. The EXIF orientation tag is not applied (the
    /// pixels are used as stored, as a camera's intrinsics describe them).
    pub fn read_jpeg(path: &Path) -> Result<Self, String> {
        use zune_jpeg::zune_core::{bytestream::ZCursor, colorspace::ColorSpace, options::DecoderOptions};
        let bytes = std::fs::read(path).map_err(|e| e.to_string())?;
        let mut decoder = zune_jpeg::JpegDecoder::new(ZCursor::new(&bytes));
        decoder.decode_headers().map_err(|e| format!("cannot decode JPEG: {e}"))?;
        let (w, h) = decoder.dimensions().ok_or("cannot decode JPEG: no frame header")?;
        let grey = decoder.input_colorspace() == Some(ColorSpace::Luma);
        let channels = if grey { 1 } else { 3 };
        check_decoded_size(w as u32, h as u32, (w * h * channels) as u64, 16)?;
        let out = if grey { ColorSpace::Luma } else { ColorSpace::RGB };
        decoder.set_options(DecoderOptions::default().jpeg_set_out_colorspace(out));
        let buf = decoder.decode().map_err(|e| format!("cannot decode JPEG: {e}"))?;
        if buf.len() != w * h * channels {
            return Err(format!("cannot decode JPEG: {} bytes decoded, expected {}", buf.len(), w * h * channels));
        }
        let mut rgba = Vec::with_capacity(4 * w * h);
        for px in buf.chunks_exact(channels) {
            let v = |c: usize| px[c] as f32 / 255.0;
            rgba.extend_from_slice(&if grey { [v(0), v(0), v(0), 1.0] } else { [v(0), v(1), v(2), 1.0] });
        }
        Ok(Self { width: w as u32, height: h as u32, rgba })
    }

    /// Decodes an 8- or 16-bit grey, grey+alpha, RGB or RGBA PNG. Missing alpha is opaque.
    pub fn read_png(path: &Path) -> Result<Self, String> {
        let file = std::fs::File::open(path).map_err(|e| e.to_string())?;
        let mut decoder = png::Decoder::new(BufReader::new(file));
        decoder.set_transformations(png::Transformations::EXPAND);
        let mut reader = decoder.read_info().map_err(|e| e.to_string())?;
        let size = reader.output_buffer_size().ok_or("image too large")?;
        check_decoded_size(reader.info().width, reader.info().height, size as u64, 16)?;
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
        check_decoded_size(reader.info().width, reader.info().height, size as u64, 4)?;
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

/// The file formats [`Image::read`] decodes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum ImageFormat {
    Png,
    Jpeg,
}

const PNG_SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0D, 0x0A, 0x1A, 0x0A];
/// A JPEG starts with its SOI marker and the first segment's marker byte.
const JPEG_SIGNATURE: [u8; 3] = [0xFF, 0xD8, 0xFF];

/// The format of the file at `path`, from its first bytes.
fn sniff(path: &Path) -> Result<ImageFormat, String> {
    use std::io::Read;
    let mut head = Vec::with_capacity(8);
    std::fs::File::open(path).and_then(|f| f.take(8).read_to_end(&mut head)).map_err(|e| e.to_string())?;
    if head.starts_with(&PNG_SIGNATURE) {
        Ok(ImageFormat::Png)
    } else if head.starts_with(&JPEG_SIGNATURE) {
        Ok(ImageFormat::Jpeg)
    } else {
        let shown: Vec<String> = head.iter().map(|b| format!("{b:02x}")).collect();
        Err(format!("neither a PNG nor a JPEG file: it starts with the bytes [{}]", shown.join(" ")))
    }
}

/// Width and height of a PNG or JPEG from its header, without decoding its pixels.
pub fn image_size(path: &Path) -> Result<(u32, u32), String> {
    match sniff(path)? {
        ImageFormat::Png => {
            let file = std::fs::File::open(path).map_err(|e| e.to_string())?;
            let reader = png::Decoder::new(BufReader::new(file)).read_info().map_err(|e| e.to_string())?;
            Ok((reader.info().width, reader.info().height))
        }
        ImageFormat::Jpeg => {
            let file = std::fs::File::open(path).map_err(|e| e.to_string())?;
            let mut decoder = zune_jpeg::JpegDecoder::new(BufReader::new(file));
            decoder.decode_headers().map_err(|e| format!("cannot decode JPEG: {e}"))?;
            let (w, h) = decoder.dimensions().ok_or("cannot decode JPEG: no frame header")?;
            Ok((w as u32, h as u32))
        }
    }
}

/// Refuses an image of `width`×`height` whose decoded samples (`buffer` bytes) and result
/// (`per_pixel` bytes a pixel) would not fit the memory budget, before either is allocated: the
/// header's size is the file's claim, and a few KiB of compressed data can claim gigabytes.
fn check_decoded_size(width: u32, height: u32, buffer: u64, per_pixel: u64) -> Result<(), String> {
    let pixels = width as u64 * height as u64;
    let bytes = buffer.saturating_add(bytes_for(pixels, per_pixel));
    MemoryBudget::current().check(&format!("image of {width}×{height} pixels"), bytes).map_err(|e| e.to_string())
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
