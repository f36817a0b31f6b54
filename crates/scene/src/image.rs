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
    /// file's first bytes, not by its name. The pixels are as stored: an EXIF orientation is not
    /// applied ([`Image::read_with_orientation`] reports it).
    pub fn read(path: &Path) -> Result<Self, String> {
        Self::read_with_orientation(path).map(|(image, _)| image)
    }

    /// Decodes a PNG or a JPEG as [`Image::read`] does, with its EXIF orientation (TIFF tag
    /// 0x0112 of a JPEG's APP1 `Exif` segment or a PNG's `eXIf` chunk, 1 to 8; 1 where it has
    /// none or an unreadable one): how the stored pixels are turned for display
    /// ([`Image::oriented`]).
    pub fn read_with_orientation(path: &Path) -> Result<(Self, u8), String> {
        match sniff(path)? {
            ImageFormat::Png => Self::decode_png(path),
            ImageFormat::Jpeg => Self::decode_jpeg(path),
        }
    }

    /// Decodes a baseline or progressive JPEG (greyscale, YCbCr or RGB; CMYK converted to RGB).
    /// JPEG has no alpha: every pixel is opaque. The EXIF orientation tag is not applied (the
    /// pixels are used as stored, as COLMAP, nerfstudio and instant-ngp read them and as a
    /// camera's intrinsics describe them).
    pub fn read_jpeg(path: &Path) -> Result<Self, String> {
        Self::decode_jpeg(path).map(|(image, _)| image)
    }

    fn decode_jpeg(path: &Path) -> Result<(Self, u8), String> {
        use zune_jpeg::zune_core::{bytestream::ZCursor, colorspace::ColorSpace, options::DecoderOptions};
        let bytes = std::fs::read(path).map_err(|e| e.to_string())?;
        let mut decoder = zune_jpeg::JpegDecoder::new(ZCursor::new(&bytes));
        decoder.decode_headers().map_err(|e| format!("cannot decode JPEG: {e}"))?;
        let orientation = decoder.exif().and_then(|tiff| tiff_orientation(tiff)).unwrap_or(1);
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
        Ok((Self { width: w as u32, height: h as u32, rgba }, orientation))
    }

    /// Decodes an 8- or 16-bit grey, grey+alpha, RGB or RGBA PNG. Missing alpha is opaque. An
    /// `eXIf` orientation is not applied.
    pub fn read_png(path: &Path) -> Result<Self, String> {
        Self::decode_png(path).map(|(image, _)| image)
    }

    fn decode_png(path: &Path) -> Result<(Self, u8), String> {
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
        let orientation = reader.info().exif_metadata.as_deref().and_then(tiff_orientation).unwrap_or(1);
        Ok((Self { width: w, height: h, rgba }, orientation))
    }

    /// The image as EXIF orientation `orientation` says to display it: 1 as stored, 2 mirrored
    /// left to right, 3 turned half round, 4 mirrored top to bottom, 5 transposed (mirrored
    /// about the main diagonal), 6 turned a quarter clockwise, 7 transversed (mirrored about
    /// the other diagonal), 8 turned a quarter anticlockwise; 5 to 8 swap width and height.
    /// Any other value leaves it as stored.
    pub fn oriented(&self, orientation: u8) -> Self {
        let (w, h) = (self.width as usize, self.height as usize);
        if !(2..=8).contains(&orientation) {
            return self.clone();
        }
        let (ow, oh) = oriented_size(self.width, self.height, orientation);
        let mut rgba = Vec::with_capacity(self.rgba.len());
        for y in 0..oh as usize {
            for x in 0..ow as usize {
                // The stored pixel shown at (x, y).
                let (sx, sy) = match orientation {
                    2 => (w - 1 - x, y),
                    3 => (w - 1 - x, h - 1 - y),
                    4 => (x, h - 1 - y),
                    5 => (y, x),
                    6 => (y, h - 1 - x),
                    7 => (w - 1 - y, h - 1 - x),
                    _ => (w - 1 - y, x),
                };
                let i = 4 * (sy * w + sx);
                rgba.extend_from_slice(&self.rgba[i..i + 4]);
            }
        }
        Self { width: ow, height: oh, rgba }
    }

    /// Encodes as an 8-bit RGBA PNG.
    pub fn write_png<W: Write>(&self, w: W) -> std::io::Result<()> {
        write_png_bytes(w, self.width, self.height, png::ColorType::Rgba, png::BitDepth::Eight, &self.rgba8())
    }

    /// The pixels as 8-bit RGBA, each value clamped to `[0, 1]` and rounded.
    pub fn rgba8(&self) -> Vec<u8> {
        self.rgba.iter().map(|&v| (v.clamp(0.0, 1.0) * 255.0).round() as u8).collect()
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

/// The size of a `width`×`height` image shown with EXIF orientation `orientation`
/// ([`Image::oriented`]): 5 to 8 swap width and height.
pub fn oriented_size(width: u32, height: u32, orientation: u8) -> (u32, u32) {
    if (5..=8).contains(&orientation) {
        (height, width)
    } else {
        (width, height)
    }
}

/// The orientation (tag 0x0112, a SHORT from 1 to 8) in the first IFD of an EXIF TIFF block
/// (byte order `II` or `MM`, the magic 42, the offset of IFD0, then its 12-byte entries); `None`
/// where the block has no such tag or is malformed.
pub fn tiff_orientation(tiff: &[u8]) -> Option<u8> {
    let le = match tiff.get(..2)? {
        b"II" => true,
        b"MM" => false,
        _ => return None,
    };
    let u16_at = |at: usize| {
        let b: [u8; 2] = tiff.get(at..at.checked_add(2)?)?.try_into().ok()?;
        Some(if le { u16::from_le_bytes(b) } else { u16::from_be_bytes(b) })
    };
    let u32_at = |at: usize| {
        let b: [u8; 4] = tiff.get(at..at.checked_add(4)?)?.try_into().ok()?;
        Some(if le { u32::from_le_bytes(b) } else { u32::from_be_bytes(b) })
    };
    if u16_at(2)? != 42 {
        return None;
    }
    let ifd = usize::try_from(u32_at(4)?).ok()?;
    for k in 0..usize::from(u16_at(ifd)?) {
        let entry = ifd.checked_add(2 + 12 * k)?;
        if u16_at(entry)? == 0x0112 {
            // Type SHORT (3), count 1: the value is the first two bytes of the value field.
            if u16_at(entry + 2)? != 3 || u32_at(entry + 4)? != 1 {
                return None;
            }
            let v = u16_at(entry + 8)?;
            return u8::try_from(v).ok().filter(|v| (1..=8).contains(v));
        }
    }
    None
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

#[cfg(test)]
mod tests {
    use super::*;

    /// An EXIF TIFF block whose IFD0 holds one entry, the orientation `value`, in byte order
    /// `II` (little-endian) or `MM`.
    fn exif_tiff(value: u16, le: bool) -> Vec<u8> {
        let (u16b, u32b) = if le {
            (u16::to_le_bytes as fn(u16) -> [u8; 2], u32::to_le_bytes as fn(u32) -> [u8; 4])
        } else {
            (u16::to_be_bytes as fn(u16) -> [u8; 2], u32::to_be_bytes as fn(u32) -> [u8; 4])
        };
        let mut t = Vec::new();
        t.extend(if le { b"II" } else { b"MM" });
        t.extend(u16b(42));
        t.extend(u32b(8));
        // Two entries: an ImageDescription-like ASCII tag first, then the orientation.
        t.extend(u16b(2));
        t.extend(u16b(0x010e));
        t.extend(u16b(2));
        t.extend(u32b(4));
        t.extend(b"abc\0");
        t.extend(u16b(0x0112));
        t.extend(u16b(3));
        t.extend(u32b(1));
        t.extend(u16b(value));
        t.extend([0, 0]);
        t.extend(u32b(0));
        t
    }

    /// A 3×2 image whose pixel (x, y) has red `10·y + x`.
    fn labelled() -> Image {
        let mut img = Image::new(3, 2);
        for y in 0..2 {
            for x in 0..3 {
                let i = 4 * (y * 3 + x);
                img.rgba[i..i + 4].copy_from_slice(&[(10 * y + x) as f32, 0.5, 0.25, 1.0]);
            }
        }
        img
    }

    fn reds(img: &Image) -> Vec<Vec<u32>> {
        (0..img.height).map(|y| (0..img.width).map(|x| img.pixel(x, y)[0] as u32).collect()).collect()
    }

    #[test]
    fn each_exif_orientation_shows_the_stored_pixels_as_the_tag_says() {
        // Stored:  0  1  2   (a b c)
        //         10 11 12   (d e f)
        let want: [(u8, &[&[u32]]); 8] = [
            (1, &[&[0, 1, 2], &[10, 11, 12]]),
            (2, &[&[2, 1, 0], &[12, 11, 10]]),
            (3, &[&[12, 11, 10], &[2, 1, 0]]),
            (4, &[&[10, 11, 12], &[0, 1, 2]]),
            (5, &[&[0, 10], &[1, 11], &[2, 12]]),
            (6, &[&[10, 0], &[11, 1], &[12, 2]]),
            (7, &[&[12, 2], &[11, 1], &[10, 0]]),
            (8, &[&[2, 12], &[1, 11], &[0, 10]]),
        ];
        let img = labelled();
        for (o, grid) in want {
            let shown = img.oriented(o);
            assert_eq!(reds(&shown), grid.iter().map(|r| r.to_vec()).collect::<Vec<_>>(), "orientation {o}");
            assert_eq!((shown.width, shown.height), oriented_size(3, 2, o));
            assert_eq!(shown.pixel(0, 0)[1..], [0.5, 0.25, 1.0]);
        }
        assert_eq!(img.oriented(0), img);
        assert_eq!(img.oriented(9), img);
    }

    #[test]
    fn the_orientation_tag_is_read_in_either_byte_order_and_a_bad_block_is_none() {
        for le in [true, false] {
            for v in 1..=8 {
                assert_eq!(tiff_orientation(&exif_tiff(v, le)), Some(v as u8), "{v} le={le}");
            }
            assert_eq!(tiff_orientation(&exif_tiff(0, le)), None);
            assert_eq!(tiff_orientation(&exif_tiff(9, le)), None);
            let whole = exif_tiff(6, le);
            for n in 0..whole.len() - 6 {
                assert_eq!(tiff_orientation(&whole[..n]), None, "{n} bytes");
            }
        }
        assert_eq!(tiff_orientation(b"XX\0*\0\0\0\x08"), None);
        // An IFD offset past the end, and one near usize::MAX.
        assert_eq!(tiff_orientation(b"II*\0\xff\xff\xff\xff"), None);
    }

    fn fixture(name: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/captures/nerfstudio/images").join(name)
    }

    #[test]
    fn a_jpegs_app1_orientation_is_reported_and_its_pixels_stay_as_stored() {
        let jpeg = std::fs::read(fixture("frame_00.jpg")).unwrap();
        let stored = Image::read(&fixture("frame_00.jpg")).unwrap();
        assert_eq!(Image::read_with_orientation(&fixture("frame_00.jpg")).unwrap().1, 1);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("o.jpg");
        for le in [true, false] {
            for v in 1..=8 {
                let tiff = exif_tiff(v, le);
                let mut bytes = jpeg[..2].to_vec();
                bytes.extend([0xFF, 0xE1]);
                bytes.extend(((2 + 6 + tiff.len()) as u16).to_be_bytes());
                bytes.extend(b"Exif\0\0");
                bytes.extend(&tiff);
                bytes.extend(&jpeg[2..]);
                std::fs::write(&path, &bytes).unwrap();
                let (img, o) = Image::read_with_orientation(&path).unwrap();
                assert_eq!((img, o), (stored.clone(), v as u8), "orientation {v}");
                assert_eq!(Image::read(&path).unwrap(), stored);
            }
        }
    }

    #[test]
    fn a_pngs_exif_chunk_orientation_is_reported() {
        let img = labelled();
        let bytes: Vec<u8> = img.rgba.iter().map(|&v| (v.min(1.0) * 255.0) as u8).collect();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("o.png");
        for v in [1, 6, 8] {
            let mut info = png::Info::with_size(3, 2);
            info.color_type = png::ColorType::Rgba;
            info.bit_depth = png::BitDepth::Eight;
            info.exif_metadata = Some(exif_tiff(v, false).into());
            let mut out = Vec::new();
            let mut w = png::Encoder::with_info(&mut out, info).unwrap().write_header().unwrap();
            w.write_image_data(&bytes).unwrap();
            w.finish().unwrap();
            std::fs::write(&path, &out).unwrap();
            let (read, o) = Image::read_with_orientation(&path).unwrap();
            assert_eq!((read.width, read.height, o), (3, 2, v as u8));
        }
    }
}
