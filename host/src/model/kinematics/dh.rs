//! The plain Denavit–Hartenberg chain's kernel: a model in the classic or modified convention
//! whose joint angles are θ_j = φ_j + δθ_j (no harmonic encoder error, no compliance) carried
//! through its rows with each joint's five elementary transforms written out (Rz(θ), Tz(d),
//! Tx(a), Rx(α), Ry(β), or α, β, a, θ, d in the modified convention), the derivatives gathered
//! as the module above describes (W and V per column, finished once the tool frame is known).
//!
//! It computes what [`Chain`]'s general pass computes for such a model, with no op to interpret
//! per transform: each transform's axis and its parameter's column are known where it is written,
//! and a joint's angle takes its encoder's kept sine and cosine by angle addition with the
//! offset's (or one sine and cosine of θ when none is kept).
//!
//! Each parameter of a DH chain moves one transform only, so each wanted column is written
//! once, W and V set rather than added: the caller's buffer needs no zeroing per pose (its
//! columns the chain does not move are zeroed only when some are wanted, see
//! [`Chain::dh_columns`]).

use super::lanes::{cross, difference, gathered, scaled, sum, Lanes, Poses, Vec3, Width};
use super::{Chain, ColumnMap, Flange, PoseDerivative, DEG};
use crate::model::{ArmModel, Convention, ParamId};

/// One DH row's constants.
#[derive(Clone, Copy)]
pub(super) struct Row {
    /// The joint (of the model).
    joint: usize,
    d_mm: f64,
    a_mm: f64,
    /// Sine and cosine of the twist α.
    alpha: (f64, f64),
    /// Sine and cosine of the axis tilt β; `None` when β = 0.
    beta: Option<(f64, f64)>,
    /// Dense indices of the row's offset, length, link offset, twist and axis tilt.
    slots: [usize; 5],
}

/// The rows of `model`'s `path` when the model is a DH chain; `None` for a URDF model.
pub(super) fn rows(model: &ArmModel, path: &[usize]) -> Option<Vec<Row>> {
    if model.convention == Convention::Urdf {
        return None;
    }
    Some(
        path.iter()
            .map(|&j| {
                let joint = &model.joints[j];
                let beta = (joint.axis_deg != 0.0).then(|| (joint.axis_deg * DEG).sin_cos());
                Row {
                    joint: j,
                    d_mm: joint.d_mm,
                    a_mm: joint.a_mm,
                    alpha: (joint.alpha_deg * DEG).sin_cos(),
                    beta,
                    slots: [
                        ParamId::Offset(j),
                        ParamId::Length(j),
                        ParamId::LinkOffset(j),
                        ParamId::Twist(j),
                        ParamId::Axis(j),
                    ]
                    .map(ParamId::dense_index),
                }
            })
            .collect(),
    )
}

/// The tool point, x axis and z axis a pass ends at (before the scale), per pose.
pub(super) type TipFrame<const N: usize> = [Vec3<N>; 3];

/// Per pose, its encoder angles (degrees) and their kept sines and cosines (none kept: empty;
/// a slice rather than an option, so that a joint's pair is one bounds check away per pose).
pub(super) type Encoders<'e> = (&'e [f64], &'e [(f64, f64)]);

