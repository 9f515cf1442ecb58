//! The user's files: atomic writes so nothing half-written is ever presented as done, and the
//! error that names the file and field an input problem is in.

use std::io::Write;
use std::path::{Path, PathBuf};

/// Write `bytes` to `path` atomically: a temporary sibling is written, synced and renamed.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp-{}", std::process::id()));
    {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
    }
    std::fs::rename(&tmp, path)
}

/// Replace directory `target` with the fully written directory `staged` (same parent).
/// An existing `target` is removed only after `staged` has taken its place.
pub fn replace_dir(staged: &Path, target: &Path) -> std::io::Result<()> {
    if target.exists() {
        let name = target.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let old = target.with_file_name(format!(".{name}.old-{}", std::process::id()));
        std::fs::rename(target, &old)?;
        std::fs::rename(staged, target)?;
        std::fs::remove_dir_all(&old)
    } else {
        std::fs::rename(staged, target)
    }
}

/// Why an input file could not be used.
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    /// The file or folder could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The operating-system error.
        source: std::io::Error,
    },
    /// The file is not JSON of the expected shape.
    #[error("{path}: {message}")]
    Syntax {
        /// The file.
        path: PathBuf,
        /// What the parser said (with line and column).
        message: String,
    },
    /// A field holds a value that cannot be used.
    #[error("{path}: field `{field}`: {message}")]
    Field {
        /// The file.
        path: PathBuf,
        /// The field, e.g. `measurements[4].joints_deg`.
        field: String,
        /// What was expected.
        message: String,
    },
    /// A folder holds no session file.
    #[error("{path}: no session files (*.json) in this folder")]
    EmptyFolder {
        /// The folder.
        path: PathBuf,
    },
}
