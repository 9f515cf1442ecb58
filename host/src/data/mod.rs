//! Input files: the certified artefact (`suta-artefact/1`) and measurement sessions
//! (`suta-session/1`, one file per artefact placement).
//!
//! ```json
//! {"format":"suta-artefact/1","landmarks":[{"id":"O","xyz_mm":[0,0,40],"yaw_deg":2.0}, …]}
//! {"format":"suta-session/1","placement":"C_A","purpose":"calibration",
//!  "measurements":[{"landmark":"M1","repeat":1,"joints_deg":[6 raw encoder angles in [0,360)],
//!                   "std_deg":[…6],"samples":1536,"rejected":0}, …]}
//! ```
//! `std_deg`, `samples` and `rejected` are optional; sessions may miss landmarks. A session
//! holds one angle per joint of the arm (1 to 12; six for the SUTA), the same count in every
//! measurement. A session recorded by `kincal record` also names the arm it was recorded on
//! (`"arm": {"id": "lab-arm-2", "firmware": "kincal-fw 0.1.0", "board": "…"}`, read by
//! [`session_arm`]); older sessions have none.
//! Tracker sessions (points measured by an instrument) are read by [`tracker`].
//! Both readers make [`Observations`], the one shape everything downstream reads
//! ([`observations`]); [`load_folder`] reads a folder of either kind or of both.

pub mod encoders;
pub mod observations;
pub mod point_distances;
pub mod tracker;

pub use encoders::Encoders;
pub use observations::{
    BindError, Block, ColumnNames, DataKind, Group, Joints, Kind, Observation, Observations, Target,
};

use crate::files::{self, check_regular_file, field_error, read_json, FileError};
use crate::model::MAX_JOINTS;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Format tag of artefact files.
pub const ARTEFACT_FORMAT: &str = "suta-artefact/1";
/// Format tag of session files.
pub const SESSION_FORMAT: &str = "suta-session/1";

/// Smallest span of an artefact's landmarks, mm: anything smaller is not a millimetre artefact.
pub const MIN_ARTEFACT_SPAN_MM: f64 = 10.0;
/// Largest span of an artefact's landmarks, mm: twice the longest reach a tracker arm has.
pub const MAX_ARTEFACT_SPAN_MM: f64 = 5000.0;
/// Closest two landmarks may be, mm.
pub const MIN_LANDMARK_SEPARATION_MM: f64 = 0.5;
/// Most landmarks an artefact may have.
pub const MAX_LANDMARKS: usize = 1000;
/// Largest session or artefact file read, bytes (a 20 000-touch session is about 6 MB).
pub const MAX_FILE_BYTES: u64 = 64 * 1024 * 1024;
/// Most session files in one folder.
pub const MAX_SESSION_FILES: usize = 5000;
/// Most touches in one folder of sessions.
pub const MAX_TOUCHES: usize = 50_000;
/// Most distance pairs one folder of sessions may form (the Jacobian holds a row per pair).
pub const MAX_PAIRS: usize = 500_000;

/// What a session is for: the folder it is read from decides which is expected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Purpose {
    /// Touches the parameters are fitted to.
    Calibration,
    /// Held-out touches the fit is judged on.
    Validation,
}

impl Purpose {
    /// The word session files use.
    pub fn as_str(self) -> &'static str {
        match self {
            Purpose::Calibration => "calibration",
            Purpose::Validation => "validation",
        }
    }
}

/// One certified landmark (pillar) of the artefact.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Landmark {
    /// Free-form identifier, e.g. `O`, `M3`.
    pub id: String,
    /// Certified position in the artefact frame, millimetres.
    pub xyz_mm: [f64; 3],
    /// Certified in-plane yaw of the asymmetric plug, degrees about the plate normal.
    pub yaw_deg: f64,
}

/// The certified artefact.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Artefact {
    /// Always [`ARTEFACT_FORMAT`].
    pub format: String,
    /// Landmarks in measuring order.
    pub landmarks: Vec<Landmark>,
    /// The number of the certificate that states these positions (the calibration lab's), as
    /// a calibration's record names its reference; optional.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub certificate: Option<String>,
}

