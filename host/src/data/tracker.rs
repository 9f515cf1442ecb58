//! Tracker sessions (`kincal-tracker/1`): points (and optionally orientations) of the arm's tool
//! measured by a laser tracker, an optical tracker or a 6-DoF probe, one CSV file per session.
//!
//! A session is one placement of the instrument: every row of a file shares one unknown
//! instrument ← robot base. A file starts with the tag line `# kincal-tracker/1` (further `#`
//! lines are comments), then a header row:
//!
//! ```text
//! # kincal-tracker/1
//! pose,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm,u95_mm
//! 1,10.0,-20.0,35.0,0.0,40.0,5.0,1234.567,-45.678,890.123,0.012
//! ```
//!
//! Required: `q1_deg … qN_deg` (joint angles as the controller reports them, N = 1…12; or
//! `q1_rad … qN_rad` for radians, as ROS `joint_states` gives them, converted to degrees) and
//! `x_mm, y_mm, z_mm` (the tool point in the instrument frame). A session of at least
//! [`RADIANS_MIN_ROWS`] rows whose degree columns all stay within ±2π holds radians, not degrees:
//! it is refused, naming the file and the columns to rename. Optional: `qw, qx, qy, qz` (the
//! probe's orientation in the instrument frame, scalar first), `sigma_mm` or `u95_mm` (the
//! instrument's stated uncertainty; σ = U95/2), `time_s`, `temp_C`, `pose` (rows with the same
//! pose id are repeats of one arm pose). Any other column is named in a warning and ignored.
//! A comment line `# arm: ID` before the header names the arm the session was measured on (its
//! controller's identity, as `kincal record` writes it into artefact sessions): a calibration
//! refuses sessions of two arms.
//! A folder is a tracker folder when it holds `*.csv` files whose first line is the tag.
//!
//! `kincal-tracker/2` is the same with named joints, for a branched robot (several tips) or any
//! URDF model: the joint columns are `<URDF joint name>_deg` (or `_rad`), in any order and for
//! every joint of the model's tree, and a column `tip` names the tip (a URDF link of the
//! model's `--tip` list) each row's point belongs to (without it, every row is the first tip's).
//! The angles are put in the model's joint order when the model is known
//! ([`crate::data::Observations::bind`]). docs/src/humanoid-data.md has an example.

use crate::data::{ColumnNames, Joints, Kind, Observation, Observations, Target};
use crate::files::{row_error, FileError};
use crate::model::MAX_JOINTS;
use crate::trace::ArmIdentity;
use nalgebra::{UnitQuaternion, Vector3};
use std::path::{Path, PathBuf};

/// The tag line every tracker CSV starts with.
pub const TRACKER_FORMAT: &str = "kincal-tracker/1";
/// The tag line of tracker CSVs with named joint columns and a `tip` column.
pub const NAMED_TRACKER_FORMAT: &str = "kincal-tracker/2";
/// Smallest spread of a session's points, mm, below which its lengths are taken for metres.
pub const MIN_SESSION_SPAN_MM: f64 = 5.0;
/// Largest plausible coordinate, mm (a tracker measures within tens of metres).
pub const MAX_COORDINATE_MM: f64 = 100_000.0;
/// Fewest rows of a session whose degree columns, all within ±2π, are taken for radians.
pub const RADIANS_MIN_ROWS: usize = 5;
/// How far a quaternion's norm may be from 1 before the row is refused.
pub const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;

/// True when `dir` holds a tracker session file (a `*.csv` starting with the tag line).
pub fn is_tracker_folder(dir: &Path) -> bool {
    csv_files(dir).is_ok_and(|files| files.iter().any(|f| starts_with_tag(f)))
}

/// True when the file's first line is a tracker tag line (either version).
pub fn starts_with_tag(path: &Path) -> bool {
    starts_with(path, TRACKER_FORMAT) || starts_with(path, NAMED_TRACKER_FORMAT)
}

/// True when the file's first line is `# FORMAT`.
pub fn starts_with(path: &Path, format: &str) -> bool {
    std::fs::read_to_string(path).is_ok_and(|t| text_starts_with(&t, format))
}

/// True when `text`'s first line is `# FORMAT`.
fn text_starts_with(text: &str, format: &str) -> bool {
    text.lines().next().is_some_and(|l| l.trim_start_matches('\u{feff}').trim() == tag_line(format))
}

fn tag_line(format: &str) -> String {
    format!("# {format}")
}

/// Least stated σ of a point, mm: a tenth of a micrometre, beyond any instrument's.
pub const MIN_SIGMA_MM: f64 = 1e-4;

/// Largest |time_s|, s (over 3000 years: Unix seconds are 1.8e9).
pub const MAX_TIME_S: f64 = 1e11;

