//! One value per pose of `N` poses carried through a chain in lockstep: the same operations in
//! the same order on every lane, so each lane's figures are those of its pose carried alone (to
//! the bit: no lane reads another's), and two lanes fill one SSE2 register, each multiply or add
//! serving two poses.

use std::ops::{Add, Mul, Neg, Sub};

/// A value per pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Lanes<const N: usize>(pub(super) [f64; N]);

/// A vector of three components, each a value per pose.
pub(super) type Vec3<const N: usize> = [Lanes<N>; 3];

impl<const N: usize> Lanes<N> {
    /// The same value on every lane.
    #[inline(always)]
    pub(super) fn splat(value: f64) -> Lanes<N> {
        Lanes([value; N])
    }

    /// `f` of each lane's values of `self` and `other`.
    #[inline(always)]
    fn zip(self, other: Lanes<N>, f: impl Fn(f64, f64) -> f64) -> Lanes<N> {
        let mut out = self.0;
        for (o, b) in out.iter_mut().zip(other.0) {
            *o = f(*o, b);
        }
        Lanes(out)
    }
}

impl<const N: usize> Add for Lanes<N> {
    type Output = Lanes<N>;
    #[inline(always)]
    fn add(self, other: Lanes<N>) -> Lanes<N> {
        self.zip(other, |a, b| a + b)
    }
}

impl<const N: usize> Sub for Lanes<N> {
    type Output = Lanes<N>;
    #[inline(always)]
    fn sub(self, other: Lanes<N>) -> Lanes<N> {
        self.zip(other, |a, b| a - b)
    }
}

impl<const N: usize> Mul for Lanes<N> {
    type Output = Lanes<N>;
    #[inline(always)]
    fn mul(self, other: Lanes<N>) -> Lanes<N> {
        self.zip(other, |a, b| a * b)
    }
}

impl<const N: usize> Neg for Lanes<N> {
    type Output = Lanes<N>;
    #[inline(always)]
    fn neg(self) -> Lanes<N> {
        Lanes(self.0.map(|a| -a))
    }
}

/// a × b, in nalgebra's order of operations (its `cross`, to the bit).
#[inline(always)]
pub(super) fn cross<const N: usize>(a: &Vec3<N>, b: &Vec3<N>) -> Vec3<N> {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// Each component of `v` times `k`.
#[inline(always)]
pub(super) fn scaled<const N: usize>(v: &Vec3<N>, k: Lanes<N>) -> Vec3<N> {
    v.map(|c| c * k)
}

/// a + b.
#[inline(always)]
pub(super) fn sum<const N: usize>(a: &Vec3<N>, b: &Vec3<N>) -> Vec3<N> {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// a − b.
#[inline(always)]
pub(super) fn difference<const N: usize>(a: &Vec3<N>, b: &Vec3<N>) -> Vec3<N> {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// Lane `i` of `v`.
#[inline(always)]
pub(super) fn lane<const N: usize>(v: &Vec3<N>, i: usize) -> nalgebra::Vector3<f64> {
    nalgebra::Vector3::new(v[0].0[i], v[1].0[i], v[2].0[i])
}

/// The six entries of buffer `buffer` of a column whose values (V's x, y, z, then W's, see the
/// [kinematics module](super)) are `values`, among `N` poses' buffers while the columns are gathered: value k
/// of pose i at flat index k·N + i, buffer flat / 6, entry flat % 6. For one pose, V in entries
/// 0..3 and W in 3..6; for two, the first buffer holds both poses' V and the second their W,
/// pose after pose, so that each component of the pair is stored and read as one register.
#[inline(always)]
pub(super) fn gathered<const N: usize>(values: &[Lanes<N>; 6], buffer: usize) -> [f64; 6] {
    let mut entries = [0.0; 6];
    for (entry, e) in entries.iter_mut().enumerate() {
        let flat = 6 * buffer + entry;
        *e = values[flat / N].0[flat % N];
    }
    entries
}

/// The values of a column gathered in `entries` (each buffer's six, see [`gathered`]).
#[inline(always)]
pub(super) fn ungathered<const N: usize>(entries: &[[f64; 6]; N]) -> [Lanes<N>; 6] {
    let mut values = [Lanes::splat(0.0); 6];
    for (k, value) in values.iter_mut().enumerate() {
        for (i, v) in value.0.iter_mut().enumerate() {
            let flat = k * N + i;
            *v = entries[flat / 6][flat % 6];
        }
    }
    values
}
