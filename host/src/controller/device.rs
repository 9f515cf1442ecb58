//! The calibrated model as the controller stores it (the protocol's parameter blob).

use crate::model::{ArmModel, Convention};
use kincal_protocol::params::{
    check_envelope, encode_blob, ArmParams, EnvelopeViolation, JointParams, MAX_PARAM_BLOB,
};

/// Why a model cannot be sent to the controller.
#[derive(Debug, thiserror::Error)]
pub enum DeviceParamsError {
    /// A value is outside the physical envelope the controller accepts (it would refuse it too).
    #[error("not sent: {0}")]
    Envelope(EnvelopeViolation),
    /// The set does not fit the controller's parameter area.
    #[error(
        "not sent: the parameter set does not fit the controller's {MAX_PARAM_BLOB}-byte parameter area"
    )]
    TooLarge,
    /// The set could not be signed.
    #[error("not sent: {0}")]
    Sign(#[from] crate::controller::signing::SignError),
}

/// The device form of `model`, tagged with parameter-set `version`.
pub fn device_params(model: &ArmModel, version: u32) -> ArmParams {
    ArmParams {
        version,
        modified_dh: model.convention == Convention::Modified,
        joints: model.joints.map(|j| JointParams {
            offset_deg: j.offset_deg,
            d_mm: j.d_mm,
            a_mm: j.a_mm,
            alpha_deg: j.alpha_deg,
            axis_deg: j.axis_deg,
            eccentricity_deg: [j.eccentricity_sin_deg, j.eccentricity_cos_deg],
            eccentricity2_deg: [j.eccentricity2_sin_deg, j.eccentricity2_cos_deg],
            compliance_deg_per_m: j.compliance_deg_per_m,
        }),
        tcp_mm: model.tcp_mm,
        scale_ppm: model.scale_ppm,
    }
}

/// The parameter blob of `model` (see [`kincal_protocol::params`]), checked against the same
/// envelope the controller applies (version ≥ 1, finite f32, lengths, angles, scale).
pub fn parameter_blob(model: &ArmModel, version: u32) -> Result<Vec<u8>, DeviceParamsError> {
    let params = device_params(model, version);
    check_envelope(&params).map_err(DeviceParamsError::Envelope)?;
    let mut out = [0u8; MAX_PARAM_BLOB];
    let n = encode_blob(&params, &mut out).map_err(|_| DeviceParamsError::TooLarge)?;
    Ok(out[..n].to_vec())
}

/// The signed parameter set of `model` as `version`, for the arm `arm_id`, signed now by `key`:
/// what [`crate::controller::link::Link::upload`] sends.
pub fn signed_parameter_set(
    model: &ArmModel,
    version: u32,
    arm_id: &str,
    key: &crate::controller::signing::StationKey,
) -> Result<Vec<u8>, DeviceParamsError> {
    let blob = parameter_blob(model, version)?;
    let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
    Ok(key.sign(&blob, arm_id, now)?)
}
