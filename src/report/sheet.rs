//! A take's contact sheet: for a few evenly spaced frames, the first camera's image (read
//! from the session folder that `take.json` names) with the frame's labeled 2D points
//! (`tracks.csv`) drawn on it, beside a render of the frame's solved mesh
//! (`mesh/frame_NNNNNN.obj` or `.ply`, else `mesh.usda`). Each image is a PNG in memory;
//! what cannot be shown is said in [`ContactSheet::notes`].
//!
//! OBJ/PLY exports are read for the sheet's frames only; a `mesh.usda` is read whole (its
//! reader has no partial read), which for a long take costs its size in memory once.

use std::collections::{BTreeSet, HashMap};
use std::path::Path;

use image::{GrayImage, Rgb, RgbImage};
use nalgebra::Point3;

use super::render::{OrthoView, fan_triangles, render_mesh};
use super::take::pick_frames;
use super::{ReportError, ReportParams, TakeSummary};
use crate::capture::{FrameSource, Replay, ReplayParams};

/// Colour of the labeled points on the camera images.
const POINT: Rgb<u8> = Rgb([255, 200, 0]);
/// Outline of the points, for contrast on bright skin.
const OUTLINE: Rgb<u8> = Rgb([20, 20, 20]);

/// One frame of the contact sheet.
#[derive(Debug, Clone, PartialEq)]
pub struct SheetFrame {
    /// Frame index.
    pub frame: usize,
    /// The frame's timecode (from `bundles.csv`), if any.
    pub timecode: Option<String>,
    /// The first camera's image with the labeled points, PNG.
    pub camera_png: Option<Vec<u8>>,
    /// Labeled points drawn on it.
    pub points: usize,
    /// The render of the solved mesh, PNG.
    pub mesh_png: Option<Vec<u8>>,
}

/// The contact sheet of a take.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ContactSheet {
    /// The frames shown, in order.
    pub frames: Vec<SheetFrame>,
    /// The camera whose images are shown (the session's first).
    pub camera: Option<String>,
    /// Why images or renders are missing.
    pub notes: Vec<String>,
}

impl ContactSheet {
    /// Builds the contact sheet of `take`: [`ReportParams::frames_per_sheet`] frames picked
    /// by [`pick_frames`] among the frames the take's files hold.
    ///
    /// # Errors
    /// [`ReportError::Draw`] when a PNG cannot be encoded; missing or unreadable inputs
    /// only add notes.
    pub fn build(take: &TakeSummary, params: &ReportParams) -> Result<Self, ReportError> {
        let mut sheet = ContactSheet::default();
        let Some((first, last)) = take.frame_range else {
            if params.frames_per_sheet > 0 {
                sheet.notes.push("the take has no frames".into());
            }
            return Ok(sheet);
        };
        let frames = pick_frames(first, last, &take.frames_seen, params.frames_per_sheet);
        if frames.is_empty() {
            return Ok(sheet);
        }
        let images = camera_images(take, &frames, &mut sheet);
        let tracks = read_tracks(&take.dir.join("tracks.csv"), &frames, &mut sheet.notes);
        let meshes = read_meshes(&take.dir, &frames, &mut sheet.notes);
        let view = OrthoView::fit(
            meshes.iter().flatten().flat_map(|(p, _)| p.iter()),
            params.render_size,
            params.render_size,
            0.04,
        );
        for (i, &frame) in frames.iter().enumerate() {
            let mut out = SheetFrame {
                frame,
                timecode: take.timecodes.get(&frame).cloned(),
                camera_png: None,
                points: 0,
                mesh_png: None,
            };
            if let Some(Some(gray)) = images.get(i) {
                let points = tracks
                    .as_ref()
                    .and_then(|t| t.get(&frame))
                    .map(Vec::as_slice)
                    .unwrap_or_default();
                let (image, drawn) = annotate(gray, points, params.sheet_width);
                out.points = drawn;
                out.camera_png = Some(encode_png(&image, &format!("frame {frame} camera image"))?);
            }
            if let (Some(Some((positions, triangles))), Some(view)) = (meshes.get(i), &view) {
                let image = render_mesh(positions, triangles, view);
                out.mesh_png = Some(encode_png(&image, &format!("frame {frame} mesh render"))?);
            }
            sheet.frames.push(out);
        }
        Ok(sheet)
    }
}

