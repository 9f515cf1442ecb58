//! Bounded nonlinear least squares with a robust loss: a Levenberg–Marquardt trust-region method.
//!
//! The solver knows residual vectors, Jacobians and bounds — nothing about arms.
//! Cost = Σ ρ(r_i) with ρ(r) = ½r² for |r| ≤ δ and δ|r| − ½δ² beyond (Huber), the same
//! cost as SciPy's `least_squares(loss='huber', f_scale=δ)`. Each iteration solves
//! (H + λ·diag H) s = −g on the variables not held by an active bound, where
//! g = Σ ρ′(r_i) r_i ∇r_i and H = Σ w_i ∇r_i ∇r_iᵀ with IRLS weights w_i = ρ′(r_i)/r_i·r_i;
//! the step is projected onto the bounds and accepted on a positive gain ratio
//! (Nielsen's update of λ). It stops on Ceres' tests ([`Termination::Ceres`]): the projected
//! gradient (gradient tolerance), a step too short to matter, checked before its point is
//! evaluated (parameter tolerance), or a step that changes the cost by too little either way
//! (function tolerance).

use nalgebra::{DMatrix, DVector};

/// A residual vector r(x) ∈ ℝᵐ and its Jacobian.
pub trait Residuals {
    /// Number of residuals m.
    fn len(&self) -> usize;
    /// True when there are no residuals.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Write r(x) into `r`; when `jacobian` is given also ∂r/∂x, row-major m × n.
    fn evaluate(&self, x: &[f64], r: &mut [f64], jacobian: Option<&mut [f64]>);
    /// Write r(x) into `r` and return the normal matrix JᵀWJ and the gradient JᵀWr over the
    /// n = `x.len()` unknowns, W the IRLS weights `loss.weight(r_i)`. The default builds the dense
    /// m × n Jacobian; a problem whose rows each touch few unknowns accumulates row by row instead
    /// (no m × n matrix, so the cost per residual does not grow with m).
    fn normal_equations(&self, x: &[f64], r: &mut [f64], loss: Loss) -> (DMatrix<f64>, DVector<f64>) {
        let n = x.len();
        let mut jacobian = vec![0.0; r.len() * n];
        self.evaluate(x, r, Some(&mut jacobian));
        let weights: Vec<f64> = r.iter().map(|&v| loss.weight(v)).collect();
        normal_equations(&jacobian, r, &weights, n)
    }
}

/// Robust loss applied to each residual.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Loss {
    /// Plain least squares: ρ(r) = ½r².
    Linear,
    /// Huber loss with threshold δ (same unit as the residuals).
    Huber(f64),
}

impl Loss {
    /// ρ(r).
    pub fn rho(self, r: f64) -> f64 {
        match self {
            Loss::Huber(d) if r.abs() > d => d * r.abs() - 0.5 * d * d,
            _ => 0.5 * r * r,
        }
    }

    /// ρ′(r)/r: the weight of residual r in the gradient and in the IRLS normal matrix.
    pub fn weight(self, r: f64) -> f64 {
        match self {
            Loss::Huber(d) if r.abs() > d => d / r.abs(),
            _ => 1.0,
        }
    }

    /// Total cost Σ ρ(r_i).
    pub fn cost(self, r: &[f64]) -> f64 {
        r.iter().map(|&v| self.rho(v)).sum()
    }
}

/// Solver settings.
#[derive(Clone, Copy, Debug)]
pub struct SolverOptions {
    /// Loss applied to every residual.
    pub loss: Loss,
    /// Most iterations (Jacobian evaluations) before giving up.
    pub max_iterations: usize,
    /// Stop when an accepted step lowers the cost by less than `ftol`·cost.
    pub ftol: f64,
    /// Stop when a step is shorter than `xtol`·(‖x‖ + `xtol`).
    pub xtol: f64,
    /// Stop when the projected gradient's largest entry is below `gtol`.
    pub gtol: f64,
    /// Which steps the cost and step tests apply to.
    pub termination: Termination,
    /// Evaluate the normal equations (with the residuals) at every trial point instead of its
    /// residuals alone: an accepted step needs them there next, so a solve whose steps are
    /// accepted (a warm start near its minimum) evaluates each point once, and one that stops
    /// on a lowered cost has its normal matrix at the solution. A rejected step costs a Jacobian.
    pub trial_normal: bool,
}