/// One averaged touch of a landmark.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Measurement {
    /// Landmark id, one of the artefact's.
    pub landmark: String,
    /// Repeat number (1-based) within the placement.
    pub repeat: u32,
    /// Raw encoder angles, degrees in [0, 360).
    pub joints_deg: Vec<f64>,
    /// Per-sample standard deviation of each encoder over the window, degrees.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub std_deg: Option<Vec<f64>>,
    /// Samples averaged.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub samples: Option<u32>,
    /// Samples rejected (bad CRC, error bit, no answer).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rejected: Option<u32>,
    /// When the touch was taken (the host's clock), Unix seconds; `kincal record` writes it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub at_unix_s: Option<u64>,
}

/// All touches of one artefact placement.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Session {
    /// Always [`SESSION_FORMAT`].
    pub format: String,
    /// Placement name, e.g. `C_A`.
    pub placement: String,
    /// `calibration` or `validation`.
    pub purpose: String,
    /// Touches in recording order.
    pub measurements: Vec<Measurement>,
    /// The arm the touches were recorded on (`kincal record` writes it; older, simulated and
    /// hand-written sessions name none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arm: Option<crate::trace::ArmIdentity>,
}

impl Artefact {
    /// Read and check an artefact file.
    pub fn load(path: &Path) -> Result<Artefact, FileError> {
        check_size(path)?;
        let artefact: Artefact = read_json(path)?;
        if artefact.format != ARTEFACT_FORMAT {
            return Err(field_error(
                path,
                "format",
                format!("expected \"{ARTEFACT_FORMAT}\", found \"{}\"", artefact.format),
            ));
        }
        if artefact.landmarks.len() < 2 {
            return Err(field_error(path, "landmarks", "at least two landmarks are needed"));
        }
        if artefact.landmarks.len() > MAX_LANDMARKS {
            return Err(field_error(
                path,
                "landmarks",
                format!("{} landmarks; at most {MAX_LANDMARKS} are supported", artefact.landmarks.len()),
            ));
        }
        let mut seen = HashMap::new();
        for (i, l) in artefact.landmarks.iter().enumerate() {
            if !l.xyz_mm.iter().chain([&l.yaw_deg]).all(|v| v.is_finite()) {
                return Err(field_error(
                    path,
                    format!("landmarks[{i}]"),
                    "xyz_mm and yaw_deg must be finite",
                ));
            }
            if l.id.trim().is_empty() {
                return Err(field_error(path, format!("landmarks[{i}].id"), "must name the landmark"));
            }
            if !(-360.0..=360.0).contains(&l.yaw_deg) {
                return Err(field_error(
                    path,
                    format!("landmarks[{i}].yaw_deg"),
                    format!("expected an angle in [-360, 360] degrees, found {}", l.yaw_deg),
                ));
            }
            if let Some(first) = seen.insert(l.id.clone(), i) {
                return Err(field_error(
                    path,
                    format!("landmarks[{i}].id"),
                    format!("duplicate landmark id \"{}\" (also landmarks[{first}])", l.id),
                ));
            }
        }
        if let Some(text) = &artefact.certificate {
            crate::trace::check_label(text).map_err(|message| field_error(path, "certificate", message))?;
        }
        artefact.check_geometry(path)?;
        Ok(artefact)
    }