/// The first camera's grey image of each of `frames` from the take's session, or `None`
/// per frame (with a note) when it cannot be had.
fn camera_images(
    take: &TakeSummary,
    frames: &[usize],
    sheet: &mut ContactSheet,
) -> Vec<Option<GrayImage>> {
    let mut images = vec![None; frames.len()];
    let Some(session) = &take.session else {
        sheet.notes.push(if take.dir.join("take.json").is_file() {
            "take.json names no session folder: camera images not shown".into()
        } else {
            "no take.json (it names the take's session folder): camera images not shown".into()
        });
        return images;
    };
    if !session.is_dir() {
        sheet.notes.push(format!(
            "session folder {} not found: camera images not shown",
            session.display()
        ));
        return images;
    }
    for (slot, &frame) in images.iter_mut().zip(frames) {
        // `select_frames` narrows a replay for good: one replay per frame.
        let mut replay = match Replay::open(session, ReplayParams::default()) {
            Ok(r) => r,
            Err(e) => {
                sheet.notes.push(format!(
                    "session not readable: {e}: camera images not shown"
                ));
                return images;
            }
        };
        sheet.camera = replay.info().cameras.first().cloned();
        let index = crate::frame_index::FrameIndex::from(frame);
        if replay.select_frames(index..=index) == 0 {
            sheet.notes.push(format!(
                "frame {frame} is not in the session {}",
                session.display()
            ));
            continue;
        }
        match FrameSource::next_frame(&mut replay) {
            Some(Ok(stereo)) => {
                let [cam0, _] = stereo.images;
                *slot = GrayImage::from_raw(cam0.width, cam0.height, cam0.data);
            }
            Some(Err(e)) => sheet.notes.push(format!("frame {frame}: {e}")),
            None => sheet
                .notes
                .push(format!("frame {frame}: no image in the session")),
        }
    }
    images
}

/// The first camera's labeled points (`u`, `v` in pixels) of each of `frames` from
/// `tracks.csv`; `None` with a note when the file is missing or malformed.
fn read_tracks(
    path: &Path,
    frames: &[usize],
    notes: &mut Vec<String>,
) -> Option<HashMap<usize, Vec<[f64; 2]>>> {
    let wanted: BTreeSet<usize> = frames.iter().copied().collect();
    let mut tracks: HashMap<usize, Vec<[f64; 2]>> = HashMap::new();
    let file = match std::fs::File::open(path) {
        Ok(f) => f,
        Err(e) => {
            notes.push(if e.kind() == std::io::ErrorKind::NotFound {
                "tracks.csv: missing (no labeled points on the camera images)".into()
            } else {
                format!("tracks.csv: unreadable: {e} (no labeled points on the camera images)")
            });
            return None;
        }
    };
    // Streamed: a long take's tracks are large, and only a few frames are wanted.
    let mut lines = std::io::BufRead::lines(std::io::BufReader::new(file)).enumerate();
    let header: Vec<String> = match lines.next() {
        Some((_, Ok(h))) => h
            .trim_end_matches('\r')
            .split(',')
            .map(|c| c.trim().to_string())
            .collect(),
        _ => Vec::new(),
    };
    let col = |name: &str| header.iter().position(|h| *h == name);
    let (Some(fc), Some(cc), Some(uc), Some(vc)) =
        (col("frame"), col("camera"), col("u"), col("v"))
    else {
        notes.push(
            "tracks.csv: not `frame,camera,marker,u,v` (no labeled points on the camera images)"
                .into(),
        );
        return None;
    };
    for (i, line) in lines {
        let Ok(line) = line else {
            notes.push(format!(
                "tracks.csv:{}: unreadable (labeled points shown up to there)",
                i + 1
            ));
            break;
        };
        if line.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = line.trim_end_matches('\r').split(',').collect();
        let num = |c: usize| f.get(c).and_then(|s| s.parse::<f64>().ok());
        let Some(frame) = f.get(fc).and_then(|s| s.parse::<usize>().ok()) else {
            notes.push(format!(
                "tracks.csv:{}: no frame number (labeled points shown up to there)",
                i + 1
            ));
            break;
        };
        if !wanted.contains(&frame) || f.get(cc).map(|c| c.trim()) != Some("0") {
            continue;
        }
        if let (Some(u), Some(v)) = (num(uc), num(vc)) {
            tracks.entry(frame).or_default().push([u, v]);
        }
    }
    Some(tracks)
}

/// A mesh of the sheet: positions (mm, head frame) and triangles.
type SheetMesh = (Vec<Point3<f64>>, std::sync::Arc<Vec<[u32; 3]>>);

