//! The error of a file that cannot be read or written, or holds a malformed line: one type
//! that the readers and writers of the text formats (meshes, bundles, marker layouts, name
//! maps) share, so every such message has the same form: `path: cause` or
//! `path:line: what is wrong`.

use std::fmt::Display;

/// A file that could not be read or written, or a malformed line in it.
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    /// The file could not be opened, read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file involved (or a stand-in such as `<writer>` for a stream).
        path: String,
        /// The system's error.
        #[source]
        source: std::io::Error,
    },
    /// A line of the file is malformed.
    #[error("{path}:{line}: {message}")]
    Parse {
        /// The file involved.
        path: String,
        /// 1-based line number (0 when the file as a whole, or a binary part, is at fault).
        line: usize,
        /// What was wrong, and how to fix it where that is known.
        message: String,
    },
}

impl FileError {
    /// [`FileError::Io`] for the file shown as `path`.
    pub fn io(path: impl Display, source: std::io::Error) -> Self {
        Self::Io {
            path: path.to_string(),
            source,
        }
    }

    /// [`FileError::Parse`] for line `line` of the file shown as `path`.
    pub fn parse(path: impl Display, line: usize, message: impl Into<String>) -> Self {
        Self::Parse {
            path: path.to_string(),
            line,
            message: message.into(),
        }
    }

    /// The 1-based line at fault, for [`FileError::Parse`].
    pub fn line(&self) -> Option<usize> {
        match self {
            Self::Parse { line, .. } => Some(*line),
            Self::Io { .. } => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_name_the_file_and_line_once() {
        let io = FileError::io(
            "a/b.obj",
            std::io::Error::new(std::io::ErrorKind::NotFound, "gone"),
        );
        assert_eq!(io.to_string(), "a/b.obj: gone");
        assert_eq!(io.line(), None);
        let parse = FileError::parse("m.csv", 7, "bad number");
        assert_eq!(parse.to_string(), "m.csv:7: bad number");
        assert_eq!(parse.line(), Some(7));
    }
}
