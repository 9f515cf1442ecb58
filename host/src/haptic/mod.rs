//! Haptic device (PHANToM) workspace calibration for visuo-haptic AR — building blocks.
//!
//! Follows the workspace-calibration paper (shared/papers): time-delay estimation between the
//! external tracker and the device, pivot (tooltip) calibration, absolute orientation, then
//! joint-angle and gimbal calibration. This module holds the tested building blocks; the full
//! `kincal haptic` pipeline (joint-angle and gimbal calibration, orientation reference, report,
//! simulator of whole recordings) is not built yet.

pub mod delay;
pub mod kinematics;
pub mod landmarks;
pub mod pivot;
pub mod position;
pub mod recording;
