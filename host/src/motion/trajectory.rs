//! A trajectory for the emulated arm: joint waypoints with times, in a CSV file.
//!
//! ```text
//! # kincal trajectory: encoder angles (deg) of the six joints at times (s)
//! t_s,j1_deg,j2_deg,j3_deg,j4_deg,j5_deg,j6_deg
//! 0,10,95,30,0,80,0
//! 1.5,18,95,30,0,80,0
//! ```
//!
//! The arm moves smoothly through the waypoints ([`kincal_protocol::trajectory`]: C², at rest at
//! both ends, a joint that turns back at a waypoint stops there). Angles are what the encoders
//! report, unwrapped: from 359° to 361° is 2°, from 359° to 1° is 358°. Two rows with the same
//! angles hold the arm still between their times.

use crate::files::{row_error, FileError};
use kincal_protocol::biss::COUNTS_PER_TURN;
use kincal_protocol::trajectory::{duration_ticks, position_at, Waypoint, MAX_WAYPOINTS};
use kincal_protocol::{joints::JOINTS, messages::TICK_HZ};
use std::path::Path;

/// The header line of a trajectory file.
pub const HEADER: &str = "t_s,j1_deg,j2_deg,j3_deg,j4_deg,j5_deg,j6_deg";
/// Fastest joint motion accepted, °/s: a hand-guided arm stays far below it, and the controller
/// rejects encoder frames that jump faster than 3 turns/s as implausible.
pub const MAX_JOINT_DEG_PER_S: f64 = 360.0;

/// Joint waypoints with times.
#[derive(Clone, Debug, PartialEq)]
pub struct Trajectory {
    /// The waypoints, times in controller ticks from the start, angles in unwrapped counts.
    pub waypoints: Vec<Waypoint>,
}

/// Counts of an angle, unwrapped.
fn counts(deg: f64) -> i32 {
    (deg / 360.0 * COUNTS_PER_TURN as f64).round() as i32
}

/// Degrees of unwrapped counts.
pub fn degrees(counts: f64) -> f64 {
    counts * 360.0 / COUNTS_PER_TURN as f64
}

/// What is wrong with a trajectory: the waypoint (0-based; none: the whole trajectory), the
/// column and the reason.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{}column `{column}`: {message}", .waypoint.map_or(String::new(), |k| format!("waypoint {}: ", k + 1)))]
pub struct TrajectoryError {
    /// The waypoint, 0-based.
    pub waypoint: Option<usize>,
    /// The column.
    pub column: String,
    /// Why.
    pub message: String,
}

fn refuse(waypoint: Option<usize>, column: impl Into<String>, message: String) -> TrajectoryError {
    TrajectoryError { waypoint, column: column.into(), message }
}

impl Trajectory {
    /// Waypoints at `(time s, encoder angles °)`, checked as a file's rows are.
    pub fn from_rows(rows: &[(f64, [f64; JOINTS])]) -> Result<Trajectory, TrajectoryError> {
        if rows.len() < 2 || rows.len() > MAX_WAYPOINTS {
            return Err(refuse(
                None,
                "t_s",
                format!("{} waypoints; 2 to {MAX_WAYPOINTS} are needed", rows.len()),
            ));
        }
        let mut waypoints: Vec<Waypoint> = Vec::with_capacity(rows.len());
        for (k, (t_s, deg)) in rows.iter().enumerate() {
            if !t_s.is_finite() || *t_s < 0.0 || *t_s > 3600.0 {
                return Err(refuse(Some(k), "t_s", format!("{t_s} s is outside 0 to 3600 s")));
            }
            if let Some(j) = deg.iter().position(|d| !d.is_finite() || d.abs() > 36_000.0) {
                let column = format!("j{}_deg", j + 1);
                return Err(refuse(Some(k), column, format!("{} is not an angle within ±36000°", deg[j])));
            }
            let at_tick = (t_s * TICK_HZ as f64).round() as u32;
            if waypoints.last().is_some_and(|w| at_tick <= w.at_tick) {
                return Err(refuse(
                    Some(k),
                    "t_s",
                    format!("{t_s} s does not come after the previous waypoint's time (by at least one tick, 1.3 ms)"),
                ));
            }
            waypoints.push(Waypoint { at_tick, counts: deg.map(counts) });
        }
        let trajectory = Trajectory { waypoints };
        trajectory.check_speed()?;
        Ok(trajectory)
    }

