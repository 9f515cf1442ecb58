//! The calibrated model as the controller stores it (the protocol's parameter blob).

use crate::model::{ArmModel, Convention};
use kincal_protocol::params::{encode_blob, ArmParams, JointParams, MAX_PARAM_BLOB};

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

/// The parameter blob of `model` (see [`kincal_protocol::params`]).
pub fn parameter_blob(model: &ArmModel, version: u32) -> Vec<u8> {
    let mut out = [0u8; MAX_PARAM_BLOB];
    let n = encode_blob(&device_params(model, version), &mut out).unwrap_or(0);
    out[..n].to_vec()
}
