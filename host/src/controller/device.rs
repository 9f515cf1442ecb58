//! The calibrated model as the controller stores it (the protocol's parameter blob).

use crate::model::{ArmModel, Convention, Joint, SUTA_JOINTS};
use kincal_protocol::params::{
    check_envelope, encode_blob, envelope, ArmParams, EnvelopeViolation, JointParams, MAX_PARAM_BLOB,
};

/// Why a model cannot be sent to the controller.
#[derive(Debug, thiserror::Error)]
pub enum DeviceParamsError {
    /// A value is outside the physical envelope the controller accepts (it would refuse it too).
    #[error("not sent: {0}")]
    Envelope(EnvelopeViolation),
    /// The controller holds six DH rows (the SUTA's encoders); this model has another number.
    #[error(
        "not sent: the controller holds {SUTA_JOINTS} joints (the SUTA's encoders), this model has {0}: \
         a model with another joint count can be calibrated and used on the host, not uploaded"
    )]
    JointCount(usize),
    /// The model uses URDF joints; the controller evaluates DH rows only.
    #[error(
        "not sent: this model uses URDF joints (convention = \"urdf\"); the controller evaluates \
         classic or modified DH rows only, so it would compute another arm. Use the model on the host, \
         or write it back with `kincal model to-urdf`"
    )]
    UrdfConvention,
    /// The set does not fit the controller's parameter area.
    #[error(
        "not sent: the parameter set does not fit the controller's {MAX_PARAM_BLOB}-byte parameter area"
    )]
    TooLarge,
    /// The set could not be signed.
    #[error("not sent: {0}")]
    Sign(#[from] crate::controller::signing::SignError),
}

