//! Drift within a tracker session: the measured points creep against time or temperature while
//! one session is measured. Four kinds, each adding its rate to that session's unknowns
//! (`--drift-session SESSION:KIND`, at most one kind per session):
//!
//! - **offset-time** (`v`, mm/h, instrument frame, three unknowns):
//!   X_i = B_s · F(q_i) · t + v · (τ_i − τ̄_s), τ = `time_s` in hours, τ̄_s the session's mean.
//!   The instrument or its stand creeps: a tripod settling, the floor under it warming.
//! - **offset-temp** (`v`, mm/K, three unknowns): the same with τ = `temp_C`: the stand or the
//!   floor expands with the air temperature rather than with time.
//! - **scale-time** (`k`, ppm/h, one unknown): X_i = B_s · (1 + k · (τ_i − τ̄_s)) · F(q_i) · t,
//!   τ = `time_s` in hours: the instrument's length scale creeps (a laser tracker's wavelength
//!   compensation lagging the air: about 1 ppm per K of air and 0.3 ppm per hPa).
//! - **scale-temp** (`k`, ppm/K, one unknown): the same with τ = `temp_C` and τ̄ the mean
//!   temperature of the calibration points outside the drifting sessions (of all of them when no
//!   other session states a temperature): the arm grows with its temperature (steel 12 ppm/K, aluminium
//!   23 ppm/K), or a scale bar does, so a session measured warmer than the others sees a longer
//!   arm; the reference is the temperature the model is fitted at, so a session's mean warming
//!   counts, not only its warming within the session.
//!
//! The scale multiplies the robot-frame point before the base's shift (X = (1 + k·Δτ)·R_s·p +
//! t_s): it acts about the robot's base, where an arm's thermal growth starts. A kind needs its column on every row of the
//! session and a span of at least [`MIN_SPAN_S`] of time or [`MIN_SPAN_C`] of temperature to be
//! a data-error candidate.

use crate::data::{Observation, Observations};
use nalgebra::Vector3;

/// Least span of `time_s` within a session, s, for a drift in time to be a candidate.
pub const MIN_SPAN_S: f64 = 60.0;
/// Least span of `temp_C` within a session, K, for a drift against temperature to be a candidate.
pub const MIN_SPAN_C: f64 = 0.5;

/// What drifts (the base's shift or the length scale) and against what (time or temperature).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DriftKind {
    /// The base shifts linearly in time, mm/h.
    OffsetTime,
    /// The length scale changes linearly in time, ppm/h.
    ScaleTime,
    /// The base shifts linearly with temperature, mm/K.
    OffsetTemp,
    /// The length scale changes linearly with temperature, ppm/K.
    ScaleTemp,
}

impl DriftKind {
    /// Every kind, in the order candidates are scored.
    pub const ALL: [DriftKind; 4] =
        [DriftKind::OffsetTime, DriftKind::ScaleTime, DriftKind::OffsetTemp, DriftKind::ScaleTemp];

    /// The name on the command line and in summary.json.
    pub fn name(self) -> &'static str {
        match self {
            DriftKind::OffsetTime => "offset-time",
            DriftKind::ScaleTime => "scale-time",
            DriftKind::OffsetTemp => "offset-temp",
            DriftKind::ScaleTemp => "scale-temp",
        }
    }

    /// Unknowns: three for a shift, one for a scale.
    pub fn unknowns(self) -> usize {
        if self.is_scale() {
            1
        } else {
            3
        }
    }

    /// True for the length-scale kinds.
    pub fn is_scale(self) -> bool {
        matches!(self, DriftKind::ScaleTime | DriftKind::ScaleTemp)
    }

    /// True for the kinds against temperature.
    pub fn is_thermal(self) -> bool {
        matches!(self, DriftKind::OffsetTemp | DriftKind::ScaleTemp)
    }

    /// The CSV column the kind drifts against.
    pub fn column(self) -> &'static str {
        if self.is_thermal() {
            "temp_C"
        } else {
            "time_s"
        }
    }

    /// Unit of the rate.
    pub fn unit(self) -> &'static str {
        match self {
            DriftKind::OffsetTime => "mm/h",
            DriftKind::ScaleTime => "ppm/h",
            DriftKind::OffsetTemp => "mm/K",
            DriftKind::ScaleTemp => "ppm/K",
        }
    }

    /// τ of a row: `time_s` in hours or `temp_C` in °C.
    pub fn variable(self, p: &Observation) -> Option<f64> {
        if self.is_thermal() {
            p.temp_c
        } else {
            p.time_s.map(|t| t / 3600.0)
        }
    }

    /// Whether block `b` of `data` carries the kind's column on every row over the least span.
    pub fn applies_to(self, data: &Observations, b: usize) -> bool {
        let members = &data.blocks[b].members;
        let values: Vec<f64> = members.iter().filter_map(|&k| self.variable(&data.obs[k])).collect();
        let span = values.iter().copied().fold(f64::NEG_INFINITY, f64::max)
            - values.iter().copied().fold(f64::INFINITY, f64::min);
        let least = if self.is_thermal() { MIN_SPAN_C } else { MIN_SPAN_S / 3600.0 };
        values.len() == members.len() && span >= least
    }

    /// The point's shift (mm, instrument frame) and growth factor from the rates and
    /// Δτ = τ_i − τ̄: X = growth · R_s·p + t_s + shift.
    pub fn effect(self, rates: &[f64], delta: f64) -> (Vector3<f64>, f64) {
        if self.is_scale() {
            (Vector3::zeros(), 1.0 + 1e-6 * rates[0] * delta)
        } else {
            (Vector3::new(rates[0], rates[1], rates[2]) * delta, 1.0)
        }
    }

    /// ∂X/∂rate_k for the rotated robot point `y` = R_s·p.
    pub fn derivative(self, k: usize, delta: f64, y: &Vector3<f64>) -> Vector3<f64> {
        if self.is_scale() {
            y * (1e-6 * delta)
        } else {
            Vector3::ith(k, delta)
        }
    }
}

