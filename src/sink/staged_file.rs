//! A file written progressively and published atomically: rows go to a hidden temporary
//! file beside the destination as frames arrive; [`StagedFile::commit`] flushes, syncs and
//! renames it into place. Until then the destination keeps its previous content (or does
//! not exist), so a reader never sees a half-written file; dropping an uncommitted file
//! removes the temporary.
//!
//! # Complete data only
//! A sink that writes frame by frame calls [`StagedFile::mark_complete`] after each frame:
//! the data is flushed to the file and its length remembered. When a later write fails
//! (disk full, an I/O error), [`StagedFile::roll_back`] cuts the file back to that length,
//! and [`StagedFile::commit`] does so by itself when the final flush fails: the published
//! file then holds every complete frame and nothing half-written, and the space of the
//! dropped bytes is free again for the other outputs of the take.

use std::fs::{File, OpenOptions};
use std::io::{self, BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use crate::pipeline::SinkError;

/// See the module docs.
#[derive(Debug)]
pub struct StagedFile {
    path: PathBuf,
    temp: PathBuf,
    writer: Option<BufWriter<File>>,
    /// Length of the complete data (see the module docs); None: never marked.
    complete_len: Option<u64>,
}

impl StagedFile {
    /// Starts `path` (its folder must exist): creates `.<name>.<pid>.partial` beside it.
    ///
    /// # Errors
    /// [`SinkError::Io`] naming the temporary file.
    pub fn create(path: &Path) -> Result<Self, SinkError> {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .ok_or_else(|| SinkError::Other(format!("{} does not name a file", path.display())))?;
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let temp = dir.join(format!(".{name}.{}.partial", std::process::id()));
        let file = OpenOptions::new()
            .write(true)
            .create(true)
            .truncate(true)
            .open(&temp)
            .map_err(|e| SinkError::io(&temp, e))?;
        Ok(Self {
            path: path.to_path_buf(),
            temp,
            writer: Some(BufWriter::with_capacity(1 << 16, file)),
            complete_len: None,
        })
    }

    /// Marks everything written so far as complete: flushes it to the file and remembers
    /// the file's length (the position of the writer).
    ///
    /// # Errors
    /// [`SinkError::Io`] naming the destination when the flush fails (nothing is marked:
    /// call [`StagedFile::roll_back`]).
    pub fn mark_complete(&mut self) -> Result<(), SinkError> {
        let path = self.path.clone();
        let w = self.writer()?;
        w.flush().map_err(|e| SinkError::io(&path, e))?;
        let len = w
            .get_mut()
            .stream_position()
            .map_err(|e| SinkError::io(&path, e))?;
        self.complete_len = Some(len);
        Ok(())
    }

    /// Length of the data marked complete, if any was.
    pub fn complete_len(&self) -> Option<u64> {
        self.complete_len
    }

    /// Drops everything written after the last [`StagedFile::mark_complete`] (buffered or
    /// already in the file) and puts the writer at the end of the complete data. The
    /// bytes after it on disk are freed.
    ///
    /// # Errors
    /// [`SinkError::Io`] naming the temporary file when it cannot be cut;
    /// [`SinkError::Other`] when nothing was ever marked complete.
    pub fn roll_back(&mut self) -> Result<(), SinkError> {
        let len = self.complete_len.ok_or_else(|| {
            SinkError::Other(format!("{}: no complete data to keep", self.path.display()))
        })?;
        let w = self.writer.take().ok_or_else(|| {
            SinkError::Other(format!("{} is already closed", self.path.display()))
        })?;
        // The buffered bytes are the incomplete frame's: dropped, never written.
        let (mut file, _dropped) = w.into_parts();
        let temp = self.temp.clone();
        let result = file
            .set_len(len)
            .and_then(|()| file.seek(SeekFrom::Start(len)).map(drop));
        // Keep the file open either way so that `Drop` still removes the temporary.
        self.writer = Some(BufWriter::with_capacity(1 << 16, file));
        result.map_err(|e| SinkError::io(temp, e))
    }

    /// The destination.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The temporary file being written.
    pub fn temp_path(&self) -> &Path {
        &self.temp
    }

    /// The writer of the temporary file.
    ///
    /// # Errors
    /// [`SinkError::Other`] after [`StagedFile::commit`].
    pub fn writer(&mut self) -> Result<&mut BufWriter<File>, SinkError> {
        self.writer
            .as_mut()
            .ok_or_else(|| SinkError::Other(format!("{} is already closed", self.path.display())))
    }

    /// Runs `f` on the writer, mapping I/O errors to [`SinkError::Io`] naming the
    /// destination.
    ///
    /// # Errors
    /// As `f`, or when already committed.
    pub fn write_with(
        &mut self,
        f: impl FnOnce(&mut BufWriter<File>) -> io::Result<()>,
    ) -> Result<(), SinkError> {
        let path = self.path.clone();
        let w = self.writer()?;
        f(w).map_err(|e| SinkError::io(path, e))
    }

    /// Flushes the data to disk (the temporary stays in place; for a consumer that reads
    /// it back, such as the USD sink).
    ///
    /// # Errors
    /// [`SinkError::Io`].
    pub fn flush(&mut self) -> Result<(), SinkError> {
        let path = self.temp.clone();
        let w = self.writer()?;
        w.flush().map_err(|e| SinkError::io(path, e))
    }

    /// Flushes, syncs and renames the temporary over the destination.
    ///
    /// # Errors
    /// [`SinkError::Io`] naming the destination; the temporary is removed.
    ///
    /// When the flush fails and data was marked complete ([`StagedFile::mark_complete`]),
    /// the file is cut back to the complete data and published all the same; the error is
    /// still returned (it says what was kept).
    pub fn commit(mut self) -> Result<(), SinkError> {
        let flushed = match self.writer.as_mut() {
            None => return Ok(()),
            Some(w) => w.flush(),
        };
        let mut kept_after = None;
        if let Err(e) = flushed {
            if self.complete_len.is_none() || self.roll_back().is_err() {
                let _ = std::fs::remove_file(&self.temp);
                self.writer = None;
                return Err(SinkError::io(&self.path, e));
            }
            kept_after = Some(e);
        }
        let Some(w) = self.writer.take() else {
            return Ok(());
        };
        let result = w
            .into_inner()
            .map_err(|e| e.into_error())
            .and_then(|f| f.sync_all())
            .and_then(|()| std::fs::rename(&self.temp, &self.path));
        if let Err(e) = result {
            let _ = std::fs::remove_file(&self.temp);
            return Err(SinkError::io(&self.path, e));
        }
        match kept_after {
            None => Ok(()),
            Some(e) => Err(SinkError::Other(format!(
                "{}: {e}; published the {} bytes complete before the error",
                self.path.display(),
                self.complete_len.unwrap_or(0)
            ))),
        }
    }

    /// Closes the temporary without publishing it; returns its path (the caller removes
    /// it).
    ///
    /// # Errors
    /// [`SinkError::Io`] when the buffered data cannot be flushed.
    pub fn close_temp(mut self) -> Result<PathBuf, SinkError> {
        if let Some(w) = self.writer.take() {
            w.into_inner()
                .map_err(|e| SinkError::io(&self.temp, e.into_error()))?;
        }
        Ok(std::mem::take(&mut self.temp))
    }
}

impl Drop for StagedFile {
    fn drop(&mut self) {
        if self.writer.is_some() && !self.temp.as_os_str().is_empty() {
            self.writer = None;
            let _ = std::fs::remove_file(&self.temp);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn publishes_only_on_commit() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.csv");
        let mut f = StagedFile::create(&path).unwrap();
        f.write_with(|w| writeln!(w, "x")).unwrap();
        assert!(!path.exists());
        f.commit().unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "x\n");
        let mut g = StagedFile::create(&path).unwrap();
        g.write_with(|w| writeln!(w, "y")).unwrap();
        drop(g);
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "x\n");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn roll_back_keeps_the_complete_data_only() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("b.csv");
        let mut f = StagedFile::create(&path).unwrap();
        f.write_with(|w| writeln!(w, "header")).unwrap();
        f.mark_complete().unwrap();
        f.write_with(|w| writeln!(w, "frame 0")).unwrap();
        f.mark_complete().unwrap();
        assert_eq!(f.complete_len(), Some(15));
        // Half a frame, some of it already on disk: cut back.
        f.write_with(|w| w.write_all(&vec![b'x'; 100_000])).unwrap();
        f.roll_back().unwrap();
        f.write_with(|w| writeln!(w, "frame 1")).unwrap();
        f.mark_complete().unwrap();
        f.commit().unwrap();
        assert_eq!(
            std::fs::read_to_string(&path).unwrap(),
            "header\nframe 0\nframe 1\n"
        );
    }
}
