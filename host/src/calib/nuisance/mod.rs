//! Unknowns that belong to one block or group of observations, not to the arm (Ceres' parameter
//! blocks with their manifold): the frame of an instrument session, a tool re-mounted in one
//! placement or session, a drift within a session, and the 6-DoF probe's rotation on the flange
//! (shared by every session). Terms read them; the problem eliminates them block by block.

pub mod drift;
pub mod frame;
pub mod tool;
