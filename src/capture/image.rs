//! Image files to the 8-bit grey images the detector reads, by content (not extension):
//! PNG (1 to 16 bits, grey or colour, with or without alpha), JPEG and TIFF.
//!
//! - **Limits.** The declared size is checked before any pixel is decoded: at most
//!   [`MAX_IMAGE_SIDE_PX`] pixels a side and [`MAX_IMAGE_BYTES`] for the decoded image (and
//!   for the file), so a tiny file that declares a huge image is an error, not an abort.
//! - **Colour** becomes grey through a [`GrayConversion`] (Rec. 601 luma by default);
//!   alpha is ignored.
//! - **16-bit samples** are scaled to 8 bits by the image's significant bits, chosen in
//!   this order:
//!   1. every sample a multiple of 257 (an 8-bit image stored as 16-bit, `v × 257`): the
//!      sample divided by 257, exactly;
//!   2. the PNG `sBIT` chunk, when it is present and every sample fits in that many bits
//!      (a writer that stored 12-bit sensor values without scaling them up);
//!   3. otherwise the smallest common sensor depth, 8, 10, 12, 14 or 16 bits, that holds
//!      the largest sample: a 12-bit camera's frame (largest sample below 4096) uses its
//!      full range.
//!
//!   A `b`-bit sample `v` becomes `round(v · 255 / (2^b − 1))`. The choice is made per
//!   image: a 12-bit frame darker than 1024 everywhere is read as 10-bit (twice as bright),
//!   which moves no dot centre, since detection looks at contrast, not absolute levels.
//! - **Float** samples (32-bit TIFF) are taken as 0..1 levels.
//!
//! PNG files are decoded with the `png` crate directly (the fastest path, kept for replay);
//! JPEG and TIFF with the `image` crate under [`image::Limits`].

use std::io::Cursor;
use std::path::{Path, PathBuf};

/// Largest image width or height the reader accepts, pixels.
pub const MAX_IMAGE_SIDE_PX: u32 = 16384;

/// Largest decoded image (all channels and bits) and largest image file the reader
/// accepts, bytes: 1 GiB.
pub const MAX_IMAGE_BYTES: u64 = 1 << 30;

pub use crate::gray_image::GrayImage;

/// How a colour image becomes the 8-bit grey image the detector reads (grey images are
/// taken as they are).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum GrayConversion {
    /// Rec. 601 luma: 0.299 R + 0.587 G + 0.114 B.
    #[default]
    Luma,
    /// One channel: 0 red, 1 green, 2 blue.
    Channel(usize),
    /// Difference of hue from a dot colour (RGB, 8-bit levels): `255 · sin θ`, θ the angle
    /// between the pixel's RGB vector and the dot colour's, so that dots of that colour
    /// come out dark whatever the light on them (a dot in the boom's shadow as dark as a
    /// lit one, where a distance to the colour would make it grey), and skin of any
    /// brightness comes out bright. Below a quarter of the dot colour's brightness hue is
    /// lost in the noise: such pixels fade to white (the pupils and the mouth's inside are
    /// not taken for ink).
    DotColor([f64; 3]),
}

impl GrayConversion {
    /// The grey level of one 8-bit RGB pixel.
    pub fn convert(&self, rgb: [u8; 3]) -> u8 {
        self.convert_levels(rgb.map(f64::from))
    }

    /// The grey level of one RGB pixel given as levels on the 8-bit scale (0..=255, not
    /// necessarily whole: 16-bit and float samples scaled to 8 bits, see the module docs).
    /// For whole levels this is [`GrayConversion::convert`].
    pub fn convert_levels(&self, rgb: [f64; 3]) -> u8 {
        PreparedConversion::new(*self).level(rgb)
    }
}

/// A [`GrayConversion`] with its per-image constants worked out, for the per-pixel loop.
#[derive(Debug, Clone, Copy)]
struct PreparedConversion {
    conversion: GrayConversion,
    /// `DotColor`: the colour, its squared length and the squared brightness below which
    /// hue fades out (a quarter of the colour's).
    colour: [f64; 3],
    colour_sq: f64,
    dim_sq: f64,
}

