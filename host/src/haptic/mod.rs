//! Haptic device (PHANToM) workspace calibration for visuo-haptic AR — building blocks.
//!
//! Follows the workspace-calibration paper (shared/papers):
//! * [`recording`] — the recording folder (`haptic-recording/1`), checked sample by sample;
//! * [`delay`] — tracker ↔ device time delay (chunked Pearson, sub-millisecond peak);
//! * [`pivot`] — tooltip calibration (Tuceryan); absolute orientation (Horn) is
//!   [`crate::geometry::absolute_orientation`];
//! * [`landmarks`] — the landmark-based initial transform (eqs. 1–6);
//! * [`position`] — iterative joint-angle calibration (Harders) with the paper's filters;
//! * [`gimbal`] — gimbal calibration against a reference axis and roll, linear or quadratic
//!   sensor models chosen on held-out error;
//! * [`kinematics`] — the 6-DoF forward kinematics and sensor models.
//!
//! Not built yet: the orientation reference from marker circles (eqs. 12–14, θ6 origin from the
//! gap in the marker-angle histogram), k-means/KD-tree sample selection, the recording simulator,
//! the `kincal haptic` command and its report.

pub mod delay;
pub mod gimbal;
pub mod kinematics;
pub mod landmarks;
pub mod pivot;
pub mod position;
pub mod recording;
