//! RGB images and their PNG files: the base station's top-down views and the evaluation's figures.
//!
//! PNG only, 8-bit RGB only, written with the `png` crate directly (the settings a general image crate
//! uses by default: fast deflate, adaptive filtering), so the build doesn't carry every image codec.

use std::io::{BufReader, BufWriter, Write};
use std::path::Path;

/// An 8-bit RGB image, row-major, top row first.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RgbImage {
    width: u32,
    height: u32,
    data: Vec<u8>,
}

impl RgbImage {
    /// A `width` × `height` image filled with `colour`.
    pub fn from_pixel(width: u32, height: u32, colour: [u8; 3]) -> Self {
        let n = width as usize * height as usize;
        RgbImage {
            width,
            height,
            data: colour.repeat(n),
        }
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    fn index(&self, x: u32, y: u32) -> usize {
        assert!(
            x < self.width && y < self.height,
            "pixel ({x}, {y}) outside a {}×{} image",
            self.width,
            self.height
        );
        (y as usize * self.width as usize + x as usize) * 3
    }

    /// The colour at (x, y); panics outside the image.
    pub fn get_pixel(&self, x: u32, y: u32) -> [u8; 3] {
        let i = self.index(x, y);
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    /// Set the colour at (x, y); panics outside the image.
    pub fn put_pixel(&mut self, x: u32, y: u32, colour: [u8; 3]) {
        let i = self.index(x, y);
        self.data[i..i + 3].copy_from_slice(&colour);
    }

    /// The pixels, RGB RGB …, row-major.
    pub fn as_raw(&self) -> &[u8] {
        &self.data
    }

    /// Write as a PNG file.
    pub fn save_png(&self, path: &Path) -> std::io::Result<()> {
        write_png(path, self.width, self.height, &self.data)
    }

    /// Read an 8-bit RGB PNG file (what [`RgbImage::save_png`] writes).
    pub fn read_png(path: &Path) -> std::io::Result<Self> {
        let file = std::fs::File::open(path)?;
        let mut reader = png::Decoder::new(BufReader::new(file))
            .read_info()
            .map_err(std::io::Error::other)?;
        let mut data = vec![0; reader.output_buffer_size()];
        let info = reader
            .next_frame(&mut data)
            .map_err(std::io::Error::other)?;
        if (info.color_type, info.bit_depth) != (png::ColorType::Rgb, png::BitDepth::Eight) {
            return Err(std::io::Error::other(format!(
                "{}: a {:?} {:?}-bit PNG, expected 8-bit RGB",
                path.display(),
                info.color_type,
                info.bit_depth as u8
            )));
        }
        data.truncate(info.buffer_size());
        Ok(RgbImage {
            width: info.width,
            height: info.height,
            data,
        })
    }
}

/// Write `rgb` (`width` × `height` pixels, RGB RGB …, row-major) as a PNG file.
pub fn write_png(path: &Path, width: u32, height: u32, rgb: &[u8]) -> std::io::Result<()> {
    let file = std::fs::File::create(path)?;
    let mut out = BufWriter::new(file);
    let mut encoder = png::Encoder::new(&mut out, width, height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.set_compression(png::Compression::Fast);
    encoder.set_filter(png::FilterType::Sub);
    encoder.set_adaptive_filter(png::AdaptiveFilterType::Adaptive);
    let mut writer = encoder.write_header().map_err(std::io::Error::other)?;
    writer
        .write_image_data(rgb)
        .map_err(std::io::Error::other)?;
    writer.finish().map_err(std::io::Error::other)?;
    out.flush()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip() {
        let mut img = RgbImage::from_pixel(3, 2, [255, 255, 255]);
        img.put_pixel(2, 1, [1, 2, 3]);
        assert_eq!(img.get_pixel(2, 1), [1, 2, 3]);
        assert_eq!(img.get_pixel(0, 0), [255; 3]);
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.png");
        img.save_png(&p).unwrap();
        assert!(std::fs::read(&p).unwrap().starts_with(b"\x89PNG\r\n\x1a\n"));
        assert_eq!(RgbImage::read_png(&p).unwrap(), img);
        assert!(RgbImage::read_png(&dir.path().join("missing.png")).is_err());
        std::fs::write(&p, b"not a png").unwrap();
        assert!(RgbImage::read_png(&p).is_err());
    }

    #[test]
    #[should_panic(expected = "outside")]
    fn outside_panics() {
        RgbImage::from_pixel(2, 2, [0; 3]).get_pixel(2, 0);
    }
}
