//! What a calibration is asked to do: one options type for every kind of data, each option
//! meaning the same on artefact touches and on tracker points (or refused at the edge, naming the
//! option and the kind, where it has no meaning).
//!
//! An option left unset takes its data kind's default, stated here and recorded in the run:
//! - loss: Huber δ = [`DEFAULT_HUBER_DELTA_MM`] (the thesis' choice) when the data hold artefact
//!   touches, plain least squares on instrument points alone (stated σ, Gaussian statistics);
//! - restarts: [`DEFAULT_RESTARTS`] random starts when the data hold artefact touches, none on
//!   instrument points alone (each session's frame has a closed form; the nominal start is good);
//! - orientations: a 6-DoF probe's orientations are fitted when the sessions carry them,
//!   weighed σ_position/σ_orientation; the artefact's relative orientations only with
//!   `--objective six-dof`.

use crate::calib::error::CalibError;
use crate::calib::nuisance::drift::DriftSpec;
use crate::data::Observations;
use crate::model::effects::Effect;
use crate::model::ArmModel;
use crate::numerics::solver::{Loss, SolverOptions};
use std::borrow::Cow;

/// Huber threshold δ on artefact touches when none is given, mm (thesis: 1.35 mm).
pub const DEFAULT_HUBER_DELTA_MM: f64 = 1.35;
/// Random starts on artefact touches when none is given.
pub const DEFAULT_RESTARTS: usize = 8;
/// Lever of the artefact's relative-orientation rows when none is given, mm per radian.
pub const DEFAULT_LEVER_MM: f64 = 100.0;
/// Orientation σ of a 6-DoF probe per axis, degrees, when `--orientation-sigma-deg` is not given
/// (a laser tracker's 6-DoF probe states 0.005–0.02°).
pub const DEFAULT_ORIENTATION_SIGMA_DEG: f64 = 0.01;
/// Position σ per axis, mm, that weighs orientations against points when no point states its
/// uncertainty (`sigma_mm` / `u95_mm`).
pub const DEFAULT_POSITION_SIGMA_MM: f64 = 0.025;
/// Per-axis scatter of a touch, mm, that weighs tracker points against artefact distances in
/// mixed data when no landmark was touched twice (the SUTA's seating, thesis §4).
pub const DEFAULT_TOUCH_SIGMA_MM: f64 = 0.1;
/// Most random restarts a calibration may ask for (the CLI and a RUN read back both check it).
pub const MAX_RESTARTS: usize = 1000;
/// Range of the Huber threshold δ, mm.
pub const HUBER_DELTA_RANGE_MM: (f64, f64) = (0.001, 1000.0);
/// Range of the orientation lever, mm per radian.
pub const LEVER_RANGE_MM: (f64, f64) = (0.001, 100_000.0);

/// Which residuals the calibration minimises.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Objective {
    /// Positions only: distances between touches, measured points.
    Distance,
    /// Positions and orientations: the relative orientation of touches of one placement (the
    /// asymmetric pillars) and a 6-DoF probe's orientations, an angle weighed as `lever_mm` mm
    /// per radian (`None`: [`DEFAULT_LEVER_MM`] for touches, σ_position/σ_orientation for a
    /// probe).
    SixDof {
        /// Millimetres per radian of orientation error.
        lever_mm: Option<f64>,
    },
}

/// Settings of one calibration; `None` takes the data kind's default (see the module doc).
#[derive(Clone, Debug)]
pub struct SolveOptions {
    /// Huber threshold δ, mm.
    pub huber_delta_mm: Option<f64>,
    /// Random starts inside the bounds, besides the start at the nominal values.
    pub restarts: Option<usize>,
    /// Seed of the random starts (and of everything else drawn at random).
    pub seed: u64,
    /// Residuals minimised.
    pub objective: Option<Objective>,
    /// Orientation σ of a 6-DoF probe per axis, degrees.
    pub orientation_sigma_deg: Option<f64>,
    /// Groups (placements or sessions) whose tool point gets its own offset (re-mounted there).
    pub float_tool: Vec<String>,
    /// Sessions whose points drift, and how (`--drift-session SESSION:KIND`).
    pub drift_sessions: Vec<DriftSpec>,
    /// Solver settings other than the loss, for problems without block unknowns.
    pub solver: SolverOptions,
}

