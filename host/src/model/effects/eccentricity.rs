//! Encoder or gear eccentricity: `eccentricity:j` (first harmonic), `eccentricity2:j` (second).
//!
//! Formula: Δθ_j = a·sin φ_j + b·cos φ_j + a₂·sin 2φ_j + b₂·cos 2φ_j (degrees), φ_j the raw
//! encoder angle, added to θ_j = φ_j + δθ_j.
//!
//! Physical cause: a code disc (or gear) mounted off-centre on its shaft reads an angle that
//! runs ahead and behind the true one once per turn (first harmonic); an elliptical disc, a
//! tilted mount or a two-lobed transmission error repeats twice per turn (second harmonic).
//! The phase is fixed to the encoder, not to the joint zero, so φ is the raw reading.

/// ∂Δθ/∂(a, b, a₂, b₂) at raw encoder angle `enc_deg`: (sin φ, cos φ, sin 2φ, cos 2φ).
pub fn partials(enc_deg: f64) -> [f64; 4] {
    let phi = enc_deg.to_radians();
    let (s1, c1) = phi.sin_cos();
    let (s2, c2) = (2.0 * phi).sin_cos();
    [s1, c1, s2, c2]
}
