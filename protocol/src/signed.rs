//! Signed parameter sets: what a calibration station signs and the controller verifies before it
//! stores anything.
//!
//! Layout: the parameter blob ([`crate::params`]) ‖ trailer = magic `KSG1` (4 bytes) ‖ arm
//! identity (ASCII, [`ARM_ID_MAX`] bytes, zero padded) ‖ time signed, Unix seconds u64 LE ‖
//! Ed25519 public key (32 bytes) ‖ Ed25519 signature (64 bytes, RFC 8032) over every byte before
//! it (blob ‖ magic ‖ arm identity ‖ time ‖ public key). The set's version is the blob's
//! [`crate::params::ArmParams::version`], so it is signed too. The whole set is what is uploaded
//! and stored; it is at most [`MAX_PARAM_BLOB`] bytes.
//!
//! A *traced* set (protocol version 5) carries where it comes from between the blob and the
//! trailer, and its trailer's magic is `KSG2`: blob ‖ [`SetTrace`] ([`TRACE_BYTES`]: the RUN's
//! SHA-256 (32 bytes) ‖ validated at, Unix seconds u64 LE ‖ valid until, Unix seconds u64 LE) ‖
//! `KSG2` ‖ arm identity ‖ time ‖ public key ‖ signature, the signature again over every byte
//! before it, the trace included. The magic sits at the same place from the end in both, so a
//! set is read one way only; `KSG1` sets stay valid (their trace is none).

use crate::params::MAX_PARAM_BLOB;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// Longest arm identity, bytes (the STM32's 96-bit unique ID in hex is 24).
pub const ARM_ID_MAX: usize = 24;
/// Ed25519 public key, bytes.
pub const PUBLIC_KEY_BYTES: usize = 32;
/// Ed25519 signature, bytes.
pub const SIGNATURE_BYTES: usize = 64;
/// Bytes the trailer adds to the blob.
pub const TRAILER_BYTES: usize = 4 + ARM_ID_MAX + 8 + PUBLIC_KEY_BYTES + SIGNATURE_BYTES;
const MAGIC: [u8; 4] = *b"KSG1";
/// Magic of a traced set's trailer.
const MAGIC_TRACED: [u8; 4] = *b"KSG2";
/// Bytes a [`SetTrace`] takes in a traced set.
pub const TRACE_BYTES: usize = 32 + 8 + 8;

/// Where a stored set comes from, signed with it: the RUN it was computed in and the validity of
/// its calibration. All zero: not recorded (a `KSG1` set, or a model that was not in a RUN).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct SetTrace {
    /// SHA-256 of the RUN the model was computed in (the host defines over which files), all
    /// zero: none.
    pub run_sha256: [u8; 32],
    /// When the calibration was validated, Unix seconds (0: not recorded).
    pub validated_at_unix_s: u64,
    /// End of the calibration's validity period, Unix seconds (0: no period). The controller has
    /// no clock: the host compares it with the time when it connects.
    pub valid_until_unix_s: u64,
}

impl SetTrace {
    /// Whether anything is recorded.
    pub fn is_none(&self) -> bool {
        *self == SetTrace::default()
    }

    fn to_bytes(self) -> [u8; TRACE_BYTES] {
        let mut out = [0u8; TRACE_BYTES];
        out[..32].copy_from_slice(&self.run_sha256);
        out[32..40].copy_from_slice(&self.validated_at_unix_s.to_le_bytes());
        out[40..].copy_from_slice(&self.valid_until_unix_s.to_le_bytes());
        out
    }

    fn from_bytes(bytes: &[u8; TRACE_BYTES]) -> SetTrace {
        let mut run_sha256 = [0u8; 32];
        run_sha256.copy_from_slice(&bytes[..32]);
        let (mut at, mut until) = ([0u8; 8], [0u8; 8]);
        at.copy_from_slice(&bytes[32..40]);
        until.copy_from_slice(&bytes[40..]);
        SetTrace {
            run_sha256,
            validated_at_unix_s: u64::from_le_bytes(at),
            valid_until_unix_s: u64::from_le_bytes(until),
        }
    }
}