/// The `*.csv` files of `dir` (any case), sorted by name. An entry so named that is
/// not a regular file (a folder, a FIFO, a device, a dangling link) is refused, naming it, never
/// skipped.
pub fn csv_files(dir: &Path) -> Result<Vec<PathBuf>, FileError> {
    let io = |source| FileError::Io { path: dir.to_owned(), source };
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let path = entry.map_err(io)?.path();
        if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("csv")) {
            crate::files::check_regular_file(&path)?;
            files.push(path);
        }
    }
    files.sort();
    Ok(files)
}

/// Which column holds what.
#[derive(Default)]
struct Layout {
    q: Vec<usize>,
    /// The joint columns are `qN_rad`: radians, converted to degrees.
    radians: bool,
    xyz: [usize; 3],
    quaternion: Option<[usize; 4]>,
    sigma: Option<(usize, f64)>,
    time: Option<usize>,
    temp: Option<usize>,
    pose: Option<usize>,
    /// `kincal-tracker/2`: the joint names of the `q` columns, and the `tip` column.
    names: Vec<String>,
    tip: Option<usize>,
}

fn layout(
    path: &Path,
    line: usize,
    header: &[&str],
    named: bool,
    warnings: &mut Vec<String>,
) -> Result<Layout, FileError> {
    let row = |column: &str, message: String| row_error(path, line, column, message);
    for (k, h) in header.iter().enumerate() {
        if header[..k].contains(h) {
            return Err(row(h, "named twice in the header".into()));
        }
    }
    let mut out = Layout::default();
    if named {
        named_joints(path, line, header, &mut out)?;
    } else {
        numbered_joints(path, line, header, &mut out)?;
    }
    rest(path, line, header, out, warnings)
}

/// The joint columns `<joint>_deg` (or `_rad`) of a `kincal-tracker/2` header, and its `tip`.
fn named_joints(path: &Path, line: usize, header: &[&str], out: &mut Layout) -> Result<(), FileError> {
    let row = |column: &str, message: String| row_error(path, line, column, message);
    const OTHER: [&str; 4] = ["x_mm", "y_mm", "z_mm", "sigma_mm"];
    let mut units = Vec::new();
    for (c, h) in header.iter().enumerate().filter(|(_, h)| !OTHER.contains(h)) {
        for (unit, radians) in [("_deg", false), ("_rad", true)] {
            if let Some(name) = h.strip_suffix(unit).filter(|n| !n.is_empty()) {
                out.q.push(c);
                out.names.push(name.to_string());
                units.push(radians);
            }
        }
    }
    if out.q.is_empty() {
        return Err(row("header", "no joint column: expected <joint>_deg (or <joint>_rad) per joint".into()));
    }
    if out.q.len() > crate::model::MAX_TREE_JOINTS {
        return Err(row(header[out.q[0]], format!("at most {} joints", crate::model::MAX_TREE_JOINTS)));
    }
    if units.iter().any(|r| *r != units[0]) {
        return Err(row(
            header[out.q[0]],
            "give every joint in degrees (_deg) or every joint in radians (_rad)".into(),
        ));
    }
    out.radians = units[0];
    out.tip = header.iter().position(|h| *h == "tip");
    Ok(())
}

/// The joint columns `q1_deg … qN_deg` (or `_rad`) of a `kincal-tracker/1` header.
fn numbered_joints(path: &Path, line: usize, header: &[&str], out: &mut Layout) -> Result<(), FileError> {
    let row = |column: &str, message: String| row_error(path, line, column, message);
    let find = |name: &str| header.iter().position(|h| *h == name);
    let any = |unit: &str| (1..=MAX_JOINTS + 1).any(|j| find(&format!("q{j}_{unit}")).is_some());
    out.radians = match (any("deg"), any("rad")) {
        (true, true) => {
            return Err(row(
                "q1_rad",
                "give every joint in degrees (qN_deg) or every joint in radians (qN_rad), not both".into(),
            ))
        }
        (deg, rad) => rad && !deg,
    };
    let unit = if out.radians { "rad" } else { "deg" };
    for j in 1..=MAX_JOINTS + 1 {
        match find(&format!("q{j}_{unit}")) {
            Some(c) if j <= MAX_JOINTS => out.q.push(c),
            Some(_) => return Err(row(&format!("q{j}_{unit}"), format!("at most {MAX_JOINTS} joints"))),
            None => break,
        }
    }
    if out.q.is_empty() {
        return Err(row(
            "q1_deg",
            "missing: expected joint columns q1_deg … qN_deg (degrees) or q1_rad … qN_rad (radians)".into(),
        ));
    }
    let gap = out.q.len() + 1;
    if let Some(later) = (gap + 1..=MAX_JOINTS).find(|j| find(&format!("q{j}_{unit}")).is_some()) {
        return Err(row(
            &format!("q{gap}_{unit}"),
            format!(
                "missing, while q{later}_{unit} is there: expected joint columns q1_{unit} … qN_{unit} without a gap"
            ),
        ));
    }
    Ok(())
}