impl Default for SolveOptions {
    fn default() -> Self {
        SolveOptions {
            huber_delta_mm: None,
            restarts: None,
            seed: 1,
            objective: None,
            orientation_sigma_deg: None,
            float_tool: Vec::new(),
            drift_sessions: Vec::new(),
            solver: SolverOptions::default(),
        }
    }
}

/// The options as they apply to one set of observations: every default resolved.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Resolved {
    /// The loss.
    pub loss: Loss,
    /// Random starts.
    pub restarts: usize,
    /// Seed.
    pub seed: u64,
    /// The objective as recorded.
    pub objective: Objective,
    /// Lever of the artefact's relative-orientation rows, mm per radian, when they are fitted.
    pub relative_lever_mm: Option<f64>,
    /// Weight of a probe's orientation rows, mm per radian, when they are fitted.
    pub orientation_weight_mm_per_rad: Option<f64>,
    /// Weight of instrument rows (points and orientations) against distances between touches:
    /// 1 for one kind of data alone; with both, σ_distance/σ_point (see
    /// [`SolveOptions::point_weight`]), so that each row counts by its noise.
    pub point_weight: f64,
}

impl SolveOptions {
    /// Every default resolved for `data`.
    pub fn resolve(&self, data: &Observations) -> Resolved {
        let touches = data.obs.iter().any(|o| o.landmark().is_some());
        let oriented = data.obs.iter().any(|o| o.orientation().is_some());
        let loss = match (self.huber_delta_mm, touches) {
            (Some(d), _) => Loss::Huber(d),
            (None, true) => Loss::Huber(DEFAULT_HUBER_DELTA_MM),
            (None, false) => Loss::Linear,
        };
        let restarts = self.restarts.unwrap_or(if touches { DEFAULT_RESTARTS } else { 0 });
        let relative_lever_mm = match self.objective {
            Some(Objective::SixDof { lever_mm }) if touches => Some(lever_mm.unwrap_or(DEFAULT_LEVER_MM)),
            _ => None,
        };
        let orientation_weight_mm_per_rad = match self.objective {
            _ if !oriented => None,
            Some(Objective::Distance) => None,
            Some(Objective::SixDof { lever_mm: Some(l) }) => Some(l),
            _ => Some(self.orientation_weight(data)),
        };
        let objective = match (relative_lever_mm, orientation_weight_mm_per_rad) {
            (None, None) => Objective::Distance,
            (l, w) => Objective::SixDof { lever_mm: l.or(w) },
        };
        Resolved {
            loss,
            restarts,
            seed: self.seed,
            objective,
            relative_lever_mm,
            orientation_weight_mm_per_rad,
            point_weight: 1.0,
        }
    }

    /// Weight of an instrument's rows against distances between touches when both are fitted
    /// together: σ_distance / σ_point, with σ_distance = √2·σ_touch the noise of a distance
    /// between two touches of per-axis scatter σ_touch (`touch_std_mm`, from repeated touches of
    /// the calibration data; [`DEFAULT_TOUCH_SIGMA_MM`] without any) and σ_point the median
    /// stated σ per axis of the points (else [`DEFAULT_POSITION_SIGMA_MM`]). Each row then counts
    /// by its noise, as in a weighted least-squares fit of both instruments.
    pub fn point_weight(&self, data: &Observations, touch_std_mm: Option<f64>) -> f64 {
        let touch = touch_std_mm.filter(|s| s.is_finite() && *s > 0.0).unwrap_or(DEFAULT_TOUCH_SIGMA_MM);
        std::f64::consts::SQRT_2 * touch / median_point_sigma_mm(data)
    }

