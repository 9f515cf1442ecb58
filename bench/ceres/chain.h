// The arm's forward kinematics for the Ceres peer, written from the DH definition and
// independent of kincal's Rust code.
//
// Joint j maps a point v of its frame into the frame before it:
//   classic:  v' = Rz(θ_j) · (Rx(α_j) Ry(β_j) v + [a_j, 0, d_j])        (Rz Tz Tx Rx Ry)
//   modified: v' = Rx(α_j) Ry(β_j) · (Rz(θ_j) (v + [0, 0, d_j]) + [a_j, 0, 0])   (Rx Ry Tx Rz Tz)
// with θ_j = encoder_j + δθ_j. The tool point is (1 + scale·1e-6) · joint_1(… joint_J(tcp)).
// Angles in the files are degrees, lengths millimetres.
//
// The free parameters are one vector x; the chain's touch-independent parts (δθ in radians, the
// fixed rotations Rx Ry, a, d, the tool point) are built once per evaluation, and each touch is
// then carried from the tool back to the base with matrix-vector products only. Derivatives are
// automatic: the same template runs on doubles (residuals) and on ceres::Jet<double, N>
// (residuals and the 3 × N Jacobian of every touch in one pass).
#pragma once

#include <array>
#include <memory>
#include <string>
#include <vector>

namespace kincal_peer {

// What a free parameter sets.
enum class Field { kOffset, kLength, kLinkOffset, kTwist, kAxis, kTcp, kScale };

struct Slot {
  Field field;
  int index;  // joint (0-based) for joint fields, axis 0..2 for kTcp, unused for kScale
};

struct Joint {
  double offset_deg = 0, d_mm = 0, a_mm = 0, alpha_deg = 0, axis_deg = 0;
};

struct Arm {
  bool modified = false;
  std::vector<Joint> joints;
  std::array<double, 3> tcp_mm{};
  double scale_ppm = 0;
  std::vector<Slot> free;  // unknown k sets free[k]
  double value(const Slot& s) const;
};

// Parses "offset:3", "length:1", "link_offset:2", "twist:4", "axis:5", "tcp.x", "scale"
// (joints 1-based, as kincal names them); throws std::runtime_error naming the text.
Slot ParseSlot(const std::string& name, int joints);

// A touch: its joint angles, radians.
using Angles = std::vector<double>;


// Tool points of many touches, and their Jacobians with respect to the arm's free parameters.
class ChainEvaluator {
 public:
  virtual ~ChainEvaluator() = default;
  // points: 3 per touch. jacobians (may be null): 3 × n per touch, row-major.
  virtual void Evaluate(const double* x, const std::vector<Angles>& touches, double* points,
                        double* jacobians) const = 0;
};

// The evaluator for `arm` (its free list fixes n, the size of the Jets); throws if the peer was
// not compiled for n. Each size is a template instance that takes seconds to compile, so the
// sizes are chosen when the peer is built: `build.sh N...` defines KINCAL_PEER_SIZES.
std::unique_ptr<ChainEvaluator> MakeChainEvaluator(const Arm& arm);

}  // namespace kincal_peer