    /// Physical plausibility of the certified positions: a spread consistent with millimetres,
    /// no landmark far from the others, no two landmarks at one point.
    fn check_geometry(&self, path: &Path) -> Result<(), FileError> {
        let n = self.landmarks.len();
        let span = self.span_mm();
        if span < 1e-3 {
            return Err(field_error(
                path,
                "landmarks",
                format!("all landmarks are at one point (span {span:.3} mm): copied rows, or not filled in?"),
            ));
        }
        if span < MIN_ARTEFACT_SPAN_MM {
            return Err(field_error(
                path,
                "landmarks",
                format!(
                    "the artefact's landmarks span {span:.3} mm (at least {MIN_ARTEFACT_SPAN_MM} mm expected): \
                     are they in metres? Coordinates are in millimetres"
                ),
            ));
        }
        for a in 0..n {
            for b in a + 1..n {
                let d = self.distance_mm(a, b);
                if d < MIN_LANDMARK_SEPARATION_MM {
                    return Err(field_error(
                        path,
                        format!("landmarks[{b}].xyz_mm"),
                        format!(
                            "landmarks \"{}\" and \"{}\" are {d:.3} mm apart: two pillars cannot share a \
                             point (at least {MIN_LANDMARK_SEPARATION_MM} mm expected); a copied row?",
                            self.landmarks[a].id, self.landmarks[b].id
                        ),
                    ));
                }
            }
        }
        if span > MAX_ARTEFACT_SPAN_MM {
            // Name the landmark farthest from the median position: that is the odd one out.
            let median = |k: usize| {
                let mut v: Vec<f64> = self.landmarks.iter().map(|l| l.xyz_mm[k]).collect();
                v.sort_by(f64::total_cmp);
                v[v.len() / 2]
            };
            let centre = [median(0), median(1), median(2)];
            let far =
                |l: &Landmark| l.xyz_mm.iter().zip(centre).map(|(a, b)| (a - b).powi(2)).sum::<f64>().sqrt();
            let (i, worst) = self
                .landmarks
                .iter()
                .enumerate()
                .max_by(|a, b| far(a.1).total_cmp(&far(b.1)))
                .map(|(i, l)| (i, far(l)))
                .unwrap_or((0, 0.0));
            return Err(field_error(
                path,
                format!("landmarks[{i}].xyz_mm"),
                format!(
                    "landmark \"{}\" is {worst:.0} mm from the others; the landmarks span {span:.0} mm, \
                     beyond any arm's reach (at most {MAX_ARTEFACT_SPAN_MM} mm): a typo, or micrometres?",
                    self.landmarks[i].id
                ),
            ));
        }
        Ok(())
    }

    /// Largest distance between two landmarks, mm.
    pub fn span_mm(&self) -> f64 {
        let n = self.landmarks.len();
        (0..n)
            .flat_map(|a| (a + 1..n).map(move |b| (a, b)))
            .fold(0.0_f64, |s, (a, b)| s.max(self.distance_mm(a, b)))
    }

    /// Index of the landmark called `id`.
    pub fn index_of(&self, id: &str) -> Option<usize> {
        self.landmarks.iter().position(|l| l.id == id)
    }

    /// Certified distance between landmarks `a` and `b`, millimetres.
    pub fn distance_mm(&self, a: usize, b: usize) -> f64 {
        let (p, q) = (self.landmarks[a].xyz_mm, self.landmarks[b].xyz_mm);
        ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
    }

    /// Write the artefact atomically.
    pub fn save(&self, path: &Path) -> Result<(), FileError> {
        write_json(path, self)
    }
}

