//! One value per pose of `N` poses carried through a chain in lockstep: the same operations in
//! the same order on every lane, so each lane's figures are those of its pose carried alone (to
//! the bit: no lane reads another's). One pose's value is an `f64`; two poses' fill one SSE2
//! register, `wide`'s `f64x2` (pose A in lane 0, pose B in lane 1), each multiply or add one
//! packed instruction serving both.
//!
//! Why `wide` rather than two `f64` per value left to the compiler: given `[f64; 2]` lanes, its
//! vectoriser packed whatever pairs it liked (x and y of one pose, a value and the next) and
//! shuffled between them, so the pair cost nearly what two poses alone cost. `f64x2` fixes the
//! packing: each operator is the one packed SSE2 instruction (`addpd`, `subpd`, `mulpd`, the
//! sign flip an `xorpd`), the same IEEE operation on each lane as the scalar code's, so the
//! figures stay those of a pose alone to the bit; and it is safe code (the library forbids
//! `unsafe`, which `core::arch` would need). No fused multiply-add anywhere: it rounds once
//! where the scalar code rounds twice.

use super::PoseDerivative;
use std::ops::{Add, Mul, Neg, Sub};
use wide::f64x2;

/// The register type holding one value per pose of a [`Poses`] count.
pub(super) trait Width {
    /// One value per pose; its operators act on each lane alone, as on an `f64`.
    type Register: Copy
        + Add<Output = Self::Register>
        + Sub<Output = Self::Register>
        + Mul<Output = Self::Register>
        + Neg<Output = Self::Register>;
    /// The same value on every lane.
    fn splat(value: f64) -> Self::Register;
    /// Lane i holding `value(i)`.
    fn from_fn(value: impl FnMut(usize) -> f64) -> Self::Register;
    /// The value of lane `i`.
    fn lane(register: Self::Register, i: usize) -> f64;
    /// Calls `each` with every column the poses' buffers `buffers` (one per pose) all hold, one
    /// per buffer, the buffers walked together (no bounds check per column).
    fn each_column(buffers: &mut [&mut [PoseDerivative]], each: impl FnMut(&mut [&mut PoseDerivative]));
}

/// `N` poses carried together (one or two: a [`Width`] for each).
pub(super) struct Poses<const N: usize>;

impl Width for Poses<1> {
    type Register = f64;
    #[inline(always)]
    fn splat(value: f64) -> f64 {
        value
    }
    #[inline(always)]
    fn from_fn(mut value: impl FnMut(usize) -> f64) -> f64 {
        value(0)
    }
    #[inline(always)]
    fn lane(register: f64, _: usize) -> f64 {
        register
    }
    #[inline(always)]
    fn each_column(buffers: &mut [&mut [PoseDerivative]], mut each: impl FnMut(&mut [&mut PoseDerivative])) {
        debug_assert_eq!(buffers.len(), 1, "one buffer per pose");
        if let [first] = buffers {
            first.iter_mut().for_each(|a| each(&mut [a]));
        }
    }
}

impl Width for Poses<2> {
    type Register = f64x2;
    #[inline(always)]
    fn splat(value: f64) -> f64x2 {
        f64x2::splat(value)
    }
    #[inline(always)]
    fn from_fn(mut value: impl FnMut(usize) -> f64) -> f64x2 {
        f64x2::new([value(0), value(1)])
    }
    #[inline(always)]
    fn lane(register: f64x2, i: usize) -> f64 {
        register.as_array()[i]
    }
    #[inline(always)]
    fn each_column(buffers: &mut [&mut [PoseDerivative]], mut each: impl FnMut(&mut [&mut PoseDerivative])) {
        debug_assert_eq!(buffers.len(), 2, "one buffer per pose");
        if let [first, second] = buffers {
            first.iter_mut().zip(second.iter_mut()).for_each(|(a, b)| each(&mut [a, b]));
        }
    }
}

/// A value per pose.
#[derive(Clone, Copy)]
pub(super) struct Lanes<const N: usize>(<Poses<N> as Width>::Register)
where
    Poses<N>: Width;

/// A vector of three components, each a value per pose.
pub(super) type Vec3<const N: usize> = [Lanes<N>; 3];

impl<const N: usize> Lanes<N>
where
    Poses<N>: Width,
{
    /// The same value on every lane.
    #[inline(always)]
    pub(super) fn splat(value: f64) -> Lanes<N> {
        Lanes(Poses::<N>::splat(value))
    }

    /// Lane i holding `value(i)`.
    #[inline(always)]
    pub(super) fn from_fn(value: impl FnMut(usize) -> f64) -> Lanes<N> {
        Lanes(Poses::<N>::from_fn(value))
    }

    /// The value of lane `i`.
    #[inline(always)]
    pub(super) fn lane(self, i: usize) -> f64 {
        Poses::<N>::lane(self.0, i)
    }
}

