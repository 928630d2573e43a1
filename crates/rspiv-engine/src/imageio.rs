//! Image reading for the engine: grey TIFF, PNG and BMP (8 or 16 bit) into a `u16` array
//! (8-bit values are kept as they are, not rescaled; colour images are converted to luma).

use ndarray::Array2;
use std::path::Path;

/// Read a grey image as `image[y, x]` counts. Errors name the file.
pub fn read_u16(path: &Path) -> Result<Array2<u16>, String> {
    let name = path.display();
    let img = image::ImageReader::open(path)
        .map_err(|e| format!("{name}: cannot open: {e}"))?
        .with_guessed_format()
        .map_err(|e| format!("{name}: cannot read: {e}"))?
        .decode()
        .map_err(|e| format!("{name}: cannot decode (TIFF, PNG or BMP expected): {e}"))?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    let data: Vec<u16> = match img {
        image::DynamicImage::ImageLuma8(g) => g.into_raw().into_iter().map(u16::from).collect(),
        image::DynamicImage::ImageLuma16(g) => g.into_raw(),
        other => other.to_luma16().into_raw(),
    };
    Array2::from_shape_vec((h, w), data).map_err(|e| format!("{name}: bad image shape: {e}"))
}
