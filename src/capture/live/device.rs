//! The camera interface ([`CameraDevice`], its image and its error) and the nokhwa driver
//! for real cameras ([`NokhwaCamera`], opened from a `[[camera]]` table).

use std::time::Instant;

use crate::capture::{CaptureError, GrayImage};

/// One image from a camera and the host time it arrived.
#[derive(Debug, Clone, PartialEq)]
pub struct CapturedImage {
    /// 8-bit grayscale image.
    pub image: GrayImage,
    /// Host time of capture (when the driver handed the frame over, or the trigger time
    /// for cameras that report it).
    pub captured_at: Instant,
}

/// Why a camera gave no image.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CameraError {
    /// One bad frame (cannot be decoded, wrong size); the camera goes on.
    #[error("bad frame: {0}")]
    BadFrame(String),
    /// The device is gone (unplugged, stream closed); the camera stops.
    #[error("device lost: {0}")]
    Lost(String),
    /// A test camera played all its frames: the end of input.
    #[error("end of input")]
    Ended,
}

/// A camera: something that delivers grayscale images at its own pace.
pub trait CameraDevice: Send {
    /// A name for messages, e.g. `cam0 (/dev/video0)`.
    fn name(&self) -> &str;
    /// Blocks until the next frame (about one frame interval) and returns it.
    ///
    /// # Errors
    /// [`CameraError`]: a bad frame (counted, the camera goes on), a lost device or the end
    /// of a test camera's input (both stop the camera).
    fn grab(&mut self) -> Result<CapturedImage, CameraError>;
}

/// Pixel formats a camera can be asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PixelFormat {
    /// 8-bit luminance (machine-vision cameras).
    Gray,
    /// YUYV 4:2:2 (the luminance bytes are taken as they are).
    Yuyv,
    /// Motion JPEG (decoded, then averaged to gray).
    Mjpeg,
    /// NV12 (converted to gray).
    Nv12,
    /// Packed 8-bit RGB (averaged to gray).
    Rgb,
}

/// One camera of `configs/live.toml` (`[[camera]]`).
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// Device index (`/dev/videoN` on Linux).
    pub device: u32,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Pixel format asked of the camera. Default `gray`.
    #[serde(default = "default_pixel_format")]
    pub pixel_format: PixelFormat,
}

fn default_pixel_format() -> PixelFormat {
    PixelFormat::Gray
}

/// A camera through nokhwa (V4L2 on Linux): opened with the exact resolution, rate and
/// pixel format asked for, streaming from [`NokhwaCamera::open`] on.
pub struct NokhwaCamera {
    name: String,
    camera: nokhwa::Camera,
    width: u32,
    height: u32,
}

impl std::fmt::Debug for NokhwaCamera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NokhwaCamera")
            .field("name", &self.name)
            .field("width", &self.width)
            .field("height", &self.height)
            .finish_non_exhaustive()
    }
}

impl NokhwaCamera {
    /// Opens camera `config.device` at `fps` and starts its stream.
    ///
    /// # Errors
    /// [`CaptureError::Device`] naming the device when it does not exist or refuses the
    /// format.
    pub fn open(name: &str, config: &CameraConfig, fps: u32) -> Result<Self, CaptureError> {
        use nokhwa::pixel_format::LumaFormat;
        use nokhwa::utils::{
            CameraFormat, CameraIndex, FrameFormat, RequestedFormat, RequestedFormatType,
        };
        let label = format!("{name} (device {})", config.device);
        let err = |message: String| CaptureError::Device {
            device: label.clone(),
            message,
        };
        let format = match config.pixel_format {
            PixelFormat::Gray => FrameFormat::GRAY,
            PixelFormat::Yuyv => FrameFormat::YUYV,
            PixelFormat::Mjpeg => FrameFormat::MJPEG,
            PixelFormat::Nv12 => FrameFormat::NV12,
            PixelFormat::Rgb => FrameFormat::RAWRGB,
        };
        let wanted = CameraFormat::new_from(config.width, config.height, format, fps);
        let request = RequestedFormat::new::<LumaFormat>(RequestedFormatType::Exact(wanted));
        let mut camera = nokhwa::Camera::new(CameraIndex::Index(config.device), request)
            .map_err(|e| err(format!("cannot open: {e}")))?;
        camera
            .open_stream()
            .map_err(|e| err(format!("cannot start streaming: {e}")))?;
        let got = camera.camera_format();
        if got.resolution().width_x != config.width || got.resolution().height_y != config.height {
            return Err(err(format!(
                "delivers {}×{}, the config asks for {}×{}",
                got.resolution().width_x,
                got.resolution().height_y,
                config.width,
                config.height
            )));
        }
        tracing::info!("{label}: streaming {got}");
        Ok(Self {
            name: label,
            camera,
            width: config.width,
            height: config.height,
        })
    }
}

impl CameraDevice for NokhwaCamera {
    fn name(&self) -> &str {
        &self.name
    }

    fn grab(&mut self) -> Result<CapturedImage, CameraError> {
        use nokhwa::utils::FrameFormat;
        let buffer = self.camera.frame().map_err(|e| {
            let text = e.to_string();
            // V4L reports an unplugged device as ENODEV ("No such device").
            if text.contains("No such device") || text.contains("not open") {
                CameraError::Lost(text)
            } else {
                CameraError::BadFrame(text)
            }
        })?;
        let captured_at = Instant::now();
        let (w, h) = (self.width, self.height);
        let pixels = w as usize * h as usize;
        let raw = buffer.buffer();
        let data = match buffer.source_frame_format() {
            FrameFormat::GRAY if raw.len() >= pixels => raw[..pixels].to_vec(),
            FrameFormat::YUYV if raw.len() >= 2 * pixels => {
                raw.iter().step_by(2).copied().take(pixels).collect()
            }
            _ => buffer
                .decode_image::<nokhwa::pixel_format::LumaFormat>()
                .map_err(|e| CameraError::BadFrame(e.to_string()))?
                .into_raw(),
        };
        if data.len() != pixels {
            return Err(CameraError::BadFrame(format!(
                "{} bytes for a {w}×{h} image",
                data.len()
            )));
        }
        Ok(CapturedImage {
            image: GrayImage {
                width: w,
                height: h,
                data,
            },
            captured_at,
        })
    }
}
