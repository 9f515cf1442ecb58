//! The haptic recording folder (`haptic-recording/1`).
//!
//! `recording.json` = `{"format":"haptic-recording/1","device":"omni"|"premium15","l1_mm":…,"l2_mm":…,
//! "joint_convention":{…}}` (the last optional, see [`JointConvention`]) and one subfolder per
//! step of the procedure: `delay/`, `gimbal/`, `reference/`, `joints/` (each `device.csv` +
//! `hip.csv`), `landmarks/` (`device.csv`, `hip.csv`, `t1.csv`, `t2.csv`) and optionally
//! `verify/`. `device.csv` has the header `t_s,raw1,raw2,raw3,raw4,raw5,raw6` (as the driver
//! reports them, 500–1000 Hz); each tracking target's CSV has `t_s,x_mm,y_mm,z_mm,qw,qx,qy,qz`
//! (target pose in tracker coordinates, 60–240 Hz). All times are on the host clock. Every sample
//! is checked: numbers finite, times increasing, unit quaternions; the device stream may not
//! drop out for longer than [`MAX_GAP_FACTOR`] median sample periods (at least [`MIN_GAP_S`]).
//! Tracker streams may have occlusion gaps: they are kept as separate segments
//! ([`TargetStream::segments`]) and nothing is ever interpolated across a gap.
//!
//! The device readings are brought to the model's convention on loading (radians, θ3 absolute,
//! the signs of the kinematic model); readings beyond ±2π with `"unit":"rad"` are refused as
//! degrees.

use super::kinematics::Device;
use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Format tag of `recording.json`.
pub const RECORDING_FORMAT: &str = "haptic-recording/1";
/// Steps every recording has, and the target files each needs besides `device.csv`.
pub const REQUIRED_STEPS: [(&str, &[&str]); 5] = [
    ("delay", &["hip"]),
    ("gimbal", &["hip"]),
    ("reference", &["hip"]),
    ("joints", &["hip"]),
    ("landmarks", &["hip", "t1", "t2"]),
];
/// A device-stream gap longer than this many median sample periods is an error.
pub const MAX_GAP_FACTOR: f64 = 10.0;
pub use crate::numerics::delay::{segments, SEGMENT_GAP_FACTOR};
/// … but never shorter than this, s.
pub const MIN_GAP_S: f64 = 0.05;
const DEVICE_HEADER: &str = "t_s,raw1,raw2,raw3,raw4,raw5,raw6";
const TARGET_HEADER: &str = "t_s,x_mm,y_mm,z_mm,qw,qx,qy,qz";

/// Why a recording could not be read.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    /// A file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating-system error.
        source: std::io::Error,
    },
    /// A file or folder the layout requires is missing.
    #[error("{path}: missing ({what})")]
    Missing {
        /// What was looked for.
        path: PathBuf,
        /// What it is for.
        what: &'static str,
    },
    /// `recording.json` is not valid.
    #[error("{path}: {message}")]
    Header {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A CSV line is not valid.
    #[error("{path}:{line}: {message}")]
    Line {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        message: String,
    },
}

/// Unit of the device readings in `device.csv`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AngleUnit {
    /// Radians.
    Rad,
    /// Degrees.
    Deg,
}

/// How the driver reports θ3.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Theta3 {
    /// The angle of the second link itself (the kinematic model's θ3; OpenHaptics
    /// `HD_CURRENT_JOINT_ANGLES`).
    Absolute,
    /// θ3 − θ2, the angle between the two links (as ROS-style joint-state drivers publish).
    Relative,
}

/// The driver's joint convention, field `joint_convention` of `recording.json`:
/// `{"unit":"rad"|"deg","theta3":"absolute"|"relative","sign":[±1 ×6],"columns":[1…6]}`.
/// Joint j is read from CSV column `raw{columns[j]}`, converted to radians, multiplied by
/// `sign[j]`, and with `"relative"` θ2 is added to θ3. Every field is optional; the defaults are
/// [`JointConvention::default_for`] the device.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct JointConvention {
    /// Unit of the readings.
    pub unit: AngleUnit,
    /// θ3 absolute or relative to θ2.
    pub theta3: Theta3,
    /// Sign of each joint (+1 or −1) relative to the kinematic model.
    pub sign: [f64; 6],
    /// CSV column (1-based) of each joint.
    pub columns: [usize; 6],
}

