//! Data errors of instrument sessions: a re-mounted tool, a drift, single bad points. Each is
//! refitted and scored on the held-out sessions by its own rule (what `kincal calibrate` reports);
//! the diagnosis scores the calibration sessions' ones again by the held-out test.
//!
//! **Single bad points.** A beam broken and caught again on the wrong spot of the reflector, a
//! probe bumped: one point carries a gross error e_i, X_i = B_s · F(q_i) · t + e_i. A calibration
//! point whose error is beyond [`BAD_POINT_FACTOR`] times the median error (chi-3 errors almost
//! never are: 5× the median is 7.7 σ) is a candidate; all of them are left out together
//! (`--exclude-point SESSION:LINE`) and the refit is scored on the held-out sessions.
//!
//! **Tool moved between sessions.** A probe or reflector taken off and put back sits a little
//! elsewhere on the flange: in session S the measured point is B_S · F(q) · (t + Δ_S). With the
//! orientation varying inside S, Δ_S cannot be absorbed by S's base, and a calibration that
//! shares t across sessions bends the arm parameters to spread it (an arm error that is not
//! one). The candidate lets the tool float in S (its own Δ_S, `--float-tool S`): in a
//! calibration session it is scored by the held-out error of the refit; in a held-out session
//! whose orientation varies by that session's error with its base and Δ_S refitted. A
//! displacement beyond [`MAX_REMOUNT_MM`] is the session's model error, not a re-mount; a gain
//! below [`MIN_GAIN`] of the held-out error is none. Only the best candidate is called, when
//! |Δ_S| is beyond three of its standard deviations and the held-out error falls: the others
//! were scored against a model the best one still bends (apply it, and score again).
//!
//! **Drift within a session.** The instrument, its stand, its length scale or the arm creeps
//! while a session is measured, against time (`time_s`) or temperature (`temp_C`): a base shift
//! X_i = B_s · F(q_i) · t + v_S · (τ_i − τ̄) or a length scale X_i = B_s · (1 + k_S · (τ_i − τ̄)) ·
//! F(q_i) · t (the four kinds, their formulas and physical causes in
//! [`crate::calib::nuisance::drift`]). A calibration that holds S still spreads the creep over the
//! arm parameters. Each calibration session is refitted drifting each way its columns allow
//! (`--drift-session S:KIND`, three unknowns for a shift, one for a scale) and scored, like the
//! others, by the held-out error of the refit; a drift is called when its rate is beyond three of
//! its standard deviations and the held-out error falls by [`MIN_GAIN`]. It claims no arm
//! effect: the arm parameters are refitted, not changed by it.

use super::{DataError, DataErrorKind, DataSet};
use crate::calib::diagnose::units::Measure;
use crate::calib::fit::{calibrate, Fit, CONSTANT_ORIENTATION_DEG};
use crate::calib::nuisance::drift::{DriftKind, DriftSpec};
use crate::calib::nuisance::tool::orientation_spread_deg;
use crate::calib::setup::{Change, SolveOptions};
use crate::calib::validate::{calibration_errors, fit_session_with_tool};
use crate::data::Observations;
use crate::model::ArmModel;
use crate::numerics::stats::rms;

/// Largest tool displacement taken for a re-mount, mm: a probe put back sits within millimetres;
/// more is the session's model error, not a tool.
pub const MAX_REMOUNT_MM: f64 = 10.0;

/// Least share of the held-out error a data error must remove to be called.
pub const MIN_GAIN: f64 = 0.05;

/// Held-out RMS of `model` over `val`'s sessions, the sessions in `floating` with their tool
/// refitted too.
pub fn held_out_rms(model: &ArmModel, val: &Observations, floating: &[String]) -> f64 {
    rms(&Measure::Points.errors(model, val, floating))
}

/// A calibration point beyond this many times the median error is a bad-point candidate.
pub const BAD_POINT_FACTOR: f64 = 5.0;

