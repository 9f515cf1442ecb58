//! The arm's controller seen from the host: the framed link (serial, pty or TCP), guided recording
//! of measurement sessions, the parameter blob for upload and its signature (station keys), which
//! arm a calibration belongs to and its validity, the short re-validation (`kincal check`), the
//! emulated controller on QEMU and the whole demo loop through it.

pub mod check;
pub mod demo;
pub mod device;
pub mod emulated_arm;
pub mod emulator;
pub mod link;
pub mod record;
pub mod signing;
pub mod traceability;
