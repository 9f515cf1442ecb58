//! The arm's controller seen from the host: the framed link (serial, pty or TCP), guided recording
//! of measurement sessions, the parameter blob for upload and its signature (station keys), which
//! arm a calibration belongs to and its validity, the short re-validation (`kincal check`), the
//! emulated controller on QEMU and the whole demo loop through it; the pose stream stamped on the
//! host clock and served to navigation software over OpenIGTLink.

pub mod check;
pub mod demo;
pub mod device;
pub mod emulated_arm;
pub mod emulator;
pub mod igtl_client;
pub mod igtl_server;
pub mod link;
pub mod motion;
pub mod pose_stream;
pub mod record;
pub mod signing;
pub mod traceability;