impl Default for JointConvention {
    fn default() -> Self {
        JointConvention {
            unit: AngleUnit::Rad,
            theta3: Theta3::Absolute,
            sign: [1.0; 6],
            columns: [1, 2, 3, 4, 5, 6],
        }
    }
}

impl JointConvention {
    /// The documented default of a device: for both the Omni and the Premium 1.5 it is what the
    /// OpenHaptics joint and gimbal angle queries report — radians, θ3 absolute, the kinematic
    /// model's signs, columns in joint order. `None` for a device the tool does not know.
    pub fn default_for(device: &str) -> Option<JointConvention> {
        matches!(device, "omni" | "premium15").then(JointConvention::default)
    }

    /// Model-convention readings of one CSV row (`row` = raw1…raw6 as written).
    pub fn apply(&self, row: &[f64; 6]) -> [f64; 6] {
        let unit = match self.unit {
            AngleUnit::Rad => 1.0,
            AngleUnit::Deg => std::f64::consts::PI / 180.0,
        };
        let mut v: [f64; 6] = std::array::from_fn(|j| row[self.columns[j] - 1] * unit * self.sign[j]);
        if self.theta3 == Theta3::Relative {
            v[2] += v[1];
        }
        v
    }

    /// The CSV row (raw1…raw6 as written) of model-convention readings `v`: the inverse of
    /// [`JointConvention::apply`].
    pub fn invert(&self, v: &[f64; 6]) -> [f64; 6] {
        let unit = match self.unit {
            AngleUnit::Rad => 1.0,
            AngleUnit::Deg => std::f64::consts::PI / 180.0,
        };
        let mut v = *v;
        if self.theta3 == Theta3::Relative {
            v[2] -= v[1];
        }
        let mut row = [0.0; 6];
        for j in 0..6 {
            row[self.columns[j] - 1] = v[j] / (unit * self.sign[j]);
        }
        row
    }

    /// As `recording.json` spells it.
    pub fn json(&self) -> String {
        serde_json::to_string(self).unwrap_or_default()
    }

    fn check(&self) -> Result<(), String> {
        if let Some(s) = self.sign.iter().find(|s| **s != 1.0 && **s != -1.0) {
            return Err(format!("field `joint_convention.sign`: expected six values of 1 or -1, found {s}"));
        }
        let mut seen = [false; 6];
        for c in self.columns {
            if !(1..=6).contains(&c) || std::mem::replace(&mut seen[c - 1], true) {
                return Err(format!(
                    "field `joint_convention.columns`: expected a permutation of 1…6, found {:?}",
                    self.columns
                ));
            }
        }
        Ok(())
    }
}

/// Raw joint readings of the device.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DeviceStream {
    /// Times, s.
    pub t_s: Vec<f64>,
    /// Six readings per sample in the model's convention (radians, θ3 absolute).
    pub raw: Vec<[f64; 6]>,
}

/// Poses of one tracking target.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TargetStream {
    /// Times, s.
    pub t_s: Vec<f64>,
    /// Positions in tracker coordinates, mm.
    pub position_mm: Vec<Vector3<f64>>,
    /// Orientations (target → tracker).
    pub rotation: Vec<UnitQuaternion<f64>>,
}

impl TargetStream {
    /// Index ranges of the unbroken pieces of the stream: a new segment starts after a gap
    /// longer than [`SEGMENT_GAP_FACTOR`] median sample periods (an occlusion).
    pub fn segments(&self) -> Vec<std::ops::Range<usize>> {
        segments(&self.t_s, SEGMENT_GAP_FACTOR)
    }

    /// The samples at `keep` (indices in increasing order).
    pub fn subset(&self, keep: &[usize]) -> TargetStream {
        TargetStream {
            t_s: keep.iter().map(|&i| self.t_s[i]).collect(),
            position_mm: keep.iter().map(|&i| self.position_mm[i]).collect(),
            rotation: keep.iter().map(|&i| self.rotation[i]).collect(),
        }
    }
}

/// One step of the procedure.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Step {
    /// Device readings.
    pub device: DeviceStream,
    /// Tracking targets by file stem (`hip`, `t1`, `t2`).
    pub targets: BTreeMap<String, TargetStream>,
}