/// The wanted columns and, per pose, the buffer they are written to.
pub(super) type Wanted<'c, 'j, const N: usize> = (&'c ColumnMap, &'c mut [&'j mut [PoseDerivative]; N]);

/// The frames carried from the base (one per pose) and the columns written so far.
struct Pass<'c, const N: usize>
where
    Poses<N>: Width,
{
    axes: [Vec3<N>; 3],
    origin: Vec3<N>,
    /// The wanted columns and, per pose, its buffer cut to the columns every pose's holds (held
    /// here, not behind the caller's array: the stores cannot alias them, so each column's
    /// buffers take no reload and one bounds check for all poses).
    wanted: Option<(&'c ColumnMap, [&'c mut [PoseDerivative]; N])>,
    /// Columns written (per pose).
    written: usize,
}

impl<'c, const N: usize> Pass<'c, N>
where
    Poses<N>: Width,
{
    /// The base frame, no column written.
    #[inline(always)]
    fn base(wanted: Option<Wanted<'c, '_, N>>) -> Self {
        let (zero, one) = (Lanes::splat(0.0), Lanes::splat(1.0));
        Pass {
            axes: [[one, zero, zero], [zero, one, zero], [zero, zero, one]],
            origin: [zero; 3],
            wanted: wanted.map(Self::cut),
            written: 0,
        }
    }

    /// The wanted columns with each pose's buffer cut to the columns every pose's holds.
    #[inline(always)]
    fn cut((columns, jacs): Wanted<'c, '_, N>) -> (&'c ColumnMap, [&'c mut [PoseDerivative]; N]) {
        let count = jacs.iter().map(|jac| jac.len()).min().unwrap_or(0);
        (columns, jacs.each_mut().map(|jac| &mut jac[..count]))
    }

    /// The poses' frames at the flange `flanges`, no column written.
    #[inline(always)]
    fn at(flanges: [&Flange; N], wanted: Option<Wanted<'c, '_, N>>) -> Self {
        let vector =
            |v: fn(&Flange) -> &[f64; 3]| std::array::from_fn(|k| Lanes::from_fn(|i| v(flanges[i])[k]));
        Pass {
            axes: [vector(|f| &f.axes[0]), vector(|f| &f.axes[1]), vector(|f| &f.axes[2])],
            origin: vector(|f| &f.origin_mm),
            wanted: wanted.map(Self::cut),
            written: 0,
        }
    }

    /// Write V and W, of `values()`, to the column of dense slot `slot` if it is wanted (where
    /// [`gathered`] says).
    #[inline(always)]
    fn put(&mut self, slot: usize, values: impl FnOnce(&Self) -> [Lanes<N>; 6]) {
        let Some(col) = self.wanted.as_ref().and_then(|(columns, _)| columns.column(slot)) else {
            return;
        };
        let values = values(self);
        if let Some((_, jacs)) = self.wanted.as_mut() {
            // Each buffer's six values built locally and copied at once: stored one by one, each
            // store may alias the buffers, so the compiler reloads and bounds-checks per value.
            for (buffer, jac) in jacs.iter_mut().enumerate() {
                jac[col][..6].copy_from_slice(&gathered(&values, buffer));
            }
        }
        self.written += 1;
    }

    /// Rotate by the angle of sine and cosine `s`, `c` about frame axis `axis` (0 x, 1 y, 2 z),
    /// the parameter in dense slot `slot` moving the angle by one degree per unit.
    #[inline(always)]
    fn turn(&mut self, axis: usize, (s, c): (Lanes<N>, Lanes<N>), slot: usize) {
        self.put(slot, |pass| {
            // V = −w × o and W = w, per degree.
            let (w, v) = (pass.axes[axis], cross(&pass.axes[axis], &pass.origin));
            let deg = Lanes::splat(DEG);
            [-v[0] * deg, -v[1] * deg, -v[2] * deg, w[0] * deg, w[1] * deg, w[2] * deg]
        });
        let (i, k) = ((axis + 1) % 3, (axis + 2) % 3);
        let (u, v) = (self.axes[i], self.axes[k]);
        self.axes[i] = sum(&scaled(&u, c), &scaled(&v, s));
        self.axes[k] = difference(&scaled(&v, c), &scaled(&u, s));
    }

    /// Translate by `value` (mm) along frame axis `axis`, the parameter in dense slot `slot`.
    #[inline(always)]
    fn shift(&mut self, axis: usize, value: f64, slot: usize) {
        let t = self.axes[axis];
        let zero = Lanes::splat(0.0);
        self.put(slot, |_| [t[0], t[1], t[2], zero, zero, zero]);
        self.origin = sum(&self.origin, &scaled(&t, Lanes::splat(value)));
    }

    /// The tilt β about the frame's y axis, when it has one or its column is wanted.
    #[inline(always)]
    fn tilt(&mut self, row: &Row) {
        let wanted = self.wanted.as_ref().is_some_and(|(columns, _)| columns.column(row.slots[4]).is_some());
        if row.beta.is_some() || wanted {
            let (s, c) = row.beta.unwrap_or((0.0, 1.0));
            self.turn(1, (Lanes::splat(s), Lanes::splat(c)), row.slots[4]);
        }
    }
}