/// The solved mesh of each of `frames`: `mesh/frame_NNNNNN.obj` (or `.ply`) when the
/// folder exists, else the time samples of `mesh.usda`; `None` per frame, with a note,
/// where there is none.
fn read_meshes(dir: &Path, frames: &[usize], notes: &mut Vec<String>) -> Vec<Option<SheetMesh>> {
    let mut meshes = vec![None; frames.len()];
    let mesh_dir = dir.join("mesh");
    let usda = dir.join("mesh.usda");
    if mesh_dir.is_dir() {
        for (slot, &frame) in meshes.iter_mut().zip(frames) {
            let obj = mesh_dir.join(format!("frame_{frame:06}.obj"));
            let ply = mesh_dir.join(format!("frame_{frame:06}.ply"));
            let path = if obj.is_file() { obj } else { ply };
            if !path.is_file() {
                notes.push(format!("mesh/: no mesh for frame {frame}"));
                continue;
            }
            match crate::mesh::read_mesh(&path) {
                Ok(m) => *slot = Some((m.positions, std::sync::Arc::new(m.triangles))),
                Err(e) => notes.push(format!("{e} (no render of frame {frame})")),
            }
        }
    } else if usda.is_file() {
        match crate::sink::read_usda_sequence(&usda) {
            Ok(seq) => {
                let triangles = std::sync::Arc::new(fan_triangles(
                    &seq.face_vertex_counts,
                    &seq.face_vertex_indices,
                ));
                let by_time: HashMap<i64, &Vec<Point3<f64>>> = seq
                    .frames
                    .iter()
                    .map(|(t, p)| (t.round() as i64, p))
                    .collect();
                for (slot, &frame) in meshes.iter_mut().zip(frames) {
                    match by_time.get(&(frame as i64)) {
                        Some(p) => *slot = Some(((*p).clone(), triangles.clone())),
                        None => notes.push(format!("mesh.usda: no time sample for frame {frame}")),
                    }
                }
            }
            Err(e) => notes.push(format!("{e} (no mesh renders)")),
        }
    } else {
        notes.push(
            "no mesh export (mesh.usda or mesh/frame_NNNNNN.obj; replay with --export usd or --export obj): no mesh renders"
                .into(),
        );
    }
    meshes
}

/// The grey camera image scaled down to `width` pixels (when wider), in colour, with
/// `points` (full-size pixel coordinates) drawn as rings; returns it and how many rings
/// fell inside.
fn annotate(gray: &GrayImage, points: &[[f64; 2]], width: u32) -> (RgbImage, usize) {
    let (w, h) = gray.dimensions();
    let (small, k) = if w > width && width > 0 {
        let k = f64::from(width) / f64::from(w);
        let height = ((f64::from(h) * k).round() as u32).max(1);
        (image::imageops::thumbnail(gray, width, height), k)
    } else {
        (gray.clone(), 1.0)
    };
    // Grey levels up to 253: with the two ring colours the image fits a 256-colour
    // palette, which [`encode_png`] then uses.
    let mut rgb = RgbImage::from_fn(small.width(), small.height(), |x, y| {
        let v = small.get_pixel(x, y)[0].min(253);
        Rgb([v, v, v])
    });
    let radius = (f64::from(rgb.width()) / 140.0).clamp(2.5, 6.0);
    let mut drawn = 0;
    for p in points {
        let (x, y) = (p[0] * k, p[1] * k);
        if x >= 0.0 && y >= 0.0 && x < f64::from(rgb.width()) && y < f64::from(rgb.height()) {
            ring(&mut rgb, x, y, radius);
            drawn += 1;
        }
    }
    (rgb, drawn)
}

/// Draws a ring of radius `r` pixels around (`cx`, `cy`) (continuous pixel coordinates,
/// pixel centres at +0.5): [`POINT`] on the circle, [`OUTLINE`] just inside and outside.
fn ring(image: &mut RgbImage, cx: f64, cy: f64, r: f64) {
    let reach = (r + 2.0).ceil() as i64;
    let (px, py) = (cx.floor() as i64, cy.floor() as i64);
    for y in py - reach..=py + reach {
        for x in px - reach..=px + reach {
            if x < 0 || y < 0 || x >= i64::from(image.width()) || y >= i64::from(image.height()) {
                continue;
            }
            let d = ((x as f64 + 0.5 - cx).powi(2) + (y as f64 + 0.5 - cy).powi(2)).sqrt();
            let off = (d - r).abs();
            if off <= 0.75 {
                image.put_pixel(x as u32, y as u32, POINT);
            } else if off <= 1.6 {
                image.put_pixel(x as u32, y as u32, OUTLINE);
            }
        }
    }
}

