#include "chain.h"

#include <ceres/jet.h>

#include <cmath>
#include <stdexcept>
#include <utility>

namespace kincal_peer {
namespace {

constexpr double kDeg = M_PI / 180.0;

// One joint's touch-independent parts. The fixed rotation Rx(α) Ry(β) is kept as doubles when
// neither angle is free, so that a constant multiplies a Jet at the cost of a scaling.
template <typename T>
struct Link {
  T offset_rad, d, a;
  bool rotation_free = false;
  std::array<double, 9> rotation_constant{};
  std::array<T, 9> rotation{};
};

template <typename T>
struct Chain {
  std::vector<Link<T>> links;
  std::array<T, 3> tcp;
  T scale;
  bool scaled = false;
};

// Rx(α) Ry(β), row-major.
template <typename T>
void FixedRotation(const T& alpha, const T& beta, T* m) {
  using std::cos;
  using std::sin;
  const T ca = cos(alpha), sa = sin(alpha), cb = cos(beta), sb = sin(beta);
  m[0] = cb, m[1] = T(0.0), m[2] = sb;
  m[3] = sa * sb, m[4] = ca, m[5] = -sa * cb;
  m[6] = -ca * sb, m[7] = sa, m[8] = ca * cb;
}

// The arm's values as T, the free ones read from x (lane k of a Jet for unknown k).
template <typename T>
Chain<T> BuildChain(const Arm& arm, const double* x, T (*unknown)(double, int)) {
  const size_t J = arm.joints.size();
  std::vector<std::array<T, 5>> values(J);
  std::vector<std::array<bool, 5>> is_free(J);
  for (size_t j = 0; j < J; ++j) {
    const Joint& q = arm.joints[j];
    values[j] = {T(q.offset_deg), T(q.d_mm), T(q.a_mm), T(q.alpha_deg), T(q.axis_deg)};
    is_free[j] = {false, false, false, false, false};
  }
  Chain<T> chain;
  chain.tcp = {T(arm.tcp_mm[0]), T(arm.tcp_mm[1]), T(arm.tcp_mm[2])};
  T scale_ppm = T(arm.scale_ppm);
  bool scale_free = false;
  for (size_t k = 0; k < arm.free.size(); ++k) {
    const Slot& s = arm.free[k];
    const T v = unknown(x[k], static_cast<int>(k));
    switch (s.field) {
      case Field::kTcp: chain.tcp[s.index] = v; break;
      case Field::kScale: scale_ppm = v, scale_free = true; break;
      default:
        values[s.index][static_cast<int>(s.field)] = v;
        is_free[s.index][static_cast<int>(s.field)] = true;
    }
  }
  chain.links.resize(J);
  for (size_t j = 0; j < J; ++j) {
    Link<T>& l = chain.links[j];
    l.offset_rad = values[j][0] * kDeg;
    l.d = values[j][1];
    l.a = values[j][2];
    l.rotation_free = is_free[j][3] || is_free[j][4];
    if (l.rotation_free) {
      FixedRotation(values[j][3] * kDeg, values[j][4] * kDeg, l.rotation.data());
    } else {
      FixedRotation<double>(arm.joints[j].alpha_deg * kDeg, arm.joints[j].axis_deg * kDeg,
                            l.rotation_constant.data());
    }
  }
  chain.scaled = scale_free || arm.scale_ppm != 0.0;
  chain.scale = T(1.0) + scale_ppm * 1e-6;
  return chain;
}

template <typename T>
void Rotate(const Link<T>& l, const T* v, T* out) {
  if (l.rotation_free) {
    const T* m = l.rotation.data();
    for (int i = 0; i < 3; ++i) out[i] = m[3 * i] * v[0] + m[3 * i + 1] * v[1] + m[3 * i + 2] * v[2];
  } else {
    const double* m = l.rotation_constant.data();
    for (int i = 0; i < 3; ++i) out[i] = v[0] * m[3 * i] + v[1] * m[3 * i + 1] + v[2] * m[3 * i + 2];
  }
}

// The tool point of one touch in the base frame.
template <typename T>
void ToolPoint(const Chain<T>& chain, bool modified, const Angles& angles, T* p) {
  using std::cos;
  using std::sin;
  T v[3] = {chain.tcp[0], chain.tcp[1], chain.tcp[2]};
  T w[3];
  for (size_t j = chain.links.size(); j-- > 0;) {
    const Link<T>& l = chain.links[j];
    const T theta = l.offset_rad + angles[j];
    const T c = cos(theta), s = sin(theta);
    if (!modified) {
      Rotate(l, v, w);
      w[0] += l.a;
      v[0] = c * w[0] - s * w[1];
      v[1] = s * w[0] + c * w[1];
      v[2] = w[2] + l.d;
    } else {
      const T z = v[2] + l.d;
      w[0] = c * v[0] - s * v[1] + l.a;
      w[1] = s * v[0] + c * v[1];
      w[2] = z;
      Rotate(l, w, v);
    }
  }
  for (int i = 0; i < 3; ++i) p[i] = chain.scaled ? v[i] * chain.scale : v[i];
}

template <int N>
class JetEvaluator final : public ChainEvaluator {
 public:
  explicit JetEvaluator(Arm arm) : arm_(std::move(arm)) {}