    /// Refuse a trajectory faster than [`MAX_JOINT_DEG_PER_S`] anywhere.
    fn check_speed(&self) -> Result<(), TrajectoryError> {
        for (k, seg) in self.waypoints.windows(2).enumerate() {
            for tick in seg[0].at_tick..seg[1].at_tick {
                let (a, b) = (self.position_counts(tick as f64), self.position_counts(tick as f64 + 1.0));
                for j in 0..JOINTS {
                    let deg_per_s = degrees(b[j] - a[j]).abs() * TICK_HZ as f64;
                    if deg_per_s > MAX_JOINT_DEG_PER_S {
                        return Err(refuse(
                            Some(k + 1),
                            format!("j{}_deg", j + 1),
                            format!(
                                "the joint moves at {deg_per_s:.0} °/s on the way here (at t = {:.3} s); at most {MAX_JOINT_DEG_PER_S} °/s: give the motion more time",
                                tick as f64 / TICK_HZ as f64
                            ),
                        ));
                    }
                }
            }
        }
        Ok(())
    }

    /// Read a trajectory file.
    pub fn load(path: &Path) -> Result<Trajectory, FileError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| FileError::Io { path: path.to_path_buf(), source: e })?;
        let err = |line: usize, column: &str, message: String| row_error(path, line, column, message);
        let mut lines = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
        match lines.next() {
            Some((_, l)) if l.trim() == HEADER => {}
            Some((n, l)) => {
                return Err(err(n + 1, "(header)", format!("expected `{HEADER}`, found `{}`", l.trim())))
            }
            None => return Err(err(1, "(header)", format!("empty: expected `{HEADER}` and waypoint rows"))),
        }
        let columns: Vec<&str> = HEADER.split(',').collect();
        let mut rows = Vec::new();
        let mut line_of = Vec::new();
        for (n, line) in lines {
            let cells: Vec<&str> = line.split(',').map(str::trim).collect();
            if cells.len() != columns.len() {
                let last = columns[cells.len().min(columns.len()) - 1];
                return Err(err(
                    n + 1,
                    last,
                    format!("{} values; expected {} (t_s and six angles)", cells.len(), columns.len()),
                ));
            }
            let mut values = [0.0; JOINTS + 1];
            for (c, cell) in cells.iter().enumerate() {
                values[c] =
                    cell.parse().map_err(|_| err(n + 1, columns[c], format!("`{cell}` is not a number")))?;
            }
            rows.push((values[0], std::array::from_fn(|j| values[j + 1])));
            line_of.push(n + 1);
        }
        Trajectory::from_rows(&rows).map_err(|e| {
            let line = e.waypoint.and_then(|k| line_of.get(k).copied()).unwrap_or(1);
            err(line, &e.column, e.message)
        })
    }

    /// The file's text.
    pub fn to_csv(&self) -> String {
        let mut out =
            format!("# kincal trajectory: encoder angles (deg) of the six joints at times (s)\n{HEADER}\n");
        for w in &self.waypoints {
            let deg: Vec<String> = w.counts.iter().map(|&c| format!("{:.6}", degrees(c as f64))).collect();
            out += &format!("{:.6},{}\n", w.at_tick as f64 / TICK_HZ as f64, deg.join(","));
        }
        out
    }

    /// Length, s.
    pub fn duration_s(&self) -> f64 {
        duration_ticks(&self.waypoints) as f64 / TICK_HZ as f64
    }

    /// Joint positions at `t_ticks` after the start, unwrapped counts.
    pub fn position_counts(&self, t_ticks: f64) -> [f64; JOINTS] {
        position_at(&self.waypoints, t_ticks, false)
    }

    /// Encoder angles at `t_s` after the start, degrees (unwrapped).
    pub fn angles_deg(&self, t_s: f64) -> [f64; JOINTS] {
        self.position_counts(t_s * TICK_HZ as f64).map(degrees)
    }

    /// A hand-guided motion around `center_deg` for the demo: rest, sweeps of the three base
    /// joints back and forth with direction changes at several speeds (0.3 to 1.2 s per sweep),
    /// a pause in the middle, rest at the end; about 16 s.
    pub fn demo(center_deg: [f64; JOINTS]) -> Trajectory {
        // (duration of the move to this waypoint s, offsets of joints 1–3 °); equal offsets hold.
        let steps: [(f64, [f64; 3]); 20] = [
            (1.0, [0.0, 0.0, 0.0]),
            (1.2, [8.0, 3.0, -4.0]),
            (0.9, [-6.0, -2.0, 3.0]),
            (0.7, [5.0, 4.0, 2.0]),
            (0.5, [-4.0, 1.0, -3.0]),
            (0.4, [3.0, -2.0, 2.0]),
            (0.35, [-3.0, 1.0, -1.0]),
            (1.0, [-3.0, 1.0, -1.0]),
            (1.1, [6.0, 5.0, 4.0]),
            (0.8, [-7.0, -4.0, -5.0]),
            (0.6, [4.0, 3.0, 4.0]),
            (0.45, [-2.0, -3.0, -2.0]),
            (0.3, [2.0, 1.0, 2.0]),
            (0.8, [2.0, 1.0, 2.0]),
            (1.2, [-8.0, 2.0, -6.0]),
            (0.9, [7.0, -3.0, 5.0]),
            (0.6, [-5.0, 2.0, -2.0]),
            (0.4, [2.0, -1.0, 1.0]),
            (1.0, [0.0, 0.0, 0.0]),
            (1.5, [0.0, 0.0, 0.0]),
        ];
        let mut t = 0.0;
        let mut rows = vec![(0.0, center_deg)];
        for (dt, offsets) in steps {
            t += dt;
            let mut deg = center_deg;
            for j in 0..3 {
                deg[j] += offsets[j];
            }
            rows.push((t, deg));
        }
        // Within the limits by construction (checked by the tests).
        let waypoints = rows
            .iter()
            .map(|(t, d)| Waypoint { at_tick: (t * TICK_HZ as f64).round() as u32, counts: d.map(counts) })
            .collect();
        Trajectory { waypoints }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(name: &str, text: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("kincal-trajectory-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.csv");
        std::fs::write(&path, text).unwrap();
        path
    }

    #[test]
    fn a_trajectory_file_round_trips() {
        let demo = Trajectory::demo([10.0, 95.0, 30.0, 0.0, 80.0, 359.9]);
        assert!(demo.check_speed().is_ok());
        assert!(demo.waypoints.len() <= MAX_WAYPOINTS && (12.0..25.0).contains(&demo.duration_s()));
        let path = write("round", &demo.to_csv());
        assert_eq!(Trajectory::load(&path).unwrap(), demo);
        let mid = demo.angles_deg(1.0);
        assert!((mid[5] - 359.9).abs() < 1e-4 && (mid[0] - 10.0).abs() < 1e-4, "{mid:?}");
    }

    #[test]
    fn bad_files_name_the_line_and_what_is_wrong() {
        let cases = [
            ("t,a\n", ":1: column `(header)`", "expected `t_s,"),
            (&format!("{HEADER}\n0,1,2,3,4,5\n"), ":2: column `j5_deg`", "6 values"),
            (&format!("{HEADER}\n0,1,2,3,4,5,x\n"), ":2: column `j6_deg`", "`x` is not a number"),
            (
                &format!("# note\n{HEADER}\n0,0,0,0,0,0,0\n1,0,0,0,0,0,0\n1,5,0,0,0,0,0\n"),
                ":5: column `t_s`",
                "does not come after",
            ),
            (&format!("{HEADER}\n0,0,0,0,0,0,0\n0.1,90,0,0,0,0,0\n"), ":3: column `j1_deg`", "moves at"),
            (&format!("{HEADER}\n0,0,0,0,0,0,0\n"), ":1: column `t_s`", "2 to 32 are needed"),
        ];
        for (text, line, what) in cases {
            let e = Trajectory::load(&write("bad", text)).unwrap_err().to_string();
            assert!(e.contains(line) && e.contains(what), "{text:?}: {e}");
        }
    }
}
