#include "steerable_catheter/catheter_settings.hpp"

#include <cmath>
#include <fstream>
#include <numbers>
#include <sstream>

#include "tendril/drivers/sim/catheter_vessel_contact.hpp"
#include "tendril/server/config_reader.hpp"
#include "tendril/teleop/vessel_centerline.hpp"

namespace tendril::server {
namespace {

using detail::Reader;

std::array<double, 2> pair(const Reader& r, const std::string& key, std::array<double, 2> fallback) {
  if (!r.has(key)) return fallback;
  const auto& v = r.raw(key);
  if (!v.is_array() || v.size() != 2 || !v[0].is_number() || !v[1].is_number() ||
      !std::isfinite(v[0].get<double>()) || !std::isfinite(v[1].get<double>()))
    r.fail(key, "two finite numbers", v);
  return {v[0].get<double>(), v[1].get<double>()};
}

// A shape matrix A (n×m, rows = powers of s, columns = powers of q, mm): n rows of m finite numbers.
Eigen::MatrixXd shape_matrix(const Reader& r, const std::string& key) {
  const auto& v = r.raw(key);
  const char* expected = "a shape matrix: 1 to 6 rows of 1 to 6 finite numbers each, all rows alike";
  if (!v.is_array() || v.empty() || v.size() > teleop::kMaxModalOrder || !v[0].is_array() || v[0].empty() ||
      v[0].size() > teleop::kMaxModalOrder)
    r.fail(key, expected, v);
  Eigen::MatrixXd A(static_cast<Eigen::Index>(v.size()), static_cast<Eigen::Index>(v[0].size()));
  for (std::size_t i = 0; i < v.size(); ++i) {
    if (!v[i].is_array() || v[i].size() != v[0].size()) r.fail(key, expected, v);
    for (std::size_t j = 0; j < v[i].size(); ++j) {
      const auto& x = v[i][j];
      if (!x.is_number() || !std::isfinite(x.get<double>())) r.fail(key, expected, v);
      A(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)) = x.get<double>();
    }
  }
  return A;
}

input::JoystickMapping evdev_mapping(const Reader& r) {
  input::JoystickMapping m;
  const auto& axes = r.array("axes", true);
  for (std::size_t i = 0; i < axes.size(); ++i) {
    const Reader a = r.element("axes", i);
    input::AxisMapping axis;
    axis.output = a.string("joint");
    axis.code = static_cast<int>(a.integer_in("code", 0, 0x3f));
    axis.minimum = a.number_or("minimum", axis.minimum);
    axis.maximum = a.number_or("maximum", axis.maximum);
    axis.deadband = a.non_negative_or("deadband", axis.deadband);
    axis.scale = a.number_or("scale", axis.scale);
    axis.invert = a.boolean_or("invert", false);
    m.axes.push_back(axis);
  }
  m.deadman_code = static_cast<int>(r.integer_in_or("deadman_button", -1, 0x2ff, -1));
  try {
    m.validate();
  } catch (const input::JoystickConfigError& e) {
    r.fail("axes", std::string("a mapping that works (") + e.what() + ")", r.raw("axes"));
  }
  return m;
}

}  // namespace

