//! 8-bit grayscale images and PNG decoding.

use std::path::Path;

/// An 8-bit grayscale image, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct GrayImage {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// `width × height` values, row by row.
    pub data: Vec<u8>,
}

impl GrayImage {
    /// The value at column `x`, row `y`, or `None` outside the image.
    pub fn get(&self, x: u32, y: u32) -> Option<u8> {
        if x < self.width && y < self.height {
            self.data
                .get(y as usize * self.width as usize + x as usize)
                .copied()
        } else {
            None
        }
    }
}

/// How a colour image becomes the 8-bit grey image the detector reads (grey images are
/// taken as they are).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum GrayConversion {
    /// Rec. 601 luma: 0.299 R + 0.587 G + 0.114 B.
    #[default]
    Luma,
    /// One channel: 0 red, 1 green, 2 blue.
    Channel(usize),
    /// Distance to a dot colour (RGB, 8-bit levels), saturated at 255: dots of that
    /// colour come out dark whatever their brightness.
    DotColor([f64; 3]),
}

impl GrayConversion {
    /// The grey level of one 8-bit RGB pixel.
    pub fn convert(&self, rgb: [u8; 3]) -> u8 {
        let [r, g, b] = rgb.map(f64::from);
        match *self {
            GrayConversion::Luma => (0.299 * r + 0.587 * g + 0.114 * b).round() as u8,
            GrayConversion::Channel(c) => rgb[c.min(2)],
            GrayConversion::DotColor([cr, cg, cb]) => {
                ((r - cr).powi(2) + (g - cg).powi(2) + (b - cb).powi(2))
                    .sqrt()
                    .round()
                    .min(255.0) as u8
            }
        }
    }
}

/// Reads a PNG as 8-bit grayscale: gray is taken as is, 16-bit is scaled down, colour is
/// converted with the Rec. 601 luma weights (0.299 R + 0.587 G + 0.114 B), alpha dropped.
///
/// # Errors
/// The decoder's or the file system's message.
pub fn read_png_gray(path: &Path) -> Result<GrayImage, String> {
    // One read of the whole file (a camera frame is a few hundred kB) costs less than the
    // many small reads of a buffered stream.
    let bytes = std::fs::read(path).map_err(|e| e.to_string())?;
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes.as_slice()));
    decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = decoder.read_info().map_err(|e| e.to_string())?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| "image too large".to_string())?;
    let mut buf = vec![0u8; size];
    let info = reader.next_frame(&mut buf).map_err(|e| e.to_string())?;
    buf.truncate(info.buffer_size());
    let (w, h) = (info.width, info.height);
    let channels = match info.color_type {
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Indexed => return Err("indexed colour was not expanded".into()),
    };
    let data = if channels == 1 {
        buf
    } else {
        buf.chunks_exact(channels)
            .map(|p| {
                if channels == 2 {
                    p[0]
                } else {
                    (0.299 * f64::from(p[0]) + 0.587 * f64::from(p[1]) + 0.114 * f64::from(p[2]))
                        .round() as u8
                }
            })
            .collect()
    };
    if data.len() != w as usize * h as usize {
        return Err(format!("decoded {} pixels for {w}×{h}", data.len()));
    }
    Ok(GrayImage {
        width: w,
        height: h,
        data,
    })
}
