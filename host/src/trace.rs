//! Traceability: which arm a session or a model belongs to, and the hashes that tie a stored
//! parameter set to the RUN and the files it was computed from.
//!
//! * [`ArmIdentity`]: the controller's arm identity (what signed sets must name), with the
//!   firmware and board that reported it. `kincal record` writes it into every session
//!   (`"arm": {"id": …, "firmware": …, "board": …}`); a model file carries it as `[arm]`.
//! * [`one_arm`]: the one arm a set of sessions was recorded on, or which sessions disagree.
//! * [`run_sha256`]: the hash of a RUN that a signed set carries: SHA-256 of the text
//!   `sha256sum model.toml summary.json` prints in the RUN folder, so anyone can recompute it
//!   with standard tools (`cd RUN && sha256sum model.toml summary.json | sha256sum`).
//! * [`hash_inputs`]: SHA-256 of every input file (folders expanded), for a RUN's record.
//! * [`UploadRecord`]: where a RUN's model went (`RUN/uploads.json`, appended by `kincal
//!   upload`): the arm, the set's version, the key that signed it and the validity.

use crate::files::FileError;
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};

/// Longest firmware or board text kept, characters.
pub const MAX_LABEL: usize = 64;

/// An arm's identity as its controller reports it.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArmIdentity {
    /// The controller's arm identity (1 to 24 ASCII letters, digits or `-_.:`), what signed
    /// parameter sets must name.
    pub id: String,
    /// Firmware name and version that reported it, e.g. `kincal-fw 0.1.0`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub firmware: Option<String>,
    /// The controller board, e.g. `mps2-an386 (emulated)`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub board: Option<String>,
}

impl ArmIdentity {
    /// The identity of arm `id` with nothing else known.
    pub fn of(id: &str) -> ArmIdentity {
        ArmIdentity { id: id.to_string(), firmware: None, board: None }
    }

    /// Check every field: `Err((field, what was expected))`, the field relative to the identity
    /// (`id`, `firmware`, `board`).
    pub fn check(&self) -> Result<(), (&'static str, String)> {
        if !kincal_protocol::signed::valid_arm_id(&self.id) {
            return Err((
                "id",
                format!(
                    "{:?} is not an arm identity: expected 1 to {} ASCII letters, digits or -_.:",
                    self.id,
                    kincal_protocol::signed::ARM_ID_MAX
                ),
            ));
        }
        for (field, text) in [("firmware", &self.firmware), ("board", &self.board)] {
            if let Some(text) = text {
                check_label(text).map_err(|message| (field, message))?;
            }
        }
        Ok(())
    }
}

/// Whether `text` is a label a record may carry (a firmware, a board, a certificate number, an
/// operator): 1 to [`MAX_LABEL`] printable characters; `Err(what was expected)` otherwise.
pub fn check_label(text: &str) -> Result<(), String> {
    if text.trim().is_empty() || text.chars().count() > MAX_LABEL || text.chars().any(|c| c.is_control()) {
        return Err(format!("expected 1 to {MAX_LABEL} printable characters, found {text:?}"));
    }
    Ok(())
}

impl std::fmt::Display for ArmIdentity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.id)?;
        match (&self.firmware, &self.board) {
            (Some(fw), Some(board)) => write!(f, " ({fw} on {board})"),
            (Some(one), None) | (None, Some(one)) => write!(f, " ({one})"),
            (None, None) => Ok(()),
        }
    }
}

/// Sessions that cannot be one arm's.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum MixedArms {
    /// Two sessions were recorded on different arms.
    #[error(
        "{first} was recorded on arm {first_arm}, {other} on arm {other_arm}: one calibration is of \
         one arm; calibrate each arm from its own sessions"
    )]
    TwoArms {
        /// A session of the first arm.
        first: PathBuf,
        /// Its arm.
        first_arm: String,
        /// A session of another arm.
        other: PathBuf,
        /// That arm.
        other_arm: String,
    },
    /// Some sessions name their arm and others do not.
    #[error(
        "{identified} was recorded on arm {arm}, {unidentified} names no arm (recorded before kincal \
         wrote the arm's identity, or written by hand): they cannot be shown to be the same arm"
    )]
    Unidentified {
        /// A session that names its arm.
        identified: PathBuf,
        /// The arm it names.
        arm: String,
        /// A session that names none.
        unidentified: PathBuf,
    },
}