impl PreparedConversion {
    fn new(conversion: GrayConversion) -> Self {
        let colour = match conversion {
            GrayConversion::DotColor(c) => c,
            _ => [0.0; 3],
        };
        let colour_sq = colour.iter().map(|v| v * v).sum::<f64>().max(1e-18);
        Self {
            conversion,
            colour,
            colour_sq,
            dim_sq: 0.0625 * colour_sq,
        }
    }

    #[inline]
    fn level(&self, rgb: [f64; 3]) -> u8 {
        let [r, g, b] = rgb;
        let level = match self.conversion {
            GrayConversion::Luma => 0.299 * r + 0.587 * g + 0.114 * b,
            GrayConversion::Channel(c) => rgb[c.min(2)],
            GrayConversion::DotColor(_) => {
                let [cr, cg, cb] = self.colour;
                let p_sq = r * r + g * g + b * b;
                let dot = r * cr + g * cg + b * cb;
                // sin θ = √(1 − cos²θ), θ the angle between the pixel and the colour.
                let sin = if p_sq > 0.0 {
                    (1.0 - dot * dot / (p_sq * self.colour_sq)).max(0.0).sqrt()
                } else {
                    1.0
                };
                if p_sq >= self.dim_sq {
                    255.0 * sin
                } else {
                    let lit = (p_sq / self.dim_sq).sqrt();
                    255.0 * (lit * sin + (1.0 - lit))
                }
            }
        };
        // Round half up (levels are never negative after the clamp); NaN becomes 0.
        (level.clamp(0.0, 255.0) + 0.5) as u8
    }
}

/// An image file that cannot be read as an image.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{path}: {message}")]
pub struct ImageReadError {
    /// The file.
    pub path: PathBuf,
    /// What is wrong (the decoder's or the file system's message, or a limit).
    pub message: String,
}

/// Reads an image file (PNG, JPEG or TIFF, recognised by content) as 8-bit grey, colour
/// converted by `conversion` (see the module docs for bit depths, alpha and limits).
///
/// # Errors
/// [`ImageReadError`] naming the file: unreadable, not a supported format, larger than
/// the limits, or corrupt.
pub fn read_gray(path: &Path, conversion: GrayConversion) -> Result<GrayImage, ImageReadError> {
    let err = |message: String| ImageReadError {
        path: path.to_path_buf(),
        message,
    };
    let len = std::fs::metadata(path)
        .map_err(|e| err(e.to_string()))?
        .len();
    if len > MAX_IMAGE_BYTES {
        return Err(err(format!(
            "file of {len} bytes is larger than the {MAX_IMAGE_BYTES} bytes an image may have"
        )));
    }
    // One read of the whole file (a camera frame is a few hundred kB) costs less than the
    // many small reads of a buffered stream.
    let bytes = std::fs::read(path).map_err(|e| err(e.to_string()))?;
    decode_gray(&bytes, conversion).map_err(err)
}

/// Reads an image file as 8-bit grey with Rec. 601 luma for colour: [`read_gray`] with
/// [`GrayConversion::Luma`], its error as a message (the path is the caller's). Despite
/// its name, any format [`read_gray`] reads is accepted.
///
/// # Errors
/// The decoder's or the file system's message.
pub fn read_png_gray(path: &Path) -> Result<GrayImage, String> {
    read_gray(path, GrayConversion::Luma).map_err(|e| e.message)
}

/// Decodes an image held in memory (PNG, JPEG or TIFF, by content) as 8-bit grey.
///
/// # Errors
/// A message saying why the bytes are not a usable image.
pub fn decode_gray(bytes: &[u8], conversion: GrayConversion) -> Result<GrayImage, String> {
    match image::guess_format(bytes) {
        Ok(image::ImageFormat::Png) => decode_png(bytes, conversion),
        Ok(format @ (image::ImageFormat::Jpeg | image::ImageFormat::Tiff)) => {
            decode_with_image(bytes, format, conversion)
        }
        Ok(format) => Err(format!(
            "{} images are not supported (PNG, JPEG and TIFF are)",
            format.to_mime_type()
        )),
        Err(_) => Err("not a PNG, JPEG or TIFF image (unknown file signature)".into()),
    }
}

