//! A RUN folder read back as types: the calibrated and nominal models, `summary.json` (today's
//! [`RUN_FORMAT`], or a version-1 artefact or tracker summary turned into it) and `residuals.json`.

use super::legacy::{ArtefactRunV1, TrackerRunV1, ARTEFACT_RUN_V1, TRACKER_RUN_V1};
use crate::calib::run::{check_run_data, RunError};
use crate::calib::summary::{StoredPairError, StoredResiduals, Summary, RESIDUALS_FORMAT, RUN_FORMAT};
use crate::calib::trust::TrustScales;
use crate::calib::validate;
use crate::data::Observations;
use crate::files::{field_error, read_tagged, FileError, TaggedJson};
use crate::model::ArmModel;
use std::path::{Path, PathBuf};

/// A RUN folder read back as types.
pub struct RunFolder {
    /// The folder.
    pub dir: PathBuf,
    /// The calibrated model (`model.toml`).
    pub model: ArmModel,
    /// `summary.json`, in today's shape whatever version wrote it.
    pub summary: Summary,
    /// The format tag `summary.json` carried ([`RUN_FORMAT`] or a version-1 tag).
    pub format: String,
}

/// Read `summary.json` of any version kincal wrote, as today's [`Summary`].
fn read_summary(path: &Path, joints: usize) -> Result<(Summary, String), FileError> {
    let json = TaggedJson::read(path)?;
    let format = json.format.clone().unwrap_or_default();
    let summary = match format.as_str() {
        ARTEFACT_RUN_V1 => json.parse::<ArtefactRunV1>()?.into_summary(joints),
        TRACKER_RUN_V1 => json.parse::<TrackerRunV1>()?.into_summary(),
        _ => json.parse_tagged(RUN_FORMAT)?,
    };
    Ok((summary, format))
}

impl RunFolder {
    /// Read `model.toml` and `summary.json` of a RUN folder; the recorded options are checked
    /// against the same limits as the command line's, since diagnose refits with them, and every
    /// figure for plausibility ([`Summary::check_figures`]).
    pub fn load(dir: &Path) -> Result<RunFolder, FileError> {
        let model = ArmModel::load(&dir.join("model.toml"))?;
        let path = dir.join("summary.json");
        let (summary, format) = read_summary(&path, model.joints.len())?;
        summary.options.check().map_err(|(field, message)| field_error(&path, field, message))?;
        summary.check_figures().map_err(|(field, message)| field_error(&path, field, message))?;
        if summary.joints != model.joints.len() {
            return Err(field_error(
                &path,
                "joints",
                format!("{} joints, but model.toml beside it has {}", summary.joints, model.joints.len()),
            ));
        }
        Ok(RunFolder { dir: dir.to_owned(), model, summary, format })
    }

    /// The nominal model the run started from (`nominal.toml`).
    pub fn nominal(&self) -> Result<ArmModel, FileError> {
        ArmModel::load(&self.dir.join("nominal.toml"))
    }

    /// Read `residuals.json`, its figures checked as [`StoredResiduals::check`] says. A run
    /// without held-out distances (tracker sessions only) has none.
    pub fn residuals(&self) -> Result<Vec<StoredPairError>, FileError> {
        if self.summary.validation.distances.is_none() {
            return Ok(Vec::new());
        }
        let path = self.dir.join("residuals.json");
        let stored: StoredResiduals = read_tagged(&path, RESIDUALS_FORMAT)?;
        stored
            .check(self.model.joints.len())
            .map_err(|(field, message)| field_error(&path, field, message))?;
        Ok(stored.pairs)
    }

    /// Read both folders the run used, with its exclusions applied, refused as `calibrate` refuses them ([`check_run_data`]),
    /// and refused when the RUN's model is beyond the model-independent scales on the artefact
    /// distances ([`TrustScales`], with `nominal.toml` as the nominal model): a diagnosis of an
    /// absurd model would blame landmarks and effects for what the model gets wrong.
    pub fn data(&self) -> Result<(Observations, Observations), RunError> {
        let inputs = &self.summary.inputs;
        let (cal, val) = inputs.read_folders()?;
        let groups: Vec<String> = cal.groups.iter().map(|g| g.name.clone()).collect();
        let options = self.summary.options.solve_options(inputs, &groups);
        let (kept, held) = inputs.exclude(cal, val)?;
        check_run_data(&self.model, &kept, &held, inputs, &options)?;
        if self.summary.validation.distances.is_some() {
            let nominal = self.nominal()?;
            let scales = TrustScales::of(&nominal, &kept, &held);
            let rms = |data: &Observations| validate::validate(&self.model, data).overall.rms_mm;
            let beyond = scales.beyond(rms(&kept), rms(&held));
            if !beyond.is_empty() {
                return Err(RunError::NotACalibration(beyond));
            }
        }
        Ok((kept, held))
    }
}
