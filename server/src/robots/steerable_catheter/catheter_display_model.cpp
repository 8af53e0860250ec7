#include "steerable_catheter/catheter_robot.hpp"

#include <algorithm>
#include "tendril/server/config.hpp"

#include "tendril/teleop/catheter_kinematics.hpp"
#include "tendril/teleop/modal_catheter_kinematics.hpp"

namespace tendril::server {
namespace {

// The SRMC drawn with constant curvature (seed 000 §4.6 gap note) while its shape is the nominal
// tip-only model; a calibrated shape matrix is drawn by ModalCatheterModel below.
class ConstantCurvatureCatheterModel final : public RobotKinematics {
 public:
  ConstantCurvatureCatheterModel(const teleop::CatheterParameters& p, std::size_t points)
      : model_(p), points_per_segment_(points) {}
  std::string frame() const override { return "world"; }
  std::vector<Eigen::Vector3d> shape(std::span<const double> q) const override {
    std::vector<Eigen::Vector3d> out(model_.backbone_point_count(points_per_segment_));
    out.resize(model_.backbone(to_vector(q), points_per_segment_, out));
    return out;
  }
  Pose tip(std::span<const double> q) const override {
    const auto t = model_.tip_pose(to_vector(q));
    return Pose{t.position, t.orientation()};
  }

 private:
  static teleop::ConstantCurvatureCatheter::JointVector to_vector(std::span<const double> q) {
    teleop::ConstantCurvatureCatheter::JointVector v;
    for (int i = 0; i < 4; ++i) v[i] = q[static_cast<std::size_t>(i)];
    return v;
  }
  teleop::ConstantCurvatureCatheter model_;
  std::size_t points_per_segment_;
};

// The model the robot itself uses once a calibration replaced constant curvature: the assembled modal
// shape θ(s, q) = Ψ(s)ᵀAη(q) through the loss lines, as the SIMULATED plant bends. Its q is what
// reaches the tubes: [insertion, roll, proximal carriage, distal actuation with the coupling]
// (SteerableCatheter::display_positions).
class ModalCatheterModel final : public RobotKinematics {
 public:
  ModalCatheterModel(const teleop::ModalCatheterParameters& p, std::size_t points)
      : model_(p), points_per_segment_(points) {}
  std::string frame() const override { return "world"; }
  std::vector<Eigen::Vector3d> shape(std::span<const double> q) const override {
    std::vector<Eigen::Vector3d> out(model_.backbone_point_count(points_per_segment_));
    out.resize(model_.backbone(to_vector(q), points_per_segment_, out));
    return out;
  }
  Pose tip(std::span<const double> q) const override {
    const auto t = model_.tip_pose(to_vector(q));
    return Pose{t.position, t.orientation()};
  }

 private:
  static teleop::ModalCatheterKinematics::JointVector to_vector(std::span<const double> q) {
    teleop::ModalCatheterKinematics::JointVector v;
    for (int i = 0; i < 4; ++i) v[i] = q[static_cast<std::size_t>(i)];
    return v;
  }
  teleop::ModalCatheterKinematics model_;
  std::size_t points_per_segment_;
};

[[noreturn]] void fail(const std::string& file, const std::string& key, const std::string& expected,
                       const nlohmann::json& got) {
  throw ConfigError(file + ": kinematics." + key + ": expected " + expected + ", got " + got.dump());
}

double number(const nlohmann::json& j, const std::string& key, const std::string& file) {
  if (!j.contains(key) || !j.at(key).is_number()) fail(file, key, "a number", j.value(key, nlohmann::json()));
  return j.at(key).get<double>();
}

std::array<double, 2> pair(const nlohmann::json& j, const std::string& key, const std::string& file,
                           bool positive) {
  const auto v = j.value(key, nlohmann::json());
  if (!v.is_array() || v.size() != 2 || !v[0].is_number() || !v[1].is_number() ||
      (positive && (v[0].get<double>() <= 0 || v[1].get<double>() <= 0)))
    fail(file, key, positive ? "two positive numbers [proximal, distal]" : "two numbers [proximal, distal]",
         v);
  return {v[0].get<double>(), v[1].get<double>()};
}

}  // namespace

std::unique_ptr<RobotKinematics> make_modal_catheter_display_model(
    const teleop::ModalCatheterParameters& assembled, const nlohmann::json& kinematics) {
  const auto points = kinematics.value("display_points_per_segment", 20);
  return std::make_unique<ModalCatheterModel>(assembled,
                                              static_cast<std::size_t>(std::clamp(points, 2, 500)));
}

std::unique_ptr<RobotKinematics> make_catheter_display_model(const nlohmann::json& k, std::size_t joint_count,
                                                             const std::string& file) {
  const auto model = k.value("model", std::string{});
  if (model == "constant_curvature_catheter") {
    if (joint_count != 4)
      throw ConfigError(file +
                        ": kinematics.model: constant_curvature_catheter needs the 4 SRMC joints "
                        "(insertion, roll, proximal bend, distal bend), the file has " +
                        std::to_string(joint_count));
    teleop::CatheterParameters p;
    const auto lengths = pair(k, "segment_lengths_mm", file, true);
    const auto gains = pair(k, "bend_gain_rad_per_mm", file, false);
    p.proximal_length = lengths[0];
    p.distal_length = lengths[1];
    p.proximal_curvature_gain = gains[0];
    p.distal_curvature_gain = gains[1];
    p.plane_offset = number(k, "plane_offset_rad", file);
    p.flexure = k.contains("flexure_rad") ? number(k, "flexure_rad", file) : 0.0;
    p.shaft_length = k.contains("shaft_display_length_mm") ? number(k, "shaft_display_length_mm", file) : 0.0;
    const auto points = k.value("display_points_per_segment", 20);
    if (points < 2 || points > 500)
      fail(file, "display_points_per_segment", "an integer from 2 to 500", points);
    return std::make_unique<ConstantCurvatureCatheterModel>(p, static_cast<std::size_t>(points));
  }
  fail(file, "model", "a known model (constant_curvature_catheter)", model);
}

}  // namespace tendril::server
