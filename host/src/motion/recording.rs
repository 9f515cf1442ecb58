//! The two recordings a dynamic validation compares, as CSV files.
//!
//! * The arm's pose: the CSV of `kincal stream --pose --csv` (columns `t_s` — the controller's
//!   sample instant on the host clock, the same stamp OpenIGTLink clients get — `valid`, `x_mm`,
//!   `y_mm`, `z_mm`), or any CSV with `t_s,x_mm,y_mm,z_mm` recorded from the OpenIGTLink side
//!   (a client's TRANSFORM timestamps and translations). Rows with `valid` 0 or an empty
//!   position are gaps.
//! * The reference tracker's recording of the same tool: `t_s,x_mm,y_mm,z_mm` at its own rate,
//!   `t_s` from its own clock (any epoch), in its own frame, occlusions simply missing; with an
//!   optional `host_s`, the instant each sample reached the host (host clock), from which the
//!   latency is measured.
//!
//! Columns are found by name, in any order; other columns are ignored; `#` lines are comments.

use crate::files::{row_error, FileError};
use std::path::Path;

/// A stream of tool positions.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Track {
    /// Sample times, s (strictly increasing).
    pub t_s: Vec<f64>,
    /// When each sample reached the host, host clock, s (tracker recordings only).
    pub host_s: Option<Vec<f64>>,
    /// Tool positions, mm.
    pub p: Vec<[f64; 3]>,
    /// Rows that were gaps (invalid poses, empty positions).
    pub gaps: usize,
    /// Rows skipped because their time did not come after the previous row's (a stream's first
    /// frames read in one burst can share a stamp); at most [`MAX_UNORDERED`] of the rows.
    pub unordered: usize,
}

/// Largest share of rows whose time does not increase that a recording may have (skipped, and
/// counted); more is an error.
pub const MAX_UNORDERED: f64 = 0.01;

impl Track {
    /// Samples.
    pub fn len(&self) -> usize {
        self.t_s.len()
    }

    /// No samples.
    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }
}

/// Read a track from `path`: `t_s`, `x_mm`, `y_mm`, `z_mm` required; `valid` and `host_s` used
/// when present.
pub fn read_track(path: &Path) -> Result<Track, FileError> {
    let text =
        std::fs::read_to_string(path).map_err(|e| FileError::Io { path: path.to_path_buf(), source: e })?;
    let row_error = |line: usize, column: &str, message: String| row_error(path, line, column, message);
    let mut lines =
        text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
    let Some((header_line, header)) = lines.next() else {
        return Err(row_error(1, "t_s", "empty: expected a header with t_s,x_mm,y_mm,z_mm and rows".into()));
    };
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    let find = |name: &str| names.iter().position(|n| *n == name);
    let mut required = [0usize; 4];
    for (slot, name) in required.iter_mut().zip(["t_s", "x_mm", "y_mm", "z_mm"]) {
        *slot = find(name).ok_or_else(|| {
            row_error(
                header_line + 1,
                name,
                format!("no `{name}` column in the header `{header}` (t_s,x_mm,y_mm,z_mm are needed)"),
            )
        })?;
    }
    let (valid_col, host_col) = (find("valid"), find("host_s"));
    let mut track = Track { host_s: host_col.map(|_| Vec::new()), ..Track::default() };
    let mut first_unordered: Option<(usize, f64, f64)> = None;
    for (n, line) in lines {
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        let cell = |c: usize| cells.get(c).copied().unwrap_or("");
        let number = |c: usize| -> Result<f64, FileError> {
            let text = cell(c);
            text.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| row_error(n + 1, names[c], format!("`{text}` is not a number")))
        };
        let t = number(required[0])?;
        let invalid =
            valid_col.is_some_and(|c| cell(c) == "0") || required[1..].iter().any(|&c| cell(c).is_empty());
        if invalid {
            track.gaps += 1;
            continue;
        }
        if let Some(&before) = track.t_s.last() {
            if t <= before {
                first_unordered.get_or_insert((n + 1, t, before));
                track.unordered += 1;
                continue;
            }
        }
        let p = [number(required[1])?, number(required[2])?, number(required[3])?];
        if let (Some(c), Some(host)) = (host_col, track.host_s.as_mut()) {
            let h = number(c)?;
            if host.last().is_some_and(|&b| h < b) {
                return Err(row_error(
                    n + 1,
                    "host_s",
                    format!(
                        "{h} comes before the previous sample's arrival: arrival times must not decrease"
                    ),
                ));
            }
            host.push(h);
        }
        track.t_s.push(t);
        track.p.push(p);
    }
    if let Some((line, t, before)) = first_unordered {
        if track.unordered as f64 > MAX_UNORDERED * (track.len() + track.unordered) as f64 {
            return Err(row_error(
                line,
                "t_s",
                format!(
                    "{t} does not come after the previous sample's {before}, and {} rows in all do not: times must increase (at most {:.0} % of the rows may repeat a time; they are skipped)",
                    track.unordered,
                    MAX_UNORDERED * 100.0
                ),
            ));
        }
    }
    if track.len() < 2 {
        return Err(row_error(
            header_line + 1,
            "t_s",
            format!("{} usable samples; a recording of the motion is needed", track.len()),
        ));
    }
    Ok(track)
}