/// The point, orientation and optional columns of a header, with its joint columns in `out`.
fn rest(
    path: &Path,
    line: usize,
    header: &[&str],
    mut out: Layout,
    warnings: &mut Vec<String>,
) -> Result<Layout, FileError> {
    let row = |column: &str, message: String| row_error(path, line, column, message);
    let find = |name: &str| header.iter().position(|h| *h == name);
    for (k, name) in ["x_mm", "y_mm", "z_mm"].iter().enumerate() {
        out.xyz[k] =
            find(name).ok_or_else(|| row(name, "missing: the measured point x_mm, y_mm, z_mm".into()))?;
    }
    let quaternion: Vec<Option<usize>> = ["qw", "qx", "qy", "qz"].iter().map(|n| find(n)).collect();
    if quaternion.iter().any(Option::is_some) {
        let mut q = [0; 4];
        for (k, name) in ["qw", "qx", "qy", "qz"].iter().enumerate() {
            q[k] = quaternion[k]
                .ok_or_else(|| row(name, "missing: an orientation needs all of qw, qx, qy, qz".into()))?;
        }
        out.quaternion = Some(q);
    }
    out.sigma = match (find("sigma_mm"), find("u95_mm")) {
        (Some(_), Some(_)) => return Err(row("u95_mm", "give sigma_mm or u95_mm, not both".into())),
        (Some(c), None) => Some((c, 1.0)),
        (None, Some(c)) => Some((c, 0.5)),
        (None, None) => None,
    };
    out.time = find("time_s");
    out.temp = find("temp_C");
    out.pose = find("pose");
    let known: Vec<usize> = out
        .q
        .iter()
        .chain(&out.xyz)
        .chain(out.quaternion.iter().flatten())
        .copied()
        .chain(out.sigma.map(|s| s.0))
        .chain(out.time)
        .chain(out.temp)
        .chain(out.pose)
        .chain(out.tip)
        .collect();
    let unknown: Vec<&str> = (0..header.len()).filter(|c| !known.contains(c)).map(|c| header[c]).collect();
    if !unknown.is_empty() {
        warnings.push(format!(
            "{}: column{} {} not a {TRACKER_FORMAT} column, ignored",
            path.display(),
            if unknown.len() == 1 { " is" } else { "s are" },
            unknown.iter().map(|u| format!("`{u}`")).collect::<Vec<_>>().join(", ")
        ));
    }
    Ok(out)
}

/// A session file read: its name and its rows as observations of group 0.
pub struct SessionFile {
    /// File name without `.csv`.
    pub name: String,
    /// The file.
    pub path: PathBuf,
    /// Rows in file order.
    pub rows: Vec<Observation>,
    /// The arm a `# arm: ID` line names.
    pub arm: Option<ArmIdentity>,
    /// `kincal-tracker/2`: the joints of the angle columns (file order) and the tips (the rows'
    /// `tip` index this list); empty for `kincal-tracker/1`.
    pub names: Option<ColumnNames>,
}

/// The arm a `# arm: ID` comment line before the header names, checked (the line and the
/// column `arm` named when it is not an identity).
fn arm_line(path: &Path, text: &str) -> Result<Option<ArmIdentity>, FileError> {
    let comments = text
        .lines()
        .enumerate()
        .skip(1)
        .take_while(|(_, l)| l.trim().is_empty() || l.trim_start().starts_with('#'));
    for (k, line) in comments {
        let body = line.trim().trim_start_matches('#').trim();
        let Some((key, value)) = body.split_once(':') else { continue };
        if !key.trim().eq_ignore_ascii_case("arm") {
            continue;
        }
        let arm = ArmIdentity::of(value.trim());
        arm.check().map_err(|(_, message)| crate::files::row_error(path, k + 1, "arm", message))?;
        return Ok(Some(arm));
    }
    Ok(None)
}

/// Read one session file.
pub fn read_session(path: &Path, warnings: &mut Vec<String>) -> Result<SessionFile, FileError> {
    let text = read_text(path)?;
    let format =
        if text_starts_with(&text, NAMED_TRACKER_FORMAT) { NAMED_TRACKER_FORMAT } else { TRACKER_FORMAT };
    parse_session(path, &text, format, warnings)
}