/// The one arm `sessions` (file, the arm it names) were recorded on: `None` when none names an
/// arm; refused when two arms are named (the first file of each named), else when some sessions
/// name an arm and others do not. The firmware may differ between sessions (an update between
/// placements), the arm may not.
pub fn one_arm(sessions: &[(PathBuf, Option<ArmIdentity>)]) -> Result<Option<ArmIdentity>, MixedArms> {
    let mut named = sessions.iter().filter_map(|(path, arm)| arm.as_ref().map(|a| (path, a)));
    let Some((first, arm)) = named.next() else { return Ok(None) };
    if let Some((other, o)) = named.find(|(_, o)| o.id != arm.id) {
        return Err(MixedArms::TwoArms {
            first: first.clone(),
            first_arm: arm.id.clone(),
            other: other.clone(),
            other_arm: o.id.clone(),
        });
    }
    if let Some((unidentified, _)) = sessions.iter().find(|(_, a)| a.is_none()) {
        return Err(MixedArms::Unidentified {
            identified: first.clone(),
            arm: arm.id.clone(),
            unidentified: unidentified.clone(),
        });
    }
    Ok(Some(arm.clone()))
}

/// `unix_s` as UTC date and time (`2026-11-24 06:15:00 UTC`).
pub fn utc(unix_s: u64) -> String {
    let days = (unix_s / 86_400) as i64;
    let secs = unix_s % 86_400;
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + (month <= 2) as i64;
    format!("{year:04}-{month:02}-{day:02} {:02}:{:02}:{:02} UTC", secs / 3600, secs / 60 % 60, secs % 60)
}

/// Lower-case hex of `bytes`.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// SHA-256 of the file at `path`.
pub fn file_sha256(path: &Path) -> Result<[u8; 32], FileError> {
    crate::files::check_regular_file(path)?;
    let io = |source| FileError::Io { path: path.to_owned(), source };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let mut hasher = Sha256::new();
    std::io::copy(&mut file, &mut hasher).map_err(io)?;
    Ok(hasher.finalize().into())
}

/// The files of a RUN folder its hash covers, in this order.
pub const RUN_HASHED_FILES: [&str; 2] = ["model.toml", "summary.json"];

/// The RUN's hash: SHA-256 of the lines `sha256sum model.toml summary.json` prints in `run`
/// (`<64 hex digits>  <name>\n` per file), so it changes with either file and can be recomputed
/// with standard tools.
pub fn run_sha256(run: &Path) -> Result<[u8; 32], FileError> {
    let mut manifest = String::new();
    for name in RUN_HASHED_FILES {
        manifest.push_str(&format!("{}  {name}\n", hex(&file_sha256(&run.join(name))?)));
    }
    Ok(Sha256::digest(manifest.as_bytes()).into())
}

/// Field of `summary.json` that records when the RUN's calibration was validated, Unix seconds.
pub const VALIDATED_AT_FIELD: &str = "validated_at_unix_s";

/// The RUN folder a model file was written in, and what a signed set records of it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RunOrigin {
    /// The RUN folder.
    pub run: PathBuf,
    /// [`run_sha256`] of it.
    pub sha256: [u8; 32],
    /// When its calibration was validated, Unix seconds.
    pub validated_at_unix_s: u64,
    /// `summary.json` records no date ([`VALIDATED_AT_FIELD`]): the date is the file's
    /// modification time, i.e. when kincal wrote the RUN (a copy that does not keep file times
    /// moves it).
    pub date_from_file_time: bool,
}