CatheterSettings parse_catheter_settings(const RobotConfig& rc) {
  const std::string file = rc.file.string();
  if (rc.joints.size() != 4)
    throw ConfigError(file +
                      ": catheter: a steerable catheter has 4 joints (insertion, roll, proximal and "
                      "distal bend drives), this robot has " +
                      std::to_string(rc.joints.size()));
  const nlohmann::json& catheter =
      rc.settings.contains("catheter") ? rc.settings["catheter"] : nlohmann::json::object();
  const Reader r(catheter, file, "catheter");
  CatheterSettings s;

  // Nominal model: the constant-curvature shape of the tip-only calibration (k rad/mm at the tip).
  {
    const Reader m = r.child("model");
    const auto lengths = pair(m, "segment_lengths_mm", {22.0, 18.8});
    const auto gains = pair(m, "nominal_bend_gain_rad_per_mm", {1.4, 1.4});
    if (!(lengths[0] > 0 && lengths[1] > 0))
      m.fail("segment_lengths_mm", "two lengths > 0", m.raw("segment_lengths_mm"));
    if (gains[0] == 0 || gains[1] == 0)
      m.fail("nominal_bend_gain_rad_per_mm", "two non-zero gains", m.raw("nominal_bend_gain_rad_per_mm"));
    teleop::CatheterParameters cc;
    cc.proximal_length = lengths[0];
    cc.distal_length = lengths[1];
    cc.plane_offset = m.number_or("plane_offset_rad", -0.76);
    cc.proximal_curvature_gain = gains[0];
    cc.distal_curvature_gain = gains[1];
    s.nominal = teleop::constant_curvature_modal_parameters(cc);
    // A calibrated tip-only model (§4.5.2, written by a calibration job) replaces constant curvature.
    if (m.has("proximal_shape_matrix"))
      s.nominal.proximal.shape_matrix = shape_matrix(m, "proximal_shape_matrix");
    if (m.has("distal_shape_matrix")) s.nominal.distal.shape_matrix = shape_matrix(m, "distal_shape_matrix");
    s.calibrated_shape = m.has("proximal_shape_matrix") || m.has("distal_shape_matrix");
    try {
      (void)teleop::ModalCatheterKinematics(s.nominal);
    } catch (const std::invalid_argument& e) {
      m.fail("", std::string("a model that works (") + e.what() + ")", catheter["model"]);
    }
    const auto proximal = pair(m, "proximal_loss", {0.063, -0.049});
    const auto distal = pair(m, "distal_loss", {0.17, 0.019});
    if (proximal[0] == 0 || distal[0] == 0)
      m.fail("proximal_loss", "loss lines [slope, offset] with non-zero slopes", m.raw("proximal_loss"));
    s.rates.proximal_loss = {proximal[0], proximal[1]};
    s.rates.distal_loss = {distal[0], distal[1]};
    s.rates.proximal_outer_radius = m.non_negative_or("proximal_outer_radius_mm", 0.6);
    s.rates.plane_offset = cc.plane_offset;
    s.rates.coupling_enabled = m.boolean_or("coupling", true);
  }

  if (r.has("spring_deflection")) {
    const Reader d = r.child("spring_deflection");
    s.deflection.node_id =
        static_cast<std::uint8_t>(d.integer_in_or("node_id", 1, 127, s.deflection.node_id));
    s.deflection.volts_per_mm = d.positive_or("volts_per_mm", s.deflection.volts_per_mm);
    s.deflection.limit_mm = d.positive_or("limit_mm", s.deflection.limit_mm);
    s.deflection.stale_ms = d.positive_or("stale_ms", s.deflection.stale_ms);
    if (s.deflection.limit_mm * s.deflection.volts_per_mm >= 2.5)
      d.fail("limit_mm", "a bound the potentiometer can still read (limit × volts_per_mm < 2.5 V)",
             d.raw("limit_mm"));
    s.deflection.resume_mm = d.positive_or("resume_mm", 0.5 * s.deflection.limit_mm);
    s.deflection.relax_timeout_s = d.positive_or("relax_timeout_s", s.deflection.relax_timeout_s);
  }

  if (r.has("active_compliance")) {
    const Reader a = r.child("active_compliance");
    auto& c = s.compliance;
    c.gain = a.positive_or("gain", c.gain);
    c.min_speed = a.non_negative_or("min_speed_mm_s", c.min_speed);
    c.max_speed = a.non_negative_or("max_speed_mm_s", c.max_speed);
    c.max_deflection = a.positive_or("max_deflection_mm", c.max_deflection);
    c.deadband = a.non_negative_or("deadband_mm", c.deadband);
    try {
      teleop::validate(c);
    } catch (const std::invalid_argument& e) {
      a.fail("", std::string("settings that work (") + e.what() + ")", catheter["active_compliance"]);
    }
    if (c.max_deflection > s.deflection.limit_mm)
      a.fail("max_deflection_mm",
             "at most spring_deflection.limit_mm (" + std::to_string(s.deflection.limit_mm) +
                 "), or compliance would saturate only after the hold",
             a.raw("max_deflection_mm"));
  }

  // Relax stops at half of resume_mm, which must lie above the compliance deadband (below which the bend
  // drives no longer move); resume_mm itself below the hold bound.
  if (!(s.deflection.resume_mm < s.deflection.limit_mm &&
        0.5 * s.deflection.resume_mm > s.compliance.deadband)) {
    if (!r.has("spring_deflection"))
      r.fail("spring_deflection", "a resume_mm above twice the active-compliance deadband", nullptr);
    const Reader d = r.child("spring_deflection");
    d.fail("resume_mm",
           "a bound below limit_mm (" + std::to_string(s.deflection.limit_mm) +
               " mm) and above twice the active-compliance deadband (" +
               std::to_string(s.compliance.deadband) + " mm)",
           d.has("resume_mm") ? d.raw("resume_mm") : nlohmann::json(s.deflection.resume_mm));
  }

  if (r.has("telemanipulation")) {
    const Reader t = r.child("telemanipulation");
    const auto& speeds = t.array("max_speed", true);
    if (speeds.size() != 4)
      t.fail("max_speed", "4 speeds (insertion mm/s, roll rad/s, bend mm/s, bend mm/s)", speeds);
    for (std::size_t i = 0; i < 4; ++i) {
      if (!speeds[i].is_number() || !(speeds[i].get<double>() >= 0) ||
          speeds[i].get<double>() > rc.joints[i].limit.max_velocity)
        t.fail("max_speed", "speeds from 0 to each joint's max_velocity", speeds);
      s.telemanipulation_max_speed[i] = speeds[i].get<double>();
    }
  } else {
    for (std::size_t i = 0; i < 4; ++i)
      s.telemanipulation_max_speed[i] =
          std::min(s.telemanipulation_max_speed[i], rc.joints[i].limit.max_velocity);
  }
  s.retraction_only_while_held = r.boolean_or("retraction_only_while_held", true);
  s.max_contact_force_n = r.positive_or("max_contact_force_n", s.max_contact_force_n);

  if (r.has("joysticks")) {
    const Reader j = r.child("joysticks");
    if (j.has("analog")) {
      const Reader a = j.child("analog");
      input::AnalogJoystickCalibration cal;
      cal.node_id = static_cast<std::uint8_t>(a.integer_in_or("node_id", 1, 127, cal.node_id));
      cal.deadband_volts = a.non_negative_or("deadband_volts", cal.deadband_volts);
      cal.deadman_digital_input =
          static_cast<int>(a.integer_in_or("deadman_digital_input", -1, 7, cal.deadman_digital_input));
      if (cal.node_id == s.deflection.node_id)
        a.fail("node_id", "a node id other than the spring-deflection sensor's", a.raw("node_id"));
      s.analog_joystick = cal;
    }
    if (j.has("evdev")) {
      const Reader e = j.child("evdev");
      input::EvdevJoystickOptions o;
      o.device = e.string("device");
      o.mapping = evdev_mapping(e);
      for (const auto& axis : o.mapping.axes) {
        bool known = false;
        for (const auto& joint : rc.joints) known = known || joint.name() == axis.output;
        if (!known)
          e.fail("axes", "each axis to name a joint of this robot (unknown: " + axis.output + ")",
                 e.raw("axes"));
      }
      s.evdev_joystick = std::move(o);
    }
  }

  if (r.has("simulation")) {
    const Reader m = r.child("simulation");
    auto& sim = s.simulation;
    sim.spring_stiffness_n_per_mm = m.positive_or("spring_stiffness_n_per_mm", sim.spring_stiffness_n_per_mm);
    sim.tube_stiffness_n_per_mm = m.non_negative_or("tube_stiffness_n_per_mm", sim.tube_stiffness_n_per_mm);
    sim.potentiometer_noise_mm = m.non_negative_or("potentiometer_noise_mm", sim.potentiometer_noise_mm);
    sim.wall_stiffness_n_per_mm = m.positive_or("wall_stiffness_n_per_mm", sim.wall_stiffness_n_per_mm);
    sim.carriage_damping_n_s_per_mm =
        m.positive_or("carriage_damping_n_s_per_mm", sim.carriage_damping_n_s_per_mm);
    sim.catheter_outer_radius_mm = m.positive_or("catheter_outer_radius_mm", sim.catheter_outer_radius_mm);
    sim.analog_joystick_node = m.boolean_or("analog_joystick_node", true);
    if (m.has("true_catheter")) {
      const Reader t = m.child("true_catheter");
      auto& truth = sim.true_catheter;
      truth.enabled = t.boolean_or("enabled", true);
      truth.bend_scale = t.positive_or("bend_scale", truth.bend_scale);
      if (truth.bend_scale > 2.0) t.fail("bend_scale", "a scale from 0 to 2", t.raw("bend_scale"));
      truth.distal_length_factor = t.positive_or("distal_length_factor", truth.distal_length_factor);
      if (truth.distal_length_factor < 0.5 || truth.distal_length_factor > 2.0)
        t.fail("distal_length_factor", "a factor from 0.5 to 2", t.raw("distal_length_factor"));
      truth.slack_mm = t.non_negative_or("slack_mm", truth.slack_mm);
      truth.stick_mm = t.non_negative_or("stick_mm", truth.stick_mm);
      if (truth.slack_mm > 20.0) t.fail("slack_mm", "at most 20 mm", t.raw("slack_mm"));
      if (truth.stick_mm > 20.0) t.fail("stick_mm", "at most 20 mm", t.raw("stick_mm"));
      truth.slip_fraction = t.positive_or("slip_fraction", truth.slip_fraction);
      if (truth.slip_fraction > 1.0)
        t.fail("slip_fraction", "a fraction from 0 to 1", t.raw("slip_fraction"));
    }
    if (m.has("vessel")) {
      const Reader v = m.child("vessel");
      VesselTubeSettings tube;
      if (v.has("centerline")) {
        if (v.string("centerline") == "scene") {
          tube.from_scene = true;
        } else {
          tube.centerline_file = (rc.directory() / v.string("centerline")).string();
        }
      }
      tube.lead_in_mm = v.non_negative_or("lead_in_mm", tube.lead_in_mm);
      tube.bend_radius_mm = v.positive_or("bend_radius_mm", tube.bend_radius_mm);
      tube.turn_deg = v.positive_or("turn_deg", tube.turn_deg);
      if (tube.turn_deg > 180) v.fail("turn_deg", "a turn of at most 180 degrees", v.raw("turn_deg"));
      tube.lumen_radius_mm = v.positive_or("lumen_radius_mm", tube.lumen_radius_mm);
      if (tube.lumen_radius_mm <= sim.catheter_outer_radius_mm)
        v.fail("lumen_radius_mm",
               "a lumen wider than the catheter (outer radius " +
                   std::to_string(sim.catheter_outer_radius_mm) + " mm)",
               v.raw("lumen_radius_mm"));
      try {
        if (!tube.from_scene) (void)vessel_centerline(tube);
      } catch (const std::exception& e) {
        v.fail("centerline", std::string("a readable centerline file (") + e.what() + ")",
               v.raw("centerline"));
      }
      sim.vessel = tube;
    }
  }
  return s;
}

