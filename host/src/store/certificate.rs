//! The calibration certificate of a RUN ([`crate::report::certificate`]): gathered from the RUN
//! folder (its summary, its hash, its upload record) and from its inputs read again (the sessions,
//! their dates and temperatures, the joint readings they visited, and whether every input file
//! still has the SHA-256 the RUN recorded), and written as `RUN/certificate.html`.

use super::{write_own_file, OutputError, RunFolder, CERTIFICATE_FILE};
use crate::data::{Artefact, Kind, Observations, Session};
use crate::files::FileError;
use crate::report::certificate::{
    certificate_page, Certificate, FileState, InputFile, JointArc, SessionFacts, CERTIFICATE_TITLE,
};
use crate::trace::{file_sha256, hex, read_uploads, run_sha256};
use std::path::{Path, PathBuf};

/// Why no certificate was made.
#[derive(Debug, thiserror::Error)]
pub enum CertificateError {
    /// The RUN folder could not be read.
    #[error(transparent)]
    File(#[from] FileError),
    /// `--operator` is not a label a record can carry.
    #[error("--operator: {0}")]
    Operator(String),
}

/// The certificate of the RUN in `dir`, issued by `operator` at `now` (Unix seconds).
pub fn gather(dir: &Path, operator: Option<&str>, now: u64) -> Result<Certificate, CertificateError> {
    if let Some(name) = operator {
        crate::trace::check_label(name).map_err(CertificateError::Operator)?;
    }
    let folder = RunFolder::load(dir)?;
    let summary = folder.summary.clone();
    let inputs = &summary.inputs;
    let role = |path: &Path| -> &'static str {
        if path == inputs.model {
            "model"
        } else if inputs.artefact.as_deref() == Some(path) {
            "artefact"
        } else if path.starts_with(&inputs.calibration) {
            "calibration"
        } else if path.starts_with(&inputs.validation) {
            "validation"
        } else {
            "input"
        }
    };
    let recorded = &summary.provenance.input_files;
    let files: Vec<InputFile> = if recorded.is_empty() {
        std::iter::once(&inputs.model)
            .chain(inputs.artefact.as_ref())
            .map(|path| InputFile {
                role: role(path).into(),
                path: path.clone(),
                sha256: None,
                state: FileState::NotRecorded,
            })
            .collect()
    } else {
        recorded
            .iter()
            .map(|f| InputFile {
                role: role(&f.path).into(),
                path: f.path.clone(),
                sha256: Some(f.sha256.clone()),
                state: match file_sha256(&f.path) {
                    Ok(now) if hex(&now) == f.sha256 => FileState::Unchanged,
                    Ok(_) => FileState::Changed,
                    Err(_) => FileState::Missing,
                },
            })
            .collect()
    };
    let artefact = inputs.artefact.as_deref().map(Artefact::load).transpose();
    let data = inputs.read_folders();
    let (sessions, coverage, inputs_unreadable) = match (&artefact, data) {
        (Ok(artefact), Ok((cal, val))) => {
            let mut sessions = session_facts(&cal, "calibration", artefact.as_ref());
            sessions.extend(session_facts(&val, "validation", artefact.as_ref()));
            let arcs = cal.joint_arcs(&[&val]);
            let coverage =
                arcs.into_iter().map(|(from_deg, span_deg)| JointArc { from_deg, span_deg }).collect();
            (sessions, coverage, None)
        }
        (Err(e), _) => (Vec::new(), Vec::new(), Some(e.to_string())),
        (_, Err(e)) => (Vec::new(), Vec::new(), Some(e.to_string())),
    };
    let artefact_landmarks = artefact.ok().flatten().map(|a| (a.landmarks.len(), a.span_mm()));
    Ok(Certificate {
        run: dir.to_path_buf(),
        run_sha256: hex(&run_sha256(dir)?),
        model_name: folder.model.name.clone(),
        uploads: read_uploads(dir)?,
        inputs: files,
        sessions,
        coverage,
        inputs_unreadable,
        artefact_landmarks,
        operator: operator.map(str::to_string),
        issued_at_unix_s: now,
        summary,
    })
}

/// What the certificate shows of each group of `data` (read for `purpose`): counts, the dates
/// an artefact session records for its touches, the temperatures of instrument rows, the arm.
fn session_facts(
    data: &Observations,
    purpose: &'static str,
    artefact: Option<&Artefact>,
) -> Vec<SessionFacts> {
    data.groups
        .iter()
        .enumerate()
        .map(|(g, group)| {
            let members: Vec<_> = data.group_members(g).into_iter().map(|k| &data.obs[k]).collect();
            let temps: Vec<f64> = members.iter().filter_map(|o| o.temp_c).collect();
            let recorded_unix_s = match (group.kind, artefact) {
                (Kind::Artefact, Some(artefact)) => {
                    Session::load(&group.source, artefact).ok().and_then(|s| {
                        let times: Vec<u64> = s.measurements.iter().filter_map(|m| m.at_unix_s).collect();
                        Some((*times.iter().min()?, *times.iter().max()?))
                    })
                }
                _ => None,
            };
            SessionFacts {
                purpose,
                kind: group.kind.word(),
                name: group.name.clone(),
                observations: members.len(),
                repeats: members.iter().map(|o| o.repeat).max().unwrap_or(0),
                recorded_unix_s,
                temp_c: (!temps.is_empty()).then(|| {
                    (
                        temps.iter().copied().fold(f64::INFINITY, f64::min),
                        temps.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                    )
                }),
                arm: group.arm.as_ref().map(|a| a.id.clone()),
            }
        })
        .collect()
}

/// Write `certificate`'s page to `out` (default `RUN/certificate.html`); an existing file there
/// is replaced only when it is a certificate kincal wrote. Returns the path written.
pub fn write_certificate(certificate: &Certificate, out: Option<&Path>) -> Result<PathBuf, OutputError> {
    let path = out.map_or_else(|| certificate.run.join(CERTIFICATE_FILE), Path::to_path_buf);
    write_own_file(&path, &certificate_page(certificate), CERTIFICATE_TITLE)?;
    Ok(path)
}