/// An arm's identity: 1 to [`ARM_ID_MAX`] characters, ASCII letters, digits and `-_.:`.
pub type ArmId = heapless::String<ARM_ID_MAX>;

/// Whether `id` is a valid arm identity (1 to [`ARM_ID_MAX`] ASCII letters, digits and `-_.:`).
pub fn valid_arm_id(id: &str) -> bool {
    (1..=ARM_ID_MAX).contains(&id.len())
        && id.bytes().all(|b| b.is_ascii_alphanumeric() || b"-_.:".contains(&b))
}

/// Why the controller refused a set on its signature, identity or key; nothing was stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum SignatureRefusal {
    /// The set carries no signature trailer (an unsigned upload).
    Unsigned,
    /// Signed by a key this controller does not trust.
    UntrustedKey,
    /// The signature does not match the bytes (changed after signing, or not signed by the key
    /// it names).
    BadSignature,
    /// Signed for another arm's identity.
    WrongArm,
}

impl core::fmt::Display for SignatureRefusal {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            SignatureRefusal::Unsigned => {
                "the parameter set is not signed; this controller stores only signed sets (kincal upload --key STATION.key)"
            }
            SignatureRefusal::UntrustedKey => "the parameter set is signed by a key this controller does not trust",
            SignatureRefusal::BadSignature => {
                "the signature does not match the parameter set (changed after signing, or a forged signature)"
            }
            SignatureRefusal::WrongArm => "the parameter set was signed for another arm's identity",
        })
    }
}

/// Who trusts what on the controller.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum TrustMode {
    /// Only the public key built into the firmware.
    BuildKey,
    /// Trust on first use: the key of the first signed set stored is the only one trusted after.
    FirstUse,
}

/// The signed fields of a set, as read from its trailer (not yet verified).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SignedSet<'a> {
    /// The parameter blob.
    pub blob: &'a [u8],
    /// The arm identity it was signed for.
    pub arm_id: &'a str,
    /// When it was signed, Unix seconds (the station's clock).
    pub signed_at_unix_s: u64,
    /// The signer's public key.
    pub public_key: &'a [u8; PUBLIC_KEY_BYTES],
    /// The signature.
    pub signature: &'a [u8; SIGNATURE_BYTES],
    /// The bytes the signature covers.
    pub message: &'a [u8],
    /// Where the set comes from (`None`: a `KSG1` set, which carries no trace).
    pub trace: Option<SetTrace>,
}

/// Split a stored or uploaded set into its signed fields; `Unsigned` when it has no (readable)
/// trailer.
pub fn split_signed(set: &[u8]) -> Result<SignedSet<'_>, SignatureRefusal> {
    let blob_len = set.len().checked_sub(TRAILER_BYTES).ok_or(SignatureRefusal::Unsigned)?;
    let (blob, trailer) = set.split_at(blob_len);
    let (magic, rest) = trailer.split_at(4);
    let (arm, rest) = rest.split_at(ARM_ID_MAX);
    let (time, rest) = rest.split_at(8);
    let (key, signature) = rest.split_at(PUBLIC_KEY_BYTES);
    let arm_len = arm.iter().position(|&b| b == 0).unwrap_or(ARM_ID_MAX);
    let arm_id = core::str::from_utf8(&arm[..arm_len]).map_err(|_| SignatureRefusal::Unsigned)?;
    if (magic != MAGIC && magic != MAGIC_TRACED)
        || !valid_arm_id(arm_id)
        || arm[arm_len..].iter().any(|&b| b != 0)
    {
        return Err(SignatureRefusal::Unsigned);
    }
    let (blob, trace) = if magic == MAGIC_TRACED {
        let at = blob.len().checked_sub(TRACE_BYTES).ok_or(SignatureRefusal::Unsigned)?;
        let (blob, trace) = blob.split_at(at);
        (blob, Some(SetTrace::from_bytes(trace.try_into().map_err(|_| SignatureRefusal::Unsigned)?)))
    } else {
        (blob, None)
    };
    let mut secs = [0u8; 8];
    secs.copy_from_slice(time);
    Ok(SignedSet {
        trace,
        blob,
        arm_id,
        signed_at_unix_s: u64::from_le_bytes(secs),
        public_key: key.try_into().map_err(|_| SignatureRefusal::Unsigned)?,
        signature: signature.try_into().map_err(|_| SignatureRefusal::Unsigned)?,
        message: &set[..set.len() - SIGNATURE_BYTES],
    })
}