impl Default for SolverOptions {
    fn default() -> Self {
        SolverOptions {
            loss: Loss::Linear,
            max_iterations: 200,
            ftol: 1e-12,
            xtol: 1e-12,
            gtol: 1e-10,
            termination: Termination::Ceres,
            trial_normal: false,
        }
    }
}

/// Which steps end a solve besides the gradient test.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Termination {
    /// Ceres' tests: a step shorter than `xtol`·(‖x‖ + `xtol`) ends the solve before its point is
    /// evaluated (parameter tolerance), and a step that changes the cost by less than
    /// `ftol`·cost, lower or higher, ends it (function tolerance; taken when it lowers the cost).
    /// A solve near its minimum stops at its first negligible step instead of shrinking the trust
    /// region step after step.
    Ceres,
    /// Only accepted steps end a solve, by a fall of the cost below `ftol`·cost or a length
    /// below `xtol`·(‖x‖ + `xtol`); rejected steps shrink the trust region until one is accepted.
    /// Kept by the simulator's inverse kinematics and the haptic fits, whose results were
    /// generated with it.
    AcceptedSteps,
}

impl Termination {
    /// The damping λ of the first step: Ceres' 10⁻⁴ (its trust region's first radius, 10⁴), or
    /// the 10⁻³ the results of [`Termination::AcceptedSteps`] were generated with.
    pub fn initial_damping(self) -> f64 {
        match self {
            Termination::Ceres => 1e-4,
            Termination::AcceptedSteps => 1e-3,
        }
    }
}

/// Why the solver stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StopReason {
    /// The cost stopped falling.
    CostConverged,
    /// The step became negligible.
    StepConverged,
    /// The projected gradient vanished.
    GradientConverged,
    /// No step could lower the cost any more.
    NoProgress,
    /// The iteration limit was hit.
    IterationLimit,
}

/// Result of one solve.
#[derive(Clone, Debug)]
pub struct Solution {
    /// Parameters at the end.
    pub x: Vec<f64>,
    /// Cost Σρ(r) at `x`.
    pub cost: f64,
    /// Residuals at `x`.
    pub residuals: Vec<f64>,
    /// Jacobian evaluations.
    pub iterations: usize,
    /// Why it stopped.
    pub stop: StopReason,
    /// Cost Σρ(r) at the start (`x0` clamped into the bounds).
    pub initial_cost: f64,
    /// The normal matrix JᵀWJ at `x` when the solve's last Jacobian evaluation was at `x` (it
    /// stopped on a negligible step, a vanished gradient or a rejected step): the covariance at
    /// the solution needs no evaluation more. `None` when its last step moved `x`.
    pub normal_at_x: Option<DMatrix<f64>>,
}

/// Normal matrix JᵀWJ and gradient JᵀWr of a row-major Jacobian with per-row weights.
pub fn normal_equations(
    jacobian: &[f64],
    r: &[f64],
    weights: &[f64],
    n: usize,
) -> (DMatrix<f64>, DVector<f64>) {
    let (mut upper, mut g) = (vec![0.0; n * n], vec![0.0; n]);
    crate::numerics::normal::add_gram(&mut upper, &mut g, n, &jacobian[..r.len() * n], weights, r);
    (symmetric(n, &upper), DVector::from_vec(g))
}

/// The symmetric n × n matrix whose upper triangle is `upper` (row-major).
pub fn symmetric(n: usize, upper: &[f64]) -> DMatrix<f64> {
    DMatrix::from_fn(n, n, |a, b| upper[a.min(b) * n + a.max(b)])
}

/// Minimise Σρ(r(x)) over lower ≤ x ≤ upper from `x0` (clamped into the bounds first).
pub fn solve(
    problem: &dyn Residuals,
    x0: &[f64],
    lower: &[f64],
    upper: &[f64],
    options: &SolverOptions,
) -> Solution {
    solve_from(problem, x0, lower, upper, options, None)
}

