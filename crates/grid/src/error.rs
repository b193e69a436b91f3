//! Errors that name the file, line, column and field at fault.

use std::fmt;
use std::path::PathBuf;

/// Where in a scene file a problem lies.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Location {
    /// The scene file, or `<scene>` when it came from a string.
    pub file: String,
    /// 1-based line and column, when known.
    pub line_column: Option<(usize, usize)>,
    /// Dotted field path such as `object[1].shape.radius`; empty for syntax errors.
    pub field: String,
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file)?;
        if let Some((l, c)) = self.line_column {
            write!(f, ":{l}:{c}")?;
        }
        if !self.field.is_empty() {
            write!(f, ": {}", self.field)?;
        }
        Ok(())
    }
}

/// Everything that can go wrong reading a scene or building its medium.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The scene file could not be read at all.
    #[error("{}: cannot read scene file", path.display())]
    Read {
        /// The file that was asked for.
        path: PathBuf,
        /// Why it could not be read.
        source: std::io::Error,
    },
    /// A value is malformed, out of range, or would not fit in memory.
    #[error("{at}: {message}")]
    Invalid {
        /// File, line, column and field.
        at: Location,
        /// What is wrong and what is expected.
        message: String,
    },
}

/// Shorthand for results in this crate.
pub type Result<T> = std::result::Result<T, Error>;