teleop::ModalCatheterParameters assembled_shape(const CatheterSettings& settings) {
  // The loss line θ_L = a·θ*_L + b (bend angles, 0 = straight) applied along the segment: the bend
  // so far, π/2 − θ(s), is scaled by a and b is spread linearly over s, so the tip gets exactly the
  // loss line. In the [1, s, …] × [1, q, …] basis: A = a·A* + (1 − a)·π/2·e₁e₁ᵀ − (b/L)·e₂e₁ᵀ, which
  // for the constant-curvature A* is constant curvature with gain a·k and offset b.
  auto p = settings.nominal;
  const auto assemble = [](teleop::ModalSegmentShape& segment, const teleop::ActuationLoss& loss) {
    Eigen::MatrixXd A = loss.slope * segment.shape_matrix;
    if (A.rows() < 2) {  // n = 1: room for the s¹ row
      A.conservativeResize(2, Eigen::NoChange);
      A.row(1).setZero();
    }
    A(0, 0) += (1.0 - loss.slope) * std::numbers::pi / 2.0;
    A(1, 0) -= loss.offset / segment.length;
    segment.shape_matrix = A;
  };
  assemble(p.proximal, settings.rates.proximal_loss);
  assemble(p.distal, settings.rates.distal_loss);
  return p;
}

