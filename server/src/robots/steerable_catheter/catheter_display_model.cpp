#include "steerable_catheter/catheter_robot.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <span>
#include "tendril/server/config.hpp"

#include "tendril/teleop/catheter_kinematics.hpp"
#include "tendril/teleop/modal_catheter_kinematics.hpp"

namespace tendril::server {
namespace {

// The SRMC drawn with constant curvature (Abah 2022, §4.5.2, gives the modal shape only after calibration)
// while its shape is the nominal tip-only model; a calibrated shape matrix is drawn by ModalCatheterModel
// below.
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

// A display model on the passive shaft (issue 31): the inner model's steerable section drawn at zero
// insertion, placed on the base the shaft lying along the vessel gives at insertion q1; the inner
// model's straight shaft (its first point, when it draws one) becomes points along the vessel.
class ShaftDisplayModel final : public RobotKinematics {
 public:
  ShaftDisplayModel(std::unique_ptr<RobotKinematics> inner, teleop::VesselShaft shaft, double shaft_length)
      : inner_(std::move(inner)), shaft_(std::move(shaft)), shaft_length_(shaft_length) {}
  std::string frame() const override { return inner_->frame(); }
  std::vector<Eigen::Vector3d> shape(std::span<const double> q) const override {
    std::array<double, 4> at_zero{0.0, q[1], q[2], q[3]};
    auto local = inner_->shape(at_zero);
    std::vector<Eigen::Vector3d> out;
    std::size_t first = 0;
    if (shaft_length_ > 0 && !local.empty() && local.front().head<2>().norm() < 1e-9 &&
        local.front().z() < -1e-9) {
      first = 1;  // the inner model's shaft start: replaced by the shaft along the vessel, a point a mm
      const auto points = static_cast<int>(std::ceil(shaft_length_));
      for (int i = 0; i < points; ++i) out.push_back(shaft_.shaft_point(q[0], shaft_length_ - i));
    }
    const std::size_t drawn = out.size();
    out.insert(out.end(), local.begin() + static_cast<std::ptrdiff_t>(first), local.end());
    shaft_.place(q[0], std::span<Eigen::Vector3d>(out).subspan(drawn));
    return out;
  }
  Pose tip(std::span<const double> q) const override {
    std::array<double, 4> at_zero{0.0, q[1], q[2], q[3]};
    const auto t = inner_->tip(at_zero);
    Eigen::Matrix3d r;
    Eigen::Vector3d p;
    shaft_.section_base(q[0], r, p);
    return Pose{p + r * t.position, Eigen::Quaterniond(r * t.orientation.toRotationMatrix())};
  }

 private:
  std::unique_ptr<RobotKinematics> inner_;
  teleop::VesselShaft shaft_;
  double shaft_length_;
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

std::unique_ptr<RobotKinematics> make_shaft_display_model(std::unique_ptr<RobotKinematics> inner,
                                                          teleop::VesselShaft shaft,
                                                          const nlohmann::json& k) {
  const double shaft_length = k.value("shaft_display_length_mm", 0.0);
  return std::make_unique<ShaftDisplayModel>(std::move(inner), std::move(shaft), shaft_length);
}

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