/// Why a set could not be laid out for signing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LayoutError {
    /// The arm identity is empty, too long or not printable ASCII.
    ArmId,
    /// Blob and trailer do not fit [`MAX_PARAM_BLOB`].
    TooLarge,
}

/// Write blob ‖ trailer without the signature into `out` (the bytes to sign); returns their
/// length. The signer appends its signature ([`SIGNATURE_BYTES`]) after them.
pub fn signing_message(
    blob: &[u8],
    arm_id: &str,
    signed_at_unix_s: u64,
    public_key: &[u8; PUBLIC_KEY_BYTES],
    out: &mut [u8; MAX_PARAM_BLOB],
) -> Result<usize, LayoutError> {
    layout(blob, None, arm_id, signed_at_unix_s, public_key, out)
}

/// [`signing_message`] of a traced set (`KSG2`): blob ‖ `trace` ‖ trailer without the signature.
pub fn traced_signing_message(
    blob: &[u8],
    trace: &SetTrace,
    arm_id: &str,
    signed_at_unix_s: u64,
    public_key: &[u8; PUBLIC_KEY_BYTES],
    out: &mut [u8; MAX_PARAM_BLOB],
) -> Result<usize, LayoutError> {
    layout(blob, Some(trace), arm_id, signed_at_unix_s, public_key, out)
}

