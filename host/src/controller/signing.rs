//! Station keys and signed parameter sets (the layout is [`kincal_protocol::signed`]'s): a
//! calibration station signs the parameter blob, the arm's identity, the version (inside the
//! blob) and the time with its Ed25519 key; the controller verifies before it stores anything.
//!
//! Key file (`kincal key new`): two lines, `kincal-station-key/1` and the 32-byte secret seed as
//! 64 hex digits; created owner-only (0600), never replaced, never printed. The public key goes
//! beside it as `FILE.pub` (`kincal-station-public-key/1` and 64 hex digits): it is what a lab
//! builds into the real controller (`KINCAL_TRUSTED_KEY`).

use crate::trace::hex;
/// `unix_s` as UTC date and time (in [`crate::trace`], which the reports share).
pub use crate::trace::utc;
use ed25519_dalek::{Signer, SigningKey, VerifyingKey};
use kincal_protocol::params::MAX_PARAM_BLOB;
use kincal_protocol::signed::{
    signing_message, split_signed, traced_signing_message, LayoutError, SetTrace, PUBLIC_KEY_BYTES,
};
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};

const KEY_HEADER: &str = "kincal-station-key/1";
const PUBLIC_HEADER: &str = "kincal-station-public-key/1";

/// Why a station key could not be made or read.
#[derive(Debug, thiserror::Error)]
pub enum KeyFileError {
    /// The key file does not exist.
    #[error("{0}: no such station key; make one with `kincal key new --out {0}`")]
    Missing(PathBuf),
    /// The file is empty.
    #[error("{0} is empty; expected a kincal station key (line 1 `{KEY_HEADER}`, line 2 the secret key as 64 hex digits)")]
    Empty(PathBuf),
    /// Another kind of file.
    #[error("{path} line 1: expected `{KEY_HEADER}`, found {found} — not a kincal station key (make one with `kincal key new`)")]
    Format {
        /// The file.
        path: PathBuf,
        /// What line 1 looks like (its kind, never its contents unless it is a PEM label).
        found: String,
    },
    /// The secret is not 64 hex digits.
    #[error("{0} line 2: expected the secret key as 64 hex digits")]
    Secret(PathBuf),
    /// `key new` never replaces a file.
    #[error(
        "{0} exists; kincal never replaces a key file (a lost key cannot be recovered): choose a new name"
    )]
    Exists(PathBuf),
    /// Reading or writing failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The system's random source failed.
    #[error("no random numbers from the operating system: {0}")]
    Random(String),
    /// Not a regular file (a FIFO, a device, a folder, a dangling link): never opened.
    #[error(transparent)]
    NotAFile(crate::files::FileError),
}

/// A station's signing key, read from its file.
pub struct StationKey {
    key: SigningKey,
}

/// A key file as read: the key and what the user should know (e.g. permissions too open).
pub struct LoadedKey {
    /// The key.
    pub key: StationKey,
    /// Warnings about the file, each naming it.
    pub warnings: Vec<String>,
}

/// The fingerprint shown for a public key: `ed25519:` and the first 8 bytes of its SHA-256, hex.
pub fn fingerprint(public_key: &[u8; PUBLIC_KEY_BYTES]) -> String {
    let digest = Sha256::digest(public_key);
    format!("ed25519:{}", hex(&digest[..8]))
}

fn unhex32(text: &str) -> Option<[u8; 32]> {
    let text = text.trim();
    if text.len() != 64 || !text.is_ascii() {
        return None;
    }
    let mut out = [0u8; 32];
    for (k, byte) in out.iter_mut().enumerate() {
        *byte = u8::from_str_radix(&text[2 * k..2 * k + 2], 16).ok()?;
    }
    Some(out)
}

