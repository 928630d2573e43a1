//! Image reading for the engine: TIFF, PNG, BMP and JPEG (8 or 16 bit) into a `u16` array
//! (8-bit values are kept as they are, not rescaled; colour images are converted to grey as
//! `rspiv.io` does, `0.299 R + 0.587 G + 0.114 B` in the image's own bit depth, rounded; an
//! alpha channel is dropped). JPEG is lossy: `rspiv piv` warns about it, the engine reads it
//! as it is.

use ndarray::Array2;
use std::path::Path;

/// The warning for a JPEG frame (the words of `rspiv.io`).
pub const JPEG_LOSSY: &str = "JPEG is lossy: its 8 x 8 px block artefacts add error to \
    sub-pixel displacements and marker centres; record TIFF or PNG where you can";

/// Read a grey image as `image[y, x]` counts. Errors name the file.
pub fn read_u16(path: &Path) -> Result<Array2<u16>, String> {
    let name = path.display();
    let reader = image::ImageReader::open(path)
        .map_err(|e| format!("{name}: cannot open: {e}"))?
        .with_guessed_format()
        .map_err(|e| format!("{name}: cannot read: {e}"))?;
    if reader.format() == Some(image::ImageFormat::Jpeg) {
        eprintln!("warning: {name}: {JPEG_LOSSY}");
    }
    let img = reader
        .decode()
        .map_err(|e| format!("{name}: cannot decode (TIFF, PNG, BMP or JPEG expected): {e}"))?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    let data: Vec<u16> = match img {
        image::DynamicImage::ImageLuma8(g) => g.into_raw().into_iter().map(u16::from).collect(),
        image::DynamicImage::ImageLuma16(g) => g.into_raw(),
        other => {
            let c = other.color();
            let eight = c.bytes_per_pixel() == c.channel_count();
            match (c.has_color(), eight) {
                (false, true) => other
                    .to_luma8()
                    .into_raw()
                    .into_iter()
                    .map(u16::from)
                    .collect(),
                (false, false) => other.to_luma16().into_raw(),
                (true, true) => grey(other.to_rgb8().pixels().map(|p| p.0.map(f32::from))),
                (true, false) => grey(other.to_rgb16().pixels().map(|p| p.0.map(f32::from))),
            }
        }
    };
    Array2::from_shape_vec((h, w), data).map_err(|e| format!("{name}: bad image shape: {e}"))
}

/// `0.299 R + 0.587 G + 0.114 B` of each pixel, rounded (the weights of `rspiv.io`).
fn grey(rgb: impl Iterator<Item = [f32; 3]>) -> Vec<u16> {
    rgb.map(|[r, g, b]| (0.299 * r + 0.587 * g + 0.114 * b).round() as u16)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn path(name: &str) -> std::path::PathBuf {
        std::env::temp_dir().join(format!("rspiv-imageio-{}-{name}", std::process::id()))
    }

    #[test]
    fn colour_and_alpha_become_grey_in_their_own_depth() {
        // 8-bit colour: Rec. 601 luma of the 8-bit values (not rescaled to 16 bits)
        let rgb = image::RgbImage::from_fn(3, 2, |x, y| {
            image::Rgb([(10 * x) as u8, 200, (y * 50) as u8])
        });
        let p = path("rgb.png");
        rgb.save(&p).unwrap();
        let g = read_u16(&p).unwrap();
        assert_eq!(g.dim(), (2, 3));
        for ((y, x), &v) in g.indexed_iter() {
            let want = (0.299 * (10 * x) as f32 + 0.587 * 200.0 + 0.114 * (y * 50) as f32).round();
            assert_eq!(v, want as u16, "pixel {x},{y}");
        }
        // 8-bit grey with alpha: the grey values
        let la = image::GrayAlphaImage::from_fn(4, 1, |x, _| image::LumaA([(60 * x) as u8, 7]));
        let p2 = path("la.png");
        la.save(&p2).unwrap();
        assert_eq!(
            read_u16(&p2).unwrap().into_raw_vec_and_offset().0,
            vec![0, 60, 120, 180]
        );
        // 16-bit colour keeps its depth
        let rgb16 = image::ImageBuffer::<image::Rgb<u16>, Vec<u16>>::from_pixel(
            2,
            2,
            image::Rgb([4000, 4000, 4000]),
        );
        let p3 = path("rgb16.png");
        rgb16.save(&p3).unwrap();
        assert!(read_u16(&p3).unwrap().iter().all(|&v| v == 4000));
        for p in [p, p2, p3] {
            std::fs::remove_file(p).ok();
        }
    }

    #[test]
    fn jpeg_frames_are_read() {
        // a smooth 8-bit ramp survives JPEG at quality 95 within a few counts
        let ramp = image::GrayImage::from_fn(64, 48, |x, y| image::Luma([(2 * x + y) as u8]));
        let p = path("ramp.jpg");
        let mut f = std::fs::File::create(&p).unwrap();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut f, 95)
            .encode_image(&ramp)
            .unwrap();
        drop(f);
        let g = read_u16(&p).unwrap();
        assert_eq!(g.dim(), (48, 64));
        let worst = g
            .indexed_iter()
            .map(|((y, x), &v)| (v as i32 - (2 * x + y) as i32).abs())
            .max()
            .unwrap();
        assert!(worst <= 3, "JPEG ramp off by {worst} counts");
        std::fs::remove_file(p).ok();
        // not an image at all: one line naming the file
        let bad = path("bad.jpg");
        std::fs::write(&bad, b"not a jpeg").unwrap();
        let e = read_u16(&bad).unwrap_err();
        assert!(e.contains("bad.jpg") && !e.contains('\n'), "{e}");
        std::fs::remove_file(bad).ok();
    }
}
