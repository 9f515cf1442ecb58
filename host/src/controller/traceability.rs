//! A stored calibration that belongs to its arm: which arm a model may be uploaded to, the RUN
//! and validity a signed set carries ([`SetTrace`]), and the warning when that validity has
//! passed.
//!
//! * A model that names its arm (`[arm] id` in model.toml) goes only to that arm's controller.
//! * A model that names none (nominal, simulated, hand-written) goes only where the uploader
//!   names the arm explicitly (`--for-arm ID`), and only when it is the connected one: a stale
//!   script cannot put it on whichever arm happens to be connected.
//! * The signed set carries the RUN's hash ([`crate::trace::run_sha256`]), the date of its
//!   validation and, optionally, the end of its validity period.

use crate::trace::{ArmIdentity, RunOrigin};
use kincal_protocol::signed::SetTrace;
use std::path::{Path, PathBuf};

/// Seconds in a day.
const DAY_S: u64 = 86_400;

/// Now, Unix seconds (0 if the clock is before 1970).
pub fn unix_now() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs())
}

/// Why a model may not go to the connected arm; nothing was sent.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ArmRefusal {
    /// The model was calibrated on another arm.
    #[error(
        "{model} was calibrated on arm {model_arm}, and the connected controller is arm {controller}: \
         a calibration belongs to its arm, nothing was uploaded (connect arm {model_arm}, or \
         calibrate arm {controller} from its own sessions)"
    )]
    OtherArm {
        /// The model file.
        model: PathBuf,
        /// The arm it names.
        model_arm: String,
        /// The connected controller's arm.
        controller: String,
    },
    /// `--for-arm` names another arm than the model does.
    #[error(
        "--for-arm {option} disagrees with {model}, which was calibrated on arm {model_arm}; nothing \
         was uploaded"
    )]
    OptionDisagrees {
        /// The model file.
        model: PathBuf,
        /// The arm it names.
        model_arm: String,
        /// The arm the option names.
        option: String,
    },
    /// The model names no arm and no arm was named for it.
    #[error(
        "{model} names no arm (a nominal, simulated or hand-written model; a calibrated RUN/model.toml \
         names the arm it was calibrated on): to upload it anyway, name the arm it is for with \
         --for-arm ID (the connected controller is arm {controller}); nothing was uploaded"
    )]
    Unnamed {
        /// The model file.
        model: PathBuf,
        /// The connected controller's arm.
        controller: String,
    },
    /// `--for-arm` names another arm than the connected one.
    #[error("--for-arm {option}, and the connected controller is arm {controller}; nothing was uploaded")]
    NotConnected {
        /// The arm the option names.
        option: String,
        /// The connected controller's arm.
        controller: String,
    },
}

/// Whether the model in `model_file` (naming `model_arm`, if any) may go to the controller of
/// arm `controller`, with `for_arm` given by the uploader.
pub fn check_upload_arm(
    model_file: &Path,
    model_arm: Option<&ArmIdentity>,
    for_arm: Option<&str>,
    controller: &str,
) -> Result<(), ArmRefusal> {
    let model = model_file.to_path_buf();
    match (model_arm, for_arm) {
        (Some(arm), Some(option)) if option != arm.id => {
            Err(ArmRefusal::OptionDisagrees { model, model_arm: arm.id.clone(), option: option.into() })
        }
        (Some(arm), _) if arm.id != controller => {
            Err(ArmRefusal::OtherArm { model, model_arm: arm.id.clone(), controller: controller.into() })
        }
        (None, None) => Err(ArmRefusal::Unnamed { model, controller: controller.into() }),
        (None, Some(option)) if option != controller => {
            Err(ArmRefusal::NotConnected { option: option.into(), controller: controller.into() })
        }
        _ => Ok(()),
    }
}

/// Why no trace can be signed with a set.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ValidityError {
    /// A validity period needs a validation date to count from.
    #[error(
        "--valid-days counts from the date the calibration was validated, and {0} is not a RUN's \
         model (RUN/model.toml with its summary.json): no date to count from; nothing was uploaded"
    )]
    NoRun(PathBuf),
    /// A period of no days.
    #[error("--valid-days 0: a calibration valid for no time cannot be used; nothing was uploaded")]
    Zero,
    /// The period has passed already.
    #[error(
        "validated {validated}, valid for {days} days: the validity ended {ended}, before this \
         upload; nothing was uploaded (validate the arm again: `kincal check`, or calibrate again)"
    )]
    Passed {
        /// The validation date.
        validated: String,
        /// The period, days.
        days: u32,
        /// When it ended.
        ended: String,
    },
}