impl StationKey {
    /// Make a new key from the operating system's random source and write it to `path`
    /// (owner-only, a new file only) and its public key to `path.pub`.
    pub fn create(path: &Path) -> Result<StationKey, KeyFileError> {
        let public_path = public_key_path(path);
        for p in [path, public_path.as_path()] {
            // A link counts too, dangling or not: nothing is written through it.
            if p.symlink_metadata().is_ok() {
                return Err(KeyFileError::Exists(p.to_path_buf()));
            }
        }
        let mut seed = [0u8; 32];
        getrandom::fill(&mut seed).map_err(|e| KeyFileError::Random(e.to_string()))?;
        let key = StationKey { key: SigningKey::from_bytes(&seed) };
        write_new(path, &format!("{KEY_HEADER}\n{}\n", hex(&seed)), 0o600)?;
        if let Err(e) =
            write_new(&public_path, &format!("{PUBLIC_HEADER}\n{}\n", hex(&key.public_key())), 0o644)
        {
            // Both or neither: a secret without its public key would block the name for good.
            let _ = std::fs::remove_file(path);
            return Err(e);
        }
        Ok(key)
    }

    /// Read the key at `path`; warns when others may read the file.
    pub fn load(path: &Path) -> Result<LoadedKey, KeyFileError> {
        if std::fs::symlink_metadata(path).is_ok() {
            // Before opening: a FIFO would block and /dev/zero never end.
            crate::files::check_regular_file(path).map_err(KeyFileError::NotAFile)?;
        }
        let text = match std::fs::read(path) {
            Ok(bytes) => bytes,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(KeyFileError::Missing(path.to_path_buf()))
            }
            Err(source) => return Err(KeyFileError::Io { path: path.to_path_buf(), source }),
        };
        if text.iter().all(|b| b.is_ascii_whitespace()) {
            return Err(KeyFileError::Empty(path.to_path_buf()));
        }
        let text = String::from_utf8_lossy(&text);
        let mut lines = text.lines();
        let first = lines.next().unwrap_or("").trim();
        if first != KEY_HEADER {
            let pem_label = first.len() <= 64 && first.ends_with("-----");
            let found = if first.starts_with("-----BEGIN") && pem_label {
                format!("`{first}` (a PEM file)")
            } else if first.starts_with("-----BEGIN") {
                "a PEM file".to_string()
            } else if first == PUBLIC_HEADER {
                "a public key (the .pub file; pass the secret key file)".to_string()
            } else if unhex32(first).is_some() {
                "64 hex digits without the header line (not shown: they may be a secret)".to_string()
            } else {
                // Never echoed: another tool's key file may hold its secret on line 1.
                format!("a line of {} characters (not shown: it may be secret)", first.chars().count())
            };
            return Err(KeyFileError::Format { path: path.to_path_buf(), found });
        }
        let seed = lines.next().and_then(unhex32).ok_or_else(|| KeyFileError::Secret(path.to_path_buf()))?;
        let mut warnings = Vec::new();
        #[cfg(unix)]
        if let Ok(meta) = std::fs::metadata(path) {
            use std::os::unix::fs::PermissionsExt;
            let mode = meta.permissions().mode() & 0o777;
            if mode & 0o077 != 0 {
                warnings.push(format!(
                    "warning: {} can be read by others (mode {mode:04o}); anyone who reads it can sign parameter sets: chmod 600 {}",
                    path.display(),
                    path.display()
                ));
            }
        }
        Ok(LoadedKey { key: StationKey { key: SigningKey::from_bytes(&seed) }, warnings })
    }

    /// The key of a known 32-byte seed (tests, reproducible examples; a real station uses
    /// [`StationKey::create`]).
    pub fn from_seed(seed: [u8; 32]) -> StationKey {
        StationKey { key: SigningKey::from_bytes(&seed) }
    }

    /// The public key.
    pub fn public_key(&self) -> [u8; PUBLIC_KEY_BYTES] {
        self.key.verifying_key().to_bytes()
    }

    /// The public key as 64 hex digits (what `KINCAL_TRUSTED_KEY` takes).
    pub fn public_key_hex(&self) -> String {
        hex(&self.public_key())
    }

    /// Sign `blob` for arm `arm_id` at `signed_at_unix_s`: the set to upload (`KSG1`, no trace).
    pub fn sign(&self, blob: &[u8], arm_id: &str, signed_at_unix_s: u64) -> Result<Vec<u8>, SignError> {
        self.sign_with(blob, None, arm_id, signed_at_unix_s)
    }

    /// [`StationKey::sign`] with where the set comes from (`KSG2`): the RUN's hash, the date of
    /// its validation and the end of its validity, all signed.
    pub fn sign_traced(
        &self,
        blob: &[u8],
        trace: &SetTrace,
        arm_id: &str,
        signed_at_unix_s: u64,
    ) -> Result<Vec<u8>, SignError> {
        self.sign_with(blob, Some(trace), arm_id, signed_at_unix_s)
    }

    fn sign_with(
        &self,
        blob: &[u8],
        trace: Option<&SetTrace>,
        arm_id: &str,
        signed_at_unix_s: u64,
    ) -> Result<Vec<u8>, SignError> {
        let mut out = [0u8; MAX_PARAM_BLOB];
        let key = self.public_key();
        let laid_out = match trace {
            Some(trace) => traced_signing_message(blob, trace, arm_id, signed_at_unix_s, &key, &mut out),
            None => signing_message(blob, arm_id, signed_at_unix_s, &key, &mut out),
        };
        let n = laid_out.map_err(|e| match e {
            LayoutError::ArmId => SignError::ArmId(arm_id.to_string()),
            LayoutError::TooLarge => SignError::TooLarge,
        })?;
        let mut set = out[..n].to_vec();
        set.extend_from_slice(&self.key.sign(&set).to_bytes());
        Ok(set)
    }
}