/// Checks a declared image size against the limits before anything is allocated.
pub(super) fn check_size(width: u32, height: u32, bytes_per_pixel: u64) -> Result<(), String> {
    if width == 0 || height == 0 {
        return Err(format!("image is {width}×{height} pixels"));
    }
    if width > MAX_IMAGE_SIDE_PX || height > MAX_IMAGE_SIDE_PX {
        return Err(format!(
            "image is {width}×{height} pixels, more than the {MAX_IMAGE_SIDE_PX} a side this \
             reader accepts"
        ));
    }
    let bytes = u64::from(width) * u64::from(height) * bytes_per_pixel;
    if bytes > MAX_IMAGE_BYTES {
        return Err(format!(
            "image of {width}×{height} pixels needs {bytes} bytes decoded, more than the \
             {MAX_IMAGE_BYTES} this reader accepts"
        ));
    }
    Ok(())
}

/// Decoded samples of one image, interleaved, `channels` per pixel.
enum Samples {
    U8(Vec<u8>),
    U16(Vec<u16>),
    F32(Vec<f32>),
}

fn decode_png(bytes: &[u8], conversion: GrayConversion) -> Result<GrayImage, String> {
    let limits = png::Limits {
        bytes: usize::try_from(MAX_IMAGE_BYTES).unwrap_or(usize::MAX),
    };
    let mut decoder = png::Decoder::new_with_limits(Cursor::new(bytes), limits);
    // Palette to RGB, grey below 8 bits to 8 bits, tRNS to alpha; 16 bits stay 16.
    decoder.set_transformations(png::Transformations::EXPAND);
    let header = decoder.read_header_info().map_err(|e| e.to_string())?;
    let bytes_per_pixel = 4 * if header.bit_depth == png::BitDepth::Sixteen {
        2
    } else {
        1
    };
    check_size(header.width, header.height, bytes_per_pixel)?;
    let mut reader = decoder.read_info().map_err(|e| e.to_string())?;
    let sbit = reader.info().sbit.as_ref().map(|s| s.to_vec());
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| "image too large".to_string())?;
    let mut buf = vec![0u8; size];
    let info = reader.next_frame(&mut buf).map_err(|e| e.to_string())?;
    buf.truncate(info.buffer_size());
    let channels = match info.color_type {
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Indexed => return Err("indexed colour was not expanded".into()),
    };
    let samples = match info.bit_depth {
        png::BitDepth::Eight => Samples::U8(buf),
        png::BitDepth::Sixteen => Samples::U16(
            buf.chunks_exact(2)
                .map(|b| u16::from_be_bytes([b[0], b[1]]))
                .collect(),
        ),
        depth => return Err(format!("{depth:?} samples were not expanded to 8 bits")),
    };
    // sBIT: one byte per channel; the colour channels' largest is the image's depth.
    let colour_channels = if channels >= 3 { 3 } else { 1 };
    let sbit = sbit.and_then(|s| s.iter().take(colour_channels).max().copied());
    to_gray(
        info.width,
        info.height,
        channels,
        samples,
        sbit.map(u32::from),
        conversion,
    )
}

fn decode_with_image(
    bytes: &[u8],
    format: image::ImageFormat,
    conversion: GrayConversion,
) -> Result<GrayImage, String> {
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIDE_PX);
    limits.max_image_height = Some(MAX_IMAGE_SIDE_PX);
    limits.max_alloc = Some(MAX_IMAGE_BYTES);
    let mut reader = image::ImageReader::with_format(Cursor::new(bytes), format);
    reader.limits(limits);
    let image = reader.decode().map_err(|e| e.to_string())?;
    let (width, height) = (image.width(), image.height());
    use image::DynamicImage as D;
    let (channels, samples) = match image {
        D::ImageLuma8(i) => (1, Samples::U8(i.into_raw())),
        D::ImageLumaA8(i) => (2, Samples::U8(i.into_raw())),
        D::ImageRgb8(i) => (3, Samples::U8(i.into_raw())),
        D::ImageRgba8(i) => (4, Samples::U8(i.into_raw())),
        D::ImageLuma16(i) => (1, Samples::U16(i.into_raw())),
        D::ImageLumaA16(i) => (2, Samples::U16(i.into_raw())),
        D::ImageRgb16(i) => (3, Samples::U16(i.into_raw())),
        D::ImageRgba16(i) => (4, Samples::U16(i.into_raw())),
        D::ImageRgb32F(i) => (3, Samples::F32(i.into_raw())),
        D::ImageRgba32F(i) => (4, Samples::F32(i.into_raw())),
        other => (4, Samples::F32(other.into_rgba32f().into_raw())),
    };
    to_gray(width, height, channels, samples, None, conversion)
}