impl std::str::FromStr for DriftKind {
    type Err = String;

    fn from_str(text: &str) -> Result<DriftKind, String> {
        DriftKind::ALL.into_iter().find(|k| k.name() == text).ok_or_else(|| {
            let names: Vec<&str> = DriftKind::ALL.iter().map(|k| k.name()).collect();
            format!("\"{text}\" is not a drift kind (expected one of {})", names.join(", "))
        })
    }
}

/// A session whose points drift, and how: `SESSION` (offset-time) or `SESSION:KIND`.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(try_from = "String", into = "String")]
pub struct DriftSpec {
    /// The calibration session.
    pub session: String,
    /// What drifts against what.
    pub kind: DriftKind,
}

impl std::str::FromStr for DriftSpec {
    type Err = String;

    /// `SESSION` or `SESSION:KIND`; a session whose name holds `:` needs its kind written out.
    fn from_str(text: &str) -> Result<DriftSpec, String> {
        let (session, kind) = match text.rsplit_once(':') {
            Some((session, kind)) => (session, kind.parse::<DriftKind>()?),
            None => (text, DriftKind::OffsetTime),
        };
        if session.trim().is_empty() {
            return Err(format!(
                "\"{text}\": expected SESSION or SESSION:KIND, the session's file name without .csv"
            ));
        }
        Ok(DriftSpec { session: session.to_string(), kind })
    }
}

impl TryFrom<String> for DriftSpec {
    type Error = String;

    fn try_from(text: String) -> Result<DriftSpec, String> {
        text.parse()
    }
}

impl From<DriftSpec> for String {
    fn from(spec: DriftSpec) -> String {
        spec.to_string()
    }
}

impl std::fmt::Display for DriftSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}:{}", self.session, self.kind.name())
    }
}

/// A session's fitted drift (`--drift-session`).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct SessionDrift {
    /// The session.
    pub session: String,
    /// What drifts against what.
    pub kind: DriftKind,
    /// The rate: a shift's velocity in the instrument frame (mm/h or mm/K, three values) or a
    /// scale's rate (ppm/h or ppm/K, one value).
    pub rate: Vec<f64>,
    /// Standard deviation of the rate's length (same unit).
    pub rate_std: f64,
    /// Unit of `rate`.
    pub unit: String,
    /// τ̄, the value of τ at which the drift is zero (hours or °C).
    pub centre: f64,
}

impl SessionDrift {
    /// Length of the rate.
    pub fn size(&self) -> f64 {
        self.rate.iter().map(|v| v * v).sum::<f64>().sqrt()
    }

    /// The drift's shift and growth at row `p` (no drift when the row lacks the column).
    pub fn effect_at(&self, p: &Observation) -> (Vector3<f64>, f64) {
        let delta = self.kind.variable(p).map_or(0.0, |v| v - self.centre);
        self.kind.effect(&self.rate, delta)
    }
}

/// Why a drift cannot be fitted as asked.
#[derive(Debug, thiserror::Error)]
pub enum DriftError {
    /// `--drift-session` names a session twice.
    #[error("--drift-session {0}: the session is named twice (one drift kind per session)")]
    Twice(String),
    /// `--drift-session` names no calibration session.
    #[error("--drift-session {0}: no calibration session of that name")]
    Unknown(String),
    /// A drifting session lacks the column its drift kind drifts against.
    #[error("--drift-session {session}:{kind}: {path}:{line} has no {column} (the drift is against {column}, on every row)")]
    Column {
        /// The session.
        session: String,
        /// The drift kind.
        kind: &'static str,
        /// The missing column.
        column: &'static str,
        /// The session's file.
        path: String,
        /// The first row without it.
        line: usize,
    },
    /// `--drift-session` names an artefact placement.
    #[error(
        "--drift-session {0}: a placement of artefact sessions; a drift is fitted on tracker sessions, whose \
         rows carry time_s or temp_C (artefact sessions carry neither)"
    )]
    Artefact(String),
}

