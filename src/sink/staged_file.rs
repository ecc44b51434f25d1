//! A file written progressively and published atomically: rows go to a hidden temporary
//! file beside the destination as frames arrive; [`StagedFile::commit`] flushes, syncs and
//! renames it into place. Until then the destination keeps its previous content (or does
//! not exist), so a reader never sees a half-written file; dropping an uncommitted file
//! removes the temporary.

use std::fs::{File, OpenOptions};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::pipeline::SinkError;

/// See the module docs.
#[derive(Debug)]
pub struct StagedFile {
    path: PathBuf,
    temp: PathBuf,
    writer: Option<BufWriter<File>>,
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
        })
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
    pub fn commit(mut self) -> Result<(), SinkError> {
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
        Ok(())
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
}