teleop::ModalCatheterParameters true_shape(const teleop::ModalCatheterParameters& assembled,
                                           const TrueCatheterSettings& truth) {
  // θ(s) is the tangent angle with π/2 straight: the bend so far, π/2 − θ, scaled by c is
  // A' = c·A + (1 − c)·π/2·e₁e₁ᵀ (as assembled_shape applies a loss slope). A longer distal segment
  // keeps its curvature per mm of actuation and so bends further in total.
  auto p = assembled;
  for (auto* segment : {&p.proximal, &p.distal}) {
    segment->shape_matrix *= truth.bend_scale;
    segment->shape_matrix(0, 0) += (1.0 - truth.bend_scale) * std::numbers::pi / 2.0;
  }
  p.distal.length *= truth.distal_length_factor;
  return p;
}

std::vector<Eigen::Vector3d> vessel_centerline(const VesselTubeSettings& vessel) {
  if (!vessel.centerline_file.empty()) {
    std::ifstream in(vessel.centerline_file);
    if (!in) throw ConfigError(vessel.centerline_file + ": cannot open the vessel centerline");
    std::stringstream text;
    text << in.rdbuf();
    const auto branches = teleop::parse_centerline_csv(text.str());
    return branches.front().points;
  }
  // Arc channel: straight along +z, then a circular arc in the x–z plane turning toward +x (the way
  // the proximal segment bends at zero roll), sampled every 0.5 mm.
  return sim::arc_channel(vessel.lead_in_mm, vessel.bend_radius_mm,
                          vessel.turn_deg * std::numbers::pi / 180.0);
}

}  // namespace tendril::server