impl Session {
    /// Read a session and check every field against `artefact`.
    pub fn load(path: &Path, artefact: &Artefact) -> Result<Session, FileError> {
        check_size(path)?;
        let session: Session = read_json(path)?;
        if session.format != SESSION_FORMAT {
            return Err(field_error(
                path,
                "format",
                format!("expected \"{SESSION_FORMAT}\", found \"{}\"", session.format),
            ));
        }
        if session.placement.trim().is_empty() {
            return Err(field_error(path, "placement", "must name the placement"));
        }
        if ![Purpose::Calibration, Purpose::Validation].iter().any(|p| p.as_str() == session.purpose) {
            return Err(field_error(
                path,
                "purpose",
                format!("expected \"calibration\" or \"validation\", found \"{}\"", session.purpose),
            ));
        }
        if let Some(arm) = &session.arm {
            arm.check().map_err(|(key, message)| field_error(path, format!("arm.{key}"), message))?;
        }
        let joints = session_joints(path, &session)?;
        let mut taken: HashMap<(&str, u32), usize> = HashMap::new();
        for (i, m) in session.measurements.iter().enumerate() {
            let at = |f: &str| format!("measurements[{i}].{f}");
            if m.repeat == 0 {
                return Err(field_error(path, at("repeat"), "repeats are numbered from 1"));
            }
            if let Some(first) = taken.insert((m.landmark.as_str(), m.repeat), i) {
                return Err(field_error(
                    path,
                    at("repeat"),
                    format!(
                        "landmark \"{}\" repeat {} was already touched in measurements[{first}]; \
                         each (landmark, repeat) is touched once — number a re-take as a new repeat",
                        m.landmark, m.repeat
                    ),
                ));
            }
            if m.samples == Some(0) {
                return Err(field_error(
                    path,
                    at("samples"),
                    "the window has 0 accepted samples: its angles are not a measurement; re-take it",
                ));
            }
            if let (Some(samples), Some(rejected)) = (m.samples, m.rejected) {
                if rejected > samples {
                    return Err(field_error(
                        path,
                        at("rejected"),
                        format!(
                            "{rejected} samples rejected but only {samples} accepted: the window is not \
                             a measurement; re-take it"
                        ),
                    ));
                }
            }
            if artefact.index_of(&m.landmark).is_none() {
                return Err(field_error(
                    path,
                    at("landmark"),
                    format!("unknown landmark \"{}\" (not in the artefact file)", m.landmark),
                ));
            }
            if m.joints_deg.len() != joints {
                return Err(field_error(
                    path,
                    at("joints_deg"),
                    format!(
                        "expected {joints} encoder angles as in the session's other measurements, found {}",
                        m.joints_deg.len()
                    ),
                ));
            }
            if let Some(k) = m.joints_deg.iter().position(|v| !(v.is_finite() && (0.0..360.0).contains(v))) {
                return Err(field_error(
                    path,
                    at(&format!("joints_deg[{k}]")),
                    format!("expected a raw encoder angle in [0, 360) degrees, found {}", m.joints_deg[k]),
                ));
            }
            if let Some(std) = &m.std_deg {
                if std.len() != joints || std.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
                    return Err(field_error(
                        path,
                        at("std_deg"),
                        format!("expected {joints} finite non-negative values, one per encoder angle"),
                    ));
                }
            }
        }
        Ok(session)
    }

    /// Write the session atomically.
    pub fn save(&self, path: &Path) -> Result<(), FileError> {
        write_json(path, self)
    }
}

/// The arm a session file names (`"arm"`, written by `kincal record`), checked; `None` for a
/// session that names none (recorded before kincal wrote it, simulated or written by hand).
pub fn session_arm(path: &Path) -> Result<Option<crate::trace::ArmIdentity>, FileError> {
    #[derive(serde::Deserialize)]
    struct Named {
        #[serde(default)]
        arm: Option<crate::trace::ArmIdentity>,
    }
    check_size(path)?;
    let named: Named = read_json(path)?;
    if let Some(arm) = &named.arm {
        arm.check().map_err(|(key, message)| field_error(path, format!("arm.{key}"), message))?;
    }
    Ok(named.arm)
}

/// The joint count of a session's measurements: the count most of them hold (1 to
/// [`MAX_JOINTS`]), so that the one measurement that differs is the one named.
fn session_joints(path: &Path, session: &Session) -> Result<usize, FileError> {
    let mut counts: HashMap<usize, usize> = HashMap::new();
    for m in &session.measurements {
        *counts.entry(m.joints_deg.len()).or_default() += 1;
    }
    let joints = counts.iter().max_by_key(|(n, c)| (**c, std::cmp::Reverse(**n))).map_or(0, |(n, _)| *n);
    if session.measurements.is_empty() {
        return Ok(0);
    }
    if !(1..=MAX_JOINTS).contains(&joints) {
        let i = session.measurements.iter().position(|m| m.joints_deg.len() == joints).unwrap_or(0);
        return Err(field_error(
            path,
            format!("measurements[{i}].joints_deg"),
            format!("expected 1 to {MAX_JOINTS} encoder angles (one per joint), found {joints}"),
        ));
    }
    Ok(joints)
}

/// Refuse a file larger than [`MAX_FILE_BYTES`] before reading it.
fn check_size(path: &Path) -> Result<(), FileError> {
    let bytes =
        std::fs::metadata(path).map_err(|source| FileError::Io { path: path.to_owned(), source })?.len();
    if bytes > MAX_FILE_BYTES {
        return Err(FileError::Field {
            path: path.to_owned(),
            field: "(whole file)".into(),
            message: format!(
                "{:.0} MB; files of at most {} MB are read (split the session by placement)",
                bytes as f64 / 1e6,
                MAX_FILE_BYTES / (1024 * 1024)
            ),
        });
    }
    Ok(())
}