/// A tracker recording as CSV text (`t_s,x_mm,y_mm,z_mm[,host_s]`).
pub fn track_csv(track: &Track) -> String {
    let mut out = String::from(if track.host_s.is_some() {
        "t_s,x_mm,y_mm,z_mm,host_s\n"
    } else {
        "t_s,x_mm,y_mm,z_mm\n"
    });
    for (k, (t, p)) in track.t_s.iter().zip(&track.p).enumerate() {
        out += &format!("{t:.6},{:.4},{:.4},{:.4}", p[0], p[1], p[2]);
        if let Some(h) = &track.host_s {
            out += &format!(",{:.6}", h[k]);
        }
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(name: &str, text: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("kincal-track-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.csv");
        std::fs::write(&path, text).unwrap();
        path
    }

    #[test]
    fn stream_csv_and_tracker_csv_are_read_by_column_name() {
        let stream = "seq,tick,valid,stale_joints,stale_ticks,x_mm,y_mm,z_mm,zx,zy,zz,xx,xy,xz,t_s,host_s\n\
                      1,5,1,,0,1,2,3,0,0,1,1,0,0,10.0,10.001\n\
                      2,6,0,3,1,,,,,,,,,,10.0013,10.0023\n\
                      3,7,1,,0,1.5,2,3,0,0,1,1,0,0,10.0026,10.0036\n";
        let t = read_track(&file("stream", stream)).unwrap();
        assert_eq!((t.len(), t.gaps), (2, 1));
        assert_eq!(t.p[1], [1.5, 2.0, 3.0]);
        let tracker = Track {
            t_s: vec![1.0, 1.01],
            host_s: Some(vec![5.0, 5.02]),
            p: vec![[1.0, 2.0, 3.0]; 2],
            gaps: 0,
            unordered: 0,
        };
        assert_eq!(read_track(&file("tracker", &track_csv(&tracker))).unwrap(), tracker);
    }

    #[test]
    fn bad_rows_name_line_and_column() {
        let cases = [
            ("a,b\n1,2\n", ":1: column `t_s`", "no `t_s` column"),
            ("t_s,x_mm,y_mm,z_mm\n1,2,3,x\n", ":2: column `z_mm`", "`x` is not a number"),
            ("t_s,x_mm,y_mm,z_mm\n1,2,3,4\n1,2,3,4\n", ":3: column `t_s`", "does not come after"),
            ("t_s,x_mm,y_mm,z_mm\n1,2,3,4\n", ":1: column `t_s`", "1 usable samples"),
        ];
        for (text, at, what) in cases {
            let e = read_track(&file("bad", text)).unwrap_err().to_string();
            assert!(e.contains(at) && e.contains(what), "{text:?}: {e}");
        }
    }
}