/// What a caller already has at a solve's start point: the normal matrix, the gradient and the
/// cost Σρ(r) there.
#[derive(Clone, Debug)]
pub struct KnownStart {
    /// JᵀWJ.
    pub normal: DMatrix<f64>,
    /// JᵀWr.
    pub gradient: DVector<f64>,
    /// Σρ(r).
    pub cost: f64,
}

/// [`solve`], with the normal equations and the cost at `x0` given when the caller has them
/// (`first`, taken only when x0 is inside the bounds): the solve then evaluates nothing there
/// (its residuals only when it takes no step, to return them).
pub fn solve_from(
    problem: &dyn Residuals,
    x0: &[f64],
    lower: &[f64],
    upper: &[f64],
    options: &SolverOptions,
    first: Option<KnownStart>,
) -> Solution {
    let n = x0.len();
    let m = problem.len();
    let loss = options.loss;
    let clamp = |x: &mut [f64]| {
        for i in 0..n {
            x[i] = x[i].clamp(lower[i], upper[i]);
        }
    };
    let ceres = options.termination == Termination::Ceres;
    let mut x = x0.to_vec();
    clamp(&mut x);
    // What the caller knows is of x0 itself: not of the point the bounds move it to.
    let first = first.filter(|_| x == x0);
    // The residuals at x once evaluated there (a step taken swaps in its point's); a start
    // given by its cost has none until a step is taken.
    let mut r = vec![0.0; m];
    let mut r_at_x = first.is_none();
    let (mut h, mut g, mut cost) = match first {
        Some(known) => (known.normal, known.gradient, known.cost),
        None => {
            let (h, g) = problem.normal_equations(&x, &mut r, loss);
            (h, g, loss.cost(&r))
        }
    };
    let initial_cost = cost;
    // The normal equations at x evaluated with its trial (`trial_normal`), not taken yet.
    let mut pending: Option<(DMatrix<f64>, DVector<f64>)> = None;
    let mut lambda = options.termination.initial_damping();
    let mut nu = 2.0;
    let mut trial = vec![0.0; n];
    let mut r_trial = vec![0.0; m];
    let mut iterations = 1;
    let mut need_jacobian = false;
    let stop = loop {
        if need_jacobian {
            if iterations >= options.max_iterations {
                break StopReason::IterationLimit;
            }
            (h, g) = match pending.take() {
                Some(known) => known,
                None => problem.normal_equations(&x, &mut r, loss),
            };
            iterations += 1;
            need_jacobian = false;
        }
        // Variables held by a bound the gradient pushes against are left out of the step.
        let at_bound = |i: usize| (x[i] <= lower[i] && g[i] > 0.0) || (x[i] >= upper[i] && g[i] < 0.0);
        let active: Vec<usize> = (0..n).filter(|&i| !at_bound(i)).collect();
        let projected_gradient = active.iter().map(|&i| g[i].abs()).fold(0.0, f64::max);
        if projected_gradient < options.gtol {
            break StopReason::GradientConverged;
        }
        let k = active.len();
        let mut a = DMatrix::zeros(k, k);
        let mut b = DVector::zeros(k);
        for (p, &i) in active.iter().enumerate() {
            b[p] = -g[i];
            for (q, &j) in active.iter().enumerate() {
                a[(p, q)] = h[(i, j)];
            }
            a[(p, p)] += lambda * h[(i, i)].max(1e-12);
        }
        let Some(step) = a.cholesky().map(|c| c.solve(&b)) else {
            lambda *= nu;
            nu *= 2.0;
            if lambda > 1e20 {
                break StopReason::NoProgress;
            }
            continue;
        };
        trial.copy_from_slice(&x);
        for (p, &i) in active.iter().enumerate() {
            trial[i] += step[p];
        }
        clamp(&mut trial);
        let s = DVector::from_iterator(n, trial.iter().zip(&x).map(|(t, v)| t - v));
        let x_norm = x.iter().map(|v| v * v).sum::<f64>().sqrt();
        let short = s.norm() < options.xtol * (x_norm + options.xtol);
        if ceres && short {
            break StopReason::StepConverged;
        }
        let predicted = -(g.dot(&s) + 0.5 * s.dot(&(&h * &s)));
        let trial_normal = if options.trial_normal {
            Some(problem.normal_equations(&trial, &mut r_trial, loss))
        } else {
            problem.evaluate(&trial, &mut r_trial, None);
            None
        };
        let trial_cost = loss.cost(&r_trial);
        let actual = cost - trial_cost;
        if ceres && actual.abs() < options.ftol * cost {
            if actual > 0.0 {
                x.copy_from_slice(&trial);
                std::mem::swap(&mut r, &mut r_trial);
                r_at_x = true;
                pending = trial_normal;
                need_jacobian = true;
            }
            break StopReason::CostConverged;
        }
        if actual > 0.0 && predicted > 0.0 {
            let ratio = actual / predicted;
            x.copy_from_slice(&trial);
            std::mem::swap(&mut r, &mut r_trial);
            r_at_x = true;
            pending = trial_normal;
            cost = trial_cost;
            lambda *= (1.0_f64 / 3.0).max(1.0 - (2.0 * ratio - 1.0).powi(3));
            nu = 2.0;
            need_jacobian = true;
            if actual < options.ftol * cost {
                break StopReason::CostConverged;
            }
            if short {
                break StopReason::StepConverged;
            }
        } else {
            lambda *= nu;
            nu *= 2.0;
            if lambda > 1e20 {
                break StopReason::NoProgress;
            }
        }
    };
    if !ceres || !r_at_x {
        // Evaluated again as these results were generated (the same values), or for the first
        // time at a given start the solve never left.
        problem.evaluate(&x, &mut r, None);
    }
    // `need_jacobian`: a step was taken since the last evaluation of the normal equations (at
    // its trial point when `trial_normal`).
    let normal_at_x = if need_jacobian { pending.map(|known| known.0) } else { Some(h) };
    Solution { cost: loss.cost(&r), x, residuals: r, iterations, stop, initial_cost, normal_at_x }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rosenbrock as residuals: r = (10(y − x²), 1 − x).
    struct Rosenbrock;
    impl Residuals for Rosenbrock {
        fn len(&self) -> usize {
            2
        }
        fn evaluate(&self, x: &[f64], r: &mut [f64], jacobian: Option<&mut [f64]>) {
            r[0] = 10.0 * (x[1] - x[0] * x[0]);
            r[1] = 1.0 - x[0];
            if let Some(j) = jacobian {
                j.copy_from_slice(&[-20.0 * x[0], 10.0, -1.0, 0.0]);
            }
        }
    }

    #[test]
    fn finds_the_rosenbrock_minimum() {
        let s = solve(&Rosenbrock, &[-1.2, 1.0], &[-5.0; 2], &[5.0; 2], &SolverOptions::default());
        assert!((s.x[0] - 1.0).abs() < 1e-6 && (s.x[1] - 1.0).abs() < 1e-6, "{:?}", s);
    }

    #[test]
    fn respects_bounds_and_stops_on_the_boundary_optimum() {
        // Unconstrained optimum (1, 1) lies outside x ≤ 0.5; constrained optimum has x = 0.5, y = 0.25.
        let s = solve(&Rosenbrock, &[-1.2, 1.0], &[-5.0, -5.0], &[0.5, 5.0], &SolverOptions::default());
        assert!((s.x[0] - 0.5).abs() < 1e-9 && (s.x[1] - 0.25).abs() < 1e-6, "{:?}", s.x);
    }

    /// Rosenbrock's residuals and Jacobian evaluations, counted.
    struct Counted {
        residuals: std::cell::Cell<usize>,
        jacobians: std::cell::Cell<usize>,
    }
    impl Residuals for Counted {
        fn len(&self) -> usize {
            2
        }
        fn evaluate(&self, x: &[f64], r: &mut [f64], jacobian: Option<&mut [f64]>) {
            let count = if jacobian.is_some() { &self.jacobians } else { &self.residuals };
            count.set(count.get() + 1);
            Rosenbrock.evaluate(x, r, jacobian);
        }
    }

    fn counted() -> Counted {
        Counted { residuals: 0.into(), jacobians: 0.into() }
    }

    /// Normal equations taken at each trial point (with rejected steps on Rosenbrock's valley)
    /// and a start given by its normal equations and cost: the same solve as the plain one, with
    /// no residual-only evaluation but the last, and the normal matrix at the solution.
    #[test]
    fn trial_normal_and_a_known_start_are_the_plain_solve() {
        let (x0, lower, upper) = ([-1.2, 1.0], [-5.0; 2], [5.0; 2]);
        let plain_problem = counted();
        let plain = solve(&plain_problem, &x0, &lower, &upper, &SolverOptions::default());
        let options = SolverOptions { trial_normal: true, ..SolverOptions::default() };
        let mut r0 = [0.0; 2];
        let (normal, gradient) = Rosenbrock.normal_equations(&x0, &mut r0, Loss::Linear);
        let known = KnownStart { normal, gradient, cost: Loss::Linear.cost(&r0) };
        let fast_problem = counted();
        let fast = solve_from(&fast_problem, &x0, &lower, &upper, &options, Some(known));
        assert!(plain.iterations > 10 && plain_problem.residuals.get() > plain.iterations, "{plain:?}");
        assert_eq!((fast.x, fast.cost, fast.residuals), (plain.x, plain.cost, plain.residuals));
        assert_eq!(
            (fast.iterations, fast.stop, fast.initial_cost),
            (plain.iterations, plain.stop, plain.initial_cost)
        );
        assert_eq!(fast_problem.residuals.get(), 0);
        assert!(fast.normal_at_x.is_some());
        // A known start the solve never leaves: its residuals are evaluated, once.
        let at_minimum = counted();
        let mut r = [0.0; 2];
        let (normal, gradient) = Rosenbrock.normal_equations(&[1.0, 1.0], &mut r, Loss::Linear);
        let known = KnownStart { normal, gradient, cost: 0.0 };
        let stopped = solve_from(&at_minimum, &[1.0, 1.0], &lower, &upper, &options, Some(known));
        assert_eq!(
            (stopped.stop, stopped.residuals.as_slice()),
            (StopReason::GradientConverged, &[0.0, 0.0][..])
        );
        assert_eq!((at_minimum.residuals.get(), at_minimum.jacobians.get()), (1, 0));
    }

    /// Line fit y = a + b t with one gross outlier.
    struct Line(Vec<(f64, f64)>);
    impl Residuals for Line {
        fn len(&self) -> usize {
            self.0.len()
        }
        fn evaluate(&self, x: &[f64], r: &mut [f64], jacobian: Option<&mut [f64]>) {
            for (i, (t, y)) in self.0.iter().enumerate() {
                r[i] = x[0] + x[1] * t - y;
            }
            if let Some(j) = jacobian {
                for (i, (t, _)) in self.0.iter().enumerate() {
                    j[2 * i] = 1.0;
                    j[2 * i + 1] = *t;
                }
            }
        }
    }

    #[test]
    fn huber_loss_resists_an_outlier() {
        let mut pts: Vec<(f64, f64)> =
            (0..20).map(|i| (i as f64, 1.0 + 0.5 * i as f64 + 0.01 * ((i * 7 % 5) as f64 - 2.0))).collect();
        pts[10].1 += 50.0;
        let line = Line(pts);
        let opts = |loss| SolverOptions { loss, ..SolverOptions::default() };
        let plain = solve(&line, &[0.0, 0.0], &[-1e3; 2], &[1e3; 2], &opts(Loss::Linear));
        let huber = solve(&line, &[0.0, 0.0], &[-1e3; 2], &[1e3; 2], &opts(Loss::Huber(0.1)));
        assert!((huber.x[1] - 0.5).abs() < 0.01, "huber slope {}", huber.x[1]);
        assert!(
            (plain.x[0] - 1.0).abs() > (huber.x[0] - 1.0).abs() * 5.0,
            "plain {:?} huber {:?}",
            plain.x,
            huber.x
        );
        assert!((Loss::Huber(1.35).rho(3.0) - (1.35 * 3.0 - 0.5 * 1.35 * 1.35)).abs() < 1e-12);
    }
}