/// Encodes `image` as a PNG; `what` names it in the error. An image of at most 256
/// colours (the mesh renders, the annotated grey camera images) is written with a palette,
/// one byte per pixel instead of three, which makes the file (and the page) 2–3 times
/// smaller.
pub(super) fn encode_png(image: &RgbImage, what: &str) -> Result<Vec<u8>, ReportError> {
    let err = |e: &dyn std::fmt::Display| ReportError::Draw {
        what: what.to_string(),
        message: e.to_string(),
    };
    if let Some((palette, indices)) = palette_of(image) {
        let mut bytes = Vec::new();
        {
            let mut encoder = png::Encoder::new(&mut bytes, image.width(), image.height());
            encoder.set_color(png::ColorType::Indexed);
            encoder.set_depth(png::BitDepth::Eight);
            encoder.set_palette(palette);
            encoder.set_compression(png::Compression::High);
            let mut writer = encoder.write_header().map_err(|e| err(&e))?;
            writer.write_image_data(&indices).map_err(|e| err(&e))?;
            writer.finish().map_err(|e| err(&e))?;
        }
        return Ok(bytes);
    }
    use image::ImageEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    let mut bytes = Vec::new();
    PngEncoder::new_with_quality(&mut bytes, CompressionType::Best, FilterType::Adaptive)
        .write_image(
            image.as_raw(),
            image.width(),
            image.height(),
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|e| err(&e))?;
    Ok(bytes)
}

/// The palette (RGB triplets) and per-pixel indices of `image`, or `None` when it has
/// more than 256 colours.
fn palette_of(image: &RgbImage) -> Option<(Vec<u8>, Vec<u8>)> {
    let mut lookup: HashMap<[u8; 3], u8> = HashMap::new();
    let mut palette = Vec::new();
    let mut indices = Vec::with_capacity(image.pixels().len());
    for p in image.pixels() {
        let i = match lookup.get(&p.0) {
            Some(&i) => i,
            None => {
                let i = u8::try_from(lookup.len()).ok()?;
                lookup.insert(p.0, i);
                palette.extend_from_slice(&p.0);
                i
            }
        };
        indices.push(i);
    }
    Some((palette, indices))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn annotate_scales_points_with_the_image() {
        let gray = GrayImage::from_pixel(960, 480, image::Luma([100]));
        let (rgb, drawn) = annotate(&gray, &[[480.0, 240.0], [2000.0, 10.0]], 480);
        assert_eq!((rgb.width(), rgb.height(), drawn), (480, 240, 1));
        let r = (480.0f64 / 140.0).clamp(2.5, 6.0);
        // On the ring (right of the centre) is the point colour; the centre is untouched.
        assert_eq!(*rgb.get_pixel((240.0 + r) as u32, 120), POINT);
        assert_eq!(*rgb.get_pixel(240, 120), Rgb([100, 100, 100]));
        let png = encode_png(&rgb, "test").unwrap();
        let back = image::load_from_memory(&png).unwrap().to_rgb8();
        assert_eq!(back, rgb, "palette PNG round trip");
        // More than 256 colours: written as RGB, still exact.
        let many = RgbImage::from_fn(64, 64, |x, y| Rgb([x as u8 * 4, y as u8 * 4, 7]));
        let back = image::load_from_memory(&encode_png(&many, "test").unwrap()).unwrap();
        assert_eq!(back.to_rgb8(), many);
    }

    #[test]
    fn tracks_of_the_first_camera_and_wanted_frames_only() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("tracks.csv");
        std::fs::write(
            &p,
            "frame,camera,marker,u,v\n0,0,a,1,2\n0,1,a,3,4\n1,0,a,5,6\n2,0,b,7,8\n",
        )
        .unwrap();
        let mut notes = Vec::new();
        let t = read_tracks(&p, &[0, 2], &mut notes).unwrap();
        assert_eq!(t[&0], vec![[1.0, 2.0]]);
        assert_eq!(t[&2], vec![[7.0, 8.0]]);
        assert!(!t.contains_key(&1) && notes.is_empty());
        assert!(read_tracks(&dir.path().join("none.csv"), &[0], &mut notes).is_none());
        assert!(notes[0].contains("tracks.csv: missing"));
    }
}