/// The trace to sign with a model from `origin` (its RUN, if it is a RUN's model), valid for
/// `valid_days` days from its validation if given, at time `now`.
pub fn upload_trace(
    model_file: &Path,
    origin: Option<&RunOrigin>,
    valid_days: Option<u32>,
    now: u64,
) -> Result<SetTrace, ValidityError> {
    let Some(origin) = origin else {
        return match valid_days {
            Some(_) => Err(ValidityError::NoRun(model_file.to_path_buf())),
            None => Ok(SetTrace::default()),
        };
    };
    let valid_until_unix_s = match valid_days {
        None => 0,
        Some(0) => return Err(ValidityError::Zero),
        Some(days) => {
            let until = origin.validated_at_unix_s.saturating_add(days as u64 * DAY_S);
            if until <= now {
                return Err(ValidityError::Passed {
                    validated: utc(origin.validated_at_unix_s),
                    days,
                    ended: utc(until),
                });
            }
            until
        }
    };
    Ok(SetTrace {
        run_sha256: origin.sha256,
        validated_at_unix_s: origin.validated_at_unix_s,
        valid_until_unix_s,
    })
}

use crate::trace::utc;

/// What `RUN/uploads.json` records of the signed `set` stored on `arm`: `None` when the set is
/// not signed, not decodable or carries no RUN hash (not a RUN's model).
pub fn upload_record(arm: &ArmIdentity, set: &[u8]) -> Option<crate::trace::UploadRecord> {
    let signed = crate::controller::signing::provenance(set)?;
    let params = kincal_protocol::params::decode_blob(&signed.blob).ok()?;
    let trace = signed.trace.filter(|t| t.run_sha256 != [0; 32])?;
    Some(crate::trace::UploadRecord {
        arm: arm.clone(),
        param_version: params.version,
        signer: crate::controller::signing::fingerprint(&signed.signer),
        signed_at_unix_s: signed.signed_at_unix_s,
        run_sha256: crate::trace::hex(&trace.run_sha256),
        validated_at_unix_s: trace.validated_at_unix_s,
        valid_until_unix_s: (trace.valid_until_unix_s != 0).then_some(trace.valid_until_unix_s),
    })
}

/// Whole days from `from` to `to` (rounded down; 0 when `to` is not later), in words.
fn days_between(from: u64, to: u64) -> String {
    match to.saturating_sub(from) / DAY_S {
        1 => "1 day".into(),
        n => format!("{n} days"),
    }
}

/// The warning to print when connecting to arm `arm` whose stored set (version `version`)
/// carries `trace`, at time `now`: `Some` once its validity has passed.
pub fn expiry_warning(arm: &str, version: u32, trace: &SetTrace, now: u64) -> Option<String> {
    let until = trace.valid_until_unix_s;
    if version == 0 || until == 0 || now < until {
        return None;
    }
    Some(format!(
        "warning: the calibration stored on arm {arm} (parameters version {version}, validated {}) \
         expired {} ({} ago): check that the arm still holds it (`kincal check`), or calibrate it \
         again",
        utc(trace.validated_at_unix_s),
        utc(until),
        days_between(until, now)
    ))
}