/// The bad-points candidate: calibration points far beyond the others, left out and refitted.
fn bad_points_candidate(
    nominal: &ArmModel,
    cal: &Observations,
    val: &Observations,
    fit: &Fit,
    options: &SolveOptions,
    before: f64,
) -> Option<DataError> {
    let errors = calibration_errors(fit, cal);
    let median = crate::numerics::stats::median(errors.iter().flatten().copied().collect());
    let mut bad = Vec::new();
    let mut dropped = vec![false; cal.obs.len()];
    for (b, e) in cal.sessions().into_iter().zip(&errors) {
        for (&k, &err) in cal.blocks[b].members.iter().zip(e) {
            if err > BAD_POINT_FACTOR * median {
                bad.push((cal.point_name(k), err, cal.block_name(b)));
                dropped[k] = true;
            }
        }
    }
    if bad.is_empty() {
        return None;
    }
    let kept = cal.without(|k| dropped[k]);
    let refit = calibrate(nominal, &kept, options).ok()?;
    let after = held_out_rms(&refit.model, val, &options.float_tool);
    let largest = bad.iter().map(|b| b.1).fold(0.0, f64::max);
    let names: Vec<&str> = bad.iter().map(|b| b.0.as_str()).collect();
    let mut sessions: Vec<&str> = bad.iter().map(|b| b.2.as_str()).collect();
    sessions.dedup();
    let change = Change::ExcludePoints(names.iter().map(|n| n.to_string()).collect());
    Some(DataError {
        kind: DataErrorKind::BadPoints,
        session: sessions.join(", "),
        set: DataSet::Calibration,
        size_mm: largest,
        size_std_mm: median / 1.538,
        held_out_before_mm: before,
        held_out_after_mm: after,
        significant: after < (1.0 - MIN_GAIN) * before,
        text: format!(
            "{} single bad point{} ({}; up to {largest:.3} mm, the median point {median:.4} mm); held-out RMS \
             {before:.4} → {after:.4} mm without {}",
            bad.len(),
            if bad.len() == 1 { "" } else { "s" },
            names.join(", "),
            if bad.len() == 1 { "it" } else { "them" }
        ),
        action: change.action(),
        change: Some(change),
    })
}

/// The drift candidates: each calibration session, with each drift kind whose column it carries
/// over the least span ([`DriftKind::applies_to`]), refitted drifting that way.
fn drift_candidates(
    nominal: &ArmModel,
    cal: &Observations,
    val: &Observations,
    options: &SolveOptions,
    before: f64,
) -> Vec<DataError> {
    let mut out = Vec::new();
    for b in cal.sessions() {
        let name = cal.block_name(b);
        if options.drift_sessions.iter().any(|d| d.session == name) {
            continue;
        }
        for kind in DriftKind::ALL.into_iter().filter(|k| k.applies_to(cal, b)) {
            let mut drift_sessions = options.drift_sessions.clone();
            drift_sessions.push(DriftSpec { session: name.clone(), kind });
            let Ok(refit) = calibrate(nominal, cal, &SolveOptions { drift_sessions, ..options.clone() })
            else {
                continue;
            };
            let Some(drift) = refit.drifts.iter().find(|d| d.session == name) else { continue };
            let after = held_out_rms(&refit.model, val, &options.float_tool);
            let (size, std) = (drift.size(), drift.rate_std);
            // A shift reads in µm (per hour or per kelvin), a scale in ppm.
            let (scale, unit) = if kind.is_scale() {
                (1.0, kind.unit().to_string())
            } else {
                (1e3, kind.unit().replacen("mm", "µm", 1))
            };
            let what = if kind.is_scale() {
                format!(
                    "its length scale changes by {:.2} ± {:.2} {unit}",
                    scale * drift.rate[0],
                    scale * std
                )
            } else {
                let along =
                    drift.rate.iter().map(|x| format!("{:.3}", x / size.max(1e-300))).collect::<Vec<_>>();
                format!(
                    "its base moves {:.1} ± {:.1} {unit} along ({}) (instrument frame)",
                    scale * size,
                    scale * std,
                    along.join(", ")
                )
            };
            let change = Change::Drift(DriftSpec { session: name.clone(), kind });
            out.push(DataError {
                kind: DataErrorKind::Drift,
                session: name.clone(),
                set: DataSet::Calibration,
                size_mm: size,
                size_std_mm: std,
                held_out_before_mm: before,
                held_out_after_mm: after,
                significant: size > 3.0 * std && after < (1.0 - MIN_GAIN) * before,
                text: format!(
                    "session {} drifts ({}, against {}): {what}; held-out RMS {before:.4} → {after:.4} mm with it drifting",
                    name,
                    kind.name(),
                    kind.column(),
                ),
                action: change.action(),
                change: Some(change),
            });
        }
    }
    out
}

