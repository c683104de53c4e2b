//! The errors of reading and writing run files: each names the file and what was being done.

use std::path::PathBuf;

/// An error of the run file.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// The output exists and overwriting was not asked for.
    #[error("output file '{}' already exists; pass --force to overwrite it", path.display())]
    Exists {
        /// The output path.
        path: PathBuf,
    },
    /// Another run is writing the same output (it holds the output's lock file).
    #[error(
        "another run is writing '{}' (it holds '{}'); wait for it to end, or write elsewhere",
        path.display(),
        lock.display()
    )]
    Busy {
        /// The output path.
        path: PathBuf,
        /// Its lock file.
        lock: PathBuf,
    },
    /// A run writing the output was killed and left its partial file.
    #[error(
        "a run writing '{}' was killed and left its partial output '{}' (readable: moreau \
         inspect it); move it away, or pass --force to replace it",
        path.display(),
        partial.display()
    )]
    Stale {
        /// The output path.
        path: PathBuf,
        /// The partial file.
        partial: PathBuf,
    },
    /// The output cannot be created where asked (no such directory, not writable, a directory).
    #[error("cannot create output file '{}': {reason}", path.display())]
    Create {
        /// The output path.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// An HDF5 call failed.
    #[error("{what} in '{}': {source}", path.display())]
    Hdf5 {
        /// The file.
        path: PathBuf,
        /// What was being done.
        what: String,
        /// The library's error.
        source: hdf5::Error,
    },
    /// The data do not fit the layout (an id beyond the people declared, a missing dataset).
    #[error("'{}': {what}", path.display())]
    Layout {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
}

/// Attaches the file and the action to an HDF5 result.
pub(crate) trait Context<T> {
    fn at(self, path: &std::path::Path, what: impl FnOnce() -> String) -> Result<T, IoError>;
}

impl<T> Context<T> for hdf5::Result<T> {
    fn at(self, path: &std::path::Path, what: impl FnOnce() -> String) -> Result<T, IoError> {
        self.map_err(|source| IoError::Hdf5 {
            path: path.to_path_buf(),
            what: what(),
            source,
        })
    }
}