/// The RUN `model` comes from: `Some` when it is `RUN/model.toml` with `RUN/summary.json`
/// beside it (what `kincal calibrate` writes), `None` for a model file anywhere else.
pub fn run_origin(model: &Path) -> Result<Option<RunOrigin>, FileError> {
    let run = model.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let summary = run.join(RUN_HASHED_FILES[1]);
    if model.file_name().is_none_or(|n| n != RUN_HASHED_FILES[0]) || !summary.exists() {
        return Ok(None);
    }
    let sha256 = run_sha256(run)?;
    let value: serde_json::Value = crate::files::read_json(&summary)?;
    let (validated_at_unix_s, date_from_file_time) = match value.get(VALIDATED_AT_FIELD) {
        Some(v) => match v.as_u64().filter(|&s| s > 0) {
            Some(s) => (s, false),
            None => {
                return Err(crate::files::field_error(
                    &summary,
                    VALIDATED_AT_FIELD,
                    format!("expected the validation time in Unix seconds (a positive integer), found {v}"),
                ))
            }
        },
        None => {
            let io = |source| FileError::Io { path: summary.clone(), source };
            let modified = std::fs::metadata(&summary).and_then(|m| m.modified()).map_err(io)?;
            let secs = modified.duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
            (secs, true)
        }
    };
    Ok(Some(RunOrigin { run: run.to_path_buf(), sha256, validated_at_unix_s, date_from_file_time }))
}

/// One input file and its SHA-256 (hex).
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct FileHash {
    /// The file as given (a folder's files under the folder's path).
    pub path: PathBuf,
    /// SHA-256, 64 hex digits.
    pub sha256: String,
}

/// SHA-256 of every input in `paths`: a file itself, a folder as each of its regular files that
/// is not hidden (sorted by name, not recursing). A folder entry that is not a regular file is
/// refused by name, as the readers refuse it.
pub fn hash_inputs(paths: &[&Path]) -> Result<Vec<FileHash>, FileError> {
    let mut out = Vec::new();
    for &path in paths {
        let files = if path.is_dir() {
            let entries =
                std::fs::read_dir(path).map_err(|source| FileError::Io { path: path.to_owned(), source })?;
            let mut files = Vec::new();
            for entry in entries {
                let file = entry.map_err(|source| FileError::Io { path: path.to_owned(), source })?.path();
                if !file.file_name().is_some_and(|n| n.to_string_lossy().starts_with('.')) {
                    files.push(file);
                }
            }
            files.sort();
            files
        } else {
            vec![path.to_path_buf()]
        };
        for file in files {
            out.push(FileHash { sha256: hex(&file_sha256(&file)?), path: file });
        }
    }
    Ok(out)
}

/// The file in a RUN folder that records where its model was uploaded.
pub const UPLOADS_FILE: &str = "uploads.json";
/// Format tag of [`UPLOADS_FILE`].
pub const UPLOADS_FORMAT: &str = "kincal-uploads/1";

/// One upload of a RUN's model to a controller, as `kincal upload` records it.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UploadRecord {
    /// The controller's arm (what the set is signed for).
    pub arm: ArmIdentity,
    /// Version of the stored parameter set.
    pub param_version: u32,
    /// Fingerprint of the station key that signed it (`ed25519:…`).
    pub signer: String,
    /// When it was signed, Unix seconds.
    pub signed_at_unix_s: u64,
    /// The RUN hash the set carries (hex).
    pub run_sha256: String,
    /// The validation date the set carries, Unix seconds.
    pub validated_at_unix_s: u64,
    /// End of the validity period, Unix seconds (`None`: no period).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub valid_until_unix_s: Option<u64>,
}

#[derive(serde::Serialize, serde::Deserialize)]
struct UploadsFile {
    format: String,
    uploads: Vec<UploadRecord>,
}

/// The uploads recorded in `run` (oldest first; none when the file does not exist).
pub fn read_uploads(run: &Path) -> Result<Vec<UploadRecord>, FileError> {
    let path = run.join(UPLOADS_FILE);
    if !path.exists() {
        return Ok(Vec::new());
    }
    let file: UploadsFile = crate::files::read_json(&path)?;
    if file.format != UPLOADS_FORMAT {
        return Err(crate::files::field_error(
            &path,
            "format",
            format!("expected \"{UPLOADS_FORMAT}\", found \"{}\"", file.format),
        ));
    }
    Ok(file.uploads)
}