fn write_json<T: serde::Serialize>(path: &Path, value: &T) -> Result<(), FileError> {
    let text = serde_json::to_string_pretty(value).unwrap_or_default();
    files::write_atomic(path, text.as_bytes())
        .map_err(|source| FileError::Io { path: path.to_owned(), source })
}

impl Observations {
    /// Observations of artefact sessions already checked against `artefact`: one group per
    /// session (placement), one block per placement × repeat.
    pub fn from_sessions(sessions: &[Session], artefact: &Artefact) -> Observations {
        Observations::from_session_files(sessions.iter().map(|s| (s, PathBuf::new())), artefact)
    }

    fn from_session_files<'a>(
        sessions: impl Iterator<Item = (&'a Session, PathBuf)>,
        artefact: &Artefact,
    ) -> Observations {
        let mut data = Observations::new(0, artefact.landmarks.clone());
        for (s, source) in sessions {
            let group = data.push_group(s.placement.clone(), source, Kind::Artefact);
            data.groups[group].arm = s.arm.clone();
            for (i, m) in s.measurements.iter().enumerate() {
                let Some(landmark) = artefact.index_of(&m.landmark) else { continue };
                let Some(q_deg) = Joints::new(&m.joints_deg) else { continue };
                let accepted = m.samples.map(|n| n.saturating_sub(m.rejected.unwrap_or(0)));
                let q_sigma_deg = match (&m.std_deg, accepted) {
                    (Some(std), Some(n)) if n > 0 && std.len() == q_deg.len() => {
                        Joints::new(std).map(|s| Box::new(s.map(|v| v / (n as f64).sqrt())))
                    }
                    _ => None,
                };
                data.joints = data.joints.max(q_deg.len());
                data.obs.push(Observation {
                    q_sigma_deg,
                    ..Observation::touch(group, landmark, m.repeat, q_deg, i + 1)
                });
            }
        }
        data.rebuild_blocks();
        data
    }

    /// Read every artefact session in `dir` (files named `*.json`, any case, not hidden; sorted
    /// by name), refusing two files of one placement, sessions of the other purpose, sessions of
    /// different joint counts, and more than [`MAX_SESSION_FILES`] files or [`MAX_TOUCHES`]
    /// touches.
    pub fn load_artefact_dir(
        dir: &Path,
        artefact: &Artefact,
        purpose: Purpose,
    ) -> Result<Observations, FileError> {
        let files = session_files(dir)?;
        if files.is_empty() {
            return Err(FileError::EmptyFolder { path: dir.to_owned() });
        }
        read_artefact_sessions(dir, &files, artefact, purpose)
    }
}

/// Session files (`*.json`, any case, not hidden) in `dir`, sorted by name.
fn session_files(dir: &Path) -> Result<Vec<PathBuf>, FileError> {
    let entries = std::fs::read_dir(dir).map_err(|source| FileError::Io { path: dir.to_owned(), source })?;
    let mut files: Vec<PathBuf> = Vec::new();
    for entry in entries {
        let path = entry.map_err(|source| FileError::Io { path: dir.to_owned(), source })?.path();
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        if !name.starts_with('.') && path.extension().is_some_and(|e| e.eq_ignore_ascii_case("json")) {
            check_regular_file(&path)?;
            files.push(path);
        }
    }
    files.sort();
    if files.len() > MAX_SESSION_FILES {
        return Err(FileError::Field {
            path: dir.to_owned(),
            field: "(folder)".into(),
            message: format!(
                "{} session files; at most {MAX_SESSION_FILES} are read in one folder",
                files.len()
            ),
        });
    }
    Ok(files)
}