/// Score the data errors, best first: "the tool moved in session S" for every session not
/// already floating, "session S drifts" for every drift kind a session's columns allow, and
/// single bad points.
pub fn data_error_candidates(
    nominal: &ArmModel,
    cal: &Observations,
    val: &Observations,
    fit: &Fit,
    options: &SolveOptions,
) -> Vec<DataError> {
    let before = held_out_rms(&fit.model, val, &options.float_tool);
    let mut out = Vec::new();
    let verdict = |session: &str, set: DataSet, offset: [f64; 3], std: f64, after: f64| {
        let size = offset.iter().map(|v| v * v).sum::<f64>().sqrt();
        let significant = size > 3.0 * std && size <= MAX_REMOUNT_MM && after < (1.0 - MIN_GAIN) * before;
        let change = Change::FloatTool(session.to_string());
        DataError {
            kind: DataErrorKind::ToolMoved,
            session: session.into(),
            set,
            size_mm: size,
            size_std_mm: std,
            held_out_before_mm: before,
            held_out_after_mm: after,
            significant,
            text: format!(
                "the tool sits {size:.3} ± {std:.3} mm elsewhere in session {session} (flange frame: {:.3}, {:.3}, {:.3} mm); \
                 held-out RMS {before:.4} → {after:.4} mm with it floating",
                offset[0], offset[1], offset[2]
            ),
            action: change.action(),
            change: Some(change),
        }
    };
    // A calibration session's own tool needs the shared one fixed by other sessions that turn it.
    let turning = |data: &Observations| -> Vec<usize> {
        data.sessions()
            .into_iter()
            .filter(|&b| !options.float_tool.contains(&data.block_name(b)))
            .filter(|&b| orientation_spread_deg(&fit.model, data, b) >= CONSTANT_ORIENTATION_DEG)
            .collect()
    };
    let cal_turning = turning(cal);
    for &b in &cal_turning {
        if cal_turning.len() < 2 {
            break;
        }
        let name = cal.block_name(b);
        let mut float_tool = options.float_tool.clone();
        float_tool.push(name.clone());
        let Ok(refit) =
            calibrate(nominal, cal, &SolveOptions { float_tool: float_tool.clone(), ..options.clone() })
        else {
            continue;
        };
        let Some(tool) = refit.tool_offsets.iter().find(|t| t.session == name) else { continue };
        let after = held_out_rms(&refit.model, val, &options.float_tool);
        out.push(verdict(&name, DataSet::Calibration, tool.offset_mm, tool.size_std_mm, after));
    }
    // A held-out session whose orientation is constant cannot tell its tool from its base.
    for b in turning(val) {
        let name = val.block_name(b);
        let tool = fit_session_with_tool(&fit.model, val, b).0;
        let mut floating = options.float_tool.clone();
        floating.push(name.clone());
        let after = held_out_rms(&fit.model, val, &floating);
        out.push(verdict(&name, DataSet::HeldOut, tool.offset_mm, tool.size_std_mm, after));
    }
    out.extend(drift_candidates(nominal, cal, val, options, before));
    out.extend(bad_points_candidate(nominal, cal, val, fit, options, before));
    out.sort_by(|a, b| a.held_out_after_mm.total_cmp(&b.held_out_after_mm));
    // One data error at a time: the others are scored against a model the best one still bends,
    // so only the best is called; apply it and score again.
    for c in out.iter_mut().skip(1) {
        c.significant = false;
    }
    out
}