impl<const N: usize> Add for Lanes<N>
where
    Poses<N>: Width,
{
    type Output = Lanes<N>;
    #[inline(always)]
    fn add(self, other: Lanes<N>) -> Lanes<N> {
        Lanes(self.0 + other.0)
    }
}

impl<const N: usize> Sub for Lanes<N>
where
    Poses<N>: Width,
{
    type Output = Lanes<N>;
    #[inline(always)]
    fn sub(self, other: Lanes<N>) -> Lanes<N> {
        Lanes(self.0 - other.0)
    }
}

impl<const N: usize> Mul for Lanes<N>
where
    Poses<N>: Width,
{
    type Output = Lanes<N>;
    #[inline(always)]
    fn mul(self, other: Lanes<N>) -> Lanes<N> {
        Lanes(self.0 * other.0)
    }
}

impl<const N: usize> Neg for Lanes<N>
where
    Poses<N>: Width,
{
    type Output = Lanes<N>;
    #[inline(always)]
    fn neg(self) -> Lanes<N> {
        Lanes(-self.0)
    }
}

/// a × b, in nalgebra's order of operations (its `cross`, to the bit).
#[inline(always)]
pub(super) fn cross<const N: usize>(a: &Vec3<N>, b: &Vec3<N>) -> Vec3<N>
where
    Poses<N>: Width,
{
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// Each component of `v` times `k`.
#[inline(always)]
pub(super) fn scaled<const N: usize>(v: &Vec3<N>, k: Lanes<N>) -> Vec3<N>
where
    Poses<N>: Width,
{
    v.map(|c| c * k)
}

/// a + b.
#[inline(always)]
pub(super) fn sum<const N: usize>(a: &Vec3<N>, b: &Vec3<N>) -> Vec3<N>
where
    Poses<N>: Width,
{
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// a − b.
#[inline(always)]
pub(super) fn difference<const N: usize>(a: &Vec3<N>, b: &Vec3<N>) -> Vec3<N>
where
    Poses<N>: Width,
{
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// Lane `i` of `v`.
#[inline(always)]
pub(super) fn lane<const N: usize>(v: &Vec3<N>, i: usize) -> nalgebra::Vector3<f64>
where
    Poses<N>: Width,
{
    nalgebra::Vector3::new(v[0].lane(i), v[1].lane(i), v[2].lane(i))
}

/// The six entries of buffer `buffer` of a column whose values (V's x, y, z, then W's, see the
/// [kinematics module](super)) are `values`, among `N` poses' buffers while the columns are gathered: value k
/// of pose i at flat index k·N + i, buffer flat / 6, entry flat % 6. For one pose, V in entries
/// 0..3 and W in 3..6; for two, the first buffer holds both poses' V and the second their W,
/// pose after pose, so that each component of the pair is stored and read as one register.
#[inline(always)]
pub(super) fn gathered<const N: usize>(values: &[Lanes<N>; 6], buffer: usize) -> [f64; 6]
where
    Poses<N>: Width,
{
    let mut entries = [0.0; 6];
    for (entry, e) in entries.iter_mut().enumerate() {
        let flat = 6 * buffer + entry;
        *e = values[flat / N].lane(flat % N);
    }
    entries
}

/// The values of a column gathered in `entries` (each buffer's six, see [`gathered`]).
#[inline(always)]
pub(super) fn ungathered<const N: usize>(entries: &[[f64; 6]; N]) -> [Lanes<N>; 6]
where
    Poses<N>: Width,
{
    std::array::from_fn(|k| {
        Lanes::from_fn(|i| {
            let flat = k * N + i;
            entries[flat / 6][flat % 6]
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::hint::black_box;

    /// Each operator on two lanes is, lane by lane and to the bit, the scalar operator: signed
    /// zeros, infinities, subnormals and rounding included, whatever the other lane holds; a NaN
    /// where the scalar gives one (which of two NaN operands an addition passes on is the
    /// compiler's choice of operand order, for a scalar too). The inputs pass a `black_box` so
    /// the scalar side is the processor's arithmetic, not the compiler's constant folding.
    #[test]
    fn two_lanes_operate_as_two_scalars() {
        let values = [
            1.0,
            -0.0,
            0.0,
            0.1,
            -3.7,
            1e308,
            -2.5e-320,
            5e-324,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            -f64::NAN,
            f64::from_bits(0x7ff0_0000_dead_beef),
        ];
        // The bits, any NaN as one.
        let bits = |v: f64| if v.is_nan() { f64::NAN.to_bits() } else { v.to_bits() };
        let lanes = |l: Lanes<2>| [bits(l.lane(0)), bits(l.lane(1))];
        for (n, &a) in values.iter().enumerate() {
            for (m, &b) in values.iter().enumerate() {
                // The other lane holds another pair of the table.
                let (c, d) = (values[(n + 3) % values.len()], values[(m + 5) % values.len()]);
                let (x, y) =
                    (black_box(Lanes::<2>::from_fn(|i| [a, c][i])), black_box(Lanes::from_fn(|i| [b, d][i])));
                let ([a, b, c, d], label) = (black_box([a, b, c, d]), format!("{a:e} {b:e} | {c:e} {d:e}"));
                let scalar = |f: fn(f64, f64) -> f64| [bits(f(a, b)), bits(f(c, d))];
                assert_eq!(lanes(x + y), scalar(|p, q| p + q), "{label} +");
                assert_eq!(lanes(x - y), scalar(|p, q| p - q), "{label} -");
                assert_eq!(lanes(x * y), scalar(|p, q| p * q), "{label} *");
                // A sign flip is exact on a NaN too.
                assert_eq!(
                    [(-x).lane(0).to_bits(), (-x).lane(1).to_bits()],
                    [(-a).to_bits(), (-c).to_bits()],
                    "{label} neg"
                );
                assert_eq!(lanes(Lanes::splat(a)), [bits(a); 2], "{label} splat");
            }
        }
    }

    /// The columns walked together are every column the buffers all hold, in order, each
    /// pose's from its own buffer (the longer buffer's last column left alone), for one pose and
    /// two.
    #[test]
    fn columns_walked_together_are_each_buffers_columns_in_order() {
        let column = |pose: usize, c: usize| [(10 * pose + c) as f64; 9];
        let mut one: Vec<PoseDerivative> = (0..3).map(|c| column(0, c)).collect();
        let mut seen = Vec::new();
        Poses::<1>::each_column(&mut [&mut one], |cols| {
            seen.push(cols.iter().map(|col| col[0]).collect::<Vec<_>>());
            cols.iter_mut().for_each(|col| col[8] = -1.0);
        });
        assert_eq!(seen, [[0.0], [1.0], [2.0]]);
        assert!(one.iter().all(|col| col[8] == -1.0));
        let (mut a, mut b): (Vec<PoseDerivative>, Vec<PoseDerivative>) =
            ((0..3).map(|c| column(0, c)).collect(), (0..4).map(|c| column(1, c)).collect());
        let mut seen = Vec::new();
        Poses::<2>::each_column(&mut [&mut a, &mut b], |cols| {
            seen.push(cols.iter().map(|col| col[0]).collect::<Vec<_>>());
            cols.iter_mut().for_each(|col| col[8] = -1.0);
        });
        assert_eq!(seen, [[0.0, 10.0], [1.0, 11.0], [2.0, 12.0]]);
        assert!(a.iter().chain(&b[..3]).all(|col| col[8] == -1.0));
        assert_eq!(b[3], column(1, 3), "the column only one buffer holds");
    }

    /// A column's values gathered into the buffers and read back are the values, for one pose
    /// and two; for two, the first buffer holds V and the second W, pose A before pose B.
    #[test]
    fn gathering_a_column_and_reading_it_back_gives_the_column() {
        let one: [Lanes<1>; 6] = std::array::from_fn(|k| Lanes::splat(k as f64 + 0.5));
        let entries = [gathered(&one, 0)];
        assert_eq!(entries, [[0.5, 1.5, 2.5, 3.5, 4.5, 5.5]]);
        assert!(ungathered(&entries).iter().zip(&one).all(|(a, b)| a.lane(0) == b.lane(0)));
        let two: [Lanes<2>; 6] = std::array::from_fn(|k| Lanes::from_fn(|i| (10 * k + i) as f64));
        let entries = [gathered(&two, 0), gathered(&two, 1)];
        assert_eq!(entries, [[0.0, 1.0, 10.0, 11.0, 20.0, 21.0], [30.0, 31.0, 40.0, 41.0, 50.0, 51.0]]);
        let back = ungathered(&entries);
        assert!(back.iter().zip(&two).all(|(a, b)| (0..2).all(|i| a.lane(i) == b.lane(i))));
    }
}
