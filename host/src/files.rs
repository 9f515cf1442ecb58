//! The user's files: atomic writes so nothing half-written is ever presented as done, outputs
//! that never land on an input, and the error that names the file and field an input problem is
//! in.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

/// Write `bytes` to `path` atomically: a new temporary sibling (same folder, so the rename never
/// crosses a file system) is written, synced and renamed over `path`. On any failure the
/// temporary is removed and `path` is as it was. Every writer of a file the user keeps goes
/// through here (or [`write_output`] for a file the user named).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    static NEXT: AtomicUsize = AtomicUsize::new(0);
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let tmp =
        dir.join(format!(".{name}.tmp-{}-{}", std::process::id(), NEXT.fetch_add(1, Ordering::Relaxed)));
    // A new file only: never through a link or over someone else's file of that name.
    let mut f = std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp)?;
    let written = f.write_all(bytes).and_then(|_| f.sync_all()).and_then(|_| {
        drop(f);
        std::fs::rename(&tmp, path)
    });
    if written.is_err() {
        // A full disk or a refused rename leaves no temporary file behind.
        let _ = std::fs::remove_file(&tmp);
    }
    written
}

/// The words every file kincal writes for the user to name (`--out FILE`) carries in its first
/// lines: only such a file is ever replaced by a later run.
pub const WRITTEN_BY: &str = "written by kincal";

/// Refuse an output `out` (given as `option`, e.g. `--out`) that would replace one of `inputs`:
/// the same file by another name, a hard link to it or a symlink to it (compared by device and
/// inode); a folder; or any existing file kincal did not write (its first lines do not say
/// [`WRITTEN_BY`]). A new name, or an earlier output of kincal that is none of the inputs, is fine.
pub fn check_output(out: &Path, option: &str, inputs: &[&Path]) -> Result<(), FileError> {
    use std::os::unix::fs::MetadataExt;
    let refuse = |message: String| FileError::Field { path: out.to_owned(), field: option.into(), message };
    let Ok(target) = std::fs::metadata(out) else { return Ok(()) };
    if target.is_dir() {
        return Err(refuse("is a folder; expected the name of a file to write".into()));
    }
    let link = std::fs::symlink_metadata(out).is_ok_and(|m| m.file_type().is_symlink());
    for input in inputs {
        let Ok(meta) = std::fs::metadata(input) else { continue };
        if (meta.dev(), meta.ino()) == (target.dev(), target.ino()) {
            let how = if link {
                "a symlink to"
            } else if out.canonicalize().ok() == input.canonicalize().ok() {
                "the same file as"
            } else {
                "a hard link to"
            };
            return Err(refuse(format!(
                "is {how} the input {}: writing it would replace the input; choose another file",
                input.display()
            )));
        }
    }
    if !target.is_file() {
        return Err(refuse("exists and is not a regular file; expected the name of a file to write".into()));
    }
    let mut head = Vec::new();
    let read = std::fs::File::open(out)
        .and_then(|f| std::io::Read::read_to_end(&mut std::io::Read::take(f, 1024), &mut head));
    if read.is_err() || !String::from_utf8_lossy(&head).contains(WRITTEN_BY) {
        return Err(refuse(format!(
            "exists and kincal did not write it (its first lines do not say \"{WRITTEN_BY}\"): kincal replaces only \
             its own earlier outputs; choose another name, or remove the file first"
        )));
    }
    Ok(())
}

