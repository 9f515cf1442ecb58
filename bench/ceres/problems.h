// The two benchmark problems as the Ceres peer reads them (problem files written by
// `kincal bench`; the SciPy peers read the same files) and solves them.
#pragma once

#include <ceres/solver.h>

#include <string>
#include <vector>

#include "chain.h"

namespace kincal_peer {

// Artefact calibration: touches of landmarks in placements; one residual per pair of touches of
// different landmarks in one placement and repeat, r = ‖p_a − p_b‖ − D_ab (mm), Huber loss.
struct ArtefactProblem {
  Arm arm;
  std::vector<Angles> touches;
  std::vector<int> pair_a, pair_b;
  std::vector<double> certified_mm;
  std::vector<double> lower, upper;
  std::vector<std::vector<double>> starts;  // the nominal start first, then the random restarts
  double huber_delta_mm = 0;
};

// Tracker calibration: measured points X_i = R_s · p(q_i) + t_s of sessions s, one base
// (angle-axis rad, shift mm) per session, three residual rows per point, plain least squares.
struct TrackerSession {
  std::vector<Angles> q;
  std::vector<double> measured_mm;  // 3 per point
};

struct TrackerProblem {
  Arm arm;
  std::vector<TrackerSession> sessions;
  std::vector<double> lower, upper;
  size_t points() const;
};

ArtefactProblem ReadArtefact(const std::string& path);
TrackerProblem ReadTracker(const std::string& path);

// One solve's outcome.
struct Outcome {
  double initial_cost = 0, final_cost = 0, rms_mm = 0;
  int iterations = 0;            // successful + unsuccessful steps
  int jacobian_evaluations = 0;  // Gauss–Newton systems formed
  std::string termination;
  std::vector<double> x;
};

// How to solve.
struct Settings {
  ceres::Solver::Options solver;
  bool bounds = true;   // the problem file's bounds (with bounds, Ceres' trust region also
                        // evaluates the Jacobian at each candidate point, for its projected line search)
  bool report = false;  // Ceres' full report of each solve on stderr
};

// Build the problem and solve from its first `starts` starts (1: the nominal start alone).
std::vector<Outcome> SolveArtefact(const ArtefactProblem& problem, size_t starts, const Settings& settings);
Outcome SolveTracker(const TrackerProblem& problem, const Settings& settings);

}  // namespace kincal_peer