/// Write `text` to the new file `path` (created only if nothing is there, a link included, with
/// `mode` from the start, so it is never readable by others meanwhile) and sync it; on a failure
/// the file is removed.
fn write_new(path: &Path, text: &str, mode: u32) -> Result<(), KeyFileError> {
    use std::io::Write;
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create_new(true);
    #[cfg(unix)]
    std::os::unix::fs::OpenOptionsExt::mode(&mut options, mode);
    #[cfg(not(unix))]
    let _ = mode;
    let io = |source| KeyFileError::Io { path: path.to_path_buf(), source };
    let mut file = options.open(path).map_err(io)?;
    if let Err(source) = file.write_all(text.as_bytes()).and_then(|_| file.sync_all()) {
        drop(file);
        let _ = std::fs::remove_file(path);
        return Err(io(source));
    }
    Ok(())
}

/// `FILE.pub` beside key file `FILE`.
pub fn public_key_path(path: &Path) -> PathBuf {
    let mut name = path.as_os_str().to_owned();
    name.push(".pub");
    PathBuf::from(name)
}

/// Why a set could not be signed.
#[derive(Debug, thiserror::Error)]
pub enum SignError {
    /// The arm identity is not one.
    #[error("arm identity {0:?} is not one (1 to 24 ASCII letters, digits or -_.:)")]
    ArmId(String),
    /// Blob and signature do not fit the controller's parameter area.
    #[error("the signed set does not fit the controller's {MAX_PARAM_BLOB}-byte parameter area")]
    TooLarge,
}

/// Who signed a stored set, checked on the host too.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SetProvenance {
    /// The parameter blob inside.
    pub blob: Vec<u8>,
    /// The arm identity it was signed for.
    pub arm_id: String,
    /// Time signed, Unix seconds.
    pub signed_at_unix_s: u64,
    /// The signer's public key.
    pub signer: [u8; PUBLIC_KEY_BYTES],
    /// The signature verifies (Ed25519, strict).
    pub signature_valid: bool,
    /// The RUN and validity it was signed with (`None`: a set that carries none).
    pub trace: Option<SetTrace>,
}

