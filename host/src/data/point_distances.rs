//! Reader of frame-free distances between an instrument's points (`kincal-point-distances/1`):
//! the tracker's columns (`pose,q1_deg,…,qN_deg,x_mm,y_mm,z_mm[,sigma_mm|u95_mm][,time_s,temp_C]`)
//! under their own tag line, one file per session, for an instrument whose frame is not kept from
//! point to point (re-levelled between points, a photogrammetry bundle with a free datum, a scale
//! bar): only the distances between the points of one session are measurements
//! ([`crate::calib::terms::point_distance`]). No frame is fitted, and nothing about the
//! instrument's placement is assumed.

use crate::data::observations::{Kind, Observation, Observations, Target};
use crate::data::tracker::read_tagged_session;
use crate::files::FileError;
use std::path::{Path, PathBuf};

/// Format tag of a frame-free distance session (the first line is `# kincal-point-distances/1`).
pub const POINT_DISTANCES_FORMAT: &str = "kincal-point-distances/1";

/// True when the file starts with this format's tag line.
pub fn is_one(path: &Path) -> bool {
    crate::data::tracker::starts_with(path, POINT_DISTANCES_FORMAT)
}

/// Read the sessions `files` of `dir`: one group and one block per file, every row a frame-free
/// point. A file with orientation columns is refused (an orientation needs a frame).
pub fn load_files(dir: &Path, files: &[PathBuf]) -> Result<Observations, FileError> {
    let mut data = Observations::default();
    for f in files {
        let session = read_tagged_session(f, POINT_DISTANCES_FORMAT, &mut data.warnings)?;
        if let Some(row) = session.rows.iter().find(|o| o.orientation().is_some()) {
            return Err(FileError::Row {
                path: f.clone(),
                line: row.line,
                column: "qw".into(),
                message: format!(
                    "{POINT_DISTANCES_FORMAT} takes positions only: an orientation needs a frame"
                ),
            });
        }
        let joints = session.rows[0].q_deg.len();
        if data.joints != 0 && data.joints != joints {
            return Err(FileError::Row {
                path: f.clone(),
                line: session.rows[0].line,
                column: format!("q{}_deg", data.joints.min(joints) + 1),
                message: format!(
                    "{joints} joints here, {} in the other sessions of {}",
                    data.joints,
                    dir.display()
                ),
            });
        }
        data.joints = joints;
        let group = data.push_group(session.name, session.path, Kind::PointDistances);
        data.groups[group].arm = session.arm;
        data.obs.extend(session.rows.into_iter().map(|o| Observation {
            group,
            target: Target::Unframed { xyz_mm: o.point_mm().unwrap_or_default() },
            ..o
        }));
    }
    data.rebuild_blocks();
    Ok(data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_points_as_frame_free_and_refuses_orientations() {
        let dir = std::env::temp_dir().join(format!("kincal-point-distances-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let good = dir.join("bar.csv");
        std::fs::write(&good, "# kincal-point-distances/1\nq1_deg,q2_deg,x_mm,y_mm,z_mm\n0,0,100,0,0\n10,0,0,200,0\n20,5,0,0,300\n")
            .unwrap();
        assert!(is_one(&good) && !crate::data::tracker::starts_with_tag(&good));
        let data = load_files(&dir, std::slice::from_ref(&good)).unwrap();
        assert_eq!((data.joints, data.obs.len(), data.blocks.len()), (2, 3, 1));
        assert_eq!(data.groups[0].kind, Kind::PointDistances);
        assert!(data.obs.iter().all(|o| o.point_mm().is_none() && o.unframed_mm().is_some()));
        assert_eq!(data.point_name(1), "bar:4");
        let oriented = dir.join("probe.csv");
        std::fs::write(
            &oriented,
            "# kincal-point-distances/1\nq1_deg,x_mm,y_mm,z_mm,qw,qx,qy,qz\n0,100,0,0,1,0,0,0\n",
        )
        .unwrap();
        let e = load_files(&dir, &[oriented]).unwrap_err().to_string();
        assert!(e.contains("probe.csv:3: column `qw`") && e.contains("positions only"), "{e}");
        std::fs::remove_dir_all(dir).ok();
    }
}
