//! Input files: the certified artefact (`suta-artefact/1`) and measurement sessions
//! (`suta-session/1`, one file per artefact placement).
//!
//! ```json
//! {"format":"suta-artefact/1","landmarks":[{"id":"O","xyz_mm":[0,0,40],"yaw_deg":2.0}, …]}
//! {"format":"suta-session/1","placement":"C_A","purpose":"calibration",
//!  "measurements":[{"landmark":"M1","repeat":1,"joints_deg":[6 raw encoder angles in [0,360)],
//!                   "std_deg":[…6],"samples":1536,"rejected":0}, …]}
//! ```
//! `std_deg`, `samples` and `rejected` are optional; sessions may miss landmarks.

use crate::files::{self, field_error, read_json, FileError};
use crate::model::JOINTS;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Format tag of artefact files.
pub const ARTEFACT_FORMAT: &str = "suta-artefact/1";
/// Format tag of session files.
pub const SESSION_FORMAT: &str = "suta-session/1";

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
}

impl Artefact {
    /// Read and check an artefact file.
    pub fn load(path: &Path) -> Result<Artefact, FileError> {
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
        let mut seen = HashMap::new();
        for (i, l) in artefact.landmarks.iter().enumerate() {
            if !l.xyz_mm.iter().chain([&l.yaw_deg]).all(|v| v.is_finite()) {
                return Err(field_error(
                    path,
                    format!("landmarks[{i}]"),
                    "xyz_mm and yaw_deg must be finite",
                ));
            }
            if seen.insert(l.id.clone(), i).is_some() {
                return Err(field_error(
                    path,
                    format!("landmarks[{i}].id"),
                    format!("duplicate landmark id \"{}\"", l.id),
                ));
            }
        }
        Ok(artefact)
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
        let session: Session = read_json(path)?;
        if session.format != SESSION_FORMAT {
            return Err(field_error(
                path,
                "format",
                format!("expected \"{SESSION_FORMAT}\", found \"{}\"", session.format),
            ));
        }
        if session.placement.is_empty() {
            return Err(field_error(path, "placement", "must name the placement"));
        }
        for (i, m) in session.measurements.iter().enumerate() {
            let at = |f: &str| format!("measurements[{i}].{f}");
            if artefact.index_of(&m.landmark).is_none() {
                return Err(field_error(
                    path,
                    at("landmark"),
                    format!("unknown landmark \"{}\" (not in the artefact file)", m.landmark),
                ));
            }
            if m.joints_deg.len() != JOINTS {
                return Err(field_error(
                    path,
                    at("joints_deg"),
                    format!("expected {JOINTS} encoder angles, found {}", m.joints_deg.len()),
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
                if std.len() != JOINTS || std.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
                    return Err(field_error(
                        path,
                        at("std_deg"),
                        format!("expected {JOINTS} finite non-negative values"),
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

fn write_json<T: serde::Serialize>(path: &Path, value: &T) -> Result<(), FileError> {
    let text = serde_json::to_string_pretty(value).unwrap_or_default();
    files::write_atomic(path, text.as_bytes())
        .map_err(|source| FileError::Io { path: path.to_owned(), source })
}

/// One touch ready for the kinematics.
#[derive(Clone, Debug, PartialEq)]
pub struct Touch {
    /// Index into [`Dataset::placements`].
    pub placement: usize,
    /// Index into the artefact's landmarks.
    pub landmark: usize,
    /// Repeat number within the placement.
    pub repeat: u32,
    /// Raw encoder angles, degrees.
    pub enc_deg: [f64; JOINTS],
    /// Standard error of each averaged encoder angle (window std / √accepted samples), degrees,
    /// when the session reports it.
    pub enc_sigma_deg: Option<[f64; JOINTS]>,
}

/// The touches of several sessions.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Dataset {
    /// Placement names, indexed by [`Touch::placement`].
    pub placements: Vec<String>,
    /// All touches.
    pub touches: Vec<Touch>,
}

impl Dataset {
    /// Build a dataset from sessions already checked against `artefact`.
    pub fn from_sessions(sessions: &[Session], artefact: &Artefact) -> Dataset {
        let mut data = Dataset::default();
        for s in sessions {
            let placement = data.placements.len();
            data.placements.push(s.placement.clone());
            for m in &s.measurements {
                let Some(landmark) = artefact.index_of(&m.landmark) else { continue };
                let Ok(enc_deg) = <[f64; JOINTS]>::try_from(m.joints_deg.as_slice()) else { continue };
                let accepted = m.samples.map(|n| n.saturating_sub(m.rejected.unwrap_or(0)));
                let enc_sigma_deg = match (&m.std_deg, accepted) {
                    (Some(std), Some(n)) if n > 0 && std.len() == JOINTS => {
                        Some(std::array::from_fn(|k| std[k] / (n as f64).sqrt()))
                    }
                    _ => None,
                };
                data.touches.push(Touch { placement, landmark, repeat: m.repeat, enc_deg, enc_sigma_deg });
            }
        }
        data
    }

    /// Read every `*.json` session in `dir` (sorted by file name).
    pub fn load_dir(dir: &Path, artefact: &Artefact) -> Result<Dataset, FileError> {
        let entries =
            std::fs::read_dir(dir).map_err(|source| FileError::Io { path: dir.to_owned(), source })?;
        let mut files: Vec<PathBuf> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "json"))
            .collect();
        files.sort();
        if files.is_empty() {
            return Err(FileError::EmptyFolder { path: dir.to_owned() });
        }
        let sessions = files.iter().map(|f| Session::load(f, artefact)).collect::<Result<Vec<_>, _>>()?;
        Ok(Dataset::from_sessions(&sessions, artefact))
    }

    /// A dataset holding only the placements listed (by index).
    pub fn subset(&self, placements: &[usize]) -> Dataset {
        let mut out = Dataset::default();
        for &p in placements {
            let new = out.placements.len();
            out.placements.push(self.placements[p].clone());
            out.touches.extend(
                self.touches
                    .iter()
                    .filter(|t| t.placement == p)
                    .map(|t| Touch { placement: new, ..t.clone() }),
            );
        }
        out
    }

    /// A copy without the touches of one landmark.
    pub fn without_landmark(&self, landmark: usize) -> Dataset {
        Dataset {
            placements: self.placements.clone(),
            touches: self.touches.iter().filter(|t| t.landmark != landmark).cloned().collect(),
        }
    }

    /// Pairs of touches of different landmarks taken in the same placement and repeat
    /// (thesis eq. 3.1), as `(touch_a, touch_b)` indices.
    pub fn touch_pairs(&self) -> Vec<(usize, usize)> {
        let mut pairs = Vec::new();
        for (a, ta) in self.touches.iter().enumerate() {
            for (b, tb) in self.touches.iter().enumerate().skip(a + 1) {
                if ta.placement == tb.placement && ta.repeat == tb.repeat && ta.landmark != tb.landmark {
                    pairs.push((a, b));
                }
            }
        }
        pairs
    }
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
        }
    }

    #[test]
    fn pairs_stay_within_one_placement_and_repeat() {
        let t = |placement, landmark, repeat| Touch {
            placement,
            landmark,
            repeat,
            enc_deg: [0.0; 6],
            enc_sigma_deg: None,
        };
        let data = Dataset {
            placements: vec!["A".into(), "B".into()],
            touches: vec![t(0, 0, 1), t(0, 1, 1), t(0, 1, 2), t(1, 0, 1), t(1, 1, 1)],
        };
        assert_eq!(data.touch_pairs(), vec![(0, 1), (3, 4)]);
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
            (ok.replace("[1,2,3,4,5,6]", "[1,2,3,4,5]"), "measurements[0].joints_deg"),
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
        assert!(matches!(Dataset::load_dir(&empty, &artefact()), Err(FileError::EmptyFolder { .. })));
        std::fs::remove_dir_all(&dir).ok();
    }
}
