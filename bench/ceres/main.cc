// Ceres Solver peer of kincal's two benchmark problems, written apart from kincal's code.
//
//   ceres_peer artefact PROBLEM.json [--starts K] [--repeats R] [tolerances] [--no-bounds] [--full-report]
//   ceres_peer tracker  PROBLEM.json [--repeats R] [tolerances] [--no-bounds] [--full-report]
//
// Solver: Levenberg–Marquardt trust region, dense normal Cholesky, one thread, bounds as the
// problem file states them (--no-bounds: none); --full-report prints Ceres' own report of each
// solve on stderr. The artefact from its first K starts (default: all; 1 is the
// nominal start alone), keeping the lowest cost. Prints one JSON object: the final cost (Ceres'
// ½Σρ, the same as kincal's and SciPy's), the RMS of the residuals, the iterations, and the CPU
// and wall time of building the problem and solving it (the median over R repeats; reading the
// file is reported apart). Bad input: a message naming the file and field on stderr, exit
// status 2.
#include <ceres/ceres.h>
#include <ceres/version.h>
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <functional>
#include <iostream>
#include <nlohmann/json.hpp>

#include "problems.h"

using kincal_peer::Outcome;
using nlohmann::json;

namespace {

struct Clock {
  double cpu_ms, wall_ms;
  static Clock Now() {
    timespec t{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    const auto wall = std::chrono::steady_clock::now().time_since_epoch();
    return {t.tv_sec * 1e3 + t.tv_nsec * 1e-6, std::chrono::duration<double, std::milli>(wall).count()};
  }
};

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

// Run `work` `repeats` times; the median CPU and wall time, ms.
json Timed(int repeats, const std::function<void()>& work) {
  std::vector<double> cpu, wall;
  for (int r = 0; r < repeats; ++r) {
    const Clock a = Clock::Now();
    work();
    const Clock b = Clock::Now();
    cpu.push_back(b.cpu_ms - a.cpu_ms);
    wall.push_back(b.wall_ms - a.wall_ms);
  }
  return {{"cpu_ms", Median(cpu)}, {"wall_ms", Median(wall)}};
}

json Describe(const Outcome& o) {
  return {{"initial_cost", o.initial_cost},
          {"cost", o.final_cost},
          {"rms_mm", o.rms_mm},
          {"iterations", o.iterations},
          {"jacobian_evaluations", o.jacobian_evaluations},
          {"termination", o.termination},
          {"x", o.x}};
}

int Usage(const char* message) {
  std::cerr << "ceres_peer: " << message
            << "\nusage: ceres_peer artefact|tracker PROBLEM.json [--repeats R] [--function-tolerance F]"
               " [--gradient-tolerance G] [--parameter-tolerance P] [--max-iterations K] [--starts K]"
               " [--no-bounds] [--full-report]\n";
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) return Usage("a problem kind and file are needed");
  const std::string kind = argv[1], path = argv[2];
  if (kind != "artefact" && kind != "tracker") return Usage(("unknown problem kind \"" + kind + "\"").c_str());
  int repeats = 1;
  size_t starts = 0;  // all
  kincal_peer::Settings settings;
  ceres::Solver::Options& options = settings.solver;
  // Tighter than Ceres' defaults (1e-6, 1e-10, 1e-8), with which the tracker's cost stops about
  // 1e-8 above the minimum: these reach it to 1e-9.
  options.linear_solver_type = ceres::DENSE_NORMAL_CHOLESKY;
  options.num_threads = 1;
  options.logging_type = ceres::SILENT;
  options.max_num_iterations = 200;
  options.function_tolerance = 1e-10;
  options.gradient_tolerance = 1e-12;
  options.parameter_tolerance = 1e-10;
  for (int i = 3; i < argc; ++i) {
    const std::string flag = argv[i];
    if (flag == "--no-bounds") {
      settings.bounds = false;
      continue;
    }
    if (flag == "--full-report") {
      settings.report = true;
      continue;
    }
    if (i + 1 >= argc) return Usage((flag + " needs a value").c_str());
    char* end = nullptr;
    const double value = std::strtod(argv[++i], &end);
    if (end == argv[i] || *end != '\0' || !(value > 0)) return Usage((flag + ": expected a positive number").c_str());
    const bool whole = flag == "--repeats" || flag == "--max-iterations" || flag == "--starts";
    if (whole && (value != std::floor(value) || value > 1e6)) {
      return Usage((flag + ": expected a whole number from 1 to 1000000").c_str());
    }
    if (flag == "--repeats") {
      repeats = static_cast<int>(value);
    } else if (flag == "--function-tolerance") {
      options.function_tolerance = value;
    } else if (flag == "--gradient-tolerance") {
      options.gradient_tolerance = value;
    } else if (flag == "--parameter-tolerance") {
      options.parameter_tolerance = value;
    } else if (flag == "--max-iterations") {
      options.max_num_iterations = static_cast<int>(value);
    } else if (flag == "--starts" && kind == "artefact") {
      starts = static_cast<size_t>(value);
    } else {
      return Usage(("unknown option " + flag).c_str());
    }
  }
  std::string why;
  if (!options.IsValid(&why)) return Usage(why.c_str());
  json out = {{"tool", "ceres"},
              {"ceres_version", CERES_VERSION_STRING},
              {"problem", kind},
              {"repeats", repeats},
              {"options",
               {{"linear_solver", "DENSE_NORMAL_CHOLESKY"},
                {"threads", options.num_threads},
                {"function_tolerance", options.function_tolerance},
                {"gradient_tolerance", options.gradient_tolerance},
                {"parameter_tolerance", options.parameter_tolerance},
                {"max_iterations", options.max_num_iterations},
                {"bounds", settings.bounds}}}};
  try {
    const Clock start = Clock::Now();
    if (kind == "artefact") {
      const kincal_peer::ArtefactProblem problem = kincal_peer::ReadArtefact(path);
      out["load_cpu_ms"] = Clock::Now().cpu_ms - start.cpu_ms;
      out["params"] = problem.arm.free.size();
      out["residuals"] = problem.pair_a.size();
      out["touches"] = problem.touches.size();
      if (starts == 0 || starts > problem.starts.size()) starts = problem.starts.size();
      std::vector<Outcome> all;
      json solve = Timed(repeats, [&] { all = SolveArtefact(problem, starts, settings); });
      // The lowest cost, the earliest start on an equal one (kincal also counts costs within its
      // function tolerance as equal: the same minimum; the costs are compared to 1e-9).
      size_t best = 0;
      for (size_t s = 1; s < all.size(); ++s) {
        if (all[s].final_cost < all[best].final_cost) best = s;
      }
      json each = json::array();
      int iterations = 0, jacobians = 0;
      for (const Outcome& o : all) {
        json d = Describe(o);
        d.erase("x");
        each.push_back(d);
        iterations += o.iterations;
        jacobians += o.jacobian_evaluations;
      }
      solve.update(Describe(all[best]));
      solve["best_start"] = best;
      solve["iterations"] = iterations;
      solve["jacobian_evaluations"] = jacobians;
      out["solve"] = solve;
      out["starts"] = each;
    } else {
      const kincal_peer::TrackerProblem problem = kincal_peer::ReadTracker(path);
      out["load_cpu_ms"] = Clock::Now().cpu_ms - start.cpu_ms;
      out["params"] = problem.arm.free.size();
      out["sessions"] = problem.sessions.size();
      out["points"] = problem.points();
      Outcome outcome;
      json time = Timed(repeats, [&] { outcome = SolveTracker(problem, settings); });
      time.update(Describe(outcome));
      out["solve"] = time;
    }
  } catch (const std::exception& e) {
    std::cerr << "ceres_peer: " << e.what() << "\n";
    return 2;
  }
  std::cout << out.dump() << "\n";
  return 0;
}