  void Evaluate(const double* x, const std::vector<Angles>& touches, double* points,
                double* jacobians) const override {
    if (jacobians == nullptr) {
      const Chain<double> chain = BuildChain<double>(arm_, x, [](double v, int) { return v; });
      for (size_t t = 0; t < touches.size(); ++t) ToolPoint(chain, arm_.modified, touches[t], points + 3 * t);
      return;
    }
    using J = ceres::Jet<double, N>;
    const Chain<J> chain = BuildChain<J>(arm_, x, [](double v, int k) { return J(v, k); });
    J p[3];
    for (size_t t = 0; t < touches.size(); ++t) {
      ToolPoint(chain, arm_.modified, touches[t], p);
      for (int i = 0; i < 3; ++i) {
        points[3 * t + i] = p[i].a;
        double* row = jacobians + (3 * t + i) * N;
        for (int k = 0; k < N; ++k) row[k] = p[i].v[k];
      }
    }
  }

 private:
  Arm arm_;
};

#ifndef KINCAL_PEER_SIZES
#error "build with -DKINCAL_PEER_SIZES=n1,n2,... (bench/ceres/build.sh does)"
#endif
constexpr int kSizes[] = {KINCAL_PEER_SIZES};

// The evaluator whose Jet size is the arm's count of free parameters, if it is one of Ns.
template <int... Ns>
std::unique_ptr<ChainEvaluator> Dispatch(const Arm& arm, std::integer_sequence<int, Ns...>) {
  std::unique_ptr<ChainEvaluator> made;
  const auto make_if = [&](auto size) {
    if (arm.free.size() == static_cast<size_t>(size.value)) made = std::make_unique<JetEvaluator<size.value>>(arm);
  };
  (make_if(std::integral_constant<int, Ns>{}), ...);
  return made;
}

}  // namespace

double Arm::value(const Slot& s) const {
  switch (s.field) {
    case Field::kOffset: return joints[s.index].offset_deg;
    case Field::kLength: return joints[s.index].d_mm;
    case Field::kLinkOffset: return joints[s.index].a_mm;
    case Field::kTwist: return joints[s.index].alpha_deg;
    case Field::kAxis: return joints[s.index].axis_deg;
    case Field::kTcp: return tcp_mm[s.index];
    case Field::kScale: return scale_ppm;
  }
  return 0.0;
}

Slot ParseSlot(const std::string& name, int joints) {
  if (name == "scale") return {Field::kScale, 0};
  if (name.size() == 5 && name.compare(0, 4, "tcp.") == 0 && name[4] >= 'x' && name[4] <= 'z') {
    return {Field::kTcp, name[4] - 'x'};
  }
  const std::pair<const char*, Field> kinds[] = {{"offset", Field::kOffset},
                                                 {"length", Field::kLength},
                                                 {"link_offset", Field::kLinkOffset},
                                                 {"twist", Field::kTwist},
                                                 {"axis", Field::kAxis}};
  const size_t colon = name.find(':');
  for (const auto& [kind, field] : kinds) {
    if (colon == std::string::npos || name.compare(0, colon, kind) != 0) continue;
    try {
      size_t used = 0;
      const int joint = std::stoi(name.substr(colon + 1), &used);
      if (used == name.size() - colon - 1 && joint >= 1 && joint <= joints) return {field, joint - 1};
    } catch (const std::exception&) {
    }
  }
  throw std::runtime_error("parameter \"" + name +
                           "\": expected offset|length|link_offset|twist|axis:J (J in 1.." +
                           std::to_string(joints) + "), tcp.x|y|z or scale");
}

std::unique_ptr<ChainEvaluator> MakeChainEvaluator(const Arm& arm) {
  std::unique_ptr<ChainEvaluator> made = Dispatch(arm, std::integer_sequence<int, KINCAL_PEER_SIZES>());
  if (!made) {
    std::string sizes;
    for (int n : kSizes) sizes += (sizes.empty() ? "" : ", ") + std::to_string(n);
    throw std::runtime_error(std::to_string(arm.free.size()) + " free parameters: this peer is built for " + sizes +
                             " (bench/ceres/build.sh OUT_DIR " + std::to_string(arm.free.size()) + ")");
  }
  return made;
}

}  // namespace kincal_peer
