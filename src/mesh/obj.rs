//! Wavefront OBJ reading and writing.
//!
//! # What is read
//! - `v x y z [w | r g b | w r g b | r g b a]`: positions; the optional 4th to 7th values
//!   (homogeneous w or a vertex colour) are checked to be numbers (`nan` allowed: some
//!   exporters write it for a missing colour) and then ignored.
//! - A line whose data ends with `\` continues on the next line (errors name the first).
//! - `vt u [v [w]]`: texture coordinates (`v` defaults to 0, `w` is ignored).
//! - `vn x y z`: normals are parsed (they must be three numbers) and their indices are
//!   checked, but they are **not stored**: helmcap deforms its meshes, so normals are
//!   always recomputed from the geometry ([`super::vertex_normals`]). Non-finite normals
//!   are tolerated for the same reason.
//! - `f` with every corner form: `v`, `v/vt`, `v//vn`, `v/vt/vn`, and the forms with
//!   empty fields other tools write (`v/`, `v//`, `v/vt/`: an empty field means none).
//!   Indices are 1-based;
//!   negative indices count back from the last element read so far (`-1` is the latest).
//!   Positive indices may refer to elements defined later in the file (as most readers
//!   allow); they are checked once the whole file is read. Polygons keep all their
//!   corners (quads stay quads, n-gons stay n-gons).
//! - `mtllib` (kept in [`Mesh::mtllib`]; only the first one if several) and `usemtl`
//!   (kept as material runs in [`Mesh::materials`]; a run that covers no face is dropped
//!   and consecutive runs of the same material are merged).
//! - `#` starts a comment (also after data on a line); blank lines, `\r\n` line ends and
//!   a UTF-8 byte-order mark are accepted. `g`, `o`, `s`, `l`, `p`, `vp` and the other
//!   statements of the format are ignored (unknown statements once with a warning).
//!
//! # UV policy
//! Per-corner UVs are kept when any face corner has a `vt` index. Corners without one
//! (files that mix textured and untextured faces, or corners like `v` among `v/vt`) all
//! point to one extra UV at (0, 0), as Blender's importer does, and the count is logged
//! as a warning: no face and no UV is dropped. When no face uses `vt`, the `vt` pool is
//! dropped too (so [`Mesh::uvs`] is empty exactly when the mesh has no UVs).
//!
//! # Writing
//! Writers produce `v`, `vt` and `f` lines (`v/vt` corners when the mesh has UVs, else
//! `v`) plus the `mtllib` and `usemtl` lines, no normals. Every `f64` is written with
//! Rust's shortest round-trip formatting (`{}`), so positions and UVs read back
//! bit-identically. Files are written atomically: to a temporary file in the target's
//! directory, flushed to disk, then renamed over the target.

use std::borrow::Cow;
use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::Path;

use nalgebra::{Point2, Point3};

use super::{Mesh, MeshError};
use crate::file_error::FileError;

/// Reads an OBJ file into a [`Mesh`] (see the [module docs](self) for what is kept).
///
/// # Errors
/// - [`FileError::Io`] when the file cannot be read (the message names the path).
/// - [`FileError::Parse`] (path and 1-based line) for a malformed `v`/`vt`/`vn`/`f` line,
///   a non-finite coordinate, a face index of zero or out of range, a face with fewer
///   than 3 corners or a repeated vertex, or faces that disagree on having UVs.
/// - [`MeshError::Empty`] when the file is empty or has no vertices or no faces.
pub fn read_obj(path: &Path) -> Result<Mesh, MeshError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| {
        MeshError::File(FileError::Io {
            path: name.clone(),
            source,
        })
    })?;
    ObjParser::new(&name).parse(&bytes)
}

/// Parses OBJ text already in memory; `name` stands for the file in error messages.
///
/// # Errors
/// As [`read_obj`], without the I/O case.
pub fn read_obj_str(text: &str, name: &str) -> Result<Mesh, MeshError> {
    ObjParser::new(name).parse(text.as_bytes())
}

/// Reads only the vertex positions (`v` lines) of an OBJ file, in file order.
///
/// The fast path for loading many shapes that share one topology (a dataset's expression
/// meshes): faces, UVs and every other statement are skipped unread. Pair the result with
/// the neutral's topology through [`Mesh::with_positions`], which checks the count.
///
/// # Errors
/// [`FileError::Io`] when the file cannot be read, [`FileError::Parse`] (path and line)
/// for a malformed `v` line or a non-finite coordinate, [`MeshError::Empty`] when the
/// file has no `v` line.
pub fn read_obj_positions(path: &Path) -> Result<Vec<Point3<f64>>, MeshError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| {
        MeshError::File(FileError::Io {
            path: name.clone(),
            source,
        })
    })?;
    parse_positions(&bytes, &name)
}

/// Writes `mesh` to an OBJ file, atomically (see the [module docs](self)).
///
/// # Errors
/// [`FileError::Io`] (naming `path`) when the file cannot be written;
/// [`MeshError::Invalid`] as [`write_obj_to`].
pub fn write_obj(path: &Path, mesh: &Mesh) -> Result<(), MeshError> {
    write_obj_positions(path, mesh, &mesh.positions)
}

/// Writes `mesh`'s polygons, UVs and materials with other vertex `positions` (#V), e.g.
/// one shape of a dataset that shares the neutral's topology. Atomic, as [`write_obj`].
///
/// # Errors
/// [`MeshError::Invalid`] when `positions.len()` differs from the mesh's vertex count or
/// a coordinate is not finite (checked before the file is created); [`FileError::Io`]
/// when the file cannot be written.
pub fn write_obj_positions(
    path: &Path,
    mesh: &Mesh,
    positions: &[Point3<f64>],
) -> Result<(), MeshError> {
    check_writable(mesh, positions)?;
    write_atomically(path, |w| write_body(w, mesh, positions))
}

/// Writes `mesh` with vertex `positions` (#V) as OBJ text to any writer (not buffered:
/// pass a [`BufWriter`] for files). The format is the one [`write_obj`] produces.
///
/// # Errors
/// [`MeshError::Invalid`] when `positions.len()` differs from the mesh's vertex count, a
/// coordinate is not finite, or a material name contains a line break (checked before
/// anything is written); [`FileError::Io`] (path `<writer>`) when the writer fails.
pub fn write_obj_to<W: Write>(
    mut w: W,
    mesh: &Mesh,
    positions: &[Point3<f64>],
) -> Result<(), MeshError> {
    check_writable(mesh, positions)?;
    write_body(&mut w, mesh, positions).map_err(|source| {
        MeshError::File(FileError::Io {
            path: "<writer>".into(),
            source,
        })
    })
}

