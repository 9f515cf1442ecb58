// Reading the problem files. Anything the peer does not model (an effect, an unknown joint key,
// a URDF chain) is refused with the field named, never ignored.
#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <stdexcept>

#include "problems.h"

namespace kincal_peer {
namespace {

using nlohmann::json;

constexpr double kDeg = M_PI / 180.0;

json Load(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error(path + ": cannot be read");
  try {
    return json::parse(in);
  } catch (const json::exception& e) {
    throw std::runtime_error(path + ": not JSON: " + e.what());
  }
}

// The member `key` of `j`, or an error naming it.
const json& At(const json& j, const std::string& key, const std::string& where) {
  if (!j.is_object() || !j.contains(key)) throw std::runtime_error(where + ": no \"" + key + "\"");
  return j.at(key);
}

// The number (or whole number) `key` of `j`, or an error naming it.
double Number(const json& j, const std::string& key, const std::string& where) {
  const json& v = At(j, key, where);
  if (!v.is_number()) throw std::runtime_error(where + "." + key + ": expected a number, found " + v.dump());
  return v.get<double>();
}

int Whole(const json& j, const std::string& key, const std::string& where) {
  const json& v = At(j, key, where);
  if (!v.is_number_integer()) throw std::runtime_error(where + "." + key + ": expected a whole number, found " + v.dump());
  return v.get<int>();
}

std::string Text(const json& v, const std::string& where) {
  if (!v.is_string()) throw std::runtime_error(where + ": expected a text, found " + v.dump());
  return v.get<std::string>();
}

std::vector<double> Numbers(const json& j, const std::string& where) {
  if (!j.is_array()) throw std::runtime_error(where + ": expected a list of numbers");
  std::vector<double> v;
  for (const json& e : j) {
    if (!e.is_number()) throw std::runtime_error(where + ": expected a list of numbers");
    v.push_back(e.get<double>());
  }
  return v;
}

std::vector<double> Numbers(const json& j, size_t n, const std::string& where) {
  std::vector<double> v = Numbers(j, where);
  if (v.size() != n) {
    throw std::runtime_error(where + ": expected " + std::to_string(n) + " numbers, found " +
                             std::to_string(v.size()));
  }
  return v;
}

Angles Radians(const std::vector<double>& deg) {
  Angles r(deg.size());
  for (size_t i = 0; i < deg.size(); ++i) r[i] = deg[i] * kDeg;
  return r;
}

// An arm model file (kincal-arm/1 as JSON), DH conventions only.
Arm ReadModel(const json& model, const std::string& where) {
  Arm arm;
  const std::string convention = Text(At(model, "convention", where), where + ".convention");
  if (convention != "classic" && convention != "modified") {
    throw std::runtime_error(where + ".convention: \"" + convention + "\": the peer models classic or modified DH");
  }
  arm.modified = convention == "modified";
  if (model.contains("effects") && !model.at("effects").empty()) {
    throw std::runtime_error(where + ".effects: the peer models the geometric chain only, found " +
                             model.at("effects").dump());
  }
  const std::vector<double> tcp = Numbers(At(model, "tcp_mm", where), 3, where + ".tcp_mm");
  std::copy(tcp.begin(), tcp.end(), arm.tcp_mm.begin());
  arm.scale_ppm = model.contains("scale_ppm") ? Number(model, "scale_ppm", where) : 0.0;
  const std::set<std::string> known = {"offset_deg", "d_mm", "a_mm", "alpha_deg", "axis_deg"};
  const json& joints = At(model, "joint", where);
  for (size_t j = 0; j < joints.size(); ++j) {
    const std::string at = where + ".joint[" + std::to_string(j) + "]";
    for (const auto& [key, value] : joints[j].items()) {
      if (!known.count(key)) throw std::runtime_error(at + "." + key + ": the peer models the DH chain only");
    }
    Joint q;
    q.offset_deg = Number(joints[j], "offset_deg", at);
    q.d_mm = Number(joints[j], "d_mm", at);
    q.a_mm = Number(joints[j], "a_mm", at);
    q.alpha_deg = Number(joints[j], "alpha_deg", at);
    q.axis_deg = joints[j].contains("axis_deg") ? Number(joints[j], "axis_deg", at) : 0.0;
    arm.joints.push_back(q);
  }
  return arm;
}

// Errors of the JSON library (a list where a number was expected, …) name the file too.
template <typename Read>
auto Reading(const std::string& path, Read read) {
  try {
    return read(Load(path));
  } catch (const json::exception& e) {
    throw std::runtime_error(path + ": " + e.what());
  }
}

}  // namespace

size_t TrackerProblem::points() const {
  size_t n = 0;
  for (const TrackerSession& s : sessions) n += s.q.size();
  return n;
}

namespace {

ArtefactProblem ParseArtefact(const json& j, const std::string& path) {
  ArtefactProblem p;
  p.arm = ReadModel(At(j, "model", path), path + ": model");
  const int joints = static_cast<int>(p.arm.joints.size());
  for (const json& name : At(j, "params", path)) p.arm.free.push_back(ParseSlot(Text(name, path + ": params"), joints));
  const size_t n = p.arm.free.size();
  p.lower = Numbers(At(j, "lower", path), n, path + ": lower");
  p.upper = Numbers(At(j, "upper", path), n, path + ": upper");
  p.starts.push_back(Numbers(At(j, "x0", path), n, path + ": x0"));
  if (j.contains("starts")) {
    for (size_t k = 0; k < j.at("starts").size(); ++k) {
      p.starts.push_back(Numbers(j.at("starts")[k], n, path + ": starts[" + std::to_string(k) + "]"));
    }
  }
  p.huber_delta_mm = Number(j, "huber_delta_mm", path);
  if (!(p.huber_delta_mm > 0)) throw std::runtime_error(path + ": huber_delta_mm must be positive");
  std::vector<std::vector<double>> landmarks;
  for (const json& l : At(j, "landmarks_mm", path)) landmarks.push_back(Numbers(l, 3, path + ": landmarks_mm"));
  struct Key {
    int placement, landmark, repeat;
  };
  std::vector<Key> keys;
  const json& touches = At(j, "touches", path);
  for (size_t t = 0; t < touches.size(); ++t) {
    const std::string at = path + ": touches[" + std::to_string(t) + "]";
    const int landmark = Whole(touches[t], "landmark", at);
    if (landmark < 0 || static_cast<size_t>(landmark) >= landmarks.size()) {
      throw std::runtime_error(at + ".landmark: " + std::to_string(landmark) + " is not a landmark index");
    }
    keys.push_back({Whole(touches[t], "placement", at), landmark, Whole(touches[t], "repeat", at)});
    p.touches.push_back(Radians(Numbers(At(touches[t], "enc_deg", at), joints, at + ".enc_deg")));
  }
  for (size_t a = 0; a < keys.size(); ++a) {
    for (size_t b = a + 1; b < keys.size(); ++b) {
      if (keys[a].placement != keys[b].placement || keys[a].repeat != keys[b].repeat ||
          keys[a].landmark == keys[b].landmark) {
        continue;
      }
      const std::vector<double>&la = landmarks[keys[a].landmark], &lb = landmarks[keys[b].landmark];
      p.pair_a.push_back(static_cast<int>(a));
      p.pair_b.push_back(static_cast<int>(b));
      p.certified_mm.push_back(std::hypot(la[0] - lb[0], la[1] - lb[1], la[2] - lb[2]));
    }
  }
  if (p.pair_a.size() < n) {
    throw std::runtime_error(path + ": " + std::to_string(p.pair_a.size()) + " pairs cannot determine " +
                             std::to_string(n) + " parameters");
  }
  return p;
}

TrackerProblem ParseTracker(const json& j, const std::string& path) {
  TrackerProblem p;
  for (const json& row : At(j, "dh", path)) {
    const std::vector<double> v = Numbers(row, 4, path + ": dh row");
    Joint q;
    q.offset_deg = v[0], q.d_mm = v[1], q.a_mm = v[2], q.alpha_deg = v[3];
    p.arm.joints.push_back(q);
  }
  const std::vector<double> tool = Numbers(At(j, "tool_mm", path), 3, path + ": tool_mm");
  std::copy(tool.begin(), tool.end(), p.arm.tcp_mm.begin());
  const int joints = static_cast<int>(p.arm.joints.size());
  for (const json& name : At(j, "params", path)) p.arm.free.push_back(ParseSlot(Text(name, path + ": params"), joints));
  const size_t n = p.arm.free.size();
  p.lower = Numbers(At(j, "lower", path), n, path + ": lower");
  p.upper = Numbers(At(j, "upper", path), n, path + ": upper");
  const json& sessions = At(j, "sessions", path);
  for (size_t s = 0; s < sessions.size(); ++s) {
    const std::string at = path + ": sessions[" + std::to_string(s) + "]";
    TrackerSession session;
    const json &q = At(sessions[s], "q_deg", at), &x = At(sessions[s], "x_mm", at);
    if (q.size() != x.size() || q.size() < 3) {
      throw std::runtime_error(at + ": q_deg and x_mm must list the same points, at least 3");
    }
    for (size_t i = 0; i < q.size(); ++i) {
      session.q.push_back(Radians(Numbers(q[i], joints, at + ".q_deg")));
      for (double v : Numbers(x[i], 3, at + ".x_mm")) session.measured_mm.push_back(v);
    }
    p.sessions.push_back(std::move(session));
  }
  return p;
}

}  // namespace

ArtefactProblem ReadArtefact(const std::string& path) {
  return Reading(path, [&](const json& j) { return ParseArtefact(j, path); });
}

TrackerProblem ReadTracker(const std::string& path) {
  return Reading(path, [&](const json& j) { return ParseTracker(j, path); });
}

}  // namespace kincal_peer