fn read_text(path: &Path) -> Result<String, FileError> {
    std::fs::read_to_string(path).map_err(|source| FileError::Io { path: path.to_owned(), source })
}

/// Read one file of the tracker's columns whose tag line is `# FORMAT` (other readers of
/// instrument points share the columns).
pub fn read_tagged_session(
    path: &Path,
    format: &str,
    warnings: &mut Vec<String>,
) -> Result<SessionFile, FileError> {
    parse_session(path, &read_text(path)?, format, warnings)
}

/// [`read_tagged_session`] of the file's `text`.
fn parse_session(
    path: &Path,
    text: &str,
    format: &str,
    warnings: &mut Vec<String>,
) -> Result<SessionFile, FileError> {
    let row_error = |line: usize, column: &str, message: String| row_error(path, line, column, message);
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(k, l)| (k + 1, l.trim_start_matches('\u{feff}').trim_end_matches('\r')));
    match lines.next() {
        Some((_, first)) if first.trim() == tag_line(format) => {}
        first => {
            return Err(row_error(
                1,
                "format",
                format!(
                    "expected the tag line \"{}\", found \"{}\"",
                    tag_line(format),
                    first.map_or("", |f| f.1).chars().take(60).collect::<String>()
                ),
            ))
        }
    }
    let mut lines = lines.filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
    let (header_line, header) =
        lines.next().ok_or_else(|| row_error(2, "header", "missing header row".into()))?;
    let mut header_cells = Vec::new();
    split_cells(header, &mut header_cells);
    let header = header_cells;
    let layout = layout(path, header_line, &header, format == NAMED_TRACKER_FORMAT, warnings)?;
    let mut points = Vec::new();
    let mut tips: Vec<String> = Vec::new();
    // One row's cells and angles, their buffers kept from row to row.
    let mut cells: Vec<&str> = Vec::with_capacity(header.len());
    let mut q = Vec::with_capacity(layout.q.len());
    for (line, text) in lines {
        split_cells(text, &mut cells);
        if cells.len() != header.len() {
            return Err(row_error(
                line,
                header.get(cells.len().min(header.len().saturating_sub(1))).copied().unwrap_or("?"),
                format!("expected {} cells as in the header, found {}", header.len(), cells.len()),
            ));
        }
        let number = |c: usize| -> Result<f64, FileError> {
            let v: f64 = cells[c].parse().map_err(|_| {
                row_error(line, header[c], format!("expected a number, found \"{}\"", cells[c]))
            })?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(row_error(line, header[c], format!("expected a finite number, found \"{}\"", cells[c])))
            }
        };
        let optional = |c: Option<usize>| -> Result<Option<f64>, FileError> {
            match c {
                Some(c) if !cells[c].is_empty() => number(c).map(Some),
                _ => Ok(None),
            }
        };
        q.clear();
        for &c in &layout.q {
            let v = if layout.radians { number(c)?.to_degrees() } else { number(c)? };
            if v.abs() > 3600.0 {
                return Err(row_error(
                    line,
                    header[c],
                    format!("{v} degrees is beyond ten turns: another unit?"),
                ));
            }
            q.push(v);
        }
        let q_deg = Joints::new(&q).ok_or_else(|| row_error(line, "q1_deg", "no joint angle".into()))?;
        let tip = match layout.tip.map(|c| cells[c]) {
            Some("") => return Err(row_error(line, "tip", "empty: expected the tip's name".into())),
            Some(name) => match tips.iter().position(|t| t == name) {
                Some(t) => t,
                None => {
                    tips.push(name.to_string());
                    tips.len() - 1
                }
            },
            None => 0,
        };
        let mut xyz = [0.0; 3];
        for k in 0..3 {
            xyz[k] = number(layout.xyz[k])?;
            if xyz[k].abs() > MAX_COORDINATE_MM {
                return Err(row_error(
                    line,
                    header[layout.xyz[k]],
                    format!("{} mm is beyond any tracker's range (|value| <= {MAX_COORDINATE_MM})", xyz[k]),
                ));
            }
        }
        let orientation = match layout.quaternion {
            Some(cols) => {
                let q = [number(cols[0])?, number(cols[1])?, number(cols[2])?, number(cols[3])?];
                let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
                if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
                    return Err(row_error(
                        line,
                        "qw",
                        format!(
                            "the quaternion (qw, qx, qy, qz) has norm {norm:.6}; expected a unit quaternion"
                        ),
                    ));
                }
                Some(UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3])))
            }
            None => None,
        };
        let sigma_mm = match layout.sigma {
            Some((c, factor)) => match optional(Some(c))? {
                Some(v) if (MIN_SIGMA_MM / factor..100.0).contains(&v) => Some(v * factor),
                Some(v) => {
                    return Err(row_error(
                        line,
                        header[c],
                        format!(
                            "expected {} <= value < 100 mm (no instrument is sure to a tenth of a µm: a zero σ would \
                             make a zero floor), found {v}",
                            MIN_SIGMA_MM / factor
                        ),
                    ));
                }
                None => None,
            },
            None => None,
        };
        let time_s = optional(layout.time)?;
        if let (Some(t), Some(c)) = (time_s, layout.time) {
            if t.abs() > MAX_TIME_S {
                return Err(row_error(
                    line,
                    header[c],
                    format!(
                        "expected seconds within ±{MAX_TIME_S:e} (over 3000 years), found {t:e}: another unit?"
                    ),
                ));
            }
        }
        points.push(Observation {
            block: 0,
            group: 0,
            repeat: 1,
            q_deg,
            q_sigma_deg: None,
            target: Target::Point { xyz_mm: Vector3::from(xyz), orientation },
            sigma_mm,
            time_s,
            temp_c: optional(layout.temp)?,
            // Two tips' points of one arm pose are no repeats of one point: the id names the tip too.
            pose: layout.pose.map(|c| cells[c].to_string()).filter(|p| !p.is_empty()).map(|p| {
                match layout.tip {
                    Some(t) => format!("{p}/{}", cells[t]),
                    None => p,
                }
            }),
            line,
            tip,
        });
    }
    if points.is_empty() {
        return Err(row_error(header_line, "header", "no data rows after the header".into()));
    }
    let largest_deg = points.iter().flat_map(|p| p.q_deg.iter()).fold(0.0_f64, |a, v| a.max(v.abs()));
    if !layout.radians && points.len() >= RADIANS_MIN_ROWS && largest_deg <= std::f64::consts::TAU {
        let n = layout.q.len();
        return Err(row_error(
            header_line,
            header[layout.q[0]],
            format!(
                "every joint angle of the session's {} rows lies within ±2π (the largest is {largest_deg:.3}): \
                 these are radians (ROS joint_states), not degrees; name the columns q1_rad … q{n}_rad to have \
                 kincal convert them, or write degrees",
                points.len()
            ),
        ));
    }
    if points.len() >= 4 {
        let (lo, hi) = points.iter().fold(
            (Vector3::repeat(f64::INFINITY), Vector3::repeat(f64::NEG_INFINITY)),
            |(lo, hi), p| {
                let p = p.point_mm().unwrap_or_default();
                (lo.inf(&p), hi.sup(&p))
            },
        );
        let span = (hi - lo).norm();
        if span < MIN_SESSION_SPAN_MM {
            return Err(row_error(
                points[0].line,
                "x_mm",
                format!(
                    "the session's points span only {span:.4} mm: lengths must be in millimetres (metres?), \
                     and a session must move the arm"
                ),
            ));
        }
    }
    let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let names = (format == NAMED_TRACKER_FORMAT).then(|| ColumnNames {
        joints: layout.names.clone(),
        tips: if layout.tip.is_some() { tips } else { Vec::new() },
        source: path.to_owned(),
    });
    Ok(SessionFile { name, path: path.to_owned(), rows: points, arm: arm_line(path, text)?, names })
}

