//! One error type for everything that reads or writes files: it always names the file, and where
//! it can, the line, byte offset or element that was wrong.

use std::fmt;
use std::path::{Path, PathBuf};

/// Where in a file a problem was found.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Location {
    /// 1-based line of a text file.
    Line(usize),
    /// Byte offset from the start of the file.
    Byte(u64),
    /// A named element, such as `vertex 12` or `mesh 0 primitive 1`.
    Element(String),
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Location::Line(n) => write!(f, "line {n}"),
            Location::Byte(n) => write!(f, "byte offset {n}"),
            Location::Element(e) => f.write_str(e),
        }
    }
}

/// An error reading or writing a file.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("{}: {cause}", path.display())]
    Io { path: PathBuf, cause: std::io::Error },
    #[error("{}: {}{message}", path.display(), at.as_ref().map(|a| format!("{a}: ")).unwrap_or_default())]
    Invalid { path: PathBuf, at: Option<Location>, message: String },
}

impl Error {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Error::Io { path: path.to_path_buf(), cause: source }
    }

    pub fn invalid(path: &Path, at: Option<Location>, message: impl Into<String>) -> Self {
        Error::Invalid { path: path.to_path_buf(), at, message: message.into() }
    }

    pub fn at_line(path: &Path, line: usize, message: impl Into<String>) -> Self {
        Self::invalid(path, Some(Location::Line(line)), message)
    }

    pub fn at_byte(path: &Path, offset: u64, message: impl Into<String>) -> Self {
        Self::invalid(path, Some(Location::Byte(offset)), message)
    }

    pub fn at_element(path: &Path, element: impl Into<String>, message: impl Into<String>) -> Self {
        Self::invalid(path, Some(Location::Element(element.into())), message)
    }

    /// The location of the problem, if one is known.
    pub fn location(&self) -> Option<&Location> {
        match self {
            Error::Io { .. } => None,
            Error::Invalid { at, .. } => at.as_ref(),
        }
    }
}

pub type Result<T> = std::result::Result<T, Error>;