/// A whole recording.
#[derive(Clone, Debug, PartialEq)]
pub struct Recording {
    /// Device model and link lengths.
    pub device: Device,
    /// Device name as given (`omni`, `premium15`).
    pub device_name: String,
    /// Steps by folder name.
    pub steps: BTreeMap<String, Step>,
    /// The joint convention the readings were converted with.
    pub convention: JointConvention,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Header {
    format: String,
    device: String,
    l1_mm: f64,
    l2_mm: f64,
    joint_convention: Option<JointConvention>,
}

fn read(path: &Path) -> Result<String, RecordingError> {
    if !path.exists() {
        return Err(RecordingError::Missing {
            path: path.to_owned(),
            what: "required by the haptic recording layout",
        });
    }
    std::fs::read_to_string(path).map_err(|source| RecordingError::Io { path: path.to_owned(), source })
}

/// Parse a CSV with `header` into rows of `columns` finite numbers; checks time order and gaps.
fn rows(
    path: &Path,
    header: &str,
    columns: usize,
    check_gaps: bool,
) -> Result<(Vec<f64>, Vec<Vec<f64>>), RecordingError> {
    let text = read(path)?;
    let line_error =
        |line: usize, message: String| RecordingError::Line { path: path.to_owned(), line, message };
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, h)) if h.trim() == header => {}
        Some((_, h)) => return Err(line_error(1, format!("header `{}`, expected `{header}`", h.trim()))),
        None => return Err(line_error(1, "empty file".into())),
    }
    let (mut times, mut values) = (Vec::new(), Vec::new());
    for (i, line) in lines {
        let n = i + 1;
        if line.trim().is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() != columns {
            return Err(line_error(n, format!("{} fields, expected {columns}", fields.len())));
        }
        let mut row = Vec::with_capacity(columns);
        for (k, f) in fields.iter().enumerate() {
            let v: f64 = f.parse().map_err(|_| {
                line_error(
                    n,
                    format!("field {} (`{f}`) is not a number", header.split(',').nth(k).unwrap_or("?")),
                )
            })?;
            if !v.is_finite() {
                return Err(line_error(
                    n,
                    format!("field {} is not finite", header.split(',').nth(k).unwrap_or("?")),
                ));
            }
            row.push(v);
        }
        if let Some(&last) = times.last() {
            if row[0] <= last {
                return Err(line_error(
                    n,
                    format!("time {} s does not increase (previous {last} s)", row[0]),
                ));
            }
        }
        times.push(row[0]);
        values.push(row);
    }
    if times.len() < 2 {
        return Err(line_error(1, "fewer than two samples".into()));
    }
    if !check_gaps {
        return Ok((times, values));
    }
    let mut periods: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
    periods.sort_by(f64::total_cmp);
    let limit = (periods[periods.len() / 2] * MAX_GAP_FACTOR).max(MIN_GAP_S);
    if let Some(k) = times.windows(2).position(|w| w[1] - w[0] > limit) {
        return Err(line_error(
            k + 3,
            format!(
                "gap of {:.0} ms before this sample (longest allowed {:.0} ms): the stream dropped out",
                (times[k + 1] - times[k]) * 1e3,
                limit * 1e3
            ),
        ));
    }
    Ok((times, values))
}

/// Largest plausible reading in radians: beyond it the readings are taken for degrees.
pub const MAX_RADIANS: f64 = 2.0 * std::f64::consts::PI;

fn device_stream(path: &Path, convention: &JointConvention) -> Result<DeviceStream, RecordingError> {
    let (t_s, rows) = rows(path, DEVICE_HEADER, 7, true)?;
    let mut raw = Vec::with_capacity(rows.len());
    for (i, r) in rows.iter().enumerate() {
        let row: [f64; 6] = std::array::from_fn(|k| r[k + 1]);
        if convention.unit == AngleUnit::Rad {
            if let Some(k) = (0..6).find(|&k| row[k].abs() > MAX_RADIANS) {
                return Err(RecordingError::Line {
                    path: path.to_owned(),
                    line: i + 2,
                    message: format!(
                        "raw{} = {} is beyond ±2π: the readings look like degrees; the tool expects \
                         radians unless recording.json says \"joint_convention\": {{\"unit\": \"deg\"}}",
                        k + 1,
                        row[k]
                    ),
                });
            }
        }
        raw.push(convention.apply(&row));
    }
    Ok(DeviceStream { t_s, raw })
}

