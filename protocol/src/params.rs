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

/// Physical envelope of a parameter set: what the controller accepts and the host checks before
/// sending. Every value must also stay finite in f32, which these limits imply.
pub mod envelope {
    /// Highest parameter-set version accepted (2³¹): no rollback means a stored version can
    /// never be exceeded, so a set stored at `u32::MAX` (a typo, a wrapped counter) would block
    /// every later update; above this limit a set is refused instead, with 2³¹ versions left.
    pub const MAX_VERSION: u32 = 1 << 31;
    /// Largest |d| and |a| of a joint row, mm.
    pub const MAX_LENGTH_MM: f64 = 2000.0;
    /// Largest |tool point coordinate|, mm.
    pub const MAX_TCP_MM: f64 = 1000.0;
    /// Largest |encoder offset| and |twist α|, degrees.
    pub const MAX_ANGLE_DEG: f64 = 360.0;
    /// Largest |Hayati β|, degrees (near-parallel axes only).
    pub const MAX_AXIS_DEG: f64 = 20.0;
    /// Largest |eccentricity amplitude| of either harmonic, degrees.
    pub const MAX_ECCENTRICITY_DEG: f64 = 5.0;
    /// Largest |gravity compliance|, degrees per metre.
    pub const MAX_COMPLIANCE_DEG_PER_M: f64 = 20.0;
    /// Largest |length scale error|, ppm.
    pub const MAX_SCALE_PPM: f64 = 1000.0;
}

/// Which parameter of a set is outside the envelope.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, postcard_schema::Schema)]
pub enum ParamField {
    /// The version number (0 is reserved for "none stored").
    Version,
    /// Encoder zero offset, degrees.
    OffsetDeg,
    /// DH d, mm.
    DMm,
    /// DH a, mm.
    AMm,
    /// DH α, degrees.
    AlphaDeg,
    /// Hayati β, degrees.
    AxisDeg,
    /// First-harmonic eccentricity, degrees.
    EccentricityDeg,
    /// Second-harmonic eccentricity, degrees.
    Eccentricity2Deg,
    /// Gravity compliance, degrees per metre.
    ComplianceDegPerM,
    /// Tool point, mm.
    TcpMm,
    /// Length scale error, ppm.
    ScalePpm,
}

impl ParamField {
    /// The field's name as in [`JointParams`] / [`ArmParams`].
    pub fn name(self) -> &'static str {
        match self {
            ParamField::Version => "version",
            ParamField::OffsetDeg => "offset_deg",
            ParamField::DMm => "d_mm",
            ParamField::AMm => "a_mm",
            ParamField::AlphaDeg => "alpha_deg",
            ParamField::AxisDeg => "axis_deg",
            ParamField::EccentricityDeg => "eccentricity_deg",
            ParamField::Eccentricity2Deg => "eccentricity2_deg",
            ParamField::ComplianceDegPerM => "compliance_deg_per_m",
            ParamField::TcpMm => "tcp_mm",
            ParamField::ScalePpm => "scale_ppm",
        }
    }
}

/// A parameter outside the physical envelope: which, where, its value and the limit.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, postcard_schema::Schema)]
pub struct EnvelopeViolation {
    /// The field.
    pub field: ParamField,
    /// Joint, 1-based (0: not a joint row field).
    pub joint: u8,
    /// The value found (NaN when it was not a number).
    pub value: f64,
    /// The largest magnitude accepted (for the version: the smallest value, 1, when it is 0;
    /// else the largest, [`envelope::MAX_VERSION`]).
    pub limit: f64,
}

impl core::fmt::Display for EnvelopeViolation {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        if self.field == ParamField::Version && self.value > 0.0 {
            return write!(
                f,
                "parameter version {} is above the highest accepted, {} (2^31); use a lower one",
                self.value, self.limit
            );
        }
        if self.field == ParamField::Version {
            return write!(
                f,
                "parameter version {} is reserved (0 means none stored); use 1 or more",
                self.value
            );
        }
        if self.joint > 0 {
            write!(f, "joint {} ", self.joint)?;
        }
        write!(f, "{} = {:e} is outside the envelope ±{}", self.field.name(), self.value, self.limit)
    }
}