/// Append `record` to `run`'s uploads, atomically (the earlier records kept).
pub fn record_upload(run: &Path, record: &UploadRecord) -> Result<(), FileError> {
    let mut uploads = read_uploads(run)?;
    uploads.push(record.clone());
    let path = run.join(UPLOADS_FILE);
    let text = serde_json::to_string_pretty(&UploadsFile { format: UPLOADS_FORMAT.into(), uploads })
        .unwrap_or_default();
    crate::files::write_atomic(&path, text.as_bytes()).map_err(|source| FileError::Io { path, source })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("kincal-trace-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// The RUN hash is the SHA-256 of `sha256sum`'s output, checked against the system's
    /// `sha256sum` where it exists and against fixed digests of known texts.
    #[test]
    fn the_run_hash_is_sha256_of_the_sha256sum_lines() {
        let dir = temp("run");
        std::fs::write(dir.join("model.toml"), "abc").unwrap();
        std::fs::write(dir.join("summary.json"), "").unwrap();
        // FIPS 180-2 test vector and the empty message.
        assert_eq!(
            hex(&file_sha256(&dir.join("model.toml")).unwrap()),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        let manifest = "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad  model.toml\n\
                        e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855  summary.json\n";
        assert_eq!(run_sha256(&dir).unwrap(), <[u8; 32]>::from(Sha256::digest(manifest)));
        if let Ok(out) =
            std::process::Command::new("sha256sum").args(RUN_HASHED_FILES).current_dir(&dir).output()
        {
            assert_eq!(String::from_utf8_lossy(&out.stdout), manifest, "sha256sum prints these lines");
        }
        std::fs::write(dir.join("summary.json"), "{}").unwrap();
        assert_ne!(run_sha256(&dir).unwrap(), <[u8; 32]>::from(Sha256::digest(manifest)));
        std::fs::remove_file(dir.join("summary.json")).unwrap();
        let missing = run_sha256(&dir).unwrap_err().to_string();
        assert!(missing.contains("summary.json"), "{missing}");
        std::fs::remove_dir_all(&dir).ok();
    }

    /// Only `RUN/model.toml` with its summary is a RUN's model; the date is the summary's when
    /// it records one, else the file's time (said so); a bad date names the field.
    #[test]
    fn a_model_comes_from_a_run_only_as_its_model_toml() {
        let dir = temp("origin");
        std::fs::write(dir.join("model.toml"), "m").unwrap();
        std::fs::write(dir.join("nominal.toml"), "n").unwrap();
        assert_eq!(run_origin(&dir.join("model.toml")).unwrap(), None, "no summary: not a RUN");
        std::fs::write(dir.join("summary.json"), "{}").unwrap();
        assert_eq!(run_origin(&dir.join("nominal.toml")).unwrap(), None, "not the RUN's model");
        let origin = run_origin(&dir.join("model.toml")).unwrap().unwrap();
        assert_eq!(origin.sha256, run_sha256(&dir).unwrap());
        assert!(origin.date_from_file_time);
        let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().as_secs();
        assert!(origin.validated_at_unix_s.abs_diff(now) < 600, "{}", origin.validated_at_unix_s);
        std::fs::write(dir.join("summary.json"), r#"{"validated_at_unix_s": 1790000000}"#).unwrap();
        let origin = run_origin(&dir.join("model.toml")).unwrap().unwrap();
        assert_eq!((origin.validated_at_unix_s, origin.date_from_file_time), (1_790_000_000, false));
        std::fs::write(dir.join("summary.json"), r#"{"validated_at_unix_s": "yesterday"}"#).unwrap();
        let err = run_origin(&dir.join("model.toml")).unwrap_err().to_string();
        assert!(err.contains("summary.json") && err.contains("validated_at_unix_s"), "{err}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn inputs_are_hashed_file_by_file_and_folders_expanded_in_order() {
        let dir = temp("inputs");
        let sessions = dir.join("cal");
        std::fs::create_dir_all(&sessions).unwrap();
        std::fs::write(sessions.join("b.json"), "b").unwrap();
        std::fs::write(sessions.join("a.json"), "a").unwrap();
        std::fs::write(sessions.join(".hidden.json"), "x").unwrap();
        std::fs::write(dir.join("artefact.json"), "abc").unwrap();
        let hashes = hash_inputs(&[&dir.join("artefact.json"), &sessions]).unwrap();
        let names: Vec<_> = hashes.iter().map(|h| h.path.file_name().unwrap().to_owned()).collect();
        assert_eq!(names, ["artefact.json", "a.json", "b.json"]);
        assert_eq!(hashes[0].sha256, "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
        std::os::unix::fs::symlink(dir.join("nowhere"), sessions.join("c.json")).unwrap();
        let err = hash_inputs(&[&sessions]).unwrap_err().to_string();
        assert!(err.contains("c.json") && err.contains("dangling"), "{err}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn sessions_of_two_arms_or_of_a_named_and_an_unnamed_arm_are_not_one_arm() {
        let a = ArmIdentity { firmware: Some("kincal-fw 0.1.0".into()), ..ArmIdentity::of("arm-A") };
        let a_updated = ArmIdentity { firmware: Some("kincal-fw 0.2.0".into()), ..a.clone() };
        let b = ArmIdentity::of("arm-B");
        let s = |name: &str, arm: Option<&ArmIdentity>| (PathBuf::from(name), arm.cloned());
        assert_eq!(one_arm(&[s("1.json", None), s("2.json", None)]), Ok(None));
        assert_eq!(one_arm(&[s("1.json", Some(&a)), s("2.json", Some(&a_updated))]), Ok(Some(a.clone())));
        let two =
            one_arm(&[s("1.json", Some(&a)), s("2.json", Some(&a)), s("3.json", Some(&b))]).unwrap_err();
        let text = two.to_string();
        assert!(text.contains("1.json") && text.contains("arm-A") && text.contains("3.json"), "{text}");
        assert!(text.contains("arm-B"), "{text}");
        let two_and_unnamed =
            one_arm(&[s("0.json", None), s("1.json", Some(&a)), s("3.json", Some(&b))]).unwrap_err();
        assert!(
            matches!(two_and_unnamed, MixedArms::TwoArms { .. }),
            "two arms told first: {two_and_unnamed}"
        );
        let unnamed = one_arm(&[s("1.json", None), s("2.json", Some(&b))]).unwrap_err();
        assert!(matches!(unnamed, MixedArms::Unidentified { .. }), "{unnamed}");
        assert!(unnamed.to_string().contains("1.json names no arm"), "{unnamed}");
    }

    #[test]
    fn uploads_are_appended_and_read_back() {
        let dir = temp("uploads");
        assert_eq!(read_uploads(&dir).unwrap(), []);
        let first = UploadRecord {
            arm: ArmIdentity::of("arm-A"),
            param_version: 1,
            signer: "ed25519:0011223344556677".into(),
            signed_at_unix_s: 1_790_000_000,
            run_sha256: "ab".repeat(32),
            validated_at_unix_s: 1_789_999_000,
            valid_until_unix_s: None,
        };
        let second =
            UploadRecord { param_version: 2, valid_until_unix_s: Some(1_821_535_000), ..first.clone() };
        record_upload(&dir, &first).unwrap();
        record_upload(&dir, &second).unwrap();
        assert_eq!(read_uploads(&dir).unwrap(), [first, second]);
        std::fs::write(dir.join(UPLOADS_FILE), r#"{"format":"other/1","uploads":[]}"#).unwrap();
        let err = read_uploads(&dir).unwrap_err().to_string();
        assert!(err.contains("uploads.json") && err.contains("kincal-uploads/1"), "{err}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn identities_are_checked_field_by_field() {
        assert_eq!(ArmIdentity::of("lab-arm-2").check(), Ok(()));
        assert_eq!(ArmIdentity::of("").check().unwrap_err().0, "id");
        assert_eq!(ArmIdentity::of("arm A").check().unwrap_err().0, "id");
        assert_eq!(ArmIdentity::of(&"x".repeat(25)).check().unwrap_err().0, "id");
        let bad_fw = ArmIdentity { firmware: Some("fw\n2".into()), ..ArmIdentity::of("a") };
        assert_eq!(bad_fw.check().unwrap_err().0, "firmware");
        let full = ArmIdentity {
            firmware: Some("kincal-fw 0.1.0".into()),
            board: Some("mps2-an386 (emulated)".into()),
            ..ArmIdentity::of("arm-A")
        };
        assert_eq!(full.to_string(), "arm-A (kincal-fw 0.1.0 on mps2-an386 (emulated))");
    }
}