fn target_stream(path: &Path) -> Result<TargetStream, RecordingError> {
    let (t_s, rows) = rows(path, TARGET_HEADER, 8, false)?;
    let mut out = TargetStream { t_s, ..TargetStream::default() };
    for (i, r) in rows.iter().enumerate() {
        let q = Quaternion::new(r[4], r[5], r[6], r[7]);
        if (q.norm() - 1.0).abs() > 0.01 {
            return Err(RecordingError::Line {
                path: path.to_owned(),
                line: i + 2,
                message: format!("quaternion norm {:.4}, expected a unit quaternion", q.norm()),
            });
        }
        out.position_mm.push(Vector3::new(r[1], r[2], r[3]));
        out.rotation.push(UnitQuaternion::from_quaternion(q));
    }
    Ok(out)
}

/// Read and check a recording folder.
pub fn load(dir: &Path) -> Result<Recording, RecordingError> {
    let header_path = dir.join("recording.json");
    let header_error = |message: String| RecordingError::Header { path: header_path.clone(), message };
    let header: Header =
        serde_json::from_str(&read(&header_path)?).map_err(|e| header_error(e.to_string()))?;
    if header.format != RECORDING_FORMAT {
        return Err(header_error(format!(
            "field `format`: expected \"{RECORDING_FORMAT}\", found \"{}\"",
            header.format
        )));
    }
    let nominal = match header.device.as_str() {
        "omni" => Device::omni(),
        "premium15" => Device::premium15(),
        other => {
            return Err(header_error(format!(
                "field `device`: expected \"omni\" or \"premium15\", found \"{other}\""
            )))
        }
    };
    for (name, v) in [("l1_mm", header.l1_mm), ("l2_mm", header.l2_mm)] {
        if !(v.is_finite() && v > 10.0 && v < 1000.0) {
            return Err(header_error(format!("field `{name}`: expected a link length in mm, found {v}")));
        }
    }
    let device = Device { l1_mm: header.l1_mm, l2_mm: header.l2_mm, ..nominal };
    let convention =
        header.joint_convention.or_else(|| JointConvention::default_for(&header.device)).unwrap_or_default();
    convention.check().map_err(header_error)?;
    let mut steps = BTreeMap::new();
    let optional: [(&str, &[&str]); 1] = [("verify", &["hip"])];
    for (name, targets) in REQUIRED_STEPS.iter().chain(optional.iter()) {
        let folder = dir.join(name);
        if !folder.is_dir() {
            if *name == "verify" {
                continue;
            }
            return Err(RecordingError::Missing {
                path: folder,
                what: "a step of the calibration procedure",
            });
        }
        let mut step = Step {
            device: device_stream(&folder.join("device.csv"), &convention)?,
            targets: BTreeMap::new(),
        };
        for t in targets.iter() {
            step.targets.insert(t.to_string(), target_stream(&folder.join(format!("{t}.csv")))?);
        }
        steps.insert(name.to_string(), step);
    }
    Ok(Recording { device, device_name: header.device, steps, convention })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_recording(dir: &Path) {
        std::fs::create_dir_all(dir).unwrap();
        std::fs::write(
            dir.join("recording.json"),
            r#"{"format":"haptic-recording/1","device":"omni","l1_mm":133.35,"l2_mm":133.0}"#,
        )
        .unwrap();
        for (step, targets) in REQUIRED_STEPS {
            let folder = dir.join(step);
            std::fs::create_dir_all(&folder).unwrap();
            let device: String = (0..100)
                .map(|k| format!("{},{},0.1,0.2,0.3,0.4,0.5\n", k as f64 * 1e-3, k as f64 * 1e-3))
                .collect();
            std::fs::write(folder.join("device.csv"), format!("{DEVICE_HEADER}\n{device}")).unwrap();
            for t in targets {
                let rows: String = (0..20).map(|k| format!("{},1,2,3,1,0,0,0\n", k as f64 / 60.0)).collect();
                std::fs::write(folder.join(format!("{t}.csv")), format!("{TARGET_HEADER}\n{rows}")).unwrap();
            }
        }
    }

    #[test]
    fn reads_a_recording_and_names_what_is_wrong() {
        let dir = std::env::temp_dir().join(format!("kincal-haptic-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        write_recording(&dir);
        let rec = load(&dir).unwrap();
        assert_eq!(rec.device.l2_mm, 133.0, "both link lengths are used as given");
        assert_eq!(rec.steps["landmarks"].targets.len(), 3);
        assert_eq!(rec.steps["joints"].device.raw.len(), 100);
        assert!(!rec.steps.contains_key("verify"));
        let hip = dir.join("delay/hip.csv");
        let good = std::fs::read_to_string(&hip).unwrap();
        let cases = [
            (good.replacen("0.05,", "0.0,", 1), "hip.csv:5", "does not increase"),
            (good.replacen("1,2,3,1,0,0,0", "1,2,x,1,0,0,0", 1), "hip.csv:2", "z_mm"),
            (good.replacen("1,2,3,1,0,0,0", "1,2,3,2,0,0,0", 1), "hip.csv:2", "quaternion"),
            (good.replacen("t_s,x_mm", "time,x_mm", 1), "hip.csv:1", "header"),
        ];
        for (text, place, what) in cases {
            std::fs::write(&hip, &text).unwrap();
            let err = load(&dir).unwrap_err().to_string();
            assert!(err.contains(place) && err.contains(what), "`{err}` should name {place} and {what}");
        }
        // An occlusion in a tracker stream splits it into segments; the samples are kept.
        let occluded: String = good
            .lines()
            .enumerate()
            .filter(|(i, _)| !(3..18).contains(i))
            .map(|(_, l)| format!("{l}\n"))
            .collect();
        std::fs::write(&hip, &occluded).unwrap();
        let rec = load(&dir).unwrap();
        assert_eq!(rec.steps["delay"].targets["hip"].segments(), vec![0..2, 2..5]);
        std::fs::write(&hip, good).unwrap();
        // A device stream that drops out is refused.
        let device = dir.join("joints/device.csv");
        let dev_good = std::fs::read_to_string(&device).unwrap();
        let dropped: String = dev_good
            .lines()
            .enumerate()
            .filter(|(i, _)| !(3..90).contains(i))
            .map(|(_, l)| format!("{l}\n"))
            .collect();
        std::fs::write(&device, dropped).unwrap();
        let err = load(&dir).unwrap_err().to_string();
        assert!(err.contains("device.csv:4") && err.contains("gap of 88 ms"), "{err}");
        // Degrees are refused unless declared; the convention is applied.
        std::fs::write(&device, dev_good.replacen("0.1,0.2,0.3,0.4,0.5", "5.7,11.5,17.2,22.9,28.6", 1))
            .unwrap();
        let err = load(&dir).unwrap_err().to_string();
        assert!(err.contains("device.csv:2") && err.contains("degrees"), "{err}");
        std::fs::write(
            dir.join("recording.json"),
            r#"{"format":"haptic-recording/1","device":"omni","l1_mm":133.35,"l2_mm":133.0,
               "joint_convention":{"unit":"deg","theta3":"relative","sign":[1,-1,1,1,1,1],"columns":[1,3,2,4,5,6]}}"#,
        )
        .unwrap();
        let rec = load(&dir).unwrap();
        let r = rec.steps["joints"].device.raw[0];
        let d = std::f64::consts::PI / 180.0;
        assert!((r[1] + 11.5 * d).abs() < 1e-12 && (r[2] - (5.7 - 11.5) * d).abs() < 1e-12, "{r:?}");
        std::fs::write(
            dir.join("recording.json"),
            r#"{"format":"haptic-recording/1","device":"omni","l1_mm":133.35,"l2_mm":133.0,
               "joint_convention":{"columns":[1,1,2,4,5,6]}}"#,
        )
        .unwrap();
        assert!(load(&dir).unwrap_err().to_string().contains("joint_convention.columns"));
        write_recording(&dir);
        std::fs::remove_dir_all(dir.join("gimbal")).unwrap();
        assert!(load(&dir).unwrap_err().to_string().contains("gimbal"));
        std::fs::remove_dir_all(&dir).ok();
    }
}