/// Check `params` against the physical envelope ([`envelope`]); the first violation is returned.
pub fn check_envelope(params: &ArmParams) -> Result<(), EnvelopeViolation> {
    use envelope::*;
    if params.version == 0 {
        return Err(EnvelopeViolation { field: ParamField::Version, joint: 0, value: 0.0, limit: 1.0 });
    }
    if params.version > MAX_VERSION {
        let (value, limit) = (params.version as f64, MAX_VERSION as f64);
        return Err(EnvelopeViolation { field: ParamField::Version, joint: 0, value, limit });
    }
    let check = |field, joint: u8, value: f64, limit: f64| {
        // NaN is not within any limit; the limits keep every value finite in f32.
        let within = value.abs() <= limit;
        if !within || !(value as f32).is_finite() {
            Err(EnvelopeViolation { field, joint, value, limit })
        } else {
            Ok(())
        }
    };
    for (k, j) in params.joints.iter().enumerate() {
        let joint = k as u8 + 1;
        check(ParamField::OffsetDeg, joint, j.offset_deg, MAX_ANGLE_DEG)?;
        check(ParamField::DMm, joint, j.d_mm, MAX_LENGTH_MM)?;
        check(ParamField::AMm, joint, j.a_mm, MAX_LENGTH_MM)?;
        check(ParamField::AlphaDeg, joint, j.alpha_deg, MAX_ANGLE_DEG)?;
        check(ParamField::AxisDeg, joint, j.axis_deg, MAX_AXIS_DEG)?;
        for v in j.eccentricity_deg {
            check(ParamField::EccentricityDeg, joint, v, MAX_ECCENTRICITY_DEG)?;
        }
        for v in j.eccentricity2_deg {
            check(ParamField::Eccentricity2Deg, joint, v, MAX_ECCENTRICITY_DEG)?;
        }
        check(ParamField::ComplianceDegPerM, joint, j.compliance_deg_per_m, MAX_COMPLIANCE_DEG_PER_M)?;
    }
    for v in params.tcp_mm {
        check(ParamField::TcpMm, 0, v, MAX_TCP_MM)?;
    }
    check(ParamField::ScalePpm, 0, params.scale_ppm, MAX_SCALE_PPM)
}

/// Why a blob was refused.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BlobError {
    /// Larger than [`MAX_PARAM_BLOB`] or shorter than its header says.
    Size,
    /// Not a parameter blob.
    Magic,
    /// A blob format this code does not read.
    Format(u16),
    /// Body CRC mismatch.
    Crc,
    /// CRC fine but the body does not decode.
    Body,
    /// The body decodes but a value is outside the physical envelope.
    Envelope(EnvelopeViolation),
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
    check_envelope(&params).map_err(BlobError::Envelope)?;
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
        assert!(matches!(
            decode_blob(&out[..m]),
            Err(BlobError::Envelope(EnvelopeViolation { field: ParamField::TcpMm, .. }))
        ));
    }

    /// Each absurd value of the issue is refused with the field and joint named; the limits
    /// themselves are accepted.
    #[test]
    fn absurd_sets_are_outside_the_envelope() {
        assert_eq!(check_envelope(&sample()), Ok(()));
        /// A way to break a set, the field and the joint the refusal must name.
        type Case = (fn(&mut ArmParams), ParamField, u8);
        let cases: [Case; 8] = [
            (|p| p.version = u32::MAX, ParamField::Version, 0),
            (|p| p.joints[2].a_mm = 1e6, ParamField::AMm, 3),
            (|p| p.joints[0].alpha_deg = 1e6, ParamField::AlphaDeg, 1),
            (|p| p.scale_ppm = 1e12, ParamField::ScalePpm, 0),
            (|p| p.joints[5].d_mm = 1e300, ParamField::DMm, 6),
            (|p| p.joints[1].compliance_deg_per_m = f64::INFINITY, ParamField::ComplianceDegPerM, 2),
            (|p| p.tcp_mm[2] = -1e40, ParamField::TcpMm, 0),
            (|p| p.version = 0, ParamField::Version, 0),
        ];
        for (break_it, field, joint) in cases {
            let mut p = sample();
            break_it(&mut p);
            let v = check_envelope(&p).unwrap_err();
            assert_eq!((v.field, v.joint), (field, joint), "{v}");
            let mut out = [0u8; MAX_PARAM_BLOB];
            let n = encode_blob(&p, &mut out).unwrap();
            assert_eq!(decode_blob(&out[..n]), Err(BlobError::Envelope(v)));
        }
        let mut edge = sample();
        edge.scale_ppm = envelope::MAX_SCALE_PPM;
        edge.joints[0].a_mm = -envelope::MAX_LENGTH_MM;
        edge.version = envelope::MAX_VERSION;
        assert_eq!(check_envelope(&edge), Ok(()));
        edge.version += 1;
        let too_new = check_envelope(&edge).unwrap_err();
        assert_eq!(
            (too_new.field, too_new.value, too_new.limit),
            (ParamField::Version, 2147483649.0, 2147483648.0)
        );
        assert!(too_new.to_string().contains("above the highest accepted"), "{too_new}");
        edge.version = envelope::MAX_VERSION;
        edge.scale_ppm = envelope::MAX_SCALE_PPM * 1.001;
        assert!(check_envelope(&edge).is_err());
    }
}
