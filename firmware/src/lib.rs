//! kincal controller firmware: the board-independent part.
//!
//! Everything here is plain `no_std` logic, tested on the host: the BiSS-C master over
//! embedded-hal-async SPI ([`biss_master`]) and the emulated encoders behind the same trait
//! ([`emulated_encoders`]), rejecting frames and counting faults ([`encoders`]), measurement windows ([`window`]), why the controller reset ([`reset_cause`]), power-loss-safe parameter storage
//! ([`flash`]), whom it trusts to sign parameter sets ([`trust`]), the on-device kinematics ([`kinematics`]) and the protocol state machine
//! ([`controller`]). Board specifics (time driver, UART, encoder bus, flash) live in one module
//! per board under `src/bin/`.
#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]

#[cfg(feature = "app")]
pub mod app;
pub mod biss_master;
pub mod controller;
pub mod emulated_encoders;
pub mod encoders;
pub mod flash;
pub mod reset_cause;
pub use kincal_kinematics as kinematics;
pub mod trust;
pub mod window;