fn read_artefact_sessions(
    dir: &Path,
    files: &[PathBuf],
    artefact: &Artefact,
    purpose: Purpose,
) -> Result<Observations, FileError> {
    let mut sessions = Vec::with_capacity(files.len());
    let mut placements: HashMap<String, &Path> = HashMap::new();
    let mut touches = 0;
    let mut joints: Option<(usize, &Path)> = None;
    for file in files {
        let session = Session::load(file, artefact)?;
        if session.purpose != purpose.as_str() {
            return Err(field_error(
                file,
                "purpose",
                format!(
                    "a {} session in the folder of {} sessions ({}): move it to the other folder",
                    session.purpose,
                    purpose.as_str(),
                    dir.display()
                ),
            ));
        }
        if let Some(first) = placements.insert(session.placement.clone(), file) {
            return Err(field_error(
                file,
                "placement",
                format!(
                    "placement \"{}\" is also in {}: one file per placement (a copied file?)",
                    session.placement,
                    first.display()
                ),
            ));
        }
        if let Some(m) = session.measurements.first() {
            match joints {
                Some((n, first)) if n != m.joints_deg.len() => {
                    return Err(field_error(
                        file,
                        "measurements[0].joints_deg",
                        format!(
                            "{} encoder angles here, {n} in {}: the sessions of one folder come from one arm",
                            m.joints_deg.len(),
                            first.display()
                        ),
                    ));
                }
                Some(_) => {}
                None => joints = Some((m.joints_deg.len(), file)),
            }
        }
        touches += session.measurements.len();
        if touches > MAX_TOUCHES {
            return Err(FileError::Field {
                path: dir.to_owned(),
                field: "(folder)".into(),
                message: format!("more than {MAX_TOUCHES} touches; at most {MAX_TOUCHES} are read"),
            });
        }
        sessions.push(session);
    }
    let data = Observations::from_session_files(sessions.iter().zip(files.iter().cloned()), artefact);
    let pairs = data.pair_count();
    if pairs > MAX_PAIRS {
        return Err(FileError::Field {
            path: dir.to_owned(),
            field: "(folder)".into(),
            message: format!(
                "the sessions form {pairs} distance pairs; at most {MAX_PAIRS} are used (fewer landmarks \
                 per placement and repeat, or fewer placements)"
            ),
        });
    }
    Ok(data)
}

