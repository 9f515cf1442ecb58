//! The tracker arm in motion: the emulated arm's trajectories, and the dynamic validation of a
//! streamed pose against a reference tracker (latency, clock offset and drift, path error
//! against speed, acceleration and at direction changes).

pub mod trajectory;
