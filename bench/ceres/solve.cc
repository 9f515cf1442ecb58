// The two problems in Ceres. Every touch's tool point and its Jacobian over the arm's free
// parameters are computed once per evaluation, in an EvaluationCallback (Ceres' hook for
// computation shared between residual blocks), with automatic derivatives (ceres::Jet); each
// residual block then only reads its touches from that cache. The artefact's pair residuals are
// one block each with a Huber loss; the tracker's points are one block of three rows each over
// the arm's parameters and their session's base.
#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <iostream>

#include "problems.h"

namespace kincal_peer {
namespace {

// Tool points (3 per touch) and Jacobians (3 × n per touch) at the current parameters.
class TouchCache : public ceres::EvaluationCallback {
 public:
  TouchCache(const Arm& arm, std::vector<Angles> touches, const double* x)
      : evaluator_(MakeChainEvaluator(arm)),
        touches_(std::move(touches)),
        x_(x),
        n(static_cast<int>(arm.free.size())),
        points(3 * touches_.size()),
        jacobians(3 * touches_.size() * n) {}

  void PrepareForEvaluation(bool evaluate_jacobians, bool new_evaluation_point) override {
    if (!new_evaluation_point && (have_jacobians_ || !evaluate_jacobians)) return;
    evaluator_->Evaluate(x_, touches_, points.data(), evaluate_jacobians ? jacobians.data() : nullptr);
    have_jacobians_ = evaluate_jacobians;
  }

 private:
  std::unique_ptr<ChainEvaluator> evaluator_;
  std::vector<Angles> touches_;
  const double* x_;
  bool have_jacobians_ = false;

 public:
  const int n;
  std::vector<double> points, jacobians;
};

// r = ‖p_a − p_b‖ − D (mm) over the arm's n free parameters.
class PairDistance final : public ceres::CostFunction {
 public:
  PairDistance(const TouchCache* cache, int a, int b, double certified_mm)
      : cache_(cache), a_(a), b_(b), certified_mm_(certified_mm) {
    set_num_residuals(1);
    mutable_parameter_block_sizes()->push_back(cache->n);
  }

  bool Evaluate(double const* const*, double* residual, double** jacobians) const override {
    const double* pa = &cache_->points[3 * a_];
    const double* pb = &cache_->points[3 * b_];
    const double d[3] = {pa[0] - pb[0], pa[1] - pb[1], pa[2] - pb[2]};
    const double length = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    residual[0] = length - certified_mm_;
    if (jacobians != nullptr && jacobians[0] != nullptr) {
      const int n = cache_->n;
      const double inv = 1.0 / std::max(length, 1e-12);
      const double* ja = &cache_->jacobians[3 * a_ * n];
      const double* jb = &cache_->jacobians[3 * b_ * n];
      for (int k = 0; k < n; ++k) {
        double g = 0;
        for (int i = 0; i < 3; ++i) g += d[i] * (ja[i * n + k] - jb[i * n + k]);
        jacobians[0][k] = g * inv;
      }
    }
    return true;
  }

