//! The joints the controller reads: their count and the mask of all of them.

/// Joints read every tick.
pub const JOINTS: usize = 6;
/// Bit mask of all joints (bit j: joint j + 1), as in [`crate::messages::PoseReport::fresh`].
pub const ALL_JOINTS: u8 = (1 << JOINTS) - 1;