/// Split a CSV row at its commas into `cells`, each trimmed, as `row.split(',').map(str::trim)`
/// does; the commas found eight bytes at a time (the cells are short: a search per cell cost more
/// than a scan, and a scan of single bytes was a fifth of the parse), and a cell that starts and
/// ends in a visible ASCII character is taken as it is. A comma is one byte in UTF-8, never part
/// of another character's bytes, so each cut is at a character's boundary.
fn split_cells<'a>(row: &'a str, cells: &mut Vec<&'a str>) {
    let trim = |cell: &'a str| match (cell.as_bytes().first(), cell.as_bytes().last()) {
        (Some(first), Some(last)) if first.is_ascii_graphic() && last.is_ascii_graphic() => cell,
        _ => cell.trim(),
    };
    cells.clear();
    let bytes = row.as_bytes();
    let (words, _) = bytes.as_chunks::<8>();
    let mut start = 0;
    for (w, word) in words.iter().enumerate() {
        let mut commas = comma_bytes(u64::from_le_bytes(*word));
        while commas != 0 {
            let k = 8 * w + (commas.trailing_zeros() / 8) as usize;
            cells.push(trim(&row[start..k]));
            start = k + 1;
            commas &= commas - 1;
        }
    }
    for k in 8 * words.len()..bytes.len() {
        if bytes[k] == b',' {
            cells.push(trim(&row[start..k]));
            start = k + 1;
        }
    }
    cells.push(trim(&row[start..]));
}

