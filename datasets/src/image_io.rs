//! Reading and writing the images and labels of a dataset: RGB8 images (PNG, or JPEG for
//! imports), single-channel L8 label PNGs. PNG encoding uses fixed settings, so the same
//! pixels always give the same bytes.

use std::io::Cursor;
use std::path::Path;

use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{DynamicImage, GrayImage, ImageEncoder, ImageFormat, ImageReader, RgbImage};

use crate::classes::is_valid_label;
use crate::error::{DatasetError, Result};

/// Decodes any supported image file (by content, not by extension).
pub fn read_image(path: &Path) -> Result<DynamicImage> {
    let bytes = std::fs::read(path).map_err(|e| DatasetError::io(path, e))?;
    decode_image(path, &bytes)
}

/// Decodes image bytes read from `path` (named in the error). A JPEG or PNG must be whole:
/// a file cut short (a download or copy that stopped) is an error, not the part that made
/// it decoded into a picture that is grey or black below the cut (see [`check_jpeg_whole`]
/// and [`check_png_whole`]).
pub fn decode_image(path: &Path, bytes: &[u8]) -> Result<DynamicImage> {
    let reader = ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| DatasetError::io(path, e))?;
    let whole = match reader.format() {
        Some(ImageFormat::Jpeg) => check_jpeg_whole(bytes),
        Some(ImageFormat::Png) => check_png_whole(bytes),
        _ => Ok(()),
    };
    whole.map_err(|problem| DatasetError::image(path, problem.to_string()))?;
    reader
        .decode()
        .map_err(|e| DatasetError::image(path, format!("not a readable image: {e}")))
}

/// What [`check_jpeg_whole`] says of JPEG data that stops early.
pub const JPEG_TRUNCATED: &str = "truncated JPEG: the data ends before its end-of-image marker";
/// What [`check_png_whole`] says of PNG data that stops early.
pub const PNG_TRUNCATED: &str = "truncated PNG: the data ends before its IEND chunk";

/// Why JPEG or PNG data is not whole ([`check_jpeg_whole`], [`check_png_whole`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NotWhole {
    #[error("not a JPEG: it does not start with a start-of-image marker")]
    NotJpeg,
    #[error("{JPEG_TRUNCATED}")]
    JpegTruncated,
    #[error("corrupt JPEG: the segment of marker FF{marker:02X} at byte {at} has length {length}")]
    JpegSegment {
        marker: u8,
        at: usize,
        length: usize,
    },
    #[error("not a PNG: it does not start with the PNG signature")]
    NotPng,
    #[error("{PNG_TRUNCATED}")]
    PngTruncated,
    #[error("corrupt PNG: the chunk at byte {at} has length {length}, over the PNG limit")]
    PngChunk { at: usize, length: u32 },
}

/// Checks that JPEG data is whole by walking its structure to the end-of-image marker (EOI):
/// the start-of-image marker, then marker segments, each skipped by its length, and after
/// each start-of-scan (SOS) segment its entropy-coded data, up to the next marker that is
/// neither a stuffed byte (FF 00) nor a restart marker (RST0-7). A progressive or
/// multi-scan file has several scans, each walked the same way. Bytes after EOI are
/// allowed (many cameras write some); stray bytes between segments are passed over, as
/// decoders do. An error says what is wrong.
pub fn check_jpeg_whole(bytes: &[u8]) -> std::result::Result<(), NotWhole> {
    const SOI: u8 = 0xD8;
    const EOI: u8 = 0xD9;
    const SOS: u8 = 0xDA;
    const TEM: u8 = 0x01;
    let is_rst = |m: u8| (0xD0..=0xD7).contains(&m);
    if !bytes.starts_with(&[0xFF, SOI]) {
        return Err(NotWhole::NotJpeg);
    }
    let mut pos = 2;
    loop {
        // The next marker: a 0xFF (fill bytes 0xFF may repeat) and the marker's code.
        let Some(ff) = bytes[pos..].iter().position(|&b| b == 0xFF) else {
            return Err(NotWhole::JpegTruncated);
        };
        pos += ff;
        while bytes.get(pos + 1) == Some(&0xFF) {
            pos += 1;
        }
        let Some(&marker) = bytes.get(pos + 1) else {
            return Err(NotWhole::JpegTruncated);
        };
        let at = pos;
        pos += 2;
        match marker {
            EOI => return Ok(()),
            // Markers without a segment, and a stuffed byte outside a scan (stray data).
            SOI | TEM | 0x00 => continue,
            m if is_rst(m) => continue,
            _ => {}
        }
        let Some(length) = bytes.get(pos..pos + 2) else {
            return Err(NotWhole::JpegTruncated);
        };
        let length = usize::from(u16::from_be_bytes([length[0], length[1]]));
        if length < 2 {
            return Err(NotWhole::JpegSegment { marker, at, length });
        }
        pos += length;
        if pos > bytes.len() {
            return Err(NotWhole::JpegTruncated);
        }
        if marker == SOS {
            // The scan's entropy-coded data runs to the first marker that is not a
            // stuffed byte or a restart marker.
            loop {
                let Some(ff) = bytes[pos..].iter().position(|&b| b == 0xFF) else {
                    return Err(NotWhole::JpegTruncated);
                };
                pos += ff;
                match bytes.get(pos + 1) {
                    None => return Err(NotWhole::JpegTruncated),
                    Some(&m) if m == 0x00 || is_rst(m) => pos += 2,
                    // Fill bytes before a marker: the outer loop reads past them.
                    Some(_) => break,
                }
            }
        }
    }
}

