//! Periodic encoder error of higher order: `harmonic:j:n` (n cycles per revolution).
//!
//! Formula: Δθ_j = a_n·sin(n·φ_j) + b_n·cos(n·φ_j) (degrees), φ_j the raw encoder angle, added to
//! θ_j = φ_j + δθ_j like the eccentricity. `harmonic:j:1` is `eccentricity:j` and `harmonic:j:2`
//! is `eccentricity2:j` (see [`super::eccentricity`]); this file holds n = 3 and 4.
//!
//! Physical cause: an error that repeats n times per turn of the encoder — a three-lobed code
//! disc or hub (three mounting screws pulling the disc), a gear or harmonic-drive transmission
//! error with n teeth-periods per output turn, an interpolation error of an n-pole-pair
//! magnetic encoder. `kincal diagnose` proposes the order from the spectrum of each joint's
//! apparent error.

/// Highest harmonic order the model holds.
pub const MAX_ORDER: u32 = 4;

/// ∂Δθ/∂(a_n, b_n) at raw encoder angle `enc_deg`: (sin nφ, cos nφ).
pub fn partials(enc_deg: f64, order: u32) -> [f64; 2] {
    let (s, c) = (f64::from(order) * enc_deg.to_radians()).sin_cos();
    [s, c]
}