/// The high bit of each byte of `word` that is a comma, and no other bit. The usual
/// `(x − 0x01…) & !x` test also marks a byte above a zero one that held 0x01 (a `-` after a
/// comma); here no carry crosses from byte to byte.
fn comma_bytes(word: u64) -> u64 {
    const LOW_SEVEN: u64 = 0x7f7f_7f7f_7f7f_7f7f;
    // Zero exactly where the byte is a comma.
    let x = word ^ 0x2c2c_2c2c_2c2c_2c2c;
    // Each byte 0xff where x's byte is not zero, 0x7f where it is.
    !(((x & LOW_SEVEN) + LOW_SEVEN) | x | LOW_SEVEN)
}

/// Read every tracker session of `dir` (each `*.csv` file; files without the tag are refused):
/// one group and one block per session.
pub fn load_dir(dir: &Path) -> Result<Observations, FileError> {
    load_files(dir, &csv_files(dir)?)
}

/// Read the tracker sessions `files` of `dir` (files without the tag are refused).
pub fn load_files(dir: &Path, files: &[PathBuf]) -> Result<Observations, FileError> {
    if files.is_empty() {
        return Err(FileError::Field {
            path: dir.to_owned(),
            field: "*.csv".into(),
            message: format!(
                "no tracker session files (*.csv starting with \"# {TRACKER_FORMAT}\") in this folder"
            ),
        });
    }
    let mut data = Observations::default();
    let mut first: Option<(usize, PathBuf)> = None;
    for f in files {
        let session = read_session(f, &mut data.warnings)?;
        let b = session.rows[0].q_deg.len();
        if let Some((a, path)) = &first {
            if *a != b {
                return Err(FileError::Row {
                    path: f.clone(),
                    line: session.rows[0].line,
                    column: format!("q{}_deg", a.min(&b) + 1),
                    message: format!("{b} joints here, {a} in {}", path.display()),
                });
            }
        } else {
            first = Some((b, f.clone()));
        }
        let tips = merge_names(&mut data.names, session.names, f)?;
        let group = data.push_group(session.name, session.path, Kind::Tracker);
        data.groups[group].arm = session.arm;
        data.obs.extend(session.rows.into_iter().map(|o| Observation {
            group,
            tip: tips.get(o.tip).copied().unwrap_or(0),
            ..o
        }));
    }
    data.joints = first.map_or(0, |f| f.0);
    data.rebuild_blocks();
    Ok(data)
}

