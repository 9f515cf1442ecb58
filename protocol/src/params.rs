//! The parameter blob: the calibrated arm model as the controller stores and evaluates it.
//!
//! Layout: magic `KCP1` (4 bytes) ‖ format u16 LE ‖ body length u16 LE ‖ CRC-32 of the body
//! u32 LE ‖ body = postcard([`ArmParams`]). At most [`MAX_PARAM_BLOB`] bytes. The upload as a
//! whole is checked with [`BLOB_CRC`] too ([`crate::messages::Request::ParamBegin`]).

use serde::{Deserialize, Serialize};

/// Blob format; bump on any change of [`ArmParams`].
pub const PARAM_FORMAT: u16 = 1;
/// Largest blob the controller stores, bytes.
pub const MAX_PARAM_BLOB: usize = 1024;
/// CRC-32 used for the blob body and for uploads.
pub const BLOB_CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
const MAGIC: [u8; 4] = *b"KCP1";
const HEADER: usize = 12;

/// One joint row with every effect the host model can hold (units as in the host model file).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointParams {
    /// Encoder zero offset, degrees.
    pub offset_deg: f64,
    /// DH d, mm.
    pub d_mm: f64,
    /// DH a, mm.
    pub a_mm: f64,
    /// DH α, degrees.
    pub alpha_deg: f64,
    /// Hayati β, degrees.
    pub axis_deg: f64,
    /// First-harmonic eccentricity, sine and cosine parts, degrees.
    pub eccentricity_deg: [f64; 2],
    /// Second-harmonic eccentricity, sine and cosine parts, degrees.
    pub eccentricity2_deg: [f64; 2],
    /// Gravity compliance, degrees per metre of unit-weight lever.
    pub compliance_deg_per_m: f64,
}

/// The calibrated arm model.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ArmParams {
    /// Version number of this parameter set (chosen by the host, shown by `kincal info`).
    pub version: u32,
    /// Modified (Craig) DH convention instead of classic.
    pub modified_dh: bool,
    /// Joint rows, base to tip.
    pub joints: [JointParams; 6],
    /// Tool point in the last frame, mm.
    pub tcp_mm: [f64; 3],
    /// Length scale error, ppm.
    pub scale_ppm: f64,
}

/// Why a blob was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BlobError {
    /// Larger than [`MAX_PARAM_BLOB`] or shorter than its header says.
    Size,
    /// Not a parameter blob.
    Magic,
    /// A blob format this code does not read.
    Format(u16),
    /// Body CRC mismatch.
    Crc,
    /// CRC fine but the body does not decode, or holds a non-finite number.
    Body,
}

/// Encode `params` into `out`; returns the blob length.
pub fn encode_blob(params: &ArmParams, out: &mut [u8; MAX_PARAM_BLOB]) -> Result<usize, BlobError> {
    let body_len = postcard::to_slice(params, &mut out[HEADER..]).map_err(|_| BlobError::Size)?.len();
    let crc = BLOB_CRC.checksum(&out[HEADER..HEADER + body_len]);
    out[..4].copy_from_slice(&MAGIC);
    out[4..6].copy_from_slice(&PARAM_FORMAT.to_le_bytes());
    out[6..8].copy_from_slice(&(body_len as u16).to_le_bytes());
    out[8..12].copy_from_slice(&crc.to_le_bytes());
    Ok(HEADER + body_len)
}

/// Check and decode a blob.
pub fn decode_blob(blob: &[u8]) -> Result<ArmParams, BlobError> {
    if blob.len() < HEADER || blob.len() > MAX_PARAM_BLOB {
        return Err(BlobError::Size);
    }
    if blob[..4] != MAGIC {
        return Err(BlobError::Magic);
    }
    let format = u16::from_le_bytes([blob[4], blob[5]]);
    if format != PARAM_FORMAT {
        return Err(BlobError::Format(format));
    }
    let len = u16::from_le_bytes([blob[6], blob[7]]) as usize;
    let body = blob.get(HEADER..HEADER + len).ok_or(BlobError::Size)?;
    if BLOB_CRC.checksum(body) != u32::from_le_bytes([blob[8], blob[9], blob[10], blob[11]]) {
        return Err(BlobError::Crc);
    }
    let params: ArmParams = postcard::from_bytes(body).map_err(|_| BlobError::Body)?;
    let finite = params.joints.iter().all(|j| {
        [
            j.offset_deg,
            j.d_mm,
            j.a_mm,
            j.alpha_deg,
            j.axis_deg,
            j.eccentricity_deg[0],
            j.eccentricity_deg[1],
            j.eccentricity2_deg[0],
            j.eccentricity2_deg[1],
            j.compliance_deg_per_m,
        ]
        .iter()
        .all(|v| v.is_finite())
    }) && params.tcp_mm.iter().all(|v| v.is_finite())
        && params.scale_ppm.is_finite();
    if !finite {
        return Err(BlobError::Body);
    }
    Ok(params)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> ArmParams {
        let mut p = ArmParams {
            version: 7,
            modified_dh: false,
            tcp_mm: [0.1, -0.2, 253.0],
            scale_ppm: 12.0,
            ..ArmParams::default()
        };
        for (j, row) in p.joints.iter_mut().enumerate() {
            *row = JointParams {
                offset_deg: j as f64 * 10.5,
                d_mm: 571.0,
                alpha_deg: 90.0,
                eccentricity_deg: [0.1, -0.2],
                compliance_deg_per_m: 0.05,
                ..JointParams::default()
            };
        }
        p
    }

    #[test]
    fn blob_round_trips_within_the_size_limit() {
        let mut out = [0u8; MAX_PARAM_BLOB];
        let n = encode_blob(&sample(), &mut out).unwrap();
        assert!(n <= MAX_PARAM_BLOB);
        assert_eq!(decode_blob(&out[..n]), Ok(sample()));
    }

    #[test]
    fn damaged_blobs_are_refused() {
        let mut out = [0u8; MAX_PARAM_BLOB];
        let n = encode_blob(&sample(), &mut out).unwrap();
        for i in 0..n {
            let mut bad = out;
            bad[i] ^= 0x10;
            assert!(decode_blob(&bad[..n]).is_err(), "byte {i}");
        }
        assert_eq!(decode_blob(&out[..n - 1]), Err(BlobError::Size));
        let mut nan = sample();
        nan.tcp_mm[0] = f64::NAN;
        let m = encode_blob(&nan, &mut out).unwrap();
        assert_eq!(decode_blob(&out[..m]), Err(BlobError::Body));
    }
}