/// Read a folder of sessions of any kinds: artefact sessions (`*.json`, read with `artefact`),
/// tracker sessions (`*.csv` starting with `# kincal-tracker/1`; `*.csv` files are tracker
/// sessions when one of them carries the tag, and then all must but those of another reader) and
/// frame-free distance sessions (`*.csv` starting with `# kincal-point-distances/1`). A folder of
/// artefact sessions without an artefact file is refused, naming `--artefact`.
pub fn load_folder(
    dir: &Path,
    artefact: Option<&Artefact>,
    purpose: Purpose,
) -> Result<Observations, FileError> {
    let json = session_files(dir)?;
    let (distances, csv): (Vec<PathBuf>, Vec<PathBuf>) =
        tracker::csv_files(dir)?.into_iter().partition(|f| point_distances::is_one(f));
    let tagged = csv.iter().any(|f| tracker::starts_with_tag(f));
    let required = |what: String| FileError::Field {
        path: dir.to_owned(),
        field: "--artefact".into(),
        message: format!("--artefact is required: {} {what}", dir.display()),
    };
    if json.is_empty() && !tagged && distances.is_empty() {
        return match (artefact, csv.is_empty()) {
            (Some(_), _) => Err(FileError::EmptyFolder { path: dir.to_owned() }),
            (None, true) => tracker::load_dir(dir),
            (None, false) => Err(required(format!(
                "holds no tracker sessions (*.csv starting with \"# {}\")",
                tracker::TRACKER_FORMAT
            ))),
        };
    }
    let artefact_part = match (json.is_empty(), artefact) {
        (true, _) => None,
        (false, Some(artefact)) => Some(read_artefact_sessions(dir, &json, artefact, purpose)?),
        (false, None) => {
            return Err(required(format!(
                "holds {} artefact session files (*.json) to read with it",
                json.len()
            )))
        }
    };
    let tracker_part = tagged.then(|| tracker::load_files(dir, &csv)).transpose()?;
    let distance_part =
        (!distances.is_empty()).then(|| point_distances::load_files(dir, &distances)).transpose()?;
    let mut parts = [artefact_part, tracker_part, distance_part].into_iter().flatten();
    let Some(mut all) = parts.next() else { return Err(FileError::EmptyFolder { path: dir.to_owned() }) };
    for part in parts {
        if part.joints != all.joints {
            return Err(FileError::Field {
                path: dir.to_owned(),
                field: "(folder)".into(),
                message: format!(
                    "the {} sessions have {} joints, the {} sessions {}: the sessions of one folder come from one arm",
                    all.groups[0].kind.word(),
                    all.joints,
                    part.groups[0].kind.word(),
                    part.joints
                ),
            });
        }
        all = all.merge(part);
    }
    Ok(all)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn artefact() -> Artefact {
        Artefact {
            format: ARTEFACT_FORMAT.into(),
            landmarks: vec![
                Landmark { id: "O".into(), xyz_mm: [0.0, 0.0, 40.0], yaw_deg: 0.0 },
                Landmark { id: "M1".into(), xyz_mm: [30.0, 40.0, 40.0], yaw_deg: 10.0 },
            ],
            certificate: None,
        }
    }

    #[test]
    fn certified_distances() {
        assert!((artefact().distance_mm(0, 1) - 50.0).abs() < 1e-12);
    }

    #[test]
    fn bad_sessions_name_file_and_field() {
        let dir = std::env::temp_dir().join(format!("kincal-data-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let ok = r#"{"format":"suta-session/1","placement":"A","purpose":"calibration","measurements":[{"landmark":"M1","repeat":1,"joints_deg":[1,2,3,4,5,6]}]}"#;
        let cases = [
            (ok.replace("suta-session/1", "suta-session/9"), "`format`"),
            (ok.replace("\"M1\"", "\"Z9\""), "measurements[0].landmark"),
            (ok.replace("[1,2,3,4,5,6]", "[1,2,3,4,5,6,7,8,9,10,11,12,13]"), "measurements[0].joints_deg"),
            (
                ok.replace("]}]}", "]},{\"landmark\":\"O\",\"repeat\":1,\"joints_deg\":[1,2,3,4,5]}]}")
                    .replace("}]}", "},{\"landmark\":\"O\",\"repeat\":2,\"joints_deg\":[1,2,3,4,5,6]}]}"),
                "measurements[1].joints_deg",
            ),
            (ok.replace("[1,2,3,4,5,6]", "[1,2,3,4,5,400]"), "measurements[0].joints_deg[5]"),
            (ok.replace("[1,2,3,4,5,6]", "[1,2,3,4,5,NaN]"), "line 1"),
            (ok[..40].to_string(), "EOF"),
        ];
        for (i, (text, expect)) in cases.iter().enumerate() {
            let path = dir.join(format!("s{i}.json"));
            std::fs::write(&path, text).unwrap();
            let err = Session::load(&path, &artefact()).unwrap_err().to_string();
            assert!(
                err.contains(&format!("s{i}.json")) && err.contains(expect),
                "{err} should name {expect}"
            );
        }
        let path = dir.join("good.json");
        std::fs::write(&path, ok).unwrap();
        assert_eq!(Session::load(&path, &artefact()).unwrap().measurements.len(), 1);
        let empty = dir.join("empty");
        std::fs::create_dir_all(&empty).unwrap();
        assert!(matches!(
            Observations::load_artefact_dir(&empty, &artefact(), Purpose::Calibration),
            Err(FileError::EmptyFolder { .. })
        ));
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn implausible_artefacts_are_refused_with_the_reason() {
        let dir = std::env::temp_dir().join(format!("kincal-artefact-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let grid = |scale: f64| -> Vec<Landmark> {
            (0..4)
                .map(|i| Landmark {
                    id: format!("L{i}"),
                    xyz_mm: [scale * (i % 2) as f64, scale * (i / 2) as f64, 40.0 * scale / 100.0],
                    yaw_deg: 0.0,
                })
                .collect()
        };
        let mut far = grid(100.0);
        far[2].xyz_mm = [1.0e6, 0.0, 40.0];
        let mut twin = grid(100.0);
        twin[3].xyz_mm = twin[1].xyz_mm;
        let cases = [
            (grid(0.1), "are they in metres"),
            (grid(0.0), "at one point"),
            (far, "landmarks[2].xyz_mm"),
            (twin, "landmarks[3].xyz_mm"),
        ];
        for (i, (landmarks, expect)) in cases.into_iter().enumerate() {
            let path = dir.join(format!("a{i}.json"));
            Artefact { format: ARTEFACT_FORMAT.into(), landmarks, certificate: None }.save(&path).unwrap();
            let err = Artefact::load(&path).unwrap_err().to_string();
            assert!(err.contains(expect), "{err} should say {expect}");
        }
        let path = dir.join("ok.json");
        Artefact { format: ARTEFACT_FORMAT.into(), landmarks: grid(100.0), certificate: None }
            .save(&path)
            .unwrap();
        assert_eq!(Artefact::load(&path).unwrap().span_mm(), 100.0 * 2.0_f64.sqrt());
        std::fs::remove_dir_all(&dir).ok();
    }

    /// A session names its arm or not; both are read as sessions, and a bad identity names its
    /// field.
    #[test]
    fn a_session_names_its_arm_or_none() {
        let dir = std::env::temp_dir().join(format!("kincal-session-arm-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let old = r#"{"format":"suta-session/1","placement":"A","purpose":"calibration","measurements":
            [{"landmark":"O","repeat":1,"joints_deg":[1,2,3,4,5,6]}]}"#;
        let path = dir.join("s.json");
        std::fs::write(&path, old).unwrap();
        assert_eq!(session_arm(&path).unwrap(), None);
        let named = old.replace(
            r#""purpose""#,
            r#""arm":{"id":"lab-arm-2","firmware":"kincal-fw 0.1.0","board":"mps2"},"purpose""#,
        );
        std::fs::write(&path, &named).unwrap();
        let arm = session_arm(&path).unwrap().unwrap();
        assert_eq!((arm.id.as_str(), arm.firmware.as_deref()), ("lab-arm-2", Some("kincal-fw 0.1.0")));
        assert_eq!(Session::load(&path, &artefact()).unwrap().measurements.len(), 1, "read as a session");
        assert_eq!(Session::load(&path, &artefact()).unwrap().arm, Some(arm), "Session carries it");
        std::fs::write(&path, named.replace("lab-arm-2", "lab arm 2")).unwrap();
        let err = session_arm(&path).unwrap_err().to_string();
        assert!(err.contains("s.json") && err.contains("arm.id"), "{err}");
        let err = Session::load(&path, &artefact()).unwrap_err().to_string();
        assert!(err.contains("s.json") && err.contains("arm.id"), "{err}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn contradictory_sessions_and_folders_are_refused() {
        let dir = std::env::temp_dir().join(format!("kincal-folder-{}", std::process::id()));
        let cal = dir.join("cal");
        std::fs::create_dir_all(&cal).unwrap();
        let touch = |landmark: &str, repeat| Measurement {
            landmark: landmark.into(),
            repeat,
            joints_deg: vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
            std_deg: None,
            samples: Some(100),
            rejected: Some(0),
            at_unix_s: None,
        };
        let session = |placement: &str, purpose: &str, measurements| Session {
            format: SESSION_FORMAT.into(),
            placement: placement.into(),
            purpose: purpose.into(),
            measurements,
            arm: None,
        };
        let good = session("A", "calibration", vec![touch("O", 1), touch("M1", 1)]);
        let mut no_samples = good.clone();
        no_samples.measurements[1].samples = Some(0);
        let mut rejected = good.clone();
        rejected.measurements[0].rejected = Some(101);
        let cases = [
            (session("A", "banana", vec![]), "purpose"),
            (session("A", "calibration", vec![touch("O", 1), touch("O", 1)]), "already touched"),
            (no_samples, "measurements[1].samples"),
            (rejected, "measurements[0].rejected"),
        ];
        for (i, (s, expect)) in cases.into_iter().enumerate() {
            let path = dir.join(format!("s{i}.json"));
            s.save(&path).unwrap();
            let err = Session::load(&path, &artefact()).unwrap_err().to_string();
            assert!(err.contains(expect), "{err} should say {expect}");
        }
        good.save(&cal.join("A.JSON")).unwrap();
        let data = Observations::load_artefact_dir(&cal, &artefact(), Purpose::Calibration).unwrap();
        assert_eq!((data.obs.len(), data.pair_count()), (2, 1), "upper-case .JSON is read");
        let err =
            Observations::load_artefact_dir(&cal, &artefact(), Purpose::Validation).unwrap_err().to_string();
        assert!(err.contains("folder of validation"), "{err}");
        good.save(&cal.join("B.json")).unwrap();
        let err =
            Observations::load_artefact_dir(&cal, &artefact(), Purpose::Calibration).unwrap_err().to_string();
        assert!(err.contains("also in") && err.contains("A.JSON"), "{err}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