/// Checks what a writer needs before it creates anything.
fn check_writable(mesh: &Mesh, positions: &[Point3<f64>]) -> Result<(), MeshError> {
    check_positions(mesh, positions)?;
    let names = mesh
        .mtllib
        .iter()
        .chain(mesh.materials.iter().map(|(_, n)| n));
    for n in names {
        if n.contains(['\n', '\r']) {
            return Err(MeshError::Invalid(format!(
                "material name {n:?} contains a line break"
            )));
        }
    }
    Ok(())
}

/// Checks that `positions` fits `mesh` and is finite (shared with the PLY writer).
pub(crate) fn check_positions(mesh: &Mesh, positions: &[Point3<f64>]) -> Result<(), MeshError> {
    if positions.len() != mesh.vertex_count() {
        return Err(MeshError::Invalid(format!(
            "{} positions given for a mesh of {} vertices",
            positions.len(),
            mesh.vertex_count()
        )));
    }
    if let Some(v) = positions
        .iter()
        .position(|p| !p.coords.iter().all(|c| c.is_finite()))
    {
        return Err(MeshError::Invalid(format!(
            "vertex {v} has a non-finite coordinate"
        )));
    }
    Ok(())
}

/// The OBJ text itself; inputs were checked by [`check_writable`].
fn write_body<W: Write>(w: &mut W, mesh: &Mesh, positions: &[Point3<f64>]) -> io::Result<()> {
    writeln!(
        w,
        "# helmcap: {} vertices, {} faces",
        positions.len(),
        mesh.face_count()
    )?;
    if let Some(lib) = &mesh.mtllib {
        writeln!(w, "mtllib {lib}")?;
    }
    // Numbers through `ryu` and `itoa` into a line buffer: formatting is most of the cost
    // of writing a mesh every frame, and `write!` is several times slower at it.
    let mut line = Vec::with_capacity(128);
    let mut floats = ryu::Buffer::new();
    let mut ints = itoa::Buffer::new();
    for p in positions {
        line.clear();
        line.push(b'v');
        for c in [p.x, p.y, p.z] {
            line.push(b' ');
            push_f64(&mut line, &mut floats, c);
        }
        line.push(b'\n');
        w.write_all(&line)?;
    }
    let has_uvs = mesh.has_uvs();
    if has_uvs {
        for t in &mesh.uvs {
            line.clear();
            line.extend_from_slice(b"vt");
            for c in [t.x, t.y] {
                line.push(b' ');
                push_f64(&mut line, &mut floats, c);
            }
            line.push(b'\n');
            w.write_all(&line)?;
        }
    }
    // Material runs in order of their first face (stable, so for equal starts the last
    // one wins on reading, as it did in the mesh).
    let mut runs: Vec<&(u32, String)> = mesh.materials.iter().collect();
    runs.sort_by_key(|r| r.0);
    let mut next_run = runs.iter().peekable();
    for f in 0..mesh.face_count() {
        while let Some(run) = next_run.next_if(|r| r.0 as usize <= f) {
            writeln!(w, "usemtl {}", run.1)?;
        }
        line.clear();
        line.push(b'f');
        if has_uvs {
            for (v, t) in mesh.face(f).iter().zip(mesh.face_uv(f)) {
                line.push(b' ');
                line.extend_from_slice(ints.format(u64::from(*v) + 1).as_bytes());
                line.push(b'/');
                line.extend_from_slice(ints.format(u64::from(*t) + 1).as_bytes());
            }
        } else {
            for v in mesh.face(f) {
                line.push(b' ');
                line.extend_from_slice(ints.format(u64::from(*v) + 1).as_bytes());
            }
        }
        line.push(b'\n');
        w.write_all(&line)?;
    }
    Ok(())
}

/// Appends `x` as the shortest decimal that reads back to the same `f64`, without a
/// trailing `.0` (as `{}` writes it; exponents only for very small or large values).
fn push_f64(out: &mut Vec<u8>, buf: &mut ryu::Buffer, x: f64) {
    let s = buf.format(x);
    out.extend_from_slice(s.strip_suffix(".0").unwrap_or(s).as_bytes());
}

/// Writes a file atomically (see [`crate::atomic_file::write_atomically`]).
///
/// # Errors
/// [`FileError::Io`] naming `path`.
pub(crate) fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> io::Result<()>,
) -> Result<(), MeshError> {
    crate::atomic_file::write_atomically(path, write).map_err(|source| {
        MeshError::File(FileError::Io {
            path: path.display().to_string(),
            source,
        })
    })
}

/// Splits OBJ bytes into `(1-based line number, logical line)`, skipping a UTF-8
/// byte-order mark. A line whose data (before any comment) ends with `\\` continues on
/// the next line (the format's line continuation): the pieces are joined with a space and
/// numbered by their first line. `\r` before `\n` is left in place: it is ASCII
/// whitespace, so tokenizing drops it.
fn lines(bytes: &[u8]) -> impl Iterator<Item = (usize, Cow<'_, [u8]>)> {
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    let mut raw = bytes.split(|&b| b == b'\n').enumerate();
    std::iter::from_fn(move || {
        let (i, first) = raw.next()?;
        let Some(head) = continued(first) else {
            return Some((i + 1, Cow::Borrowed(first)));
        };
        let mut joined = head.to_vec();
        for (_, next) in raw.by_ref() {
            joined.push(b' ');
            match continued(next) {
                Some(part) => joined.extend_from_slice(part),
                None => {
                    joined.extend_from_slice(next);
                    break;
                }
            }
        }
        Some((i + 1, Cow::Owned(joined)))
    })
}

/// The data of a line that ends with a continuation backslash, without the backslash
/// (and without any comment); `None` when the line does not continue.
fn continued(line: &[u8]) -> Option<&[u8]> {
    strip_comment(line).trim_ascii_end().strip_suffix(b"\\")
}

/// A line without its comment (`#` to the end of the line).
fn strip_comment(line: &[u8]) -> &[u8] {
    match line.iter().position(|&b| b == b'#') {
        Some(c) => &line[..c],
        None => line,
    }
}

/// Whitespace-separated tokens of a line.
fn tokens(line: &[u8]) -> impl Iterator<Item = &[u8]> {
    line.split(|b| b.is_ascii_whitespace())
        .filter(|t| !t.is_empty())
}

/// A token for an error message (lossy UTF-8, shortened).
fn show(token: &[u8]) -> String {
    let s = String::from_utf8_lossy(token);
    if s.chars().count() > 40 {
        format!("{}...", s.chars().take(40).collect::<String>())
    } else {
        s.into_owned()
    }
}