/// Checks that PNG data is whole by walking its chunks (length, type, data, CRC) to the
/// IEND chunk. Bytes after IEND are allowed. An error says what is wrong.
pub fn check_png_whole(bytes: &[u8]) -> std::result::Result<(), NotWhole> {
    const SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0D, 0x0A, 0x1A, 0x0A];
    if !bytes.starts_with(&SIGNATURE) {
        return Err(NotWhole::NotPng);
    }
    let mut pos = SIGNATURE.len();
    loop {
        let Some(head) = bytes.get(pos..pos + 8) else {
            return Err(NotWhole::PngTruncated);
        };
        let length = u32::from_be_bytes([head[0], head[1], head[2], head[3]]);
        let kind = [head[4], head[5], head[6], head[7]];
        if length > 0x7FFF_FFFF {
            return Err(NotWhole::PngChunk { at: pos, length });
        }
        // Length, type, data and CRC.
        let end = pos + 12 + length as usize;
        if end > bytes.len() {
            return Err(NotWhole::PngTruncated);
        }
        if &kind == b"IEND" {
            return Ok(());
        }
        pos = end;
    }
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

    /// A picture with detail everywhere, so its JPEG is some kilobytes.
    fn busy_image(width: u32, height: u32) -> RgbImage {
        RgbImage::from_fn(width, height, |x, y| {
            image::Rgb([
                (x * 7 + y * 3) as u8,
                ((x ^ y) * 5) as u8,
                (x * y % 251) as u8,
            ])
        })
    }

    /// Baseline JPEG bytes from the image crate's encoder.
    fn jpeg(image: &RgbImage) -> Vec<u8> {
        let mut out = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 90)
            .encode_image(image)
            .expect("encoding into a Vec");
        out
    }

    fn message(result: Result<DynamicImage>) -> String {
        match result {
            Ok(image) => panic!("accepted: a {}x{} image", image.width(), image.height()),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn a_cut_jpeg_is_refused_naming_the_file_and_the_whole_one_is_read() {
        let image = busy_image(96, 64);
        let bytes = jpeg(&image);
        assert!(bytes.len() > 2000, "{} bytes", bytes.len());
        let path = Path::new("photos/cut.jpg");
        let whole = decode_image(path, &bytes).expect("the whole JPEG");
        assert_eq!((whole.width(), whole.height()), (96, 64));

        // Cut in the scan data (the image crate alone decodes these into a picture, grey
        // below the cut), and short of the last byte.
        for len in [700, bytes.len() / 2, bytes.len() - 1] {
            let err = message(decode_image(path, &bytes[..len]));
            assert_eq!(
                err, "photos/cut.jpg: truncated JPEG: the data ends before its end-of-image marker",
                "cut to {len}"
            );
        }
        // No cut anywhere passes, down to the last byte of the end-of-image marker.
        for len in 0..bytes.len() {
            assert!(
                check_jpeg_whole(&bytes[..len]).is_err(),
                "cut to {len} bytes"
            );
        }
    }

    #[test]
    fn a_jpeg_with_bytes_after_its_end_is_read() {
        let image = busy_image(48, 32);
        let mut bytes = jpeg(&image);
        let clean = decode_image(Path::new("a.jpg"), &bytes)
            .expect("the JPEG")
            .into_rgb8();
        // What cameras append after the end-of-image marker (padding, a second marker).
        bytes.extend_from_slice(b"\0\0\0camera trailer \xff\xd8\xff\xe1 more");
        assert_eq!(check_jpeg_whole(&bytes), Ok(()));
        let read = decode_image(Path::new("a.jpg"), &bytes)
            .expect("trailing bytes are fine")
            .into_rgb8();
        assert_eq!(read, clean);
    }

    /// Marker structure only (no decodable picture): a progressive-style file with two scans
    /// whose data holds stuffed bytes and restart markers, fill bytes before a marker, and a
    /// segment after the first scan.
    #[test]
    fn the_walk_crosses_scans_stuffing_restarts_and_fill_bytes() {
        let mut bytes = vec![0xFF, 0xD8];
        bytes.extend([0xFF, 0xE0, 0x00, 0x06, b'J', b'F', b'I', b'F']); // APP0
        bytes.extend([0xFF, 0xC2, 0x00, 0x05, 8, 0xFF, 0xD9]); // SOF2 holding FF D9
        bytes.extend([0xFF, 0xDA, 0x00, 0x03, 1]); // SOS
        bytes.extend([0x12, 0xFF, 0x00, 0x34, 0xFF, 0xD0, 0x56, 0xFF, 0xD7, 0x78]);
        bytes.extend([0xFF, 0xFF, 0xC4, 0x00, 0x03, 0]); // fill, DHT
        bytes.extend([0xFF, 0xDA, 0x00, 0x03, 2]); // SOS
        bytes.extend([0x9A, 0xFF, 0x00, 0xFF, 0x00, 0xBC]);
        bytes.extend([0xFF, 0xD9]);
        assert_eq!(check_jpeg_whole(&bytes), Ok(()));
        for len in 0..bytes.len() {
            assert!(
                check_jpeg_whole(&bytes[..len]).is_err(),
                "cut to {len} bytes"
            );
        }
        assert_eq!(
            check_jpeg_whole(&bytes[..bytes.len() - 2]),
            Err(NotWhole::JpegTruncated)
        );
        // A segment length below 2 is corrupt, not truncated.
        let mut bad = bytes.clone();
        bad[4..6].copy_from_slice(&[0, 1]);
        let err = check_jpeg_whole(&bad).expect_err("length 1");
        assert!(err.to_string().starts_with("corrupt JPEG: "), "{err}");
    }

    /// A progressive JPEG (ten scans, a restart marker after every MCU; made with
    /// libjpeg-turbo's `cjpeg -progressive -restart 1`) is read, and refused when cut.
    #[test]
    fn a_progressive_jpeg_with_restarts_is_read_and_refused_when_cut() {
        let bytes = include_bytes!("../tests/data/progressive_restart.jpg");
        let path = Path::new("progressive_restart.jpg");
        let image = decode_image(path, bytes).expect("the progressive JPEG");
        assert_eq!((image.width(), image.height()), (64, 48));
        for len in 0..bytes.len() {
            assert!(
                check_jpeg_whole(&bytes[..len]).is_err(),
                "cut to {len} bytes"
            );
        }
        let err = message(decode_image(path, &bytes[..bytes.len() * 2 / 3]));
        assert!(err.contains("truncated JPEG"), "{err}");
    }

    #[test]
    fn a_cut_png_is_refused_and_bytes_after_its_end_are_fine() {
        let image = busy_image(64, 48);
        let bytes = encode_rgb_png(&image);
        let path = Path::new("cut.png");
        assert_eq!(read_back(path, &bytes), image);
        // Cut inside the image data, just before the IEND chunk (all pixels there), and in
        // IEND's checksum (the image crate alone reads that last one).
        for len in [bytes.len() / 2, bytes.len() - 12, bytes.len() - 1] {
            let err = message(decode_image(path, &bytes[..len]));
            assert_eq!(
                err, "cut.png: truncated PNG: the data ends before its IEND chunk",
                "cut to {len}"
            );
        }
        for len in 0..bytes.len() {
            assert!(
                check_png_whole(&bytes[..len]).is_err(),
                "cut to {len} bytes"
            );
        }
        let mut trailing = bytes.clone();
        trailing.extend_from_slice(b"trailer");
        assert_eq!(read_back(path, &trailing), image);
    }

    fn read_back(path: &Path, bytes: &[u8]) -> RgbImage {
        decode_image(path, bytes).expect("a whole PNG").into_rgb8()
    }

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
