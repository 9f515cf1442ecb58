//! Wire types shared by the kincal controller firmware and the host (`no_std`, no alloc).
//!
//! * [`joints`] — the joint count of the arm the controller reads.
//! * [`messages`] — requests, responses and streamed frames, with a protocol version and a
//!   schema hash exchanged on connect ([`messages::Request::Hello`]).
//! * [`framing`] — one frame = COBS( postcard(message) ‖ CRC-16 ) followed by 0x00; the decoder
//!   checks the CRC before decoding and resynchronises at the next delimiter.
//! * [`biss`] — the BiSS-C single-cycle frame of a 22-bit absolute encoder, with its CRC-6.
//! * [`params`] — the calibrated arm model as stored on the controller (version, CRC, size limit).
//! * [`signed`] — the signed parameter set: blob, arm identity, time, Ed25519 key and signature.
//! * [`trajectory`] — the emulated arm's motion: joint waypoints with times and the smooth path
//!   through them, evaluated alike by the emulated encoders and the host.
//!
//! The `std` feature adds what the host needs (allocation-backed helpers).
#![cfg_attr(not(any(feature = "std", test)), no_std)]
#![deny(missing_docs)]
#![forbid(unsafe_code)]

pub mod biss;
pub mod framing;
pub mod joints;
pub mod messages;
pub mod params;
pub mod signed;
pub mod trajectory;