    /// Weight of an orientation residual, mm per rad: σ_position / σ_orientation, so that a
    /// residual of one stated σ counts the same in a point's coordinate (mm) as in an orientation
    /// axis. σ_position is the median stated point σ (`sigma_mm`, `u95_mm`/2), else
    /// [`DEFAULT_POSITION_SIGMA_MM`]; σ_orientation is `--orientation-sigma-deg`, else
    /// [`DEFAULT_ORIENTATION_SIGMA_DEG`].
    pub fn orientation_weight(&self, data: &Observations) -> f64 {
        let position = median_point_sigma_mm(data);
        let orientation = self.orientation_sigma_deg.unwrap_or(DEFAULT_ORIENTATION_SIGMA_DEG).to_radians();
        position / orientation
    }
}

/// The median stated σ per axis of the points (`sigma_mm`, `u95_mm`/2), else
/// [`DEFAULT_POSITION_SIGMA_MM`].
fn median_point_sigma_mm(data: &Observations) -> f64 {
    let mut stated: Vec<f64> =
        data.obs.iter().filter(|o| o.point_mm().is_some()).filter_map(|o| o.sigma_mm).collect();
    stated.sort_by(f64::total_cmp);
    stated.get(stated.len() / 2).copied().unwrap_or(DEFAULT_POSITION_SIGMA_MM)
}

impl Resolved {
    /// The Huber threshold, mm, when the loss is Huber's.
    pub fn huber_delta_mm(&self) -> Option<f64> {
        match self.loss {
            Loss::Huber(d) => Some(d),
            Loss::Linear => None,
        }
    }
}

/// One change to a calibration: an effect added to the model, or the remedy of a data error.
/// Typed: the diagnosis proposes changes and the auto loop applies them; their command-line
/// text ([`Change::action`]) is only ever written, never read back.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Change {
    /// Add a library effect to the model (`--add`).
    Effect(Effect),
    /// Let the tool float in a group, calibration or held out: a re-mounted tool or probe
    /// (`--float-tool`).
    FloatTool(String),
    /// Let a calibration session drift (`--drift-session`).
    Drift(DriftSpec),
    /// Leave calibration observations out, named `SESSION:LINE` or `PLACEMENT/REPEAT/LANDMARK`
    /// (`--exclude-point`).
    ExcludePoints(Vec<String>),
    /// Leave a calibration block out: `PLACEMENT/REPEAT` (the artefact moved), or a session
    /// (`--exclude-block`).
    ExcludeBlock(String),
    /// A landmark's certified position is wrong: scored with the position freed; its remedy
    /// leaves the landmark out of both folders (`--exclude-landmark`) until the certificate is
    /// checked.
    FreeLandmark(String),
}

impl Change {
    /// Its name in a diagnosis: the effect, or the data error's kind and place.
    pub fn name(&self) -> String {
        match self {
            Change::Effect(e) => e.to_string(),
            Change::FloatTool(group) => format!("tool moved: {group}"),
            Change::Drift(spec) => format!("drift: {spec}"),
            Change::ExcludePoints(points) => format!("bad points: {}", points.join(", ")),
            Change::ExcludeBlock(block) => format!("block:{block}"),
            Change::FreeLandmark(id) => format!("landmark:{id}"),
        }
    }

    /// The `kincal calibrate` options that apply it.
    pub fn action(&self) -> String {
        match self {
            Change::Effect(e) => format!("--add {e}"),
            Change::FloatTool(group) => format!("--float-tool {group}"),
            Change::Drift(spec) => format!("--drift-session {spec}"),
            Change::ExcludePoints(points) => {
                points.iter().map(|p| format!("--exclude-point {p}")).collect::<Vec<_>>().join(" ")
            }
            Change::ExcludeBlock(block) => format!("--exclude-block {block}"),
            Change::FreeLandmark(id) => format!("--exclude-landmark {id}"),
        }
    }

    /// A data error's remedy (every change but an effect).
    pub fn is_data_error(&self) -> bool {
        !matches!(self, Change::Effect(_))
    }
}

