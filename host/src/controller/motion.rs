//! The emulated arm in motion: send a trajectory to the emulated controller and start it.

use crate::controller::link::{Link, LinkError};
use crate::motion::trajectory::Trajectory;
use kincal_protocol::messages::{SimPlay, SimWaypoint};

/// Ticks between the start request and the trajectory's start (0.5 s): time for the request to
/// arrive on a slow link, so the start tick is still ahead when it does.
pub const LEAD_TICKS: u32 = 384;

/// Send `trajectory` to the emulated controller on `link` and start it [`LEAD_TICKS`] from now;
/// with `repeat` it starts again at its end. Returns the controller tick of the trajectory's
/// time 0: the sample of tick `k` is the trajectory at `k − start`.
pub fn play(link: &mut Link, trajectory: &Trajectory, repeat: bool) -> Result<u32, LinkError> {
    for (index, waypoint) in trajectory.waypoints.iter().enumerate() {
        link.call_retrying(SimWaypoint { index: index as u8, waypoint: *waypoint })?;
    }
    let start_tick = link.info()?.ticks.wrapping_add(LEAD_TICKS);
    link.call_retrying(SimPlay { waypoints: trajectory.waypoints.len() as u8, start_tick, repeat })?;
    Ok(start_tick)
}