/// The significant bits of 16-bit samples (module docs, steps 2 and 3); `None` when every
/// sample is a multiple of 257 (an 8-bit image stored as `v × 257`).
fn significant_bits(samples: &[u16], channels: usize, sbit: Option<u32>) -> Option<u32> {
    let colour = |i: &usize| channels < 2 || channels == 3 || i % channels != channels - 1;
    let mut max = 0u16;
    let mut all_257 = true;
    for (_, &v) in samples.iter().enumerate().filter(|(i, _)| colour(i)) {
        max = max.max(v);
        all_257 &= v % 257 == 0;
    }
    if all_257 {
        return None;
    }
    let fits = |bits: u32| u32::from(max) < 1u32 << bits;
    if let Some(b) = sbit.filter(|b| (1..=16).contains(b))
        && fits(b)
    {
        return Some(b);
    }
    Some(
        [8, 10, 12, 14, 16]
            .into_iter()
            .find(|&b| fits(b))
            .unwrap_or(16),
    )
}

fn to_gray(
    width: u32,
    height: u32,
    channels: usize,
    samples: Samples,
    sbit: Option<u32>,
    conversion: GrayConversion,
) -> Result<GrayImage, String> {
    let pixels = width as usize * height as usize;
    let len = match &samples {
        Samples::U8(s) => s.len(),
        Samples::U16(s) => s.len(),
        Samples::F32(s) => s.len(),
    };
    if len != pixels * channels {
        return Err(format!(
            "decoded {len} samples for {width}×{height} pixels of {channels} channels"
        ));
    }
    let data = match samples {
        Samples::U8(s) if channels == 1 => s,
        Samples::U8(s) if channels == 2 => s.chunks_exact(2).map(|p| p[0]).collect(),
        Samples::U8(s) => {
            let prepared = PreparedConversion::new(conversion);
            s.chunks_exact(channels)
                .map(|p| prepared.level([p[0], p[1], p[2]].map(f64::from)))
                .collect()
        }
        Samples::U16(s) => {
            // Full scale of the samples: 65535 for the ×257 case, else 2^bits − 1.
            let full = significant_bits(&s, channels, sbit).map_or(65535, |b| (1u32 << b) - 1);
            if channels <= 2 {
                // round(v · 255 / full) in integers: exact for v = 257·k when full = 65535.
                s.chunks_exact(channels)
                    .map(|p| ((u32::from(p[0]) * 510 + full) / (2 * full)).min(255) as u8)
                    .collect()
            } else {
                let scale = 255.0 / f64::from(full);
                let prepared = PreparedConversion::new(conversion);
                s.chunks_exact(channels)
                    .map(|p| {
                        prepared.level([
                            f64::from(p[0]) * scale,
                            f64::from(p[1]) * scale,
                            f64::from(p[2]) * scale,
                        ])
                    })
                    .collect()
            }
        }
        Samples::F32(s) => {
            let prepared = PreparedConversion::new(conversion);
            s.chunks_exact(channels)
                .map(|p| {
                    let level = |v: f32| f64::from(v) * 255.0;
                    if channels <= 2 {
                        level(p[0]).round().clamp(0.0, 255.0) as u8
                    } else {
                        prepared.level([level(p[0]), level(p[1]), level(p[2])])
                    }
                })
                .collect()
        }
    };
    Ok(GrayImage {
        width,
        height,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn png_bytes(
        w: u32,
        h: u32,
        colour: png::ColorType,
        depth: png::BitDepth,
        data: &[u8],
        sbit: Option<u8>,
    ) -> Vec<u8> {
        let mut out = Vec::new();
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(colour);
        enc.set_depth(depth);
        let mut writer = enc.write_header().unwrap();
        if let Some(b) = sbit {
            writer.write_chunk(png::chunk::sBIT, &[b]).unwrap();
        }
        writer.write_image_data(data).unwrap();
        writer.finish().unwrap();
        out
    }

    fn be16(values: &[u16]) -> Vec<u8> {
        values.iter().flat_map(|v| v.to_be_bytes()).collect()
    }

    /// A 16×8 grey ramp 0..=255 and back, every level present.
    fn ramp8() -> Vec<u8> {
        (0..128u32).map(|i| (i * 2 + i / 64) as u8).collect()
    }

    #[test]
    fn eight_bit_png_as_is_and_16_bit_times_257_exactly() {
        let g = ramp8();
        let png8 = png_bytes(
            16,
            8,
            png::ColorType::Grayscale,
            png::BitDepth::Eight,
            &g,
            None,
        );
        let a = decode_gray(&png8, GrayConversion::Luma).unwrap();
        assert_eq!((a.width, a.height), (16, 8));
        assert_eq!(a.data, g);
        let wide: Vec<u16> = g.iter().map(|&v| u16::from(v) * 257).collect();
        let png16 = png_bytes(
            16,
            8,
            png::ColorType::Grayscale,
            png::BitDepth::Sixteen,
            &be16(&wide),
            None,
        );
        assert_eq!(decode_gray(&png16, GrayConversion::Luma).unwrap(), a);
        // A dark 8-bit image (largest level 40) stored ×257 is still divided exactly.
        let dark: Vec<u16> = (0..128u16).map(|i| (i % 41) * 257).collect();
        let png16 = png_bytes(
            16,
            8,
            png::ColorType::Grayscale,
            png::BitDepth::Sixteen,
            &be16(&dark),
            None,
        );
        let d = decode_gray(&png16, GrayConversion::Luma).unwrap();
        assert!(
            d.data
                .iter()
                .zip(&dark)
                .all(|(&a, &b)| u16::from(a) * 257 == b)
        );
    }

    #[test]
    fn twelve_bit_in_16_uses_the_full_range() {
        let v: Vec<u16> = (0..64u16).map(|i| i * 65).collect(); // 0..=4095
        let png16 = png_bytes(
            8,
            8,
            png::ColorType::Grayscale,
            png::BitDepth::Sixteen,
            &be16(&v),
            None,
        );
        let g = decode_gray(&png16, GrayConversion::Luma).unwrap();
        assert_eq!(g.data[63], 255);
        assert_eq!(g.data[0], 0);
        for (&out, &inp) in g.data.iter().zip(&v) {
            let want = f64::from(inp) * 255.0 / 4095.0;
            assert!((f64::from(out) - want).abs() <= 0.5, "{inp} -> {out}");
        }
        // A dark 12-bit frame (largest sample 1000): by the data alone it reads as 10-bit,
        // with sBIT = 12 as 12-bit.
        let dark: Vec<u16> = (0..64u16).map(|i| i * 1000 / 63).collect();
        let plain = png_bytes(
            8,
            8,
            png::ColorType::Grayscale,
            png::BitDepth::Sixteen,
            &be16(&dark),
            None,
        );
        let tagged = png_bytes(
            8,
            8,
            png::ColorType::Grayscale,
            png::BitDepth::Sixteen,
            &be16(&dark),
            Some(12),
        );
        assert_eq!(
            decode_gray(&plain, GrayConversion::Luma).unwrap().data[63],
            249
        );
        assert_eq!(
            decode_gray(&tagged, GrayConversion::Luma).unwrap().data[63],
            62
        );
    }

    #[test]
    fn colour_alpha_and_conversions() {
        let rgb: Vec<[u8; 3]> = (0..64u32)
            .map(|i| [(i * 4) as u8, (255 - i * 3) as u8, (i * 7 % 256) as u8])
            .collect();
        let rgba: Vec<u8> = rgb.iter().flat_map(|p| [p[0], p[1], p[2], 17]).collect();
        let rgba16: Vec<u16> = rgba.iter().map(|&v| u16::from(v) * 257).collect();
        let png_rgba = png_bytes(
            8,
            8,
            png::ColorType::Rgba,
            png::BitDepth::Eight,
            &rgba,
            None,
        );
        let png_rgba16 = png_bytes(
            8,
            8,
            png::ColorType::Rgba,
            png::BitDepth::Sixteen,
            &be16(&rgba16),
            None,
        );
        for conversion in [
            GrayConversion::Luma,
            GrayConversion::Channel(1),
            GrayConversion::DotColor([40.0, 170.0, 70.0]),
        ] {
            let want: Vec<u8> = rgb.iter().map(|&p| conversion.convert(p)).collect();
            assert_eq!(decode_gray(&png_rgba, conversion).unwrap().data, want);
            assert_eq!(decode_gray(&png_rgba16, conversion).unwrap().data, want);
        }
        assert_eq!(GrayConversion::Luma.convert([10, 200, 30]), 124);
        assert_eq!(GrayConversion::Channel(2).convert([10, 200, 30]), 30);
        assert_eq!(
            GrayConversion::DotColor([10.0, 200.0, 30.0]).convert([10, 200, 30]),
            0
        );
        // Hue, not brightness: a green dot in shadow stays dark, skin in shadow stays as
        // bright as lit skin, and near-black (a pupil) is not ink.
        let green = GrayConversion::DotColor([20.0, 115.0, 41.0]);
        assert!(green.convert([10, 58, 21]) <= 2);
        let (lit, shaded) = (green.convert([200, 150, 130]), green.convert([100, 75, 65]));
        assert!(lit > 120 && lit.abs_diff(shaded) <= 1, "{lit} {shaded}");
        assert!(green.convert([3, 4, 3]) > 200);
        // Grey with alpha: the grey channel.
        let ga: Vec<u8> = (0..64u8).flat_map(|v| [v * 3, 255 - v]).collect();
        let png_ga = png_bytes(
            8,
            8,
            png::ColorType::GrayscaleAlpha,
            png::BitDepth::Eight,
            &ga,
            None,
        );
        let g = decode_gray(&png_ga, GrayConversion::Luma).unwrap();
        assert_eq!(g.data, (0..64u8).map(|v| v * 3).collect::<Vec<_>>());
    }

    #[test]
    fn tiff_and_jpeg_by_content() {
        let g = ramp8();
        let img8 = image::GrayImage::from_raw(16, 8, g.clone()).unwrap();
        let mut tiff = Vec::new();
        img8.write_to(&mut Cursor::new(&mut tiff), image::ImageFormat::Tiff)
            .unwrap();
        assert_eq!(decode_gray(&tiff, GrayConversion::Luma).unwrap().data, g);
        let wide: Vec<u16> = g.iter().map(|&v| u16::from(v) * 257).collect();
        let img16 =
            image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(16, 8, wide).unwrap();
        let mut tiff16 = Vec::new();
        img16
            .write_to(&mut Cursor::new(&mut tiff16), image::ImageFormat::Tiff)
            .unwrap();
        assert_eq!(decode_gray(&tiff16, GrayConversion::Luma).unwrap().data, g);
        // JPEG is lossy: a smooth 64×64 gradient at quality 100 comes back within 3 levels.
        let smooth: Vec<u8> = (0..64 * 64u32)
            .map(|i| (i % 64 * 2 + i / 64) as u8)
            .collect();
        let img = image::GrayImage::from_raw(64, 64, smooth.clone()).unwrap();
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 100)
            .encode_image(&img)
            .unwrap();
        let j = decode_gray(&jpeg, GrayConversion::Luma).unwrap();
        assert_eq!((j.width, j.height), (64, 64));
        let worst = j
            .data
            .iter()
            .zip(&smooth)
            .map(|(&a, &b)| a.abs_diff(b))
            .max()
            .unwrap();
        assert!(worst <= 3, "JPEG differs by {worst} levels");
    }

    /// CRC-32 (ISO-HDLC, as PNG uses), bit by bit.
    fn crc32(bytes: &[u8]) -> u32 {
        let mut crc = !0u32;
        for &b in bytes {
            crc ^= u32::from(b);
            for _ in 0..8 {
                crc = if crc & 1 == 1 {
                    (crc >> 1) ^ 0xEDB8_8320
                } else {
                    crc >> 1
                };
            }
        }
        !crc
    }

    fn chunk(kind: &[u8; 4], data: &[u8]) -> Vec<u8> {
        let mut c = (data.len() as u32).to_be_bytes().to_vec();
        let body: Vec<u8> = kind.iter().chain(data).copied().collect();
        c.extend(&body);
        c.extend(crc32(&body).to_be_bytes());
        c
    }

    #[test]
    fn huge_declared_size_and_garbage_are_errors_naming_the_file() {
        // 65 bytes: signature, IHDR of 1,000,000 × 1,000,000 grey, an empty IDAT, IEND.
        let mut ihdr = Vec::new();
        ihdr.extend(1_000_000u32.to_be_bytes());
        ihdr.extend(1_000_000u32.to_be_bytes());
        ihdr.extend([8, 0, 0, 0, 0]);
        let mut bomb = b"\x89PNG\r\n\x1a\n".to_vec();
        bomb.extend(chunk(b"IHDR", &ihdr));
        bomb.extend(chunk(
            b"IDAT",
            &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01],
        ));
        bomb.extend(chunk(b"IEND", &[]));
        assert_eq!(bomb.len(), 65);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bomb.png");
        std::fs::write(&path, &bomb).unwrap();
        let e = read_gray(&path, GrayConversion::Luma)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("bomb.png") && e.contains("1000000×1000000") && e.contains("16384"),
            "{e}"
        );
        let path = dir.path().join("x.jpg");
        std::fs::write(&path, b"GIF89a not really").unwrap();
        let e = read_gray(&path, GrayConversion::Luma)
            .unwrap_err()
            .to_string();
        assert!(e.contains("x.jpg") && e.contains("image/gif"), "{e}");
        std::fs::write(&path, b"hello").unwrap();
        let e = read_gray(&path, GrayConversion::Luma)
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a PNG, JPEG or TIFF"), "{e}");
        // A truncated PNG.
        let png8 = png_bytes(
            16,
            8,
            png::ColorType::Grayscale,
            png::BitDepth::Eight,
            &ramp8(),
            None,
        );
        std::fs::write(&path, &png8[..png8.len() - 30]).unwrap();
        assert!(read_gray(&path, GrayConversion::Luma).is_err());
        let e = read_gray(&dir.path().join("none.png"), GrayConversion::Luma)
            .unwrap_err()
            .to_string();
        assert!(e.contains("none.png"), "{e}");
    }

    /// Decode timings of a 1280×1024 frame (reported, not asserted): the `png` path, the
    /// `image` crate on the same PNG, TIFF and JPEG. Run with
    /// `cargo test --release --lib capture::image::tests::decode_timing -- --ignored --nocapture`.
    #[test]
    #[ignore = "a timing, run by hand"]
    fn decode_timing() {
        let (w, h) = (1280u32, 1024u32);
        // A face-like frame: smooth shading, dots and noise.
        let data: Vec<u8> = (0..w * h)
            .map(|i| {
                let (x, y) = (f64::from(i % w), f64::from(i / w));
                let base = 120.0 + 60.0 * ((x / 200.0).sin() * (y / 150.0).cos());
                let dot = if (x % 40.0 - 20.0).hypot(y % 40.0 - 20.0) < 4.0 {
                    -80.0
                } else {
                    0.0
                };
                (base + dot + f64::from((i.wrapping_mul(2_654_435_761) >> 29) as u8))
                    .clamp(0.0, 255.0) as u8
            })
            .collect();
        let png8 = png_bytes(
            w,
            h,
            png::ColorType::Grayscale,
            png::BitDepth::Eight,
            &data,
            None,
        );
        let img = image::GrayImage::from_raw(w, h, data.clone()).unwrap();
        let mut tiff = Vec::new();
        img.write_to(&mut Cursor::new(&mut tiff), image::ImageFormat::Tiff)
            .unwrap();
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
            .encode_image(&img)
            .unwrap();
        let time = |name: &str, f: &dyn Fn() -> GrayImage| {
            let mut ms: Vec<f64> = (0..15)
                .map(|_| {
                    let t = std::time::Instant::now();
                    let g = f();
                    assert_eq!(g.data.len(), (w * h) as usize);
                    t.elapsed().as_secs_f64() * 1e3
                })
                .collect();
            ms.sort_by(f64::total_cmp);
            println!(
                "{name}: median {:.2} ms (min {:.2})",
                ms[ms.len() / 2],
                ms[0]
            );
        };
        time("PNG, png crate path", &|| {
            decode_gray(&png8, GrayConversion::Luma).unwrap()
        });
        time("PNG, image crate", &|| {
            decode_with_image(&png8, image::ImageFormat::Png, GrayConversion::Luma).unwrap()
        });
        time("TIFF", &|| {
            decode_gray(&tiff, GrayConversion::Luma).unwrap()
        });
        time("JPEG q95", &|| {
            decode_gray(&jpeg, GrayConversion::Luma).unwrap()
        });
    }
}
