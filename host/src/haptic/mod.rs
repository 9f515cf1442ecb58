//! Haptic device (PHANToM) workspace calibration for visuo-haptic AR.
//!
//! Follows the workspace-calibration paper (shared/papers):
//! * [`recording`] — the recording folder (`haptic-recording/1`), checked sample by sample;
//! * the tracker ↔ device time delay is [`crate::numerics::delay`] (chunked Pearson,
//!   sub-millisecond peak), shared with the dynamic validation of tracker arms;
//! * [`pivot`] — tooltip calibration (Tuceryan); absolute orientation (Horn) is
//!   [`crate::numerics::geometry::absolute_orientation`];
//! * [`landmarks`] — the landmark-based initial transform (eqs. 1–6);
//! * [`position`] — iterative joint-angle calibration (Harders) with the paper's filters;
//! * [`reference`](mod@reference) — the orientation reference from the roll step (marker circles, axis by SVD,
//!   eq. 14, θ6 origin from the gap in the marker angles);
//! * [`gimbal`] — gimbal calibration against a reference axis and roll, linear or quadratic
//!   sensor models chosen on held-out error;
//! * [`kinematics`] — the 6-DoF forward kinematics and sensor models.
//!
//! * [`pipeline`] — the whole procedure over a recording; [`simulate`] — recordings with known
//!   truth.
//!
//! * [`clean`] — wild tracker samples; [`report_data`] — where the held-out errors are.
//! * [`select`] — k-means sample selection (N = 200, seeded, re-clustered every iteration).

pub mod clean;
pub mod gimbal;
pub mod kinematics;
pub mod landmarks;
pub mod pipeline;
pub mod pivot;
pub mod position;
pub mod recording;
pub mod reference;
pub mod report_data;
pub mod select;
pub mod simulate;
