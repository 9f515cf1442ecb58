//! Whom the controller trusts: a parameter set is stored only when it is signed (Ed25519,
//! `ed25519-compact`) by a trusted key, for this arm's identity, with a version higher than the
//! stored one ([`kincal_protocol::signed`] has the layout).
//!
//! Trusted keys: the public key built into the firmware (`KINCAL_TRUSTED_KEY`, 64 hex digits, at
//! build time) or, when none was built in, trust on first use: the key that signed the stored set
//! is the only one trusted. The stored set is the pin, so it is as power-safe as the set itself;
//! it goes only when the parameter flash is erased (a re-flash that erases it, or a new
//! emulator). The arm identity comes from the board (`KINCAL_ARM_ID` at build time, else the
//! STM32's unique ID or the emulator's start option).

use kincal_protocol::messages::WireError;
use kincal_protocol::params::{decode_blob, ArmParams, BlobError};
use kincal_protocol::signed::{
    split_signed, valid_arm_id, ArmId, SetTrace, SignatureRefusal, TrustMode, PUBLIC_KEY_BYTES,
};

include!(concat!(env!("OUT_DIR"), "/provisioning.rs"));

/// The emulated arm's identity when no start option or build-time identity names another.
pub const EMULATED_ARM_ID: &str = "emulated-arm";

/// Who signed the active set, and when.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Provenance {
    /// The signer's public key.
    pub signer: [u8; PUBLIC_KEY_BYTES],
    /// Time signed, Unix seconds (the station's clock).
    pub signed_at_unix_s: u64,
    /// The RUN and validity the set was signed with (zero for a set that carries none).
    pub trace: SetTrace,
}

/// The arm's identity and the key built into the firmware, if any.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Trust {
    arm_id: ArmId,
    build_key: Option<[u8; PUBLIC_KEY_BYTES]>,
}

impl Trust {
    /// Trust for arm `arm_id` with the build-time key if one was built in; `None` when `arm_id`
    /// is not a valid identity.
    pub fn provisioned(arm_id: &str) -> Option<Trust> {
        Trust::new(arm_id, BUILD_KEY)
    }

    /// Trust for arm `arm_id`: only `build_key`, or (`None`) trust on first use.
    pub fn new(arm_id: &str, build_key: Option<[u8; PUBLIC_KEY_BYTES]>) -> Option<Trust> {
        if !valid_arm_id(arm_id) {
            return None;
        }
        Some(Trust { arm_id: ArmId::try_from(arm_id).ok()?, build_key })
    }

    /// The arm's identity.
    pub fn arm_id(&self) -> &ArmId {
        &self.arm_id
    }

    /// Which keys are trusted.
    pub fn mode(&self) -> TrustMode {
        if self.build_key.is_some() {
            TrustMode::BuildKey
        } else {
            TrustMode::FirstUse
        }
    }

    /// Check an uploaded set before it is stored. `stored`: the active set's parameters and
    /// provenance (its signer is the pinned key on first use; its version must be exceeded).
    /// Cheap checks first: the signature is verified only for a trusted key.
    pub fn admit(
        &self,
        set: &[u8],
        stored: Option<(&ArmParams, &Provenance)>,
    ) -> Result<(ArmParams, Provenance), WireError> {
        let refuse = |r| WireError::ParamSignature(r);
        let signed = split_signed(set).map_err(refuse)?;
        let trusted = match (self.build_key, stored) {
            (Some(key), _) => key,
            (None, Some((_, pinned))) => pinned.signer,
            (None, None) => *signed.public_key,
        };
        if *signed.public_key != trusted {
            return Err(refuse(SignatureRefusal::UntrustedKey));
        }
        verify(signed.public_key, signed.message, signed.signature).map_err(refuse)?;
        let params = decode_blob(signed.blob).map_err(|e| match e {
            BlobError::Envelope(v) => WireError::ParamEnvelope(v),
            _ => WireError::ParamInvalid,
        })?;
        if signed.arm_id != self.arm_id.as_str() {
            return Err(refuse(SignatureRefusal::WrongArm));
        }
        if let Some((current, _)) = stored {
            if params.version <= current.version {
                return Err(WireError::ParamRollback { stored: current.version, offered: params.version });
            }
        }
        Ok((
            params,
            Provenance {
                signer: *signed.public_key,
                signed_at_unix_s: signed.signed_at_unix_s,
                trace: signed.trace.unwrap_or_default(),
            },
        ))
    }

    /// The stored set at boot: used only if it still passes every check but the version (so a
    /// set from before signing, for another arm or from a key no longer built in is not used).
    pub fn load(&self, set: &[u8]) -> Option<(ArmParams, Provenance)> {
        self.admit(set, None).ok()
    }
}

/// Verify `signature` of `message` by `public_key` (RFC 8032 Ed25519, canonical S, small-order
/// keys refused).
fn verify(
    public_key: &[u8; PUBLIC_KEY_BYTES],
    message: &[u8],
    signature: &[u8; 64],
) -> Result<(), SignatureRefusal> {
    let key = ed25519_compact::PublicKey::new(*public_key);
    key.verify(message, &ed25519_compact::Signature::new(*signature))
        .map_err(|_| SignatureRefusal::BadSignature)
}
