//! A sequence's outputs: numbered frames, a contact sheet (every frame,
//! small, in a grid) and an animated PNG preview, as a person reviewing a
//! shot looks at them.

use anyhow::Context;
use image::RgbImage;
use std::path::{Path, PathBuf};

/// Widest contact sheet, pixels.
pub const SHEET_WIDTH: u32 = 1600;
/// Largest side of an animated preview's frame, pixels.
pub const PREVIEW_SIDE: u32 = 480;
/// Frames per second of the animated preview.
pub const PREVIEW_FPS: u16 = 12;

/// Frame `i` of a sequence written to `out`: `out`'s stem, a dash, the
/// frame number in four digits, and `ext` (`render.png` → `render-0007.png`).
pub fn numbered(out: &Path, i: usize, ext: &str) -> PathBuf {
    let stem =
        out.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "frame".into());
    out.with_file_name(format!("{stem}-{i:04}.{ext}"))
}

/// `out` with `-suffix` added to its stem, as a PNG.
pub fn beside(out: &Path, suffix: &str) -> PathBuf {
    let stem =
        out.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "frame".into());
    out.with_file_name(format!("{stem}-{suffix}.png"))
}

/// Decodes the PNG frames of a sequence.
pub fn decode(frames: &[Vec<u8>]) -> anyhow::Result<Vec<RgbImage>> {
    frames
        .iter()
        .enumerate()
        .map(|(i, png)| {
            Ok(image::load_from_memory_with_format(png, image::ImageFormat::Png)
                .with_context(|| format!("frame {i}"))?
                .to_rgb8())
        })
        .collect()
}

/// Every frame in a grid, row by row, scaled to fit [`SHEET_WIDTH`], with
/// a dark gap between them.
pub fn contact_sheet(frames: &[RgbImage]) -> RgbImage {
    let n = frames.len().max(1) as u32;
    let cols = (n as f64).sqrt().ceil() as u32;
    let rows = n.div_ceil(cols);
    let (w, h) = frames.first().map_or((1, 1), |f| f.dimensions());
    let gap = 4;
    let cell_w = ((SHEET_WIDTH - gap * (cols + 1)) / cols).min(w).max(1);
    let cell_h = ((cell_w as u64 * h as u64) / w.max(1) as u64).max(1) as u32;
    let mut sheet = RgbImage::from_pixel(
        gap + cols * (cell_w + gap),
        gap + rows * (cell_h + gap),
        image::Rgb([24, 24, 24]),
    );
    for (i, f) in frames.iter().enumerate() {
        let small =
            image::imageops::resize(f, cell_w, cell_h, image::imageops::FilterType::Triangle);
        let (c, r) = (i as u32 % cols, i as u32 / cols);
        image::imageops::replace(
            &mut sheet,
            &small,
            (gap + c * (cell_w + gap)) as i64,
            (gap + r * (cell_h + gap)) as i64,
        );
    }
    sheet
}

/// Writes the frames as an animated PNG (APNG: browsers play it, other
/// viewers show the first frame) at [`PREVIEW_FPS`], looping, each frame
/// scaled to at most [`PREVIEW_SIDE`] on its longer side.
pub fn write_animation(frames: &[RgbImage], path: &Path) -> anyhow::Result<()> {
    anyhow::ensure!(!frames.is_empty(), "no frames to animate");
    let (w, h) = frames[0].dimensions();
    let scale = (PREVIEW_SIDE as f64 / w.max(h) as f64).min(1.0);
    let (pw, ph) =
        (((w as f64 * scale).round() as u32).max(1), ((h as f64 * scale).round() as u32).max(1));
    let file =
        std::fs::File::create(path).with_context(|| format!("{}: cannot write", path.display()))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), pw, ph);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_animated(frames.len() as u32, 0)?;
    enc.set_frame_delay(1, PREVIEW_FPS)?;
    let mut writer = enc.write_header()?;
    for f in frames {
        anyhow::ensure!(f.dimensions() == (w, h), "the frames of a sequence differ in size");
        let small = if (pw, ph) == (w, h) {
            f.clone()
        } else {
            image::imageops::resize(f, pw, ph, image::imageops::FilterType::Triangle)
        };
        writer.write_image_data(small.as_raw())?;
    }
    writer.finish()?;
    Ok(())
}

/// Writes a sequence's frames (numbered PNGs, and EXRs where given), its
/// contact sheet and its animated preview beside `out`; returns the paths
/// written, frames first.
pub fn write_all(
    out: &Path,
    pngs: &[Vec<u8>],
    exrs: Option<&[Vec<u8>]>,
) -> anyhow::Result<Vec<PathBuf>> {
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("{}: cannot create", dir.display()))?;
    }
    let mut written = Vec::new();
    for (i, png) in pngs.iter().enumerate() {
        let p = numbered(out, i, "png");
        std::fs::write(&p, png).with_context(|| format!("{}: cannot write", p.display()))?;
        written.push(p);
    }
    for (i, exr) in exrs.unwrap_or_default().iter().enumerate() {
        let p = numbered(out, i, "exr");
        std::fs::write(&p, exr).with_context(|| format!("{}: cannot write", p.display()))?;
        written.push(p);
    }
    let frames = decode(pngs)?;
    let sheet = beside(out, "contact");
    contact_sheet(&frames)
        .save(&sheet)
        .with_context(|| format!("{}: cannot write", sheet.display()))?;
    written.push(sheet);
    let anim = beside(out, "preview");
    write_animation(&frames, &anim)?;
    written.push(anim);
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sequence_becomes_numbered_frames_a_sheet_and_an_animation() {
        let dir = std::env::temp_dir().join(format!("sylva-seq-{}", std::process::id()));
        let frames: Vec<RgbImage> = (0..5u8)
            .map(|i| RgbImage::from_pixel(64, 32, image::Rgb([i * 50, 100, 200 - i * 40])))
            .collect();
        let pngs: Vec<Vec<u8>> = frames
            .iter()
            .map(|f| {
                let mut b = std::io::Cursor::new(Vec::new());
                f.write_to(&mut b, image::ImageFormat::Png).unwrap();
                b.into_inner()
            })
            .collect();
        let out = dir.join("shot.png");
        let written = write_all(&out, &pngs, None).unwrap();
        assert_eq!(written[0], dir.join("shot-0000.png"));
        assert_eq!(written[4], dir.join("shot-0004.png"));
        assert_eq!(
            image::open(&written[3]).unwrap().to_rgb8().get_pixel(5, 5),
            &image::Rgb([150, 100, 80])
        );
        // Five frames: three columns, two rows.
        let sheet = image::open(dir.join("shot-contact.png")).unwrap().to_rgb8();
        assert_eq!(sheet.dimensions(), (4 + 3 * (64 + 4), 4 + 2 * (32 + 4)));
        assert_eq!(
            sheet.get_pixel(4 + 68 + 10, 4 + 36 + 10),
            &image::Rgb([200, 100, 40]),
            "frame 4 is second in the second row"
        );
        // The animation: five frames, each the frame it stands for.
        let decoder = png::Decoder::new(std::io::BufReader::new(
            std::fs::File::open(dir.join("shot-preview.png")).unwrap(),
        ));
        let mut reader = decoder.read_info().unwrap();
        assert_eq!(reader.info().animation_control().map(|a| a.num_frames), Some(5));
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        for i in 0..5u8 {
            reader.next_frame(&mut buf).unwrap();
            assert_eq!(&buf[..3], &[i * 50, 100, 200 - i * 40], "frame {i}");
        }
        std::fs::remove_dir_all(&dir).ok();
    }
}