/// Parses a decimal floating-point token (Rust's `f64` syntax: `1`, `-2.5e3`, `.5`,
/// also `inf`/`nan`, which callers reject where needed).
fn parse_f64(token: &[u8]) -> Option<f64> {
    std::str::from_utf8(token).ok()?.parse().ok()
}

/// Parses a `v` line's values (after the keyword) into a position.
fn parse_vertex<'b>(rest: impl Iterator<Item = &'b [u8]>) -> Result<Point3<f64>, String> {
    let mut xyz = [0.0; 3];
    let mut n = 0;
    for tok in rest {
        let x = parse_f64(tok)
            .ok_or_else(|| format!("malformed `v` line: `{}` is not a number", show(tok)))?;
        // Only the position must be finite: w and colour values are ignored, and some
        // exporters write `nan` for a colour they do not have.
        if n < 3 && !x.is_finite() {
            return Err(format!("non-finite value `{}` in a `v` line", show(tok)));
        }
        if let Some(slot) = xyz.get_mut(n) {
            *slot = x;
        }
        n += 1;
    }
    match n {
        3 | 4 | 6 | 7 => Ok(Point3::new(xyz[0], xyz[1], xyz[2])),
        _ => Err(format!(
            "malformed `v` line: {n} values; expected x y z, optionally followed by w \
             or a colour"
        )),
    }
}

/// Parses the `v` lines of OBJ bytes only (see [`read_obj_positions`]).
fn parse_positions(bytes: &[u8], name: &str) -> Result<Vec<Point3<f64>>, MeshError> {
    // A face-model OBJ spends roughly 90 bytes per vertex on `v`, `vt` and `f` lines.
    let mut positions = Vec::with_capacity(bytes.len() / 96);
    for (line_no, line) in lines(bytes) {
        // Skip every other line on its first bytes, before looking for a comment. A `v`
        // keyword ends at whitespace, a comment or the end of the line.
        let line = line.trim_ascii_start();
        let is_v = line.first() == Some(&b'v')
            && line
                .get(1)
                .is_none_or(|&b| b.is_ascii_whitespace() || b == b'#');
        if !is_v {
            continue;
        }
        let mut toks = tokens(strip_comment(line)).skip(1);
        let p = parse_vertex(&mut toks).map_err(|message| {
            MeshError::File(FileError::Parse {
                path: name.to_string(),
                line: line_no,
                message,
            })
        })?;
        positions.push(p);
    }
    if positions.is_empty() {
        return Err(MeshError::Empty {
            path: name.to_string(),
            message: "no vertices (`v` lines)".into(),
        });
    }
    Ok(positions)
}

/// The largest 0-based index a kind of face reference used, and the line that used it.
#[derive(Default)]
struct MaxRef(Option<(u32, usize)>);

impl MaxRef {
    fn note(&mut self, index: u32, line: usize) {
        if self.0.is_none_or(|(m, _)| index > m) {
            self.0 = Some((index, line));
        }
    }
}

/// Placeholder in `face_uvs` for a corner without a `vt` index.
const NO_UV: u32 = u32::MAX;

/// State of one OBJ parse.
struct ObjParser<'a> {
    name: &'a str,
    positions: Vec<Point3<f64>>,
    uvs: Vec<Point2<f64>>,
    normal_count: usize,
    face_offsets: Vec<u32>,
    face_vertices: Vec<u32>,
    face_uvs: Vec<u32>,
    /// Corners that carry a `vt` index (the others hold [`NO_UV`] in `face_uvs`).
    uv_corners: usize,
    max_v: MaxRef,
    max_vt: MaxRef,
    max_vn: MaxRef,
    mtllib: Option<String>,
    materials: Vec<(u32, String)>,
    /// Count of unknown statements and the line of the first.
    unknown: Option<(usize, usize)>,
}

/// One reference of a face corner: which pool it indexes and how many elements of that
/// pool were read before the face (for negative indices).
#[derive(Clone, Copy)]
enum Pool {
    Vertex,
    TexCoord,
    Normal,
}

impl Pool {
    fn what(self) -> &'static str {
        match self {
            Pool::Vertex => "vertex",
            Pool::TexCoord => "texture coordinate",
            Pool::Normal => "normal",
        }
    }
}

impl<'a> ObjParser<'a> {
    fn new(name: &'a str) -> Self {
        ObjParser {
            name,
            positions: Vec::new(),
            uvs: Vec::new(),
            normal_count: 0,
            face_offsets: vec![0],
            face_vertices: Vec::new(),
            face_uvs: Vec::new(),
            uv_corners: 0,
            max_v: MaxRef::default(),
            max_vt: MaxRef::default(),
            max_vn: MaxRef::default(),
            mtllib: None,
            materials: Vec::new(),
            unknown: None,
        }
    }

    fn error(&self, line: usize, message: impl Into<String>) -> MeshError {
        MeshError::File(FileError::Parse {
            path: self.name.to_string(),
            line,
            message: message.into(),
        })
    }

    fn empty(&self, message: &str) -> MeshError {
        MeshError::Empty {
            path: self.name.to_string(),
            message: message.into(),
        }
    }

    fn parse(mut self, bytes: &[u8]) -> Result<Mesh, MeshError> {
        if bytes.iter().all(|b| b.is_ascii_whitespace()) {
            return Err(self.empty("the file is empty"));
        }
        // Rough capacity from the size of a typical face-model OBJ.
        let guess = bytes.len() / 96;
        self.positions.reserve(guess);
        self.uvs.reserve(guess);
        self.face_offsets.reserve(guess);
        self.face_vertices.reserve(4 * guess);
        self.face_uvs.reserve(4 * guess);

        for (line_no, line) in lines(bytes) {
            let line = strip_comment(&line);
            let mut toks = tokens(line);
            let Some(keyword) = toks.next() else {
                continue;
            };
            match keyword {
                b"v" => {
                    let p = parse_vertex(&mut toks).map_err(|m| self.error(line_no, m))?;
                    self.positions.push(p);
                }
                b"vt" => {
                    let t = self.parse_texcoord(&mut toks, line_no)?;
                    self.uvs.push(t);
                }
                b"vn" => {
                    self.parse_normal(&mut toks, line_no)?;
                    self.normal_count += 1;
                }
                b"f" => self.parse_face(&mut toks, line_no)?,
                b"mtllib" => self.parse_mtllib(line, line_no),
                b"usemtl" => self.parse_usemtl(line),
                b"g" | b"o" | b"s" | b"l" | b"p" | b"vp" | b"mg" | b"usemap" | b"maplib"
                | b"lod" | b"bevel" | b"c_interp" | b"d_interp" | b"shadow_obj" | b"trace_obj"
                | b"cstype" | b"deg" | b"bmat" | b"step" | b"curv" | b"curv2" | b"surf"
                | b"parm" | b"trim" | b"hole" | b"scrv" | b"sp" | b"end" | b"con" | b"ctech"
                | b"stech" => {}
                _ => {
                    let (count, first) = self.unknown.unwrap_or((0, line_no));
                    self.unknown = Some((count + 1, first));
                }
            }
        }
        self.finish()
    }