/// What a calibration is asked besides the model: the solve options, the groups whose tool
/// floats (held-out ones too: their tool is refitted with their frame), the stated σ of held-out
/// points, and the changes a diagnosis applied on top of the data it was given (which already
/// lack what the run itself left out).
#[derive(Clone, Debug, Default)]
pub struct Setup {
    /// Loss, restarts, seed, objective, the probe's σ and the drifting sessions.
    pub options: SolveOptions,
    /// Groups whose tool floats, calibration and held out.
    pub float_tool: Vec<String>,
    /// The instrument's stated σ per axis of held-out points that carry none, mm.
    pub stated_sigma_mm: Option<f64>,
    /// The changes applied, in order.
    pub changes: Vec<Change>,
    /// The run's own options beyond its data and model, as `kincal calibrate` spells them.
    pub given: Vec<String>,
}

impl Setup {
    /// A setup of these solve options alone (their floated tools too).
    pub fn new(options: SolveOptions) -> Setup {
        Setup { float_tool: options.float_tool.clone(), options, ..Setup::default() }
    }

    /// The setup and the model with `change` applied: an effect is added to the model (at zero,
    /// its parameters free), a data error's remedy to the setup.
    pub fn apply(&self, change: &Change, model: &ArmModel) -> (Setup, ArmModel) {
        let (mut setup, mut model) = (self.clone(), model.clone());
        match change {
            Change::Effect(e) => e.add_to(&mut model),
            Change::FloatTool(group) => setup.float_tool.push(group.clone()),
            Change::Drift(spec) => setup.options.drift_sessions.push(spec.clone()),
            Change::ExcludePoints(_) | Change::ExcludeBlock(_) | Change::FreeLandmark(_) => {}
        }
        setup.changes.push(change.clone());
        (setup, model)
    }

    /// The solve options for calibration data `cal`: the floated tools of its groups.
    pub fn solve_options(&self, cal: &Observations) -> SolveOptions {
        SolveOptions {
            float_tool: self.float_tool.iter().filter(|n| cal.find_group(n).is_some()).cloned().collect(),
            ..self.options.clone()
        }
    }

    /// Which observations of `cal` the changes leave out (named observations, blocks,
    /// landmarks).
    pub fn left_out(&self, cal: &Observations) -> Result<Vec<bool>, CalibError> {
        let mut out = vec![false; cal.obs.len()];
        for change in &self.changes {
            let drop: Vec<usize> = match change {
                Change::ExcludePoints(names) => {
                    let mut found = Vec::new();
                    for name in names {
                        let named = cal.find_point(name);
                        if named.is_empty() {
                            return Err(CalibError::NotInData(change.action()));
                        }
                        found.extend(named);
                    }
                    found
                }
                Change::ExcludeBlock(name) => {
                    let b = cal.find_block(name).ok_or_else(|| CalibError::NotInData(change.action()))?;
                    cal.blocks[b].members.clone()
                }
                Change::FreeLandmark(id) => {
                    let l = cal.landmark_index(id).ok_or_else(|| CalibError::NotInData(change.action()))?;
                    (0..cal.obs.len()).filter(|&k| cal.obs[k].landmark() == Some(l)).collect()
                }
                Change::Effect(_) | Change::FloatTool(_) | Change::Drift(_) => Vec::new(),
            };
            drop.into_iter().for_each(|k| out[k] = true);
        }
        Ok(out)
    }

    /// `cal` without what the changes leave out ([`Setup::left_out`]).
    pub fn data<'a>(&self, cal: &'a Observations) -> Result<Cow<'a, Observations>, CalibError> {
        let out = self.left_out(cal)?;
        Ok(if out.contains(&true) { Cow::Owned(cal.without(|k| out[k])) } else { Cow::Borrowed(cal) })
    }

    /// The effects added by the changes.
    pub fn added(&self) -> Vec<String> {
        self.changes
            .iter()
            .filter_map(|c| match c {
                Change::Effect(e) => Some(e.to_string()),
                _ => None,
            })
            .collect()
    }

    /// The command-line options that make this setup, beyond the data folders and the model:
    /// the run's own, then the changes'.
    pub fn options_text(&self) -> String {
        self.given
            .iter()
            .cloned()
            .chain(self.changes.iter().map(Change::action))
            .collect::<Vec<_>>()
            .join(" ")
    }
}