fn layout(
    blob: &[u8],
    trace: Option<&SetTrace>,
    arm_id: &str,
    signed_at_unix_s: u64,
    public_key: &[u8; PUBLIC_KEY_BYTES],
    out: &mut [u8; MAX_PARAM_BLOB],
) -> Result<usize, LayoutError> {
    if !valid_arm_id(arm_id) {
        return Err(LayoutError::ArmId);
    }
    let trace_bytes = trace.map(|t| t.to_bytes());
    let (trace_part, magic): (&[u8], _) = match &trace_bytes {
        Some(bytes) => (bytes, MAGIC_TRACED),
        None => (&[], MAGIC),
    };
    let len = blob.len() + trace_part.len() + TRAILER_BYTES - SIGNATURE_BYTES;
    if len + SIGNATURE_BYTES > MAX_PARAM_BLOB {
        return Err(LayoutError::TooLarge);
    }
    let mut arm = [0u8; ARM_ID_MAX];
    arm[..arm_id.len()].copy_from_slice(arm_id.as_bytes());
    let mut at = 0;
    for part in [blob, trace_part, &magic[..], &arm[..], &signed_at_unix_s.to_le_bytes()[..], &public_key[..]]
    {
        out[at..at + part.len()].copy_from_slice(part);
        at += part.len();
    }
    Ok(len)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The layout byte by byte as documented, independent of the writer.
    #[test]
    fn trailer_is_laid_out_as_documented() {
        let blob = [1u8, 2, 3];
        let key = [7u8; 32];
        let mut out = [0u8; MAX_PARAM_BLOB];
        let n = signing_message(&blob, "arm-7", 0x0102_0304_0506_0708, &key, &mut out).unwrap();
        assert_eq!(n, 3 + 4 + 24 + 8 + 32);
        assert_eq!(&out[..3], &blob);
        assert_eq!(&out[3..7], b"KSG1");
        assert_eq!(&out[7..12], b"arm-7");
        assert!(out[12..31].iter().all(|&b| b == 0));
        assert_eq!(&out[31..39], &[8, 7, 6, 5, 4, 3, 2, 1]);
        assert_eq!(&out[39..71], &key);
        let mut set = out[..n].to_vec();
        set.extend_from_slice(&[9u8; 64]);
        let s = split_signed(&set).unwrap();
        assert_eq!((s.blob, s.arm_id, s.signed_at_unix_s), (&blob[..], "arm-7", 0x0102_0304_0506_0708));
        assert_eq!((s.public_key, s.signature, s.message), (&key, &[9u8; 64], &set[..n]));
    }

    /// A traced set byte by byte as documented: the trace between blob and trailer, magic
    /// `KSG2` at the same distance from the end as `KSG1`.
    #[test]
    fn a_traced_set_is_laid_out_as_documented() {
        let blob = [1u8, 2, 3];
        let key = [7u8; 32];
        let trace = SetTrace {
            run_sha256: core::array::from_fn(|k| k as u8 + 100),
            validated_at_unix_s: 0x1112_1314_1516_1718,
            valid_until_unix_s: 0x2122_2324_2526_2728,
        };
        let mut out = [0u8; MAX_PARAM_BLOB];
        let n = traced_signing_message(&blob, &trace, "arm-7", 5, &key, &mut out).unwrap();
        assert_eq!(n, 3 + 48 + 4 + 24 + 8 + 32);
        assert_eq!(&out[..3], &blob);
        assert_eq!(out[3], 100);
        assert_eq!(out[34], 131);
        assert_eq!(&out[35..43], &[0x18, 0x17, 0x16, 0x15, 0x14, 0x13, 0x12, 0x11]);
        assert_eq!(&out[43..51], &[0x28, 0x27, 0x26, 0x25, 0x24, 0x23, 0x22, 0x21]);
        assert_eq!(&out[51..55], b"KSG2");
        assert_eq!(&out[55..60], b"arm-7");
        let mut set = out[..n].to_vec();
        set.extend_from_slice(&[9u8; 64]);
        let s = split_signed(&set).unwrap();
        assert_eq!((s.blob, s.arm_id, s.trace), (&blob[..], "arm-7", Some(trace)));
        assert_eq!(s.message, &set[..n], "the signature covers the trace");
        // The same blob unsigned-traced is a KSG1 set with no trace.
        let m = signing_message(&blob, "arm-7", 5, &key, &mut out).unwrap();
        let mut plain = out[..m].to_vec();
        plain.extend_from_slice(&[9u8; 64]);
        assert_eq!(split_signed(&plain).unwrap().trace, None);
        assert!(SetTrace::default().is_none() && !trace.is_none());
        // A KSG2 trailer with no room for its trace is not a set.
        assert_eq!(split_signed(&set[3 + 48 - 10..]).map(|s| s.blob.len()), Err(SignatureRefusal::Unsigned));
        assert_eq!(
            traced_signing_message(&[0; 850], &trace, "a", 1, &key, &mut out),
            Err(LayoutError::TooLarge),
            "the trace counts against the parameter area"
        );
    }

    #[test]
    fn sets_without_a_readable_trailer_are_unsigned() {
        let mut out = [0u8; MAX_PARAM_BLOB];
        let n = signing_message(&[5; 40], "a", 1, &[1; 32], &mut out).unwrap();
        let mut set = out[..n].to_vec();
        set.extend_from_slice(&[0u8; 64]);
        assert!(split_signed(&set).is_ok());
        assert_eq!(split_signed(&set[..TRAILER_BYTES - 1]), Err(SignatureRefusal::Unsigned));
        for at in [40, 44, 46] {
            // Magic, a character of the identity, its zero padding.
            let mut bad = set.clone();
            bad[at] ^= 0x80;
            assert_eq!(split_signed(&bad), Err(SignatureRefusal::Unsigned), "byte {at}");
        }
        assert_eq!(signing_message(&[0; 10], "", 1, &[1; 32], &mut out), Err(LayoutError::ArmId));
        assert_eq!(signing_message(&[0; 10], "a b", 1, &[1; 32], &mut out), Err(LayoutError::ArmId));
        assert_eq!(signing_message(&[0; 900], "a", 1, &[1; 32], &mut out), Err(LayoutError::TooLarge));
    }
}