/// Write the file `out` the user named with `option`, atomically ([`write_atomic`]), after
/// [`check_output`] against `inputs`.
pub fn write_output(out: &Path, option: &str, inputs: &[&Path], bytes: &[u8]) -> Result<(), FileError> {
    check_output(out, option, inputs)?;
    write_atomic(out, bytes).map_err(|source| FileError::Io { path: out.to_owned(), source })
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
    /// A row of a CSV file holds a value that cannot be used.
    #[error("{path}:{line}: column `{column}`: {message}")]
    Row {
        /// The file.
        path: PathBuf,
        /// The line, 1-based, counting the header and comment lines.
        line: usize,
        /// The column's name from the header.
        column: String,
        /// What was expected.
        message: String,
    },
    /// An element of an XML file (a URDF joint) holds a value that cannot be used.
    #[error("{path}:{line}: {element}: {message}")]
    Element {
        /// The file.
        path: PathBuf,
        /// The element's line, 1-based.
        line: usize,
        /// The element, e.g. `<joint name="elbow">`.
        element: String,
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

/// Refuse an input that is not a regular file (a symlink to one is followed): a dangling
/// symlink, a symlink loop, a device such as `/dev/zero`, a FIFO or a folder is named, never
/// skipped or opened (a device or FIFO would never end, or block), so no file the user believes
/// was read is silently left out. Checked before any input file is opened.
pub fn check_regular_file(path: &Path) -> Result<(), FileError> {
    let not_a_file = |what: String| FileError::Field {
        path: path.to_owned(),
        field: "(file type)".into(),
        message: format!(
            "{what}, not an input file: kincal reads regular files only; pass a file, or move this entry \
             out of the folder"
        ),
    };
    let meta = match std::fs::metadata(path) {
        Ok(meta) => meta,
        Err(e) => {
            let link = std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_symlink());
            return Err(if link {
                not_a_file(format!("a symlink whose target cannot be read ({e}: dangling or a loop)"))
            } else {
                FileError::Io { path: path.to_owned(), source: e }
            });
        }
    };
    if meta.is_file() {
        return Ok(());
    }
    use std::os::unix::fs::FileTypeExt;
    let kind = meta.file_type();
    let what = if kind.is_dir() {
        "a folder"
    } else if kind.is_fifo() {
        "a FIFO (named pipe)"
    } else if kind.is_char_device() || kind.is_block_device() {
        "a device"
    } else if kind.is_socket() {
        "a socket"
    } else {
        "not a regular file"
    };
    Err(not_a_file(what.to_string()))
}

/// Read a JSON file into `T`, naming the file (and the parser's line and column) on error.
pub fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T, FileError> {
    check_regular_file(path)?;
    let text =
        std::fs::read_to_string(path).map_err(|source| FileError::Io { path: path.to_owned(), source })?;
    serde_json::from_str(&text).map_err(|e| json_error(path, &text, e))
}

/// The error for JSON that does not fit the expected shape: a value of the wrong type (`null`, a
/// string where a number belongs) names the field it sits in, a syntax error its line and column.
pub fn json_error(path: &Path, text: &str, e: serde_json::Error) -> FileError {
    let message = e.to_string();
    // serde names the field itself when one is missing, unknown or doubled; the key before the
    // error position would be a neighbour.
    let names_itself =
        ["missing field", "unknown field", "duplicate field"].iter().any(|m| message.contains(m));
    let key = key_before(text, e.line(), e.column()).filter(|_| !names_itself);
    match (e.classify(), key) {
        (serde_json::error::Category::Data, Some(key)) => field_error(path, key, message),
        (serde_json::error::Category::Syntax, Some(key)) => {
            FileError::Syntax { path: path.to_owned(), message: format!("{message} (after field `{key}`)") }
        }
        _ => FileError::Syntax { path: path.to_owned(), message },
    }
}

/// The object key nearest before line `line`, column `column` (1-based) of `text`.
fn key_before(text: &str, line: usize, column: usize) -> Option<String> {
    let start: usize = text.split_inclusive('\n').take(line.saturating_sub(1)).map(str::len).sum();
    let end = (start + column).min(text.len());
    let prefix = text.get(..end)?;
    let colon = prefix.rfind("\":")?;
    let open = prefix[..colon].rfind('"')?;
    Some(prefix[open + 1..colon].to_string())
}

/// A JSON file kincal wrote, read whole, with its `format` tag (`None` when it has none).
pub struct TaggedJson {
    path: PathBuf,
    text: String,
    /// The file's `format` tag.
    pub format: Option<String>,
}

impl TaggedJson {
    /// Read `path` (a regular file) and its `format` tag.
    pub fn read(path: &Path) -> Result<TaggedJson, FileError> {
        #[derive(serde::Deserialize)]
        struct Tag {
            format: Option<String>,
        }
        check_regular_file(path)?;
        let text = std::fs::read_to_string(path)
            .map_err(|source| FileError::Io { path: path.to_owned(), source })?;
        let tag: Tag = serde_json::from_str(&text).map_err(|e| json_error(path, &text, e))?;
        Ok(TaggedJson { path: path.to_owned(), text, format: tag.format })
    }

    /// The file as a `T`, whatever its tag.
    pub fn parse<T: serde::de::DeserializeOwned>(&self) -> Result<T, FileError> {
        serde_json::from_str(&self.text).map_err(|e| json_error(&self.path, &self.text, e))
    }

    /// The file as a `T` when its tag is `format`; a file of another kind or version is named as
    /// such instead of failing on some later field.
    pub fn parse_tagged<T: serde::de::DeserializeOwned>(&self, format: &str) -> Result<T, FileError> {
        match self.format.as_deref() {
            Some(found) if found == format => self.parse(),
            Some(found) => {
                Err(field_error(&self.path, "format", format!("expected \"{format}\", found \"{found}\"")))
            }
            None => Err(field_error(&self.path, "format", format!("missing; expected \"{format}\""))),
        }
    }
}

/// Read a JSON file kincal wrote whose `format` tag must be `format` ([`TaggedJson::parse_tagged`]).
pub fn read_tagged<T: serde::de::DeserializeOwned>(path: &Path, format: &str) -> Result<T, FileError> {
    TaggedJson::read(path)?.parse_tagged(format)
}

/// The error for a row of a text file (`line` 1-based) whose `column` holds what cannot be used.
pub fn row_error(path: &Path, line: usize, column: &str, message: impl Into<String>) -> FileError {
    FileError::Row { path: path.to_owned(), line, column: column.to_string(), message: message.into() }
}

/// The error for a field that holds a value that cannot be used.
pub fn field_error(path: &Path, field: impl Into<String>, message: impl Into<String>) -> FileError {
    FileError::Field { path: path.to_owned(), field: field.into(), message: message.into() }
}

/// Deserialise a number that JSON stores as `null` when it was infinite (serde_json writes
/// non-finite numbers as `null`), such as the condition number of a singular Jacobian.
pub fn null_as_infinity<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    let value: Option<f64> = serde::Deserialize::deserialize(d)?;
    Ok(value.unwrap_or(f64::INFINITY))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_atomic_write_leaves_no_temporary_file() {
        let dir = std::env::temp_dir().join(format!("kincal-atomic-{}", std::process::id()));
        let target = dir.join("summary.json");
        std::fs::create_dir_all(target.join("in the way")).unwrap();
        assert!(write_atomic(&target, b"{}").is_err(), "a folder cannot be replaced by a file");
        let names: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names, ["summary.json"], "only the folder that was there");
        std::fs::remove_dir_all(&dir).ok();
    }

    /// An output over an input is refused by name, by hard link and by symlink, and over a file
    /// of the user's; a new file, or kincal's own earlier output, is written.
    #[test]
    fn an_output_that_is_an_input_is_refused_however_it_is_named() {
        let dir = std::env::temp_dir().join(format!("kincal-output-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let input = dir.join("robot.urdf");
        std::fs::write(&input, b"mine").unwrap();
        std::fs::hard_link(&input, dir.join("hard.urdf")).unwrap();
        std::os::unix::fs::symlink(&input, dir.join("soft.urdf")).unwrap();
        std::fs::write(dir.join("other.urdf"), b"the user's").unwrap();
        std::fs::write(dir.join("earlier.urdf"), b"<!-- written by kincal model to-urdf -->").unwrap();
        for (name, how) in [
            ("robot.urdf", "the same file as"),
            ("./robot.urdf", "the same file as"),
            ("hard.urdf", "a hard link to"),
            ("soft.urdf", "a symlink to"),
        ] {
            let err = write_output(&dir.join(name), "--out", &[&input], b"new").unwrap_err().to_string();
            assert!(
                err.contains("--out") && err.contains(how) && err.contains("robot.urdf"),
                "{name}: {err}"
            );
        }
        let err = write_output(&dir, "--out", &[&input], b"new").unwrap_err().to_string();
        assert!(err.contains("is a folder"), "{err}");
        let err = write_output(&dir.join("other.urdf"), "--out", &[&input], b"new").unwrap_err().to_string();
        assert!(err.contains("other.urdf") && err.contains("kincal did not write it"), "{err}");
        write_output(&dir.join("earlier.urdf"), "--out", &[&input], b"new").unwrap();
        write_output(&dir.join("new.urdf"), "--out", &[&input], b"new").unwrap();
        assert_eq!(std::fs::read(&input).unwrap(), b"mine");
        assert_eq!(std::fs::read(dir.join("other.urdf")).unwrap(), b"the user's");
        assert_eq!(std::fs::read(dir.join("earlier.urdf")).unwrap(), b"new");
        let names: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into())
            .collect();
        assert!(names.iter().all(|n| !n.contains(".tmp-")), "{names:?}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn a_wrong_value_names_its_field_and_a_missing_field_is_not_blamed_on_a_neighbour() {
        #[derive(Debug, serde::Deserialize)]
        #[allow(dead_code)]
        struct Row {
            id: String,
            xyz_mm: [f64; 3],
        }
        let path = Path::new("rows.json");
        let error =
            |text: &str| json_error(path, text, serde_json::from_str::<Row>(text).unwrap_err()).to_string();
        let null = error("{\n  \"id\": \"O\",\n  \"xyz_mm\": [\n    1.0,\n    null,\n    3.0\n  ]\n}");
        assert!(null.contains("field `xyz_mm`") && null.contains("null"), "{null}");
        let missing = error("{\n  \"id\": \"O\"\n}");
        assert!(missing.contains("missing field `xyz_mm`") && !missing.contains("field `id`"), "{missing}");
        let four = error("{\"id\": \"O\", \"xyz_mm\": [1, 2, 3, 4]}");
        assert!(four.contains("xyz_mm"), "{four}");
    }
}