impl Chain<'_> {
    /// The poses (and the wanted columns) of a plain DH chain (see the module doc) at `N` poses'
    /// encoders `enc`, carried through the chain in lockstep: the tool point, x and z axes
    /// before the scale, and the columns' W and V (the scale's zero).
    pub(super) fn dh_columns<const N: usize>(
        &self,
        rows: &[Row],
        enc: [Encoders<'_>; N],
        wanted: Option<Wanted<'_, '_, N>>,
    ) -> TipFrame<N>
    where
        Poses<N>: Width,
    {
        self.columns_by(
            wanted,
            #[inline(always)]
            |wanted| self.tool_shift(self.dh_rows(rows, &enc, Pass::base(wanted))),
        )
    }

    /// As [`Chain::dh_columns`] from the poses' frames at the flange (of a pass over the same
    /// rows at the same values but the tool point's and the scale's): the tool shift alone, the
    /// same operations on the same frames as the whole pass ends with.
    pub(super) fn dh_tool_columns<const N: usize>(
        &self,
        flanges: [&Flange; N],
        wanted: Option<Wanted<'_, '_, N>>,
    ) -> TipFrame<N>
    where
        Poses<N>: Width,
    {
        self.columns_by(
            wanted,
            #[inline(always)]
            |wanted| self.tool_shift(Pass::at(flanges, wanted)),
        )
    }

    /// The frames at the flange of `N` poses: the pass over `rows` without columns (a pass
    /// with columns carries the same frames: writing a column moves none).
    pub(super) fn dh_flanges<const N: usize>(&self, rows: &[Row], enc: [Encoders<'_>; N]) -> [Flange; N]
    where
        Poses<N>: Width,
    {
        let pass = self.dh_rows(rows, &enc, Pass::base(None));
        std::array::from_fn(|i| Flange {
            origin_mm: pass.origin.map(|c| c.lane(i)),
            axes: pass.axes.map(|axis| axis.map(|c| c.lane(i))),
        })
    }

    /// The frame and the wanted columns of a pass `pass` (given the columns, or none, it
    /// returns the tool frame and the count of columns it wrote), every column written: when a
    /// wanted column is none of the chain's parameters, all zeroed and the pass run again; the
    /// scale's zero (the finish adds its share).
    #[inline(always)]
    fn columns_by<const N: usize>(
        &self,
        mut wanted: Option<Wanted<'_, '_, N>>,
        pass: impl Fn(Option<Wanted<'_, '_, N>>) -> (TipFrame<N>, usize),
    ) -> TipFrame<N>
    where
        Poses<N>: Width,
    {
        let Some((columns, jacs)) = wanted.as_mut() else {
            return pass(None).0;
        };
        let (pose, written) = pass(Some((*columns, &mut **jacs)));
        let scale = columns.column(ParamId::Scale.dense_index());
        let moved = columns.len() - usize::from(scale.is_some());
        for jac in jacs.iter_mut() {
            if written != moved {
                jac.iter_mut().for_each(|col| *col = [0.0; 9]);
            } else if let Some(c) = scale {
                jac[c] = [0.0; 9];
            }
        }
        if written != moved {
            pass(Some((*columns, &mut **jacs)));
        }
        pose
    }

    /// `pass` carried through `rows`.
    #[inline(always)]
    fn dh_rows<'c, const N: usize>(
        &self,
        rows: &[Row],
        enc: &[Encoders<'_>; N],
        mut pass: Pass<'c, N>,
    ) -> Pass<'c, N>
    where
        Poses<N>: Width,
    {
        let modified = self.model.convention == Convention::Modified;
        for row in rows {
            let theta = self.theta_sin_cos(row.joint, enc);
            let alpha = (Lanes::splat(row.alpha.0), Lanes::splat(row.alpha.1));
            if modified {
                pass.turn(0, alpha, row.slots[3]);
                pass.tilt(row);
                pass.shift(0, row.a_mm, row.slots[2]);
                pass.turn(2, theta, row.slots[0]);
                pass.shift(2, row.d_mm, row.slots[1]);
            } else {
                pass.turn(2, theta, row.slots[0]);
                pass.shift(2, row.d_mm, row.slots[1]);
                pass.shift(0, row.a_mm, row.slots[2]);
                pass.turn(0, alpha, row.slots[3]);
                pass.tilt(row);
            }
        }
        pass
    }

    /// The tool shift ending a pass at the flange: the tool frame and the count of columns the
    /// whole pass wrote.
    #[inline(always)]
    fn tool_shift<const N: usize>(&self, mut pass: Pass<'_, N>) -> (TipFrame<N>, usize)
    where
        Poses<N>: Width,
    {
        for (k, tool) in self.tool.into_iter().enumerate() {
            pass.shift(k, tool.0, tool.1);
        }
        ([pass.origin, pass.axes[0], pass.axes[2]], pass.written)
    }

    /// The sine and cosine of joint j's angle θ = φ + δθ per pose: by angle addition of the
    /// encoder's kept sine and cosine and the offset's (every lane in one go when every pose has
    /// them kept: the same operations on each), else one sine and cosine of θ.
    #[inline(always)]
    fn theta_sin_cos<const N: usize>(&self, j: usize, enc: &[Encoders<'_>; N]) -> (Lanes<N>, Lanes<N>)
    where
        Poses<N>: Width,
    {
        let (so, co) = self.offset_sin_cos[j];
        let kept = enc.map(|(_, sin_cos)| sin_cos.get(j).copied());
        if kept.iter().all(Option::is_some) {
            let sin_cos = kept.map(Option::unwrap_or_default);
            let (s, c) = (Lanes::from_fn(|i| sin_cos[i].0), Lanes::from_fn(|i| sin_cos[i].1));
            let (so, co) = (Lanes::splat(so), Lanes::splat(co));
            return (s * co + c * so, c * co - s * so);
        }
        let theta: [(f64, f64); N] = std::array::from_fn(|i| match kept[i] {
            Some((s, c)) => (s * co + c * so, c * co - s * so),
            None => {
                ((enc[i].0.get(j).copied().unwrap_or(0.0) + self.model.joints[j].offset_deg) * DEG).sin_cos()
            }
        });
        (Lanes::from_fn(|i| theta[i].0), Lanes::from_fn(|i| theta[i].1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::kinematics::{encoder_sin_cos, ColumnMap, Tips, ToolPose};
    use crate::model::Joint;

    /// A 7-joint DH arm with every kind of row value (β on some rows, zero lengths on others).
    fn arm(convention: Convention) -> ArmModel {
        let mut model = ArmModel::suta_nominal();
        model.convention = convention;
        model.free.clear();
        model.joints = (0..7)
            .map(|j| Joint {
                offset_deg: 3.0 * j as f64 - 7.0,
                d_mm: if j % 3 == 1 { 0.0 } else { 120.0 - 9.0 * j as f64 },
                a_mm: if j % 2 == 0 { 0.0 } else { 35.0 + j as f64 },
                alpha_deg: [90.0, -90.0, 0.3, 90.0, -89.0, 90.0, 0.0][j],
                axis_deg: if j % 3 == 2 { 0.4 * j as f64 } else { 0.0 },
                ..Default::default()
            })
            .collect();
        model.tcp_mm = [12.0, -7.0, 140.0];
        model.scale_ppm = 80.0;
        model
    }

    /// The parameters of the arm above the kernel moves: its rows', the tool point's, the scale.
    fn dh_params() -> Vec<ParamId> {
        (0..7)
            .flat_map(|j| {
                [
                    ParamId::Offset(j),
                    ParamId::Length(j),
                    ParamId::LinkOffset(j),
                    ParamId::Twist(j),
                    ParamId::Axis(j),
                ]
            })
            .chain([ParamId::Tcp(0), ParamId::Tcp(1), ParamId::Tcp(2), ParamId::Scale])
            .collect()
    }

    /// The kernel gives what the general pass over the chain's ops gives, pose and every column
    /// (offsets, lengths, link offsets, twists, axis tilts, the tool point, the scale, a column
    /// the chain does not move), in both conventions, with the encoders' sines and cosines kept
    /// and without, into a buffer not zeroed beforehand.
    #[test]
    fn the_kernel_matches_the_general_pass() {
        for convention in [Convention::Classic, Convention::Modified] {
            let model = arm(convention);
            let chain = Chain::new(&model);
            assert!(chain.dh.is_some(), "a DH chain takes the kernel");
            let params = dh_params();
            // A column the chain does not move (a joint the arm does not have): zero.
            let mut stray = params[3..20].to_vec();
            stray.insert(5, ParamId::Offset(9));
            for columns in [
                ColumnMap::new(&params),
                ColumnMap::new(&params[3..20]).positions_only(),
                ColumnMap::new(&stray).positions_only(),
            ] {
                for pose in 0..20 {
                    let enc: Vec<f64> =
                        (0..7).map(|j| ((pose * 7 + j) as f64 * 0.77).sin() * 170.0).collect();
                    let sin_cos: Vec<(f64, f64)> = enc.iter().map(|&q| encoder_sin_cos(q)).collect();
                    let mut general = vec![[0.0; 9]; columns.len()];
                    let reference = chain.general_pass(&enc, None, Some((&columns, &mut general)));
                    for kept in [None, Some(sin_cos.as_slice())] {
                        // The kernel writes every column: a buffer of garbage (NaN) is no matter.
                        let mut fast = vec![[f64::NAN; 9]; columns.len()];
                        let p = chain.evaluate(&enc, kept, Some((&columns, &mut fast)));
                        let plain = chain.evaluate(&enc, kept, None);
                        for (a, b) in [(p, reference), (plain, reference)] {
                            assert!((a.position_mm - b.position_mm).norm() < 1e-10);
                            assert!(
                                (a.x_axis - b.x_axis).norm() < 1e-13 && (a.z_axis - b.z_axis).norm() < 1e-13
                            );
                        }
                        for (c, (f, g)) in fast.iter().zip(&general).enumerate() {
                            for k in 0..9 {
                                assert!(
                                    (f[k] - g[k]).abs() < 1e-11 * (1.0 + g[k].abs()),
                                    "{convention:?} column {c} [{k}]: {} vs {}",
                                    f[k],
                                    g[k]
                                );
                            }
                        }
                    }
                }
            }
        }
    }

    /// A URDF arm of the DH arm's lengths, and DH arms with a compliance or an encoder harmonic:
    /// chains the two-pose kernel does not take (the general pass, one pose after the other).
    fn arms_off_the_kernel() -> [ArmModel; 3] {
        let mut urdf = arm(Convention::Urdf);
        for joint in &mut urdf.joints {
            joint.origin_xyz_mm = [joint.a_mm, 0.0, joint.d_mm];
        }
        let mut compliant = arm(Convention::Classic);
        compliant.joints[1].compliance_deg_per_m = 0.5;
        let mut harmonic = arm(Convention::Modified);
        harmonic.joints[2].eccentricity_sin_deg = 0.03;
        [urdf, compliant, harmonic]
    }

    /// Two poses carried together are, to the bit, the two carried alone (pose and every column),
    /// in both conventions, for all the columns, those of the position alone and a set with a
    /// column the chain does not move, into buffers of garbage; the arms off the kernel too. A
    /// pose with a NaN angle leaves the other lane's pose and columns as they are (NaN on its
    /// own), and a pose lacking angles reads them as zero in either lane.
    #[test]
    fn two_poses_together_are_the_two_alone() {
        let params = dh_params();
        let mut stray = params[2..30].to_vec();
        stray.insert(4, ParamId::Offset(9));
        let [urdf, compliant, harmonic] = arms_off_the_kernel();
        let models = [(arm(Convention::Classic), true), (arm(Convention::Modified), true), (urdf, false)];
        for (model, dh) in models.into_iter().chain([(compliant, false), (harmonic, false)]) {
            let chain = Chain::new(&model);
            for (set, columns) in [
                ColumnMap::new(&params),
                ColumnMap::new(&params[1..25]).positions_only(),
                ColumnMap::new(&stray).positions_only(),
                ColumnMap::new(&ParamId::all()),
            ]
            .into_iter()
            .enumerate()
            {
                // The plain DH arms take the two-pose kernel for the first three sets (every
                // parameter's set has harmonics and compliance: the general pass).
                let kernel = dh && set < 3;
                assert_eq!(
                    chain.kernel(Some(&columns)).is_some(),
                    kernel,
                    "{:?} set {set}",
                    model.convention
                );
                for pose in 0..10 {
                    let mut enc: [Vec<f64>; 2] = [0, 1].map(|lane| {
                        (0..7).map(|j| ((pose * 14 + lane * 7 + j) as f64 * 0.53).sin() * 175.0).collect()
                    });
                    match pose {
                        3 => enc[1][4] = f64::NAN,
                        4 => enc[0][0] = f64::NAN,
                        5 => enc[1].truncate(5),
                        _ => {}
                    }
                    let sin_cos =
                        enc.clone().map(|e| e.iter().map(|&q| encoder_sin_cos(q)).collect::<Vec<_>>());
                    let mut alone = [0, 1].map(|_| vec![[f64::NAN; 9]; columns.len()]);
                    let mut together = alone.clone();
                    let single: Vec<ToolPose> = alone
                        .iter_mut()
                        .zip(&enc)
                        .zip(&sin_cos)
                        .map(|((jac, e), sc)| chain.pose_with_sin_cos_and_jacobian(e, sc, &columns, jac))
                        .collect();
                    let [first, second] = &mut together;
                    let pair = chain.pose_pair_with_sin_cos_and_jacobian(
                        [&enc[0], &enc[1]],
                        [&sin_cos[0], &sin_cos[1]],
                        &columns,
                        [first, second],
                    );
                    let bits =
                        |p: &ToolPose| [p.position_mm, p.x_axis, p.z_axis].map(|v| v.map(f64::to_bits));
                    for lane in 0..2 {
                        let label = format!("{:?} kernel {kernel} pose {pose} lane {lane}", model.convention);
                        assert_eq!(bits(&pair[lane]), bits(&single[lane]), "{label}");
                        for (c, (t, a)) in together[lane].iter().zip(&alone[lane]).enumerate() {
                            assert_eq!(t.map(f64::to_bits), a.map(f64::to_bits), "{label} column {c}");
                        }
                        let nan = enc[lane].iter().any(|q| q.is_nan());
                        assert_eq!(single[lane].position_mm.x.is_nan(), nan, "{label}");
                        if !nan {
                            assert!(alone[lane].iter().flatten().all(|v| v.is_finite()), "{label}");
                        }
                    }
                    assert_ne!(single[0].position_mm, single[1].position_mm, "two different poses");
                }
            }
        }
    }

    /// Two poses carried together without columns are, to the bit, the two carried alone: the
    /// DH arms (a tool point, a scale) through the two-pose kernel; a URDF arm and DH arms with a
    /// compliance or an encoder harmonic through the general pass. A pose with a NaN angle
    /// leaves the other lane as it is, and a pose lacking angles reads them as zero in either.
    #[test]
    fn two_poses_without_columns_are_the_two_alone() {
        let [urdf, compliant, harmonic] = arms_off_the_kernel();
        let models = [(arm(Convention::Classic), true), (arm(Convention::Modified), true)];
        for (model, kernel) in
            models.into_iter().chain([(urdf, false), (compliant, false), (harmonic, false)])
        {
            let chain = Chain::new(&model);
            assert_eq!(chain.kernel(None).is_some(), kernel, "{:?}", model.convention);
            for pose in 0..12 {
                let mut enc: [Vec<f64>; 2] = [0, 1].map(|lane| {
                    (0..7).map(|j| ((pose * 14 + lane * 7 + j) as f64 * 0.41).cos() * 165.0).collect()
                });
                match pose {
                    3 => enc[1][4] = f64::NAN,
                    4 => enc[0][0] = f64::NAN,
                    5 => enc[1].truncate(5),
                    _ => {}
                }
                let sin_cos = enc.clone().map(|e| e.iter().map(|&q| encoder_sin_cos(q)).collect::<Vec<_>>());
                let pair = chain.pose_pair_with_sin_cos([&enc[0], &enc[1]], [&sin_cos[0], &sin_cos[1]]);
                let bits = |p: &ToolPose| [p.position_mm, p.x_axis, p.z_axis].map(|v| v.map(f64::to_bits));
                for lane in 0..2 {
                    let alone = chain.pose_with_sin_cos(&enc[lane], &sin_cos[lane]);
                    let label = format!("{:?} kernel {kernel} pose {pose} lane {lane}", model.convention);
                    assert_eq!(bits(&pair[lane]), bits(&alone), "{label}");
                    let nan = enc[lane].iter().any(|q| q.is_nan());
                    assert_eq!(alone.position_mm.x.is_nan(), nan, "{label}");
                }
            }
        }
    }

    /// [`arm`] with a second tip on its fifth joint (a branched model; both tips on the kernel).
    fn branched(convention: Convention) -> ArmModel {
        use crate::model::tree::Tip;
        let mut model = arm(convention);
        model.tree.parents = (0..7_usize).map(|j| j.checked_sub(1)).collect();
        let tip = |name: &str, joint, tcp_mm| Tip { name: name.into(), joint, tcp_mm };
        model.tree.tips = vec![tip("end", 6, [0.0; 3]), tip("side", 4, [-20.0, 15.0, 60.0])];
        model
    }

    /// Poses started at their flanges are, to the bit, the whole pass' (the pose and every
    /// column, into buffers of garbage), two together and one alone, in both conventions and on
    /// both tips of a branched model, for the tool point's columns with the scale, without it,
    /// of the position alone, one of them, and none; the flanges taken on the chain of other
    /// values of those parameters (they read none of them). A chain whose columns move anything
    /// before the tool, or off the kernel, does not start there; nor does a tip for another
    /// tip's tool point.
    #[test]
    fn poses_from_their_flanges_are_the_whole_pass() {
        let tcp =
            |tip: usize| [0, 1, 2].map(|k| if tip == 0 { ParamId::Tcp(k) } else { ParamId::TipTcp(tip, k) });
        for model in
            [Convention::Classic, Convention::Modified].into_iter().flat_map(|c| [arm(c), branched(c)])
        {
            let tips = model.tree.tip_count();
            for tip in 0..tips {
                let [x, y, z] = tcp(tip);
                let sets = [
                    ColumnMap::new(&[x, y, z, ParamId::Scale]),
                    ColumnMap::new(&[ParamId::Scale, z, x]),
                    ColumnMap::new(&[x, y, z]).positions_only(),
                    ColumnMap::new(&[y]),
                    ColumnMap::new(&[]),
                ];
                let chain = Chain::for_tip(&model, tip);
                // The flanges' chain: every parameter the columns may move, moved.
                let mut other = model.clone();
                for id in [x, y, z, ParamId::Scale] {
                    other.set(id, other.get(id) * 1.3 + 4.5);
                }
                let flanges_of = Chain::for_tip(&other, tip);
                for (set, columns) in sets.iter().enumerate() {
                    let label = format!("{:?} tip {tip} of {tips}, set {set}", model.convention);
                    assert!(chain.starts_at_flange(columns), "{label}");
                    for pose in 0..8 {
                        let mut enc: [Vec<f64>; 2] = [0, 1].map(|lane| {
                            (0..7).map(|j| ((pose * 14 + lane * 7 + j) as f64 * 0.37).sin() * 170.0).collect()
                        });
                        if pose == 3 {
                            enc[1][2] = f64::NAN;
                        }
                        let sin_cos =
                            enc.clone().map(|e| e.iter().map(|&q| encoder_sin_cos(q)).collect::<Vec<_>>());
                        let flanges = flanges_of
                            .flange_pair([&enc[0], &enc[1]], [&sin_cos[0], &sin_cos[1]])
                            .expect("a DH chain");
                        for lane in 0..2 {
                            let alone = flanges_of.flange(&enc[lane], &sin_cos[lane]).expect("a DH chain");
                            assert_eq!(
                                format!("{alone:?}"),
                                format!("{:?}", flanges[lane]),
                                "{label}: a flange of two is one alone"
                            );
                        }
                        let mut whole = [0, 1].map(|_| vec![[f64::NAN; 9]; columns.len()]);
                        let (mut started, mut single) = (whole.clone(), whole.clone());
                        let [w0, w1] = &mut whole;
                        let reference = chain.pose_pair_with_sin_cos_and_jacobian(
                            [&enc[0], &enc[1]],
                            [&sin_cos[0], &sin_cos[1]],
                            columns,
                            [w0, w1],
                        );
                        let [s0, s1] = &mut started;
                        let pair =
                            chain.pose_pair_from_flanges([&flanges[0], &flanges[1]], columns, [s0, s1]);
                        let one: Vec<ToolPose> = (0..2)
                            .map(|lane| chain.pose_from_flange(&flanges[lane], columns, &mut single[lane]))
                            .collect();
                        let bits =
                            |p: &ToolPose| [p.position_mm, p.x_axis, p.z_axis].map(|v| v.map(f64::to_bits));
                        let column_bits = |jac: &[PoseDerivative]| {
                            jac.iter().map(|c| c.map(f64::to_bits)).collect::<Vec<_>>()
                        };
                        for lane in 0..2 {
                            let label = format!("{label} pose {pose} lane {lane}");
                            for (p, j) in [(&pair[lane], &started[lane]), (&one[lane], &single[lane])] {
                                assert_eq!(bits(p), bits(&reference[lane]), "{label}");
                                assert_eq!(column_bits(j), column_bits(&whole[lane]), "{label}");
                            }
                            let nan = enc[lane].iter().any(|q| q.is_nan());
                            assert_eq!(reference[lane].position_mm.x.is_nan(), nan, "{label}");
                            if !nan && set < 4 {
                                assert!(whole[lane].iter().flatten().any(|v| *v != 0.0), "{label}: columns");
                            }
                        }
                    }
                }
                // A row's parameter, another tip's tool point: the whole pass.
                let chain_parameter = ColumnMap::new(&[x, ParamId::Length(2)]);
                let [a, b, c] = tcp(tips - 1 - tip);
                let another_tool = ColumnMap::new(&[a, b, c]);
                assert!(!chain.starts_at_flange(&chain_parameter), "{:?} tip {tip}", model.convention);
                assert_eq!(
                    chain.starts_at_flange(&another_tool),
                    tips == 1,
                    "{:?} tip {tip}",
                    model.convention
                );
            }
            let columns = ColumnMap::new(&tcp(0));
            assert_eq!(Tips::new(&model).start_at_flange(&columns), tips == 1, "{:?}", model.convention);
        }
        // A URDF arm, a compliance, an encoder harmonic: no flange.
        for model in arms_off_the_kernel() {
            let chain = Chain::new(&model);
            let label = format!("{:?}", model.convention);
            assert!(!chain.starts_at_flange(&ColumnMap::new(&[ParamId::Tcp(0)])), "{label}");
            let enc = [10.0; 7];
            let sin_cos = enc.map(encoder_sin_cos);
            assert!(chain.flange(&enc, &sin_cos).is_none(), "{label}");
        }
    }

    /// The columns of the position alone are the full columns' positions to the bit (their
    /// finish is a loop of its own), the axes' derivatives zero: both conventions (offsets, β
    /// tilts, a scale other than one) and a URDF arm (the general pass).
    #[test]
    fn positions_alone_are_the_full_columns_positions() {
        let mut urdf = ArmModel::suta_nominal();
        urdf.convention = Convention::Urdf;
        urdf.scale_ppm = -40.0;
        for model in [arm(Convention::Classic), arm(Convention::Modified), urdf] {
            let chain = Chain::new(&model);
            let params = ParamId::all();
            let (full, positions) = (ColumnMap::new(&params), ColumnMap::new(&params).positions_only());
            for pose in 0..10 {
                let enc: Vec<f64> = (0..7).map(|j| ((pose * 7 + j) as f64 * 0.61).cos() * 150.0).collect();
                let mut both = [vec![[f64::NAN; 9]; params.len()], vec![[f64::NAN; 9]; params.len()]];
                chain.pose_with_jacobian(&enc, &full, &mut both[0]);
                chain.pose_with_jacobian(&enc, &positions, &mut both[1]);
                for (c, (f, p)) in both[0].iter().zip(&both[1]).enumerate() {
                    let label = format!("{:?} column {c}", model.convention);
                    assert!(f[..3].iter().zip(&p[..3]).all(|(a, b)| a.to_bits() == b.to_bits()), "{label}");
                    assert_eq!(p[3..], [0.0; 6], "{label}");
                }
                assert!(both[1].iter().any(|p| p[0] != 0.0), "columns of something");
            }
        }
    }
}