/// A drifting block's unknowns in the calibration: its first column (counted from the first
/// drift column), the kind and τ̄.
#[derive(Clone, Copy, Debug)]
pub struct DriftSlot {
    /// First column, from the first drift column.
    pub column: usize,
    /// What drifts against what.
    pub kind: DriftKind,
    /// τ̄ (hours or °C).
    pub centre: f64,
}

/// Each block's drift slot from `--drift-session` (its columns, kind and τ̄), checked: the
/// session exists, is named once, is an instrument's session, and has the kind's column on every
/// row. Columns are counted in the order the specs come.
pub fn drift_slots(data: &Observations, specs: &[DriftSpec]) -> Result<Vec<Option<DriftSlot>>, DriftError> {
    let mut slots = vec![None; data.blocks.len()];
    let mut column = 0;
    let named_before = |k: usize| specs[..k].iter().any(|e| e.session == specs[k].session);
    if let Some(k) = (0..specs.len()).find(|&k| named_before(k)) {
        return Err(DriftError::Twice(specs[k].session.clone()));
    }
    for spec in specs {
        let b = data.find_block(&spec.session).ok_or_else(|| match data.find_group(&spec.session) {
            Some(g) if data.groups[g].kind == crate::data::Kind::Artefact => {
                DriftError::Artefact(spec.to_string())
            }
            _ => DriftError::Unknown(spec.to_string()),
        })?;
        let group = &data.groups[data.blocks[b].group];
        if group.kind == crate::data::Kind::Artefact {
            return Err(DriftError::Artefact(spec.to_string()));
        }
        let members = &data.blocks[b].members;
        if let Some(&k) = members.iter().find(|&&k| spec.kind.variable(&data.obs[k]).is_none()) {
            return Err(DriftError::Column {
                session: spec.session.clone(),
                kind: spec.kind.name(),
                column: spec.kind.column(),
                path: group.source.display().to_string(),
                line: data.obs[k].line,
            });
        }
        slots[b] = Some(DriftSlot { column, kind: spec.kind, centre: 0.0 });
        column += spec.kind.unknowns();
    }
    // τ̄: a session's own mean, except a scale against temperature, which is zero at the mean
    // temperature of the sessions that do not drift (the temperature the model is fitted at).
    let mean =
        |values: Vec<f64>| (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64);
    let temperatures = |b: usize| data.blocks[b].members.iter().filter_map(|&k| data.obs[k].temp_c);
    let still: Vec<f64> =
        (0..data.blocks.len()).filter(|&b| slots[b].is_none()).flat_map(temperatures).collect();
    let every = (0..data.blocks.len()).flat_map(temperatures).collect();
    let reference_c = mean(still).or(mean(every)).unwrap_or(0.0);
    for (b, slot) in slots.iter_mut().enumerate() {
        if let Some(slot) = slot {
            slot.centre = if slot.kind == DriftKind::ScaleTemp {
                reference_c
            } else {
                let members = &data.blocks[b].members;
                mean(members.iter().filter_map(|&k| slot.kind.variable(&data.obs[k])).collect())
                    .unwrap_or(0.0)
            };
        }
    }
    Ok(slots)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs_parse_and_print_back() {
        let plain: DriftSpec = "day_2".parse().unwrap();
        assert_eq!(plain, DriftSpec { session: "day_2".into(), kind: DriftKind::OffsetTime });
        let scale: DriftSpec = "a:b:scale-temp".parse().unwrap();
        assert_eq!((scale.session.as_str(), scale.kind), ("a:b", DriftKind::ScaleTemp));
        assert_eq!(scale.to_string().parse::<DriftSpec>().unwrap(), scale);
        let e = "day_2:scael-temp".parse::<DriftSpec>().unwrap_err();
        assert!(
            e.contains("\"scael-temp\"") && e.contains("offset-time, scale-time, offset-temp, scale-temp"),
            "{e}"
        );
        assert!(":scale-time".parse::<DriftSpec>().unwrap_err().contains("SESSION"));
        let json = serde_json::to_string(&scale).unwrap();
        assert_eq!(json, "\"a:b:scale-temp\"");
        assert_eq!(serde_json::from_str::<DriftSpec>("\"day_2\"").unwrap(), plain);
    }

    #[test]
    fn a_scale_grows_the_rotated_point_and_a_shift_adds() {
        let y = Vector3::new(1000.0, 0.0, 0.0);
        let (shift, growth) = DriftKind::ScaleTemp.effect(&[12.0], 2.0);
        assert_eq!(shift, Vector3::zeros());
        assert!((growth * y - y - Vector3::new(0.024, 0.0, 0.0)).norm() < 1e-12);
        assert!((DriftKind::ScaleTemp.derivative(0, 2.0, &y) - Vector3::new(2e-3, 0.0, 0.0)).norm() < 1e-15);
        let (shift, growth) = DriftKind::OffsetTime.effect(&[1.0, 2.0, 3.0], 0.5);
        assert_eq!((shift, growth), (Vector3::new(0.5, 1.0, 1.5), 1.0));
    }
}