/// What a stored set's trace says, one `(label, text)` per line, at time `now` (empty when it
/// carries none).
pub fn trace_lines(trace: &SetTrace, now: u64) -> Vec<(&'static str, String)> {
    if trace.is_none() {
        return vec![("RUN", "not recorded (a set signed without its RUN)".into())];
    }
    let mut lines = Vec::new();
    if trace.run_sha256 != [0; 32] {
        lines.push(("RUN", format!("sha256:{}", crate::trace::hex(&trace.run_sha256))));
    }
    if trace.validated_at_unix_s != 0 {
        lines.push(("validated", utc(trace.validated_at_unix_s)));
    }
    let until = trace.valid_until_unix_s;
    lines.push((
        "valid",
        match until {
            0 => "no validity period".to_string(),
            u if now >= u => format!("until {}: EXPIRED {} ago", utc(u), days_between(u, now)),
            u => format!("until {} ({} left)", utc(u), days_between(now, u)),
        },
    ));
    lines
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_model_goes_only_to_the_arm_it_names_or_the_one_named_for_it() {
        let m = Path::new("runs/a/model.toml");
        let a = ArmIdentity::of("arm-A");
        assert_eq!(check_upload_arm(m, Some(&a), None, "arm-A"), Ok(()));
        assert_eq!(check_upload_arm(m, Some(&a), Some("arm-A"), "arm-A"), Ok(()));
        let other = check_upload_arm(m, Some(&a), None, "arm-B").unwrap_err().to_string();
        assert!(
            other.contains("runs/a/model.toml was calibrated on arm arm-A")
                && other.contains("connected controller is arm arm-B"),
            "{other}"
        );
        let disagree = check_upload_arm(m, Some(&a), Some("arm-B"), "arm-B").unwrap_err();
        assert!(matches!(disagree, ArmRefusal::OptionDisagrees { .. }), "{disagree}");
        let unnamed = check_upload_arm(m, None, None, "arm-B").unwrap_err().to_string();
        assert!(unnamed.contains("names no arm") && unnamed.contains("--for-arm"), "{unnamed}");
        assert_eq!(check_upload_arm(m, None, Some("arm-B"), "arm-B"), Ok(()));
        let elsewhere = check_upload_arm(m, None, Some("arm-A"), "arm-B").unwrap_err().to_string();
        assert!(elsewhere.contains("--for-arm arm-A") && elsewhere.contains("arm arm-B"), "{elsewhere}");
    }

    #[test]
    fn a_validity_counts_from_the_validation_and_must_not_have_passed() {
        let m = Path::new("RUN/model.toml");
        let origin = RunOrigin {
            run: "RUN".into(),
            sha256: [7; 32],
            validated_at_unix_s: 1_790_000_000,
            date_from_file_time: false,
        };
        let now = 1_790_000_000 + 10 * DAY_S;
        let trace = upload_trace(m, Some(&origin), Some(30), now).unwrap();
        assert_eq!(trace.valid_until_unix_s, 1_790_000_000 + 30 * DAY_S);
        assert_eq!((trace.run_sha256, trace.validated_at_unix_s), ([7; 32], 1_790_000_000));
        assert_eq!(upload_trace(m, Some(&origin), None, now).unwrap().valid_until_unix_s, 0);
        let passed = upload_trace(m, Some(&origin), Some(10), now).unwrap_err();
        assert!(passed.to_string().contains("valid for 10 days"), "{passed}");
        assert_eq!(upload_trace(m, Some(&origin), Some(0), now), Err(ValidityError::Zero));
        assert_eq!(upload_trace(m, None, None, now), Ok(SetTrace::default()));
        assert_eq!(upload_trace(m, None, Some(5), now), Err(ValidityError::NoRun(m.into())));
    }

    #[test]
    fn an_expired_set_is_warned_about_with_its_dates() {
        let trace = SetTrace {
            run_sha256: [1; 32],
            validated_at_unix_s: 1_790_000_000,
            valid_until_unix_s: 1_790_000_000 + 30 * DAY_S,
        };
        let before = 1_790_000_000 + 29 * DAY_S;
        let after = 1_790_000_000 + 42 * DAY_S + 5;
        assert_eq!(expiry_warning("arm-A", 3, &trace, before), None);
        assert_eq!(expiry_warning("arm-A", 0, &trace, after), None, "nothing stored");
        assert_eq!(expiry_warning("arm-A", 3, &SetTrace::default(), after), None, "no period");
        let w = expiry_warning("arm-A", 3, &trace, after).unwrap();
        assert!(w.contains("arm arm-A") && w.contains("version 3") && w.contains("12 days ago"), "{w}");
        assert!(w.contains("validated 2026-09-21") && w.contains("expired 2026-10-21"), "{w}");
        let lines = trace_lines(&trace, after);
        assert_eq!(lines[0], ("RUN", format!("sha256:{}", "01".repeat(32))));
        assert!(lines[2].1.contains("EXPIRED 12 days ago"), "{lines:?}");
        assert!(trace_lines(&trace, before)[2].1.contains("(1 day left)"), "{lines:?}");
    }
}