    fn parse_texcoord<'b>(
        &self,
        toks: impl Iterator<Item = &'b [u8]>,
        line: usize,
    ) -> Result<Point2<f64>, MeshError> {
        let mut uv = [0.0; 2];
        let mut n = 0;
        for tok in toks {
            let x = parse_f64(tok).ok_or_else(|| {
                self.error(
                    line,
                    format!("malformed `vt` line: `{}` is not a number", show(tok)),
                )
            })?;
            if !x.is_finite() {
                return Err(self.error(
                    line,
                    format!("non-finite value `{}` in a `vt` line", show(tok)),
                ));
            }
            if let Some(slot) = uv.get_mut(n) {
                *slot = x;
            }
            n += 1;
        }
        if !(1..=3).contains(&n) {
            return Err(self.error(
                line,
                format!("malformed `vt` line: {n} values; expected u [v [w]]"),
            ));
        }
        Ok(Point2::new(uv[0], uv[1]))
    }

    fn parse_normal<'b>(
        &self,
        toks: impl Iterator<Item = &'b [u8]>,
        line: usize,
    ) -> Result<(), MeshError> {
        let mut n = 0;
        for tok in toks {
            if parse_f64(tok).is_none() {
                return Err(self.error(
                    line,
                    format!("malformed `vn` line: `{}` is not a number", show(tok)),
                ));
            }
            n += 1;
        }
        if n != 3 {
            return Err(self.error(
                line,
                format!("malformed `vn` line: {n} values; expected x y z"),
            ));
        }
        Ok(())
    }

    /// Resolves one 1-based (or negative, relative) OBJ index to a 0-based index.
    /// Positive indices are range-checked at the end of the file.
    fn resolve(&mut self, token: &[u8], pool: Pool, line: usize) -> Result<u32, MeshError> {
        let bad = |s: &Self, why: &str| {
            s.error(
                line,
                format!(
                    "malformed `f` line: {} index `{}` {why}",
                    pool.what(),
                    show(token)
                ),
            )
        };
        let (negative, digits) = match token.split_first() {
            Some((b'-', rest)) => (true, rest),
            Some((b'+', rest)) => (false, rest),
            _ => (false, token),
        };
        if digits.is_empty() {
            return Err(bad(self, "is missing"));
        }
        let mut value: u64 = 0;
        for &d in digits {
            if !d.is_ascii_digit() {
                return Err(bad(self, "is not an integer"));
            }
            value = value
                .checked_mul(10)
                .and_then(|v| v.checked_add(u64::from(d - b'0')))
                .ok_or_else(|| bad(self, "is too large"))?;
        }
        if value == 0 {
            return Err(self.error(
                line,
                format!("{} index 0 in a face (OBJ indices start at 1)", pool.what()),
            ));
        }
        let count = match pool {
            Pool::Vertex => self.positions.len(),
            Pool::TexCoord => self.uvs.len(),
            Pool::Normal => self.normal_count,
        } as u64;
        let index = if negative {
            count.checked_sub(value).ok_or_else(|| {
                self.error(
                    line,
                    format!(
                        "relative {} index -{value} reaches before the first one \
                         ({count} read so far)",
                        pool.what()
                    ),
                )
            })?
        } else {
            value - 1
        };
        let index = u32::try_from(index).map_err(|_| bad(self, "is too large"))?;
        match pool {
            Pool::Vertex => self.max_v.note(index, line),
            Pool::TexCoord => self.max_vt.note(index, line),
            Pool::Normal => self.max_vn.note(index, line),
        }
        Ok(index)
    }

    fn parse_face<'b>(
        &mut self,
        toks: impl Iterator<Item = &'b [u8]>,
        line: usize,
    ) -> Result<(), MeshError> {
        let start = self.face_vertices.len();
        for corner in toks {
            let mut parts = corner.split(|&b| b == b'/');
            let v_tok = parts.next().unwrap_or_default();
            let vt_tok = parts.next();
            let vn_tok = parts.next();
            if parts.next().is_some() {
                return Err(self.error(
                    line,
                    format!(
                        "malformed `f` line: corner `{}` has more than v/vt/vn",
                        show(corner)
                    ),
                ));
            }
            let v = self.resolve(v_tok, Pool::Vertex, line)?;
            if self.face_vertices[start..].contains(&v) {
                return Err(self.error(line, format!("face repeats vertex {}", u64::from(v) + 1)));
            }
            self.face_vertices.push(v);
            // Empty fields mean "none": `v/`, `v//`, `v//vn`, `v/vt/` are all written by
            // common tools.
            let vt_tok = vt_tok.filter(|t| !t.is_empty());
            let vn_tok = vn_tok.filter(|t| !t.is_empty());
            match vt_tok {
                Some(t) => {
                    let t = self.resolve(t, Pool::TexCoord, line)?;
                    self.face_uvs.push(t);
                    self.uv_corners += 1;
                }
                // Filled in by `finish` when other corners have UVs.
                None => self.face_uvs.push(NO_UV),
            }
            if let Some(n) = vn_tok {
                self.resolve(n, Pool::Normal, line)?;
            }
        }
        let corners = self.face_vertices.len() - start;
        if corners < 3 {
            return Err(self.error(
                line,
                format!("face has {corners} corners (at least 3 needed)"),
            ));
        }
        let end = u32::try_from(self.face_vertices.len())
            .map_err(|_| self.error(line, "too many face corners for 32-bit indices"))?;
        self.face_offsets.push(end);
        Ok(())
    }

    /// Text after the keyword, trimmed (names may contain spaces).
    fn rest_of_line(line: &[u8], keyword_len: usize) -> String {
        let start = line
            .iter()
            .position(|b| !b.is_ascii_whitespace())
            .unwrap_or(0)
            + keyword_len;
        String::from_utf8_lossy(line.get(start..).unwrap_or_default().trim_ascii()).into_owned()
    }

    fn parse_mtllib(&mut self, line: &[u8], line_no: usize) {
        let lib = Self::rest_of_line(line, b"mtllib".len());
        if lib.is_empty() {
            return;
        }
        match &self.mtllib {
            None => self.mtllib = Some(lib),
            Some(first) if *first != lib => tracing::warn!(
                "{}:{line_no}: second material library `{lib}` ignored (keeping `{first}`)",
                self.name
            ),
            Some(_) => {}
        }
    }

    fn parse_usemtl(&mut self, line: &[u8]) {
        let name = Self::rest_of_line(line, b"usemtl".len());
        let face = (self.face_offsets.len() - 1) as u32;
        match self.materials.last_mut() {
            // The previous run covers no face: replace it.
            Some(last) if last.0 == face => {
                last.1 = name;
                let n = self.materials.len();
                if n >= 2 && self.materials[n - 2].1 == self.materials[n - 1].1 {
                    self.materials.pop();
                }
            }
            Some(last) if last.1 == name => {}
            _ => self.materials.push((face, name)),
        }
    }

    fn finish(mut self) -> Result<Mesh, MeshError> {
        if let Some((count, first)) = self.unknown {
            tracing::warn!(
                "{}: {count} unknown OBJ statement(s) ignored, first at line {first}",
                self.name
            );
        }
        if self.positions.is_empty() {
            return Err(self.empty("no vertices (`v` lines)"));
        }
        if self.face_offsets.len() < 2 {
            return Err(self.empty("no faces (`f` lines)"));
        }
        // A `usemtl` after the last face starts a run that covers nothing.
        let face_count = (self.face_offsets.len() - 1) as u32;
        while self.materials.last().is_some_and(|r| r.0 >= face_count) {
            self.materials.pop();
        }
        let checks = [
            (&self.max_v, self.positions.len(), Pool::Vertex),
            (&self.max_vt, self.uvs.len(), Pool::TexCoord),
            (&self.max_vn, self.normal_count, Pool::Normal),
        ];
        for (max, count, pool) in checks {
            if let Some((index, line)) = max.0
                && index as usize >= count
            {
                return Err(self.error(
                    line,
                    format!(
                        "face uses {} {} but the file has {count}",
                        pool.what(),
                        u64::from(index) + 1
                    ),
                ));
            }
        }
        if u32::try_from(self.positions.len()).is_err() || u32::try_from(self.uvs.len()).is_err() {
            return Err(self.empty("too many vertices for 32-bit indices"));
        }
        if self.uv_corners == 0 {
            self.uvs = Vec::new();
            self.face_uvs = Vec::new();
        } else if self.uv_corners < self.face_uvs.len() {
            // Some corners have UVs and some not: the ones without get one extra UV at
            // (0, 0), as Blender does, so no face and no UV is lost.
            let missing = self.face_uvs.len() - self.uv_corners;
            let origin = u32::try_from(self.uvs.len())
                .map_err(|_| self.empty("too many texture coordinates for 32-bit indices"))?;
            self.uvs.push(Point2::origin());
            for t in &mut self.face_uvs {
                if *t == NO_UV {
                    *t = origin;
                }
            }
            tracing::warn!(
                "{}: {missing} face corner(s) without texture coordinates among corners \
                 with them; they get UV (0, 0)",
                self.name
            );
        }
        Mesh::from_flat(
            self.positions,
            self.uvs,
            self.face_offsets,
            self.face_vertices,
            self.face_uvs,
            self.mtllib,
            self.materials,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::test_meshes::grid;

    fn parse(text: &str) -> Result<Mesh, MeshError> {
        read_obj_str(text, "test.obj")
    }

    /// Asserts a parse error at `line` whose message contains `needle`.
    fn assert_parse_error(text: &str, line: usize, needle: &str) {
        match parse(text) {
            Err(e @ MeshError::File(FileError::Parse { line: l, .. })) => {
                let msg = e.to_string();
                assert_eq!(l, line, "wrong line in `{msg}`");
                assert!(msg.starts_with(&format!("test.obj:{line}: ")), "{msg}");
                assert!(msg.contains(needle), "`{msg}` lacks `{needle}`");
            }
            other => panic!("expected a parse error at line {line}, got {other:?}"),
        }
    }

    const SQUARE: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n";

    /// Coordinates are written as the shortest decimals that read back bit for bit,
    /// whole numbers without `.0`, tiny and huge ones with an exponent.
    #[test]
    fn written_numbers_read_back_exactly() {
        let m = parse(&format!(
            "{SQUARE}vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n"
        ))
        .unwrap();
        let positions = [
            Point3::new(2.0, -0.0, 0.1),
            Point3::new(-2.5485162262958167e-21, 95.13780939531594, 1e17),
            Point3::new(123456789.125, -1e-7, f64::MIN_POSITIVE),
            Point3::new(f64::MAX, -3.0, 1.0 / 3.0),
        ];
        let mut text = Vec::new();
        write_obj_to(&mut text, &m, &positions).unwrap();
        let text = String::from_utf8(text).unwrap();
        assert!(text.contains("\nv 2 -0 0.1\n"), "{text}");
        assert!(text.contains("\nf 1/1 2/2 3/3 4/4\n"), "{text}");
        let back = parse(&text).unwrap();
        for (a, b) in back.positions.iter().zip(&positions) {
            for k in 0..3 {
                assert_eq!(a[k].to_bits(), b[k].to_bits(), "{} vs {}", a[k], b[k]);
            }
        }
        assert_eq!(back.uvs, m.uvs);
    }

    #[test]
    fn every_index_form() {
        let uv = "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n";
        let vn = "vn 0 0 1\n";
        let m = parse(&format!("{SQUARE}f 1 2 3 4\n")).unwrap();
        assert_eq!(m.face(0), &[0, 1, 2, 3]);
        assert!(!m.has_uvs() && m.uvs.is_empty());

        let m = parse(&format!("{SQUARE}{uv}f 1/4 2/3 3/2 4/1\n")).unwrap();
        assert_eq!(m.face(0), &[0, 1, 2, 3]);
        assert_eq!(m.face_uv(0), &[3, 2, 1, 0]);
        assert_eq!(m.uvs[m.face_uv(0)[1] as usize], Point2::new(1.0, 1.0));

        let m = parse(&format!("{SQUARE}{vn}f 1//1 2//1 3//1 4//1\n")).unwrap();
        assert_eq!(m.face(0), &[0, 1, 2, 3]);
        assert!(!m.has_uvs());

        let m = parse(&format!("{SQUARE}{uv}{vn}f 1/1/1 2/2/1 3/3/1 4/4/1\n")).unwrap();
        assert_eq!(m.face_uv(0), &[0, 1, 2, 3]);
        assert_eq!(m.triangles.len(), 2);
    }

    #[test]
    fn negative_indices_are_relative() {
        let text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\n\
                    f -3/-3 -2/-2 -1/-1\nv 0 1 0\nvt 0 1\nf -4/-4 -2/-2 -1/-1\n";
        let m = parse(text).unwrap();
        assert_eq!(m.face(0), &[0, 1, 2]);
        assert_eq!(m.face(1), &[0, 2, 3]);
        assert_eq!(m.face_uv(1), &[0, 2, 3]);
        assert_parse_error(
            "v 0 0 0\nv 1 0 0\nf -1 -2 -3\n",
            3,
            "reaches before the first",
        );
    }

    #[test]
    fn polygons_keep_all_corners() {
        let text = "v 1 0 0\nv 0.31 0.95 0\nv -0.81 0.59 0\nv -0.81 -0.59 0\nv 0.31 -0.95 0\n\
                    v 2 0 0\nv 2 1 0\nv 2 2 0\nv 1 2 0\n\
                    f 1 2 3 4 5\nf 1 6 7 8 9 2\n";
        let m = parse(text).unwrap();
        assert_eq!(m.face_count(), 2);
        assert_eq!(m.face(0), &[0, 1, 2, 3, 4]);
        assert_eq!(m.face(1), &[0, 5, 6, 7, 8, 1]);
        assert_eq!(m.triangles.len(), 3 + 4);
        assert_eq!(m.triangles[..3], [[0, 1, 2], [0, 2, 3], [0, 3, 4]]);
    }

    #[test]
    fn comments_groups_materials_and_crlf() {
        let text = "# header\r\n\r\nmtllib face.mtl\r\no head\r\ng skin\r\n\
                    v 0 0 0 1\r\nv 1 0 0 0.5 0.5 0.5\r\nv 1 1 0   # trailing comment\r\n\
                    v 0 1 0\r\nv 2 0 0\r\nvp 0.5\r\ns 1\r\nusemtl A\r\nusemtl Skin Mat\r\n\
                    f 1 2 3\r\nf 1 3 4\r\nusemtl Skin Mat\r\nf 2 5 3\r\nusemtl Eye\r\n\
                    l 1 2\r\nf 1 2 4\r\ns off\r\nusemtl Unused\r\n";
        let m = parse(text).unwrap();
        assert_eq!(m.vertex_count(), 5);
        assert_eq!(m.positions[2], Point3::new(1.0, 1.0, 0.0));
        assert_eq!(m.face_count(), 4);
        assert_eq!(m.mtllib.as_deref(), Some("face.mtl"));
        // `A` covers no face, the repeated `Skin Mat` is merged, `Unused` covers none.
        assert_eq!(
            m.materials,
            vec![(0, "Skin Mat".to_string()), (3, "Eye".to_string())]
        );
    }

    #[test]
    fn forward_references_and_bom() {
        let m = parse("\u{feff}f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\n").unwrap();
        assert_eq!(m.face(0), &[0, 1, 2]);
    }

    #[test]
    fn missing_file_is_io_error_naming_the_path() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("absent.obj");
        for result in [
            read_obj(&path).map(|_| ()),
            read_obj_positions(&path).map(|_| ()),
        ] {
            match result {
                Err(e @ MeshError::File(FileError::Io { .. })) => {
                    assert!(e.to_string().contains("absent.obj"), "{e}");
                }
                other => panic!("expected an I/O error, got {other:?}"),
            }
        }
    }

    #[test]
    fn malformed_lines_name_the_line() {
        assert_parse_error("v 0 0 0\nv 1 0\n", 2, "`v` line: 2 values");
        assert_parse_error("v 0 0 0\nv 1 x 0\n", 2, "`x` is not a number");
        assert_parse_error("v 0 0 0\nv 1 2 3 4 5\n", 2, "5 values");
        assert_parse_error("v 0 0 0\nvt\n", 2, "`vt` line: 0 values");
        assert_parse_error("v 0 0 0\nvt 0.5 y\n", 2, "`y` is not a number");
        assert_parse_error("vn 0 0\n", 1, "`vn` line");
        assert_parse_error(&format!("{SQUARE}f 1 2 a\n"), 5, "not an integer");
        assert_parse_error(&format!("{SQUARE}f 1 2 3/1/1/1\n"), 5, "more than v/vt/vn");
        assert_parse_error(&format!("{SQUARE}f 1 2 /1\n"), 5, "vertex index");
    }

    #[test]
    fn non_finite_coordinates_are_rejected() {
        assert_parse_error("v 0 0 0\n\nv 1 NaN 0\n", 3, "non-finite");
        assert_parse_error("v 0 0 inf\n", 1, "non-finite");
        assert_parse_error("v 0 0 0\nvt -inf 0\n", 2, "non-finite");
        assert_parse_error("v 0 0 1e999\n", 1, "non-finite");
    }

    #[test]
    fn bad_face_indices_are_rejected() {
        assert_parse_error(&format!("{SQUARE}f 1 2 0\n"), 5, "index 0");
        assert_parse_error(
            &format!("{SQUARE}f 1 2 3\nf 1 2 9\nf 1 3 4\n"),
            6,
            "vertex 9",
        );
        assert_parse_error(
            &format!("{SQUARE}vt 0 0\nf 1/1 2/1 3/2\n"),
            6,
            "coordinate 2",
        );
        assert_parse_error(
            &format!("{SQUARE}vn 0 0 1\nf 1//1 2//2 3//1\n"),
            6,
            "normal 2",
        );
        assert_parse_error(
            &format!("{SQUARE}f 1 2 99999999999999999999999\n"),
            5,
            "too large",
        );
    }

    #[test]
    fn degenerate_faces_are_rejected() {
        assert_parse_error(&format!("{SQUARE}f 1 2 3\nf 1 2\n"), 6, "2 corners");
        assert_parse_error(&format!("{SQUARE}f\n"), 5, "0 corners");
        assert_parse_error(&format!("{SQUARE}f 1 2 3 1\n"), 5, "repeats vertex 1");
        // The same vertex through a negative index.
        assert_parse_error(&format!("{SQUARE}f 1 2 -1 4\n"), 5, "repeats vertex 4");
    }

    /// Faces with and without UVs in one file (issue 18): every face is kept, corners
    /// without `vt` share one extra UV at (0, 0).
    #[test]
    fn mixed_uv_faces_load() {
        let uv = "vt 0.5 0.5\nvt 1 0\nvt 1 1\n";
        let m = parse(&format!("{SQUARE}{uv}f 1/1 2/2 3/3\nf 1 3 4\n")).unwrap();
        assert_eq!(m.face_count(), 2);
        assert_eq!(m.uvs.len(), 4);
        assert_eq!(m.face_uv(0), &[0, 1, 2]);
        assert_eq!(m.face_uv(1), &[3, 3, 3]);
        assert_eq!(m.uvs[3], Point2::origin());
        let m = parse(&format!("{SQUARE}{uv}f 1/1 2 3/3\n")).unwrap();
        assert_eq!(m.face_uv(0), &[0, 3, 2]);
    }

    /// The corner forms with empty fields, line continuation and a `nan` colour that
    /// other tools write (issue 18).
    #[test]
    fn forms_other_tools_write() {
        let uv = "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n";
        let m = parse(&format!("{SQUARE}f 1// 2// 3//\nf 1/ 3/ 4/\n")).unwrap();
        assert_eq!((m.face_count(), m.uvs.len()), (2, 0));
        assert_eq!(m.face(1), &[0, 2, 3]);
        let m = parse(&format!("{SQUARE}{uv}f 1/1/ 2/2/ 3/3/\n")).unwrap();
        assert_eq!(m.face_uv(0), &[0, 1, 2]);
        let m = parse(&format!("{SQUARE}f 1 2 \\\n  3 4\nv 5 \\\n 6 7\nf 1 5 2\n")).unwrap();
        assert_eq!(m.face(0), &[0, 1, 2, 3]);
        assert_eq!(m.positions[4], Point3::new(5.0, 6.0, 7.0));
        assert_eq!(m.face_count(), 2);
        // A comment ending in a backslash does not continue.
        let m = parse(&format!("{SQUARE}# note \\\nf 1 2 3\n")).unwrap();
        assert_eq!(m.face_count(), 1);
        // Errors after a continuation name the first line of the statement.
        assert_parse_error(&format!("{SQUARE}f 1 2 \\\n x\n"), 5, "not an integer");
        let m =
            parse("v 0 0 0 nan nan nan\nv 1 0 0 0.5 0.5 0.5\nv 0 1 0 1 1 1\nf 1 2 3\n").unwrap();
        assert_eq!(m.positions.len(), 3);
        assert_parse_error("v 0 nan 0 1 1 1\n", 1, "non-finite");
    }

    #[test]
    fn empty_inputs_are_rejected() {
        for (text, needle) in [
            ("", "empty"),
            ("  \r\n\n", "empty"),
            ("# only a comment\n", "no vertices"),
            ("vt 0 0\nf 1 2 3\n", "no vertices"),
            ("v 0 0 0\nv 1 0 0\nv 0 1 0\nl 1 2\n", "no faces"),
        ] {
            match parse(text) {
                Err(e @ MeshError::Empty { .. }) => {
                    let msg = e.to_string();
                    assert!(msg.starts_with("test.obj: "), "{msg}");
                    assert!(msg.contains(needle), "`{msg}` lacks `{needle}`");
                }
                other => panic!("{text:?}: expected Empty, got {other:?}"),
            }
        }
    }

    #[test]
    fn positions_fast_path() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("shape.obj");
        std::fs::write(
            &path,
            "# c\nv 1 2 3\r\nvt 0 0\nvn 0 0 1\nv -1 0.5 2e-3 1\nf 1 2 3\n",
        )
        .unwrap();
        let p = read_obj_positions(&path).unwrap();
        assert_eq!(
            p,
            vec![Point3::new(1.0, 2.0, 3.0), Point3::new(-1.0, 0.5, 2e-3)]
        );

        std::fs::write(&path, "v 1 2 3\nv 1 nan 3\n").unwrap();
        match read_obj_positions(&path) {
            Err(e @ MeshError::File(FileError::Parse { line: 2, .. })) => {
                assert!(e.to_string().contains(":2: "))
            }
            other => panic!("expected a parse error at line 2, got {other:?}"),
        }
        std::fs::write(&path, "vt 0 0\n").unwrap();
        assert!(matches!(
            read_obj_positions(&path),
            Err(MeshError::Empty { .. })
        ));
        // A bare `v` keyword is as malformed here as in the full reader.
        for text in ["v 1 2 3\nv", "v 1 2 3\nv# c\n", "v 1 2 3\n  v\r\n"] {
            std::fs::write(&path, text).unwrap();
            let err = read_obj_positions(&path).unwrap_err();
            assert!(
                matches!(err, MeshError::File(FileError::Parse { line: 2, .. })),
                "{text:?}: {err}"
            );
            let err = read_obj_str(text, "s").unwrap_err();
            assert!(
                matches!(err, MeshError::File(FileError::Parse { line: 2, .. })),
                "{text:?}: {err}"
            );
        }
    }

    /// A small mesh whose coordinates need all 17 significant digits, with seams,
    /// materials, a triangle and a pentagon.
    fn awkward_mesh() -> Mesh {
        let positions = vec![
            Point3::new(0.1 + 0.2, 1.0 / 3.0, -0.0),
            Point3::new(1e-300, 123_456_789.0 + 1.0 / 9.0, -2.5e-7),
            Point3::new(f64::MIN_POSITIVE, 5e-324, 1e300),
            Point3::new(-std::f64::consts::PI, std::f64::consts::E, 7.0),
            Point3::new(0.7, -0.3, 1.0 / 7.0),
            Point3::new(2.0, 2.0, 2.0),
        ];
        let uvs = vec![
            Point2::new(0.1 + 0.2, 2.0 / 3.0),
            Point2::new(1e-17, 1.0 - f64::EPSILON),
            Point2::new(0.5, 0.25),
            Point2::new(0.125, 1.0 / 9.0),
            Point2::new(0.75, 0.0),
        ];
        let faces = vec![vec![0, 1, 2], vec![1, 3, 4, 5, 2]];
        let face_uvs = vec![vec![0, 1, 2], vec![1, 3, 4, 0, 2]];
        let mut m = Mesh::new(positions, &faces, uvs, Some(&face_uvs)).unwrap();
        m.mtllib = Some("my lib.mtl".into());
        m.materials = vec![(0, "Skin".into()), (1, "Eye White".into())];
        m
    }

    fn assert_bit_identical(a: &Mesh, b: &Mesh) {
        assert_eq!(a.positions.len(), b.positions.len());
        for (p, q) in a.positions.iter().zip(&b.positions) {
            for k in 0..3 {
                assert_eq!(p[k].to_bits(), q[k].to_bits(), "{p} vs {q}");
            }
        }
        assert_eq!(a.uvs.len(), b.uvs.len());
        for (p, q) in a.uvs.iter().zip(&b.uvs) {
            for k in 0..2 {
                assert_eq!(p[k].to_bits(), q[k].to_bits(), "{p} vs {q}");
            }
        }
        assert_eq!(a.face_offsets, b.face_offsets);
        assert_eq!(a.face_vertices, b.face_vertices);
        assert_eq!(a.face_uvs, b.face_uvs);
        assert_eq!(a.mtllib, b.mtllib);
        assert_eq!(a.materials, b.materials);
        assert_eq!(a.triangles, b.triangles);
    }

    #[test]
    fn round_trip_is_bit_identical() {
        let m = awkward_mesh();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.obj");
        write_obj(&path, &m).unwrap();
        let back = read_obj(&path).unwrap();
        assert_bit_identical(&m, &back);
        // No temporary file is left behind.
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1);

        // Without UVs the faces are written as plain `v`.
        let g = Mesh::new(m.positions.clone(), &[vec![0, 1, 2]], Vec::new(), None).unwrap();
        let mut text = Vec::new();
        write_obj_to(&mut text, &g, &g.positions).unwrap();
        let text = String::from_utf8(text).unwrap();
        assert!(
            text.contains("\nf 1 2 3\n") && !text.contains("vt"),
            "{text}"
        );
        assert_bit_identical(&g, &read_obj_str(&text, "mem").unwrap());
    }

    #[test]
    fn write_positions_checks_and_overwrites() {
        let m = grid(2, 1.0);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("g.obj");
        write_obj(&path, &m).unwrap();
        let moved: Vec<_> = m
            .positions
            .iter()
            .map(|p| p + nalgebra::Vector3::z())
            .collect();
        write_obj_positions(&path, &m, &moved).unwrap();
        let back = read_obj(&path).unwrap();
        assert_eq!(back.positions, moved);
        assert_eq!(back.face_uvs, m.face_uvs);

        let err = write_obj_positions(&path, &m, &moved[1..]).unwrap_err();
        assert!(matches!(err, MeshError::Invalid(_)), "{err}");
        let mut nan = moved.clone();
        nan[3].y = f64::NAN;
        let err = write_obj_positions(&path, &m, &nan).unwrap_err();
        assert!(err.to_string().contains("vertex 3"), "{err}");
        // The failed writes left the earlier file intact.
        assert_eq!(read_obj(&path).unwrap().positions, moved);

        let missing_dir = dir.path().join("no/such/dir/g.obj");
        let err = write_obj(&missing_dir, &m).unwrap_err();
        assert!(
            matches!(err, MeshError::File(FileError::Io { .. }))
                && err.to_string().contains("g.obj")
        );
    }

    fn ict_dir() -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/ict-facekit")
    }

    #[test]
    fn ict_neutral_round_trip() {
        let path = ict_dir().join("generic_neutral_mesh.obj");
        if !path.exists() {
            eprintln!(
                "skipping ict_neutral_round_trip: {} not found (the ICT-FaceKit test data \
                 is not checked out beside the repository)",
                path.display()
            );
            return;
        }
        let m = read_obj(&path).unwrap();
        assert_eq!(m.vertex_count(), 26_719);
        assert_eq!(m.face_count(), 26_384);
        assert_eq!(m.uvs.len(), 28_911);
        assert!(m.has_uvs());
        assert_eq!(m.mtllib.as_deref(), Some("ICTFaceModelMaterial.mtl"));
        assert_eq!(m.materials.len(), 12);
        assert_eq!(m.materials[0], (0, "M_Face".to_string()));
        let quads = m.faces().filter(|f| f.len() == 4).count();
        assert_eq!(quads, 25_836);

        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("neutral.obj");
        write_obj(&out, &m).unwrap();
        let back = read_obj(&out).unwrap();
        assert_bit_identical(&m, &back);
        assert_eq!(read_obj_positions(&path).unwrap(), m.positions);
    }

    /// Load timings on the ICT data; run with
    /// `cargo test --release --lib ict_load_timing -- --ignored --nocapture`.
    #[test]
    #[ignore = "timing report, not a check"]
    fn ict_load_timing() {
        use std::time::Instant;
        let dir = ict_dir();
        let neutral = dir.join("generic_neutral_mesh.obj");
        let expression = dir.join("jawOpen.obj");
        if !neutral.exists() {
            eprintln!("skipping: ICT-FaceKit data not found at {}", dir.display());
            return;
        }
        let median = |f: &dyn Fn()| {
            let mut t: Vec<f64> = (0..5)
                .map(|_| {
                    let s = Instant::now();
                    f();
                    s.elapsed().as_secs_f64() * 1e3
                })
                .collect();
            t.sort_by(f64::total_cmp);
            t[2]
        };
        let m = read_obj(&neutral).unwrap();
        let t_mesh = median(&|| {
            read_obj(&neutral).unwrap();
        });
        let t_pos = median(&|| {
            read_obj_positions(&expression).unwrap();
        });
        // Share of float parsing in the positions path (to judge a faster float parser).
        let bytes = std::fs::read(&expression).unwrap();
        let floats: Vec<&[u8]> = bytes
            .split(|&b| b == b'\n')
            .filter(|l| l.starts_with(b"v "))
            .flat_map(|l| tokens(l).skip(1))
            .collect();
        let t_float = median(&|| {
            let s: f64 = floats.iter().map(|t| parse_f64(t).unwrap()).sum();
            std::hint::black_box(s);
        });
        let out = tempfile::tempdir().unwrap();
        let t_write = median(&|| write_obj(&out.path().join("n.obj"), &m).unwrap());
        let mut all: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "obj") && *p != neutral)
            .collect();
        all.sort();
        // Every ICT file parses with the full reader and shares the neutral's polygons.
        for p in &all {
            let shape = read_obj(p).unwrap();
            assert_eq!(shape.face_vertices, m.face_vertices, "{}", p.display());
            assert_eq!(shape.positions, read_obj_positions(p).unwrap());
        }
        let t_all = median(&|| {
            use rayon::prelude::*;
            read_obj(&neutral).unwrap();
            let shapes: Vec<_> = all
                .par_iter()
                .map(|p| read_obj_positions(p).unwrap())
                .collect();
            assert_eq!(shapes.len(), all.len());
        });
        eprintln!("read_obj(neutral): median {t_mesh:.1} ms");
        eprintln!("read_obj_positions(jawOpen): median {t_pos:.1} ms");
        eprintln!(
            "  of which parsing its {} floats: median {t_float:.1} ms",
            floats.len()
        );
        eprintln!("write_obj(neutral): median {t_write:.1} ms");
        eprintln!(
            "neutral + {} shapes (rayon): median {t_all:.1} ms",
            all.len()
        );
    }
}
