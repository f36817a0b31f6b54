//! Animated PNG (APNG): frames of one size shown in turn and looped. Every current browser plays
//! it, and a reader that knows only PNG shows its first frame.

use std::io::Write;

use crate::image::Image;

/// The rate that plays `frames` frames recorded over `seconds` (first to last) in real time, at
/// most 1000 per second; 10 per second for a single frame or no time.
pub fn real_time_fps(frames: usize, seconds: f64) -> f64 {
    if frames > 1 && seconds > 0.0 {
        ((frames - 1) as f64 / seconds).min(1000.0)
    } else {
        10.0
    }
}

/// Writes `frames` (one size, RGBA composited as they are) as an 8-bit APNG that shows each
/// for `1/fps` seconds, rounded to the millisecond, and loops for ever.
pub fn write_apng<W: Write>(w: W, frames: &[Image], fps: f64) -> std::io::Result<()> {
    let invalid = |m: String| std::io::Error::new(std::io::ErrorKind::InvalidInput, m);
    let first = frames.first().ok_or_else(|| invalid("an animation needs at least one frame".into()))?;
    if let Some((i, f)) = frames.iter().enumerate().find(|(_, f)| (f.width, f.height) != (first.width, first.height)) {
        return Err(invalid(format!(
            "frame {i} is {}×{} pixels, frame 0 {}×{}: an animation's frames share one size",
            f.width, f.height, first.width, first.height
        )));
    }
    let bytes: Vec<Vec<u8>> = frames.iter().map(Image::rgba8).collect();
    write_frames(w, (first.width, first.height), png::ColorType::Rgba, &bytes, fps)
}

/// [`write_apng`] for frames of 8-bit RGB bytes (rows from the top), each `width × height`.
pub fn write_apng_rgb<W: Write>(w: W, width: u32, height: u32, frames: &[Vec<u8>], fps: f64) -> std::io::Result<()> {
    write_frames(w, (width, height), png::ColorType::Rgb, frames, fps)
}

fn write_frames<W: Write>(
    w: W,
    (width, height): (u32, u32),
    colour: png::ColorType,
    frames: &[Vec<u8>],
    fps: f64,
) -> std::io::Result<()> {
    let invalid = |m: String| std::io::Error::new(std::io::ErrorKind::InvalidInput, m);
    if frames.is_empty() {
        return Err(invalid("an animation needs at least one frame".into()));
    }
    let size = colour.samples() * width as usize * height as usize;
    if let Some(i) = frames.iter().position(|f| f.len() != size) {
        return Err(invalid(format!("frame {i} has {} bytes, a {width}×{height} frame {size}", frames[i].len())));
    }
    if !(fps.is_finite() && fps > 0.0 && fps <= 1000.0) {
        return Err(invalid(format!("{fps} frames per second: must be in (0, 1000]")));
    }
    let count = u32::try_from(frames.len()).map_err(|_| invalid(format!("{} frames: too many", frames.len())))?;
    let mut enc = png::Encoder::new(w, width, height);
    enc.set_color(colour);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    enc.set_animated(count, 0).map_err(std::io::Error::other)?;
    let ms = (1000.0 / fps).round().clamp(1.0, f64::from(u16::MAX)) as u16;
    enc.set_frame_delay(ms, 1000).map_err(std::io::Error::other)?;
    let mut writer = enc.write_header().map_err(std::io::Error::other)?;
    for f in frames {
        writer.write_image_data(f).map_err(std::io::Error::other)?;
    }
    writer.finish().map_err(std::io::Error::other)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(value: f32) -> Image {
        let mut im = Image::new(3, 2);
        for (i, v) in im.rgba.iter_mut().enumerate() {
            *v = if i % 4 == 3 { 1.0 } else { value * (1 + i % 4) as f32 / 4.0 };
        }
        im
    }

    /// What is written reads back through the `png` crate's decoder (not our code) as the same
    /// frames, the frame count and loop in its animation control, the delay in each frame's.
    #[test]
    fn frames_round_trip_through_a_png_decoder() {
        let frames = [frame(0.2), frame(0.6), frame(1.0)];
        let mut bytes = Vec::new();
        write_apng(&mut bytes, &frames, 8.0).unwrap();
        let mut reader = png::Decoder::new(std::io::Cursor::new(bytes)).read_info().unwrap();
        let control = reader.info().animation_control.expect("an animation control chunk");
        assert_eq!((control.num_frames, control.num_plays), (3, 0));
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        for f in &frames {
            let info = reader.next_frame(&mut buf).unwrap();
            assert_eq!((info.width, info.height), (3, 2));
            assert_eq!(&buf[..info.buffer_size()], &f.rgba8()[..]);
            let fc = reader.info().frame_control.expect("a frame control chunk");
            assert_eq!((fc.delay_num, fc.delay_den), (125, 1000));
        }
    }

    #[test]
    fn real_time_is_frames_over_their_span() {
        assert_eq!(real_time_fps(55, 5.4), 10.0);
        assert_eq!(real_time_fps(3, 0.5), 4.0);
        assert_eq!(real_time_fps(1, 0.0), 10.0);
        assert_eq!(real_time_fps(5, 0.0), 10.0);
        assert_eq!(real_time_fps(5000, 1e-3), 1000.0);
    }

    #[test]
    fn frames_of_two_sizes_and_a_zero_rate_are_refused() {
        let mut sink = Vec::new();
        let e = write_apng(&mut sink, &[frame(0.1), Image::new(2, 2)], 10.0).unwrap_err();
        assert!(e.to_string().contains("frame 1 is 2×2"), "{e}");
        let e = write_apng(&mut sink, &[frame(0.1)], 0.0).unwrap_err();
        assert!(e.to_string().contains("frames per second"), "{e}");
        assert!(write_apng(&mut sink, &[], 10.0).is_err());
        let e = write_apng_rgb(&mut sink, 2, 2, &[vec![0; 12], vec![0; 11]], 10.0).unwrap_err();
        assert!(e.to_string().contains("frame 1 has 11 bytes"), "{e}");
    }
}