/// Merge a session's names into the folder's: the same joint columns in the same order as the
/// first file, the tips added to the folder's list. Returns the folder's tip index of each of the
/// session's tips.
fn merge_names(
    folder: &mut Option<ColumnNames>,
    session: Option<ColumnNames>,
    path: &Path,
) -> Result<Vec<usize>, FileError> {
    let mismatch =
        |message: String| FileError::Row { path: path.to_owned(), line: 2, column: "header".into(), message };
    let (Some(all), Some(mine)) = (folder.as_mut(), session.as_ref()) else {
        return match (folder.is_some(), session) {
            (false, Some(mine)) if !mine.tips.is_empty() || !mine.joints.is_empty() => {
                let tips = (0..mine.tips.len()).collect();
                *folder = Some(mine);
                Ok(tips)
            }
            (true, None) => Err(mismatch(format!(
                "a {TRACKER_FORMAT} file among {NAMED_TRACKER_FORMAT} files: name the joint columns in every file"
            ))),
            _ => Ok(Vec::new()),
        };
    };
    if all.joints != mine.joints {
        return Err(mismatch(format!(
            "the joint columns differ from those of {}: expected {} in that order",
            all.source.display(),
            all.joints.iter().map(|j| format!("{j}_deg")).collect::<Vec<_>>().join(", ")
        )));
    }
    Ok(mine
        .tips
        .iter()
        .map(|t| match all.tips.iter().position(|a| a == t) {
            Some(k) => k,
            None => {
                all.tips.push(t.clone());
                all.tips.len() - 1
            }
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn folder(name: &str, files: &[(&str, &str)]) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("kincal-tracker-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        for (f, text) in files {
            std::fs::write(dir.join(f), text).unwrap();
        }
        dir
    }

    const GOOD: &str = "# kincal-tracker/1\n# a comment\npose,q1_deg,q2_deg,x_mm,y_mm,z_mm,u95_mm,note\n\
                        1,0,10,100,0,0,0.02,a\n1,0,10,100.01,0,0,0.02,b\n2,30,10,0,200,0,,c\n3,60,-10,0,0,300,0.02,d\n";

    #[test]
    fn reads_a_session_and_warns_about_foreign_columns() {
        let dir = folder("good", &[("day1.csv", GOOD)]);
        assert!(is_tracker_folder(&dir));
        let data = load_dir(&dir).unwrap();
        assert_eq!(data.joints, 2);
        let s = &data.obs;
        assert_eq!((data.groups[0].name.as_str(), s.len(), data.blocks.len()), ("day1", 4, 1));
        assert_eq!(s[0].sigma_mm, Some(0.01));
        assert_eq!(s[2].sigma_mm, None);
        assert_eq!(s[1].pose.as_deref(), Some("1"));
        assert_eq!(s[3].line, 7);
        assert!(data.warnings.iter().any(|w| w.contains("`note`")), "{:?}", data.warnings);
        std::fs::remove_dir_all(dir).ok();
    }

    /// A `# arm: ID` line before the header names the session's arm; without one it names none.
    #[test]
    fn a_session_names_its_arm_in_a_comment_line() {
        let named = GOOD.replace("# a comment", "# a comment\n#  Arm :  lab-arm-2 ");
        let dir = folder("arm", &[("a.csv", &named), ("b.csv", GOOD)]);
        let data = load_dir(&dir).unwrap();
        let arms: Vec<_> = data.groups.iter().map(|g| g.arm.as_ref().map(|a| a.id.as_str())).collect();
        assert_eq!(arms, [Some("lab-arm-2"), None]);
        std::fs::remove_dir_all(dir).ok();
    }

    #[test]
    fn bad_rows_name_the_file_line_and_column() {
        let cases = [
            (GOOD.replace("2,30,10,0,200", "2,30,ten,0,200"), ":6: column `q2_deg`", "number"),
            (GOOD.replace("# kincal-tracker/1\n", ""), ":1: column `format`", "tag line"),
            (GOOD.replace(",x_mm", ",xx_mm"), ":3: column `x_mm`", "missing"),
            (GOOD.replace("3,60,-10,0,0,300,0.02,d", "3,60,-10,0,0"), ":7:", "cells"),
            (GOOD.replace("100.01", "inf"), ":5: column `x_mm`", "finite"),
            (GOOD.replace("u95_mm,note", "sigma_mm,u95_mm"), ":3: column `u95_mm`", "not both"),
            (GOOD.replace("# a comment", "# arm: lab arm 2"), ":2: column `arm`", "not an arm identity"),
        ];
        for (k, (text, place, what)) in cases.iter().enumerate() {
            let dir = folder(&format!("bad{k}"), &[("s.csv", text)]);
            let e = load_dir(&dir).unwrap_err().to_string();
            assert!(e.contains(&format!("s.csv{place}")) && e.contains(what), "case {k}: {e}");
            std::fs::remove_dir_all(dir).ok();
        }
        let metres =
            "# kincal-tracker/1\nq1_deg,x_mm,y_mm,z_mm\n0,0.1,0,0\n10,0.2,0,0\n20,0.3,0,0\n30,0.4,0.1,0\n";
        let dir = folder("metres", &[("m.csv", metres)]);
        let e = load_dir(&dir).unwrap_err().to_string();
        assert!(e.contains("m.csv:3") && e.contains("metres"), "{e}");
        std::fs::remove_dir_all(dir).ok();
        let both = GOOD.replace("q2_deg", "q2_rad");
        let dir = folder("both", &[("b.csv", &both)]);
        let e = load_dir(&dir).unwrap_err().to_string();
        assert!(e.contains("b.csv:3: column `q1_rad`") && e.contains("not both"), "{e}");
        std::fs::remove_dir_all(dir).ok();
        let q = "# kincal-tracker/1\nq1_deg,x_mm,y_mm,z_mm,qw,qx,qy,qz\n0,1,2,3,1,0,0,0.5\n";
        let dir = folder("quat", &[("q.csv", q)]);
        let e = load_dir(&dir).unwrap_err().to_string();
        assert!(e.contains("q.csv:3: column `qw`") && e.contains("unit quaternion"), "{e}");
        std::fs::remove_dir_all(dir).ok();
    }

    /// The file is read once and its tag line picks the format: a `kincal-tracker/2` file (after a
    /// byte-order mark) is read with named joints, and its bad cells and an unreadable file are
    /// named as before.
    #[test]
    fn the_tag_line_read_with_the_rows_picks_the_format() {
        let named = "\u{feff}# kincal-tracker/2\nshoulder_deg,elbow_deg,x_mm,y_mm,z_mm,tip\n\
                     0,10,100,0,0,hand\n30,10,0,200,0,hand\n60,-10,0,0,300,hand\n";
        let dir = folder("named", &[("n.csv", named), ("bad.csv", &named.replace("30,10", "30,ten"))]);
        let mut warnings = Vec::new();
        let session = read_session(&dir.join("n.csv"), &mut warnings).unwrap();
        let names = session.names.expect("kincal-tracker/2 names its joints");
        assert_eq!(
            (names.joints, names.tips),
            (vec!["shoulder".into(), "elbow".into()], vec!["hand".into()])
        );
        assert_eq!((session.rows.len(), session.rows[1].q_deg[0], session.rows[2].line), (3, 30.0, 5));
        let e = read_session(&dir.join("bad.csv"), &mut warnings).err().expect("a bad cell").to_string();
        assert!(e.contains("bad.csv:4: column `elbow_deg`") && e.contains("\"ten\""), "{e}");
        let missing = dir.join("missing.csv");
        let e = read_session(&missing, &mut warnings).err().expect("no file");
        assert!(matches!(&e, FileError::Io { path, .. } if *path == missing), "{e}");
        std::fs::remove_dir_all(dir).ok();
    }

    /// The cells are those of `split(',')` and `trim`, whatever the spaces and empty cells.
    #[test]
    fn cells_are_split_and_trimmed_as_split_and_trim_do() {
        let rows = [
            "",
            ",",
            "a",
            "1,2.5,-3e2",
            " 1 ,\t2\t, 3,",
            ",,x,, ,",
            "\u{a0}é,ü\u{2003},\u{feff}q ,  ",
            "pose,q1_deg, x_mm ,y_mm,z_mm,,",
        ];
        let mut cells = vec!["left over"];
        for row in rows {
            split_cells(row, &mut cells);
            let expected: Vec<&str> = row.split(',').map(str::trim).collect();
            assert_eq!(cells, expected, "{row:?}");
        }
        // Rows of every length from characters that test each byte of a word: a comma, a minus
        // (one above a comma's byte), spaces, and characters of two and three bytes.
        let alphabet = [",", "-", "1", " ", "\t", "é", "\u{a0}", "\u{2003}", ",-", "x"];
        let mut rng = 0x9e37_79b9_7f4a_7c15_u64;
        for k in 0..20_000 {
            let mut row = String::new();
            for _ in 0..k % 41 {
                rng ^= rng << 13;
                rng ^= rng >> 7;
                rng ^= rng << 17;
                row.push_str(alphabet[(rng % alphabet.len() as u64) as usize]);
            }
            let mut cells = Vec::new();
            split_cells(&row, &mut cells);
            let expected: Vec<&str> = row.split(',').map(str::trim).collect();
            assert_eq!(cells, expected, "{row:?}");
        }
        for byte in 0..=255u8 {
            let word = u64::from_le_bytes([byte, b',', byte, b'-', 0x2d, 0x01, b',', 0x2c ^ 0x80]);
            let expected = (0..8).fold(0, |bits, k| {
                let b = word.to_le_bytes()[k];
                bits | if b == b',' { 0x80 << (8 * k) } else { 0 }
            });
            assert_eq!(comma_bytes(word), expected, "{word:#x}");
        }
    }

    /// ROS joint_states in radians: read as degrees they would be a session that barely moves.
    const RADIANS: &str = "# kincal-tracker/1\npose,q1_deg,q2_deg,x_mm,y_mm,z_mm\n1,0.1,-1.2,100,0,0\n\
                           2,0.5,1.3,0,200,0\n3,-2.9,0.2,0,0,300\n4,3.1,-0.7,10,20,30\n5,1.7,2.2,40,0,90\n";

    #[test]
    fn radians_in_degree_columns_are_refused_and_radian_columns_converted() {
        let dir = folder("radians", &[("ros.csv", RADIANS)]);
        let e = load_dir(&dir).unwrap_err().to_string();
        assert!(
            e.contains("ros.csv:2: column `q1_deg`")
                && e.contains("within ±2π")
                && e.contains("q1_rad … q2_rad"),
            "{e}"
        );
        std::fs::remove_dir_all(dir).ok();
        let dir = folder("rad-columns", &[("ros.csv", &RADIANS.replace("_deg", "_rad"))]);
        let data = load_dir(&dir).unwrap();
        assert!((data.obs[2].q_deg[0] - (-2.9_f64).to_degrees()).abs() < 1e-12, "{:?}", data.obs[2].q_deg);
        assert!((data.obs[4].q_deg[1] - 2.2_f64.to_degrees()).abs() < 1e-12);
        std::fs::remove_dir_all(dir).ok();
        // Four rows cannot tell: a short session in degrees within ±2π is read as it is.
        let short: String = RADIANS.lines().take(6).map(|l| format!("{l}\n")).collect();
        let dir = folder("rad-short", &[("s.csv", &short)]);
        assert_eq!(load_dir(&dir).unwrap().obs.len(), 4);
        std::fs::remove_dir_all(dir).ok();
    }
}