/// The device form of `model`, tagged with parameter-set `version`; refused when the controller
/// cannot hold the model (not six joints, or URDF joints).
pub fn device_params(model: &ArmModel, version: u32) -> Result<ArmParams, DeviceParamsError> {
    if model.convention == Convention::Urdf {
        return Err(DeviceParamsError::UrdfConvention);
    }
    let joints: &[_; SUTA_JOINTS] =
        model.joints.as_slice().try_into().map_err(|_| DeviceParamsError::JointCount(model.joints.len()))?;
    Ok(ArmParams {
        version,
        modified_dh: model.convention == Convention::Modified,
        joints: joints.map(|j| JointParams {
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
    })
}

/// The host model of a parameter set as the controller evaluates it (no free parameters): what
/// `kincal check` re-validates.
pub fn model_from_params(params: &ArmParams) -> ArmModel {
    ArmModel {
        name: format!("stored on the controller (parameters version {})", params.version),
        convention: if params.modified_dh { Convention::Modified } else { Convention::Classic },
        joints: params
            .joints
            .iter()
            .map(|j| Joint {
                offset_deg: j.offset_deg,
                d_mm: j.d_mm,
                a_mm: j.a_mm,
                alpha_deg: j.alpha_deg,
                axis_deg: j.axis_deg,
                eccentricity_sin_deg: j.eccentricity_deg[0],
                eccentricity_cos_deg: j.eccentricity_deg[1],
                eccentricity2_sin_deg: j.eccentricity2_deg[0],
                eccentricity2_cos_deg: j.eccentricity2_deg[1],
                compliance_deg_per_m: j.compliance_deg_per_m,
                ..Joint::default()
            })
            .collect(),
        tcp_mm: params.tcp_mm,
        scale_ppm: params.scale_ppm,
        free: Vec::new(),
        urdf: None,
        arm: None,
        tree: Default::default(),
    }
}

/// The parameter blob of `model` (see [`kincal_protocol::params`]), checked against the same
/// envelope the controller applies (version ≥ 1, finite f32, lengths, angles, scale).
pub fn parameter_blob(model: &ArmModel, version: u32) -> Result<Vec<u8>, DeviceParamsError> {
    let params = device_params(model, version)?;
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
    Ok(key.sign(&blob, arm_id, crate::controller::traceability::unix_now())?)
}

/// [`signed_parameter_set`] carrying `trace` (the RUN's hash, validation date and validity).
pub fn traced_parameter_set(
    model: &ArmModel,
    version: u32,
    arm_id: &str,
    key: &crate::controller::signing::StationKey,
    trace: &kincal_protocol::signed::SetTrace,
) -> Result<Vec<u8>, DeviceParamsError> {
    let blob = parameter_blob(model, version)?;
    Ok(key.sign_traced(&blob, trace, arm_id, crate::controller::traceability::unix_now())?)
}

/// Why no version can be given to a new set.
#[derive(Debug, PartialEq, Eq, thiserror::Error)]
pub enum VersionError {
    /// The requested version is not above the stored one.
    #[error("the controller holds version {stored}; version {requested} would be a rollback, which it refuses. To put these values back, upload them as a new set: --version {next} (or leave --version out)")]
    Rollback {
        /// The stored version.
        stored: u32,
        /// The version asked for.
        requested: u32,
        /// The next version.
        next: u32,
    },
    /// The stored version is the highest there is: the controller takes no newer set.
    #[error("the controller holds version {stored}, the highest there is: it refuses every other version (no rollback) until its parameter flash is erased")]
    Exhausted {
        /// The stored version.
        stored: u32,
    },
    /// The requested version is above the highest the controller accepts.
    #[error("version {requested} is above the highest the controller accepts, {max} (2^31); use a lower one (a stored version that high would block every later update)")]
    TooHigh {
        /// The version asked for.
        requested: u32,
        /// [`envelope::MAX_VERSION`].
        max: u32,
    },
}

/// The version of a new set: `requested`, or the stored version + 1; above the stored one.
pub fn next_version(stored: u32, requested: Option<u32>) -> Result<u32, VersionError> {
    if stored >= envelope::MAX_VERSION {
        return Err(VersionError::Exhausted { stored });
    }
    let next = stored + 1;
    match requested {
        Some(requested) if requested > envelope::MAX_VERSION => {
            Err(VersionError::TooHigh { requested, max: envelope::MAX_VERSION })
        }
        Some(requested) if requested <= stored => Err(VersionError::Rollback { stored, requested, next }),
        Some(requested) => Ok(requested),
        None => Ok(next),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_model_of_another_joint_count_is_not_sent() {
        let mut model = ArmModel::suta_nominal();
        model.joints.push(model.joints[5]);
        let e = parameter_blob(&model, 1).unwrap_err();
        assert!(matches!(e, DeviceParamsError::JointCount(7)), "{e}");
        assert!(e.to_string().contains("holds 6 joints"), "{e}");
    }

    /// What the controller holds, read back as a host model, is the same set again.
    #[test]
    fn a_stored_set_reads_back_as_the_model_it_came_from() {
        let mut model = ArmModel::suta_nominal();
        model.convention = Convention::Modified;
        for (j, row) in model.joints.iter_mut().enumerate() {
            row.a_mm = j as f64 * 0.5;
            row.axis_deg = 0.01 * j as f64;
            row.eccentricity_sin_deg = 0.02;
            row.eccentricity_cos_deg = -0.03;
            row.eccentricity2_sin_deg = 0.004;
            row.eccentricity2_cos_deg = -0.005;
            row.compliance_deg_per_m = 0.3;
        }
        model.scale_ppm = 12.0;
        let params = device_params(&model, 9).unwrap();
        let back = model_from_params(&params);
        assert_eq!(device_params(&back, 9).unwrap(), params);
        assert_eq!(
            (back.joints, back.tcp_mm, back.convention),
            (model.joints, model.tcp_mm, model.convention)
        );
    }

    #[test]
    fn a_urdf_model_is_not_sent() {
        let mut model = ArmModel::suta_nominal();
        model.convention = Convention::Urdf;
        let e = parameter_blob(&model, 1).unwrap_err();
        assert!(e.to_string().contains("URDF joints") && e.to_string().contains("DH rows only"), "{e}");
    }

    #[test]
    fn a_new_set_is_numbered_above_the_stored_one_and_never_wraps() {
        assert_eq!(next_version(0, None), Ok(1));
        assert_eq!(next_version(7, None), Ok(8));
        assert_eq!(next_version(7, Some(20)), Ok(20));
        assert_eq!(
            next_version(7, Some(7)),
            Err(VersionError::Rollback { stored: 7, requested: 7, next: 8 })
        );
        assert_eq!(
            next_version(7, Some(3)),
            Err(VersionError::Rollback { stored: 7, requested: 3, next: 8 })
        );
        let max = envelope::MAX_VERSION;
        assert_eq!(next_version(max - 1, None), Ok(max));
        assert_eq!(next_version(7, Some(max)), Ok(max));
        assert_eq!(next_version(7, Some(max + 1)), Err(VersionError::TooHigh { requested: max + 1, max }));
        assert_eq!(next_version(7, Some(u32::MAX)), Err(VersionError::TooHigh { requested: u32::MAX, max }));
        assert_eq!(next_version(max, None), Err(VersionError::Exhausted { stored: max }));
        assert_eq!(next_version(u32::MAX, Some(1)), Err(VersionError::Exhausted { stored: u32::MAX }));
        let e = parameter_blob(&ArmModel::suta_nominal(), u32::MAX).unwrap_err();
        assert!(e.to_string().contains("above the highest accepted"), "{e}");
    }
}