/// Read the signed fields of `set` and verify its signature here; `None` when it is not signed.
pub fn provenance(set: &[u8]) -> Option<SetProvenance> {
    let s = split_signed(set).ok()?;
    let signature_valid = VerifyingKey::from_bytes(s.public_key)
        .and_then(|k| k.verify_strict(s.message, &ed25519_dalek::Signature::from_bytes(s.signature)))
        .is_ok();
    Some(SetProvenance {
        blob: s.blob.to_vec(),
        arm_id: s.arm_id.to_string(),
        signed_at_unix_s: s.signed_at_unix_s,
        signer: *s.public_key,
        signature_valid,
        trace: s.trace,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("kincal-signing-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn a_new_key_is_owner_only_never_replaced_and_signs_verifiable_sets() {
        let dir = temp("new");
        let path = dir.join("station.key");
        let key = StationKey::create(&path).unwrap();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            assert_eq!(std::fs::metadata(&path).unwrap().permissions().mode() & 0o777, 0o600);
        }
        assert!(matches!(StationKey::create(&path), Err(KeyFileError::Exists(_))));
        let loaded = StationKey::load(&path).unwrap();
        assert!(loaded.warnings.is_empty());
        assert_eq!(loaded.key.public_key(), key.public_key());
        let public = std::fs::read_to_string(public_key_path(&path)).unwrap();
        assert_eq!(public, format!("{PUBLIC_HEADER}\n{}\n", key.public_key_hex()));
        let set = key.sign(&[1, 2, 3], "arm-1", 1_790_000_000).unwrap();
        let p = provenance(&set).unwrap();
        assert!(p.signature_valid);
        assert_eq!(
            (p.blob.as_slice(), p.arm_id.as_str(), p.signer),
            (&[1u8, 2, 3][..], "arm-1", key.public_key())
        );
        let mut flipped = set.clone();
        flipped[1] ^= 1;
        assert!(!provenance(&flipped).unwrap().signature_valid);
        assert_eq!(p.trace, None);
        let trace = SetTrace { run_sha256: [3; 32], validated_at_unix_s: 5, valid_until_unix_s: 9 };
        let traced = key.sign_traced(&[1, 2, 3], &trace, "arm-1", 1_790_000_000).unwrap();
        let t = provenance(&traced).unwrap();
        assert!(t.signature_valid);
        assert_eq!((t.blob.as_slice(), t.trace), (&[1u8, 2, 3][..], Some(trace)));
        std::fs::remove_dir_all(&dir).ok();
    }

    /// A key file in another format may hold secret material on its first line (a bare hex
    /// seed, a base64 key): the error names the file and the format, never echoes the line.
    #[test]
    fn a_key_file_in_another_format_is_refused_without_echoing_its_contents() {
        let dir = temp("format");
        let secret = "4b1d2c3e4f5a6b7c8d9e0f1a2b3c4d5e6f7a8b9c0d1e2f3a4b5c6d7e8f9a0b1c";
        for (name, text) in [
            ("bare-hex.key", format!("{secret}\n")),
            ("base64.key", "S1QsPk9aa3yNng8aKzxNXm96i5wNHi86S1xtfo+aCxw=\n".to_string()),
            ("swapped.key", format!("{secret}\n{KEY_HEADER}\n")),
            ("one-line.pem", format!("-----BEGIN PRIVATE KEY-----{secret}-----END PRIVATE KEY-----\n")),
        ] {
            let path = dir.join(name);
            std::fs::write(&path, &text).unwrap();
            let Err(e) = StationKey::load(&path) else { panic!("{name} was read as a key") };
            let message = e.to_string();
            assert!(message.contains(name) && message.contains("line 1"), "{message}");
            let first_line = text.lines().next().unwrap();
            for k in 0..first_line.len().saturating_sub(8) {
                assert!(!message.contains(&first_line[k..k + 8]), "{name}: {message}");
            }
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    /// `key new` writes nothing through a link planted where its files go, and when it cannot
    /// write both files it leaves no secret behind (a half-made key blocks the name forever).
    #[cfg(unix)]
    #[test]
    fn a_new_key_never_follows_a_planted_link_and_is_made_whole_or_not_at_all() {
        let dir = temp("planted");
        let path = dir.join("station.key");
        let elsewhere = dir.join("elsewhere.pub");
        std::os::unix::fs::symlink(&elsewhere, public_key_path(&path)).unwrap();
        assert!(StationKey::create(&path).is_err(), "wrote through a planted link");
        assert!(!elsewhere.exists(), "the link's target was written");
        assert!(!path.exists(), "a secret key without its public key was left behind");
        let names: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names, ["station.key.pub"], "only the planted link stays");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn dates_are_utc() {
        assert_eq!(utc(0), "1970-01-01 00:00:00 UTC");
        assert_eq!(utc(951_782_400), "2000-02-29 00:00:00 UTC");
        assert_eq!(utc(1_790_000_000), "2026-09-21 14:13:20 UTC");
    }
}
