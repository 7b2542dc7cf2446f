//! Reading and writing the images and labels of a dataset: RGB8 images (PNG, or JPEG for
//! imports), single-channel L8 label PNGs. PNG encoding uses fixed settings, so the same
//! pixels always give the same bytes.

use std::io::Cursor;
use std::path::Path;

use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{DynamicImage, GrayImage, ImageEncoder, ImageReader, RgbImage};

use crate::classes::is_valid_label;
use crate::error::{DatasetError, Result};

/// Decodes any supported image file (by content, not by extension).
pub fn read_image(path: &Path) -> Result<DynamicImage> {
    let bytes = std::fs::read(path).map_err(|e| DatasetError::io(path, e))?;
    decode_image(path, &bytes)
}

/// Decodes image bytes read from `path` (named in the error).
pub fn decode_image(path: &Path, bytes: &[u8]) -> Result<DynamicImage> {
    ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| DatasetError::io(path, e))?
        .decode()
        .map_err(|e| DatasetError::image(path, format!("not a readable image: {e}")))
}

/// Reads an image as RGB8 (grey or RGBA images are converted; alpha is dropped).
pub fn read_rgb(path: &Path) -> Result<RgbImage> {
    Ok(read_image(path)?.into_rgb8())
}

/// Reads a label: an 8-bit single-channel image whose values are ids. Colour labels are
/// refused rather than guessed at.
pub fn read_label(path: &Path) -> Result<GrayImage> {
    match read_image(path)? {
        DynamicImage::ImageLuma8(label) => Ok(label),
        other => Err(DatasetError::image(
            path,
            format!(
                "a label must be a single-channel 8-bit image of class ids, not {:?}",
                other.color()
            ),
        )),
    }
}

/// Reads a label of our class table and checks its size and values.
pub fn read_class_label(path: &Path, width: u32, height: u32) -> Result<GrayImage> {
    let label = read_label(path)?;
    check_label_size(path, &label, width, height)?;
    if let Some(bad) = label.as_raw().iter().copied().find(|&v| !is_valid_label(v)) {
        return Err(DatasetError::invalid(
            path,
            format!("label value {bad} is not a class id (0-4) or 255 (ignore)"),
        ));
    }
    Ok(label)
}

/// Checks that a label has its image's size.
pub fn check_label_size(path: &Path, label: &GrayImage, width: u32, height: u32) -> Result<()> {
    if label.dimensions() == (width, height) {
        Ok(())
    } else {
        Err(DatasetError::invalid(
            path,
            format!(
                "label is {}x{} but its image is {width}x{height}",
                label.width(),
                label.height()
            ),
        ))
    }
}

fn encoder(out: &mut Vec<u8>) -> PngEncoder<&mut Vec<u8>> {
    PngEncoder::new_with_quality(out, CompressionType::Fast, FilterType::Adaptive)
}

/// PNG bytes of an RGB8 image (fast deflate, adaptive filter: fixed, so deterministic).
pub fn encode_rgb_png(image: &RgbImage) -> Vec<u8> {
    let mut out = Vec::new();
    // Writing into a Vec cannot fail, and the buffer's size matches its dimensions.
    let _ = encoder(&mut out).write_image(
        image.as_raw(),
        image.width(),
        image.height(),
        image::ExtendedColorType::Rgb8,
    );
    out
}

/// PNG bytes of a single-channel label.
pub fn encode_label_png(label: &GrayImage) -> Vec<u8> {
    let mut out = Vec::new();
    let _ = encoder(&mut out).write_image(
        label.as_raw(),
        label.width(),
        label.height(),
        image::ExtendedColorType::L8,
    );
    out
}

/// Writes bytes to a file, creating its folder.
pub fn write_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| DatasetError::io(parent, e))?;
    }
    std::fs::write(path, bytes).map_err(|e| DatasetError::io(path, e))
}

/// The colour preview of a label (see [`crate::classes::label_color`]).
pub fn colorize_label(label: &GrayImage) -> RgbImage {
    let mut out = RgbImage::new(label.width(), label.height());
    for (dst, &v) in out.as_mut().chunks_exact_mut(3).zip(label.as_raw()) {
        dst.copy_from_slice(&crate::classes::label_color(v));
    }
    out
}

/// The image with its label's colours blended in (`alpha` of the label colour; ignore
/// pixels stay as they are).
pub fn overlay_label(image: &RgbImage, label: &GrayImage, alpha: f32) -> RgbImage {
    let mut out = image.clone();
    for (dst, &v) in out.as_mut().chunks_exact_mut(3).zip(label.as_raw()) {
        if v == crate::classes::IGNORE {
            continue;
        }
        let c = crate::classes::label_color(v);
        for (d, c) in dst.iter_mut().zip(c) {
            *d = (f32::from(*d) * (1.0 - alpha) + f32::from(c) * alpha).round() as u8;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_round_trip_is_exact_and_deterministic() -> Result<()> {
        let dir = tempfile::tempdir().map_err(|e| DatasetError::io(Path::new("tmp"), e))?;
        let image = RgbImage::from_fn(7, 5, |x, y| image::Rgb([x as u8 * 30, y as u8 * 40, 9]));
        let label = GrayImage::from_fn(7, 5, |x, _| image::Luma([if x < 3 { 0 } else { 255 }]));
        assert_eq!(encode_rgb_png(&image), encode_rgb_png(&image));
        let (ip, lp) = (dir.path().join("i.png"), dir.path().join("l.png"));
        write_bytes(&ip, &encode_rgb_png(&image))?;
        write_bytes(&lp, &encode_label_png(&label))?;
        assert_eq!(read_rgb(&ip)?, image);
        assert_eq!(read_class_label(&lp, 7, 5)?, label);
        assert!(read_class_label(&lp, 5, 7).is_err());
        // An RGB file is not a label.
        assert!(read_label(&ip).is_err());
        Ok(())
    }
}