 private:
  const TouchCache* cache_;
  int a_, b_;
  double certified_mm_;
};

double RmsOfRows(ceres::Problem& problem, int rows_per_point) {
  ceres::Problem::EvaluateOptions options;
  options.apply_loss_function = false;
  std::vector<double> r;
  problem.Evaluate(options, nullptr, &r, nullptr, nullptr);
  double sum = 0;
  for (double v : r) sum += v * v;
  return std::sqrt(sum / (r.size() / rows_per_point));
}

Outcome OutcomeOf(const ceres::Solver::Summary& summary, const std::vector<double>& x, double rms_mm) {
  Outcome o;
  o.initial_cost = summary.initial_cost;
  o.final_cost = summary.final_cost;
  o.iterations = summary.num_successful_steps + summary.num_unsuccessful_steps;
  o.jacobian_evaluations = summary.num_jacobian_evaluations;
  o.termination = ceres::TerminationTypeToString(summary.termination_type);
  o.x = x;
  o.rms_mm = rms_mm;
  return o;
}

// Horn/Kabsch: the rotation and shift that best map `from` onto `to` (3 per point).
void AbsoluteOrientation(const std::vector<double>& from, const double* to, size_t points, double* base) {
  Eigen::Vector3d cf = Eigen::Vector3d::Zero(), ct = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < points; ++i) {
    cf += Eigen::Vector3d(&from[3 * i]);
    ct += Eigen::Vector3d(&to[3 * i]);
  }
  cf /= points, ct /= points;
  Eigen::Matrix3d h = Eigen::Matrix3d::Zero();
  for (size_t i = 0; i < points; ++i) {
    h += (Eigen::Vector3d(&from[3 * i]) - cf) * (Eigen::Vector3d(&to[3 * i]) - ct).transpose();
  }
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(h, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  d(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0 ? -1.0 : 1.0;
  const Eigen::Matrix3d r = svd.matrixV() * d * svd.matrixU().transpose();
  ceres::RotationMatrixToAngleAxis(r.data(), base);  // Eigen is column-major, as this overload wants
  const Eigen::Vector3d t = ct - r * cf;
  base[3] = t[0], base[4] = t[1], base[5] = t[2];
}

// Tracker: the arm's tool points as TouchCache computes them, plus each session's rotation R_s
// and its derivatives ∂R_s/∂ω_k (automatic, once per evaluation).
class SessionCache : public ceres::EvaluationCallback {
 public:
  SessionCache(TouchCache* arm, const std::vector<std::vector<double>>* bases) : arm_(arm), bases_(bases) {
    rotation.resize(bases->size());
    derivative.resize(bases->size());
  }

  void PrepareForEvaluation(bool evaluate_jacobians, bool new_evaluation_point) override {
    arm_->PrepareForEvaluation(evaluate_jacobians, new_evaluation_point);
    using J = ceres::Jet<double, 3>;
    for (size_t s = 0; s < bases_->size(); ++s) {
      const double* w = (*bases_)[s].data();
      const J omega[3] = {J(w[0], 0), J(w[1], 1), J(w[2], 2)};
      J r[9];
      ceres::AngleAxisToRotationMatrix(omega, ceres::RowMajorAdapter3x3(r));
      for (int e = 0; e < 9; ++e) {
        rotation[s][e] = r[e].a;
        for (int k = 0; k < 3; ++k) derivative[s][k][e] = r[e].v[k];
      }
    }
  }

 private:
  TouchCache* arm_;
  const std::vector<std::vector<double>>* bases_;

 public:
  std::vector<std::array<double, 9>> rotation;                   // row-major
  std::vector<std::array<std::array<double, 9>, 3>> derivative;  // ∂R/∂ω_k, row-major
};

// r = R_s p_i + t_s − X_i (mm) over the arm's n parameters and the session's base (ω, t).
class PointResidual final : public ceres::CostFunction {
 public:
  PointResidual(const TouchCache* arm, const SessionCache* sessions, int point, int session, const double* measured)
      : arm_(arm), sessions_(sessions), point_(point), session_(session), measured_(measured) {
    set_num_residuals(3);
    mutable_parameter_block_sizes()->push_back(arm->n);
    mutable_parameter_block_sizes()->push_back(6);
  }

  bool Evaluate(double const* const* parameters, double* residual, double** jacobians) const override {
    const double* p = &arm_->points[3 * point_];
    const double* r = sessions_->rotation[session_].data();
    const double* t = parameters[1] + 3;
    for (int i = 0; i < 3; ++i) {
      residual[i] = r[3 * i] * p[0] + r[3 * i + 1] * p[1] + r[3 * i + 2] * p[2] + t[i] - measured_[i];
    }
    if (jacobians == nullptr) return true;
    const int n = arm_->n;
    if (jacobians[0] != nullptr) {
      const double* jp = &arm_->jacobians[3 * point_ * n];
      for (int i = 0; i < 3; ++i) {
        for (int k = 0; k < n; ++k) {
          jacobians[0][i * n + k] = r[3 * i] * jp[k] + r[3 * i + 1] * jp[n + k] + r[3 * i + 2] * jp[2 * n + k];
        }
      }
    }
    if (jacobians[1] != nullptr) {
      for (int i = 0; i < 3; ++i) {
        for (int k = 0; k < 3; ++k) {
          const double* d = sessions_->derivative[session_][k].data();
          jacobians[1][i * 6 + k] = d[3 * i] * p[0] + d[3 * i + 1] * p[1] + d[3 * i + 2] * p[2];
          jacobians[1][i * 6 + 3 + k] = i == k ? 1.0 : 0.0;
        }
      }
    }
    return true;
  }

 private:
  const TouchCache* arm_;
  const SessionCache* sessions_;
  int point_, session_;
  const double* measured_;
};

void Bound(ceres::Problem& problem, double* x, const std::vector<double>& lower, const std::vector<double>& upper,
           const Settings& settings) {
  if (!settings.bounds) return;
  for (size_t k = 0; k < lower.size(); ++k) {
    if (std::isfinite(lower[k])) problem.SetParameterLowerBound(x, static_cast<int>(k), lower[k]);
    if (std::isfinite(upper[k])) problem.SetParameterUpperBound(x, static_cast<int>(k), upper[k]);
  }
}

ceres::Solver::Summary Solve(const Settings& settings, ceres::Problem& problem) {
  ceres::Solver::Summary summary;
  ceres::Solve(settings.solver, &problem, &summary);
  if (settings.report) std::cerr << summary.FullReport() << "\n";
  return summary;
}

}  // namespace

std::vector<Outcome> SolveArtefact(const ArtefactProblem& p, size_t starts, const Settings& settings) {
  std::vector<double> x(p.arm.free.size());
  TouchCache cache(p.arm, p.touches, x.data());
  ceres::HuberLoss huber(p.huber_delta_mm);
  ceres::Problem::Options problem_options;
  problem_options.evaluation_callback = &cache;
  problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  for (size_t k = 0; k < p.pair_a.size(); ++k) {
    problem.AddResidualBlock(new PairDistance(&cache, p.pair_a[k], p.pair_b[k], p.certified_mm[k]), &huber, x.data());
  }
  Bound(problem, x.data(), p.lower, p.upper, settings);
  std::vector<Outcome> outcomes;
  for (size_t s = 0; s < std::min(starts, p.starts.size()); ++s) {
    for (size_t k = 0; k < x.size(); ++k) x[k] = std::clamp(p.starts[s][k], p.lower[k], p.upper[k]);
    const ceres::Solver::Summary summary = Solve(settings, problem);
    outcomes.push_back(OutcomeOf(summary, x, RmsOfRows(problem, 1)));
  }
  return outcomes;
}

Outcome SolveTracker(const TrackerProblem& p, const Settings& settings) {
  std::vector<Angles> touches;
  std::vector<int> session_of;
  for (size_t s = 0; s < p.sessions.size(); ++s) {
    touches.insert(touches.end(), p.sessions[s].q.begin(), p.sessions[s].q.end());
    session_of.insert(session_of.end(), p.sessions[s].q.size(), static_cast<int>(s));
  }
  std::vector<double> x(p.arm.free.size());
  for (size_t k = 0; k < x.size(); ++k) x[k] = std::clamp(p.arm.value(p.arm.free[k]), p.lower[k], p.upper[k]);
  TouchCache arm(p.arm, touches, x.data());
  // Each base starts at its closed form for the nominal arm.
  std::vector<std::vector<double>> bases(p.sessions.size(), std::vector<double>(6));
  arm.PrepareForEvaluation(false, true);
  size_t first = 0;
  for (size_t s = 0; s < p.sessions.size(); ++s) {
    const size_t count = p.sessions[s].q.size();
    const std::vector<double> model(arm.points.begin() + 3 * first, arm.points.begin() + 3 * (first + count));
    AbsoluteOrientation(model, p.sessions[s].measured_mm.data(), count, bases[s].data());
    first += count;
  }
  SessionCache cache(&arm, &bases);
  ceres::Problem::Options problem_options;
  problem_options.evaluation_callback = &cache;
  ceres::Problem problem(problem_options);
  first = 0;
  for (size_t s = 0; s < p.sessions.size(); ++s) {
    for (size_t i = 0; i < p.sessions[s].q.size(); ++i) {
      problem.AddResidualBlock(new PointResidual(&arm, &cache, static_cast<int>(first + i), static_cast<int>(s),
                                                 &p.sessions[s].measured_mm[3 * i]),
                               nullptr, x.data(), bases[s].data());
    }
    first += p.sessions[s].q.size();
  }
  Bound(problem, x.data(), p.lower, p.upper, settings);
  const ceres::Solver::Summary summary = Solve(settings, problem);
  return OutcomeOf(summary, x, RmsOfRows(problem, 3));
}

}  // namespace kincal_peer
