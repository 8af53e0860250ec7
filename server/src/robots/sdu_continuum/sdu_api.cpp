// The sdu_continuum's part of the network API (network threads): the `continuum` fields of GET /robots
// and of operating_state, the live state topic /{robot}/continuum, and the commands hri_mode, map,
// simulation_scene, roll and unbias. Bodies are checked here; the control thread gets a PluginCommand.
#include <cmath>
#include <cstdio>
#include <limits>
#include <utility>

#include "sdu_continuum/sdu_robot.hpp"
#include "tendril/server/robot_api_extension.hpp"

namespace tendril::server {

namespace {

namespace cont = tendril::continuum;
using nlohmann::json;

json vec3(const Eigen::Vector3d& v) { return {v.x(), v.y(), v.z()}; }
json number_or_null(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

const char* hri_name(cont::GuidanceMode m) {
  switch (m) {
    case cont::GuidanceMode::kContactless:
      return "contactless";
    case cont::GuidanceMode::kContactBased:
      return "contact";
    default:
      return "off";
  }
}

const char* supervisor_state(cont::SduSafetyState s) {
  switch (s) {
    case cont::SduSafetyState::kUnbiasing:
      return "unbiasing";
    case cont::SduSafetyState::kClear:
      return "normal";
    case cont::SduSafetyState::kSlowed:
      return "slowed";
    case cont::SduSafetyState::kContact:
      return "stopped_contact";
    case cont::SduSafetyState::kHold:
      return "holding_fault";
  }
  return "holding_fault";
}

class SduApi final : public RobotApiExtension {
 public:
  SduApi(SduContinuum& robot, std::function<bool(const PluginCommand&)> post)
      : robot_(robot), post_(std::move(post)) {}

  void describe(json& out) const override {
    const auto& s = robot_.settings();
    auto disks = json::array();
    for (std::size_t i = 0; i < kSdus; ++i)
      disks.push_back({{"index", i}, {"arc_mm", s.model.disk_arc_mm[i]}, {"slots", cont::kTofPerSdu}});
    const auto& load = robot_.bus_load();
    out["continuum"] = {{"disks", disks},
                        {"segment",
                         {{"length_mm", s.model.length_mm},
                          {"disk_radius_mm", s.model.disk_radius_mm},
                          {"max_bending_rad", s.model.max_bending_rad},
                          // Where the windows sit around a disk (from its x axis): the ToF windows and
                          // the Hall windows between them, so a contact slot is drawn at its own angle.
                          {"tof_slot0_deg", s.model.tof_slot0_rad * 180.0 / M_PI},
                          {"hall_slot0_deg", s.model.hall_slot0_rad * 180.0 / M_PI},
                          {"slot_pitch_deg", s.model.slot_pitch_rad * 180.0 / M_PI}}},
                        {"hri_modes", {"off", "contactless", "contact"}},
                        {"speed",
                         {{"max_mm_s", s.supervisor.proximity.v_max_mm_s},
                          {"min_mm_s", s.supervisor.proximity.v_min_mm_s},
                          {"d_max_mm", s.supervisor.proximity.d_max_mm}}},
                        {"contact_threshold_n", s.supervisor.contact_threshold_n},
                        {"bus",
                         {{"name", s.bus},
                          {"rate_hz", s.rate_hz},
                          {"sdu_bits_per_second", load.bits_per_second},
                          {"sdu_load", load.load},
                          {"breakdown", load.breakdown}}},
                        {"simulated", robot_.simulation() != nullptr},
                        {"scene_arm", robot_.simulation() && robot_.simulation()->has_arm()}};
  }

  void state(json& out) const override {
    const auto s = robot_.snapshot();
    const auto samples = robot_.samples();
    const auto& settings = robot_.settings();
    const auto poses = cont::disk_poses(settings.model, segment_configuration(s.q));
    const double nan = std::numeric_limits<double>::quiet_NaN();
    auto disks = json::array();
    for (std::size_t i = 0; i < kSdus; ++i) {
      const auto& d = samples.disk[i];
      auto ranges = json::array();
      double nearest = nan;
      for (std::size_t j = 0; j < cont::kTofPerSdu; ++j) {
        const bool ok =
            d.received && d.tof_status[j] == cont::TofStatus::kValid && std::isfinite(d.tof_mm[j]);
        ranges.push_back(ok ? json(d.tof_mm[j]) : json(nullptr));
        if (ok && !(d.tof_mm[j] >= nearest)) nearest = d.tof_mm[j];
      }
      auto forces = json::array();
      for (double f : s.forces_n[i]) forces.push_back(std::isfinite(f) ? f : 0.0);
      json fault = nullptr;
      if (!s.fresh[i])
        fault = d.received ? "no sample for " + std::to_string(s.age_ns[i] / 1'000'000) + " ms (silent)"
                           : std::string("no sample received yet");
      else if (s.cause_disk == static_cast<int>(i) && s.cause != cont::SduCause::kContact &&
               s.cause != cont::SduCause::kNone)
        fault = std::string(s.reason);
      disks.push_back({{"index", i},
                       {"position_mm", vec3(poses[i].translation())},
                       {"fresh", s.fresh[i]},
                       {"ranges_mm", ranges},
                       {"nearest_mm", number_or_null(nearest)},
                       {"force_n", forces},
                       {"contact", s.contact && s.contact_disk == static_cast<int>(i)},
                       {"fault", fault}});
    }
    const auto m = robot_.mapper().status();
    const double vmax = settings.supervisor.proximity.v_max_mm_s;
    json continuum = {
        {"speed_scale", vmax > 0.0 ? s.speed_limit_mm_s / vmax : 0.0},
        {"speed_limit_mm_s", s.speed_limit_mm_s},
        {"nearest_mm",
         s.nearest_mm < settings.supervisor.proximity.d_max_mm ? json(s.nearest_mm) : json(nullptr)},
        {"step_kept", s.step_kept},
        {"surface_speed_mm_s", s.surface_speed_mm_s},
        {"hri_mode", hri_name(s.hri)},
        {"guidance_mm_s", s.guidance_mm_s},
        {"rolling", s.rolling},
        {"contact", s.contact},
        {"contact_disk", s.contact ? json(s.contact_disk) : json(nullptr)},
        {"contact_slot", s.contact ? json(s.contact_slot) : json(nullptr)},
        {"contact_force_n", s.contact ? json(s.contact_force_n) : json(nullptr)},
        {"disks", disks},
        {"supervisor", {{"state", supervisor_state(s.state)}, {"reason", std::string(s.reason)}}},
        {"map",
         {{"points", m.points},
          {"planes", m.planes},
          {"points_per_s", m.points_per_s},
          {"refused_full", m.refused_full},
          {"bracing", {{"admissible", m.admissible}, {"reason", m.reason}}}}},
        {"bus",
         {{"samples", samples.samples},
          {"incomplete", samples.incomplete},
          {"malformed", samples.malformed}}}};
    if (auto* sim = robot_.simulation(); sim && sim->has_arm()) {
      static const char* actions[] = {"hold", "approach", "retreat"};
      continuum["simulation"] = {{"arm_centre_mm", vec3(sim->arm_centre())},
                                 {"arm_action", actions[static_cast<int>(sim->arm_action())]},
                                 {"true_max_force_n", sim->true_max_force()}};
    }
    out["continuum"] = std::move(continuum);
    // A hold of the disks' supervisor: its sentence and the way out, for the operator.
    const bool holds = s.state == cont::SduSafetyState::kUnbiasing ||
                       s.state == cont::SduSafetyState::kHold || s.state == cont::SduSafetyState::kContact;
    if (holds && out.contains("hold") && out["hold"].is_object()) {
      out["hold"]["message"] = std::string(s.reason);
      out["hold"]["next"] = way_out(s.cause);
    }
  }

  std::string way_out(cont::SduCause cause) const {
    const std::string base = "POST /api/v1/robots/" + robot_.config().name;
    switch (cause) {
      case cont::SduCause::kContact:
        // Only what works while held: guidance (also contact-based) is refused until the hold clears.
        return "Move the object away (or roll along it: " + base + "/roll), then resume.";
      case cont::SduCause::kBaselineDrift:
        return "Take the sleeve clear of every object and re-zero the Hall sensors (" + base +
               "/unbias), then resume.";
      case cont::SduCause::kUnbiasing:
        return "Wait for the Hall baseline (half a second at rest, nothing touching the sleeve), then "
               "resume.";
      default:
        return "Check the disk's cable and sensors; resume once it reads again.";
    }
  }

  std::optional<LiveState> live_state() const override {
    // Ranges, forces, the speed law and the map change with every sample: /{robot}/continuum at 20 Hz.
    return LiveState{"continuum",
                     "tendril.ContinuumState",
                     20.0,
                     {"continuum.speed_scale", "continuum.speed_limit_mm_s", "continuum.nearest_mm",
                      "continuum.step_kept", "continuum.surface_speed_mm_s", "continuum.guidance_mm_s",
                      "continuum.contact_force_n", "continuum.disks", "continuum.map", "continuum.bus",
                      "continuum.simulation", "continuum.supervisor.reason"}};
  }

  // The SIMULATED scene the disks sense, drawn beside the robot so that a person sees what they range:
  // the planes as 400 mm square plates (they are infinite), the boxes, and the moving arm cylinder.
  void scene(json& entities) const override {
    if (robot_.simulation() == nullptr || !entities.is_array() || entities.empty()) return;
    const auto& sim = robot_.settings().simulation;
    json e = entities[0];  // the backbone entity: same stamp and frame (the base frame {0})
    for (const char* key :
         {"lines", "arrows", "spheres", "cubes", "cylinders", "triangles", "texts", "models"})
      e.erase(key);
    e["id"] = robot_.config().name + "/simulated_scene";
    e["metadata"] = json::array({{{"key", "simulated"}, {"value", "true"}}});
    const auto pose = [](const Eigen::Vector3d& at, const Eigen::Quaterniond& q) {
      return json{{"position", {{"x", at.x()}, {"y", at.y()}, {"z", at.z()}}},
                  {"orientation", {{"x", q.x()}, {"y", q.y()}, {"z", q.z()}, {"w", q.w()}}}};
    };
    const auto size = [](double x, double y, double z) { return json{{"x", x}, {"y", y}, {"z", z}}; };
    const auto colour = [](double r, double g, double b, double a) {
      return json{{"r", r}, {"g", g}, {"b", b}, {"a", a}};
    };
    auto cubes = json::array();
    for (const auto& p : sim.planes) {
      const auto q = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), p.normal.normalized());
      cubes.push_back({{"pose", pose(p.point, q)},
                       {"size", size(400.0, 400.0, 2.0)},
                       {"color", colour(0.55, 0.55, 0.6, 0.25)}});
    }
    for (const auto& b : sim.boxes) {
      const Eigen::Quaterniond q(b.pose.rotation());
      const Eigen::Vector3d extent = 2.0 * b.half_extent_mm;
      cubes.push_back({{"pose", pose(b.pose.translation(), q)},
                       {"size", size(extent.x(), extent.y(), extent.z())},
                       {"color", colour(0.6, 0.5, 0.35, 0.35)}});
    }
    e["cubes"] = std::move(cubes);
    auto cylinders = json::array();
    if (sim.arm && robot_.simulation()->has_arm()) {
      const auto& arm = *sim.arm;
      const auto q = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), arm.axis.normalized());
      const double d = 2.0 * arm.radius_mm;
      cylinders.push_back({{"pose", pose(robot_.simulation()->arm_centre(), q)},
                           {"size", size(d, d, 2.0 * arm.half_length_mm)},
                           {"bottom_scale", 1.0},
                           {"top_scale", 1.0},
                           {"color", colour(0.85, 0.62, 0.5, 0.45)}});
    }
    e["cylinders"] = std::move(cylinders);
    entities.push_back(std::move(e));
  }

  std::vector<RobotCommandInfo> commands() const override {
    const json number = {{"type", "number"}};
    return {{"hri_mode",
             {{"type", "object"},
              {"properties", {{"mode", {{"type", "string"}, {"enum", {"off", "contactless", "contact"}}}}}},
              {"required", {"mode"}}},
             false,
             "",
             "the HRI law of guidance mode: contactless v = γ(d_r − d_l), contact-based v = γ(ΔB_z,r − "
             "ΔB_z,l), or off"},
            {"map",
             {{"type", "object"},
              {"properties", {{"action", {{"type", "string"}, {"enum", {"clear", "extract"}}}}}},
              {"required", {"action"}}},
             false,
             "",
             "the ToF map: extract fits planes (RANSAC, 40 mm) and checks bracing (150 × 150 mm); clear "
             "forgets it"},
            {"simulation_scene",
             {{"type", "object"},
              {"properties",
               {{"action", {{"type", "string"}, {"enum", {"approach", "retreat", "stop", "reset"}}}},
                {"speed_mm_s", number}}},
              {"required", {"action"}}},
             false,
             "",
             "moves the SIMULATED cylinder standing for a human arm towards the segment, away, or back to "
             "its start"},
            {"roll",
             {{"type", "object"}, {"properties", {{"rate_rad_s", number}}}, {"required", {"rate_rad_s"}}},
             true,
             "",
             "while stopped on a contact: the 1-DoF no-slip roll about the contact (Abah 2022, eq. 3.6); "
             "refresh within the servo timeout"},
            {"unbias",
             {{"type", "object"}},
             false,
             "",
             "collects a new Hall baseline (the way out of a drift hold); nothing may touch the sleeve"}};
  }

  ApiResult command(const std::string& name, const json& body) override {
    if (!body.is_object()) return bad(name, "the body must be a JSON object");
    if (name == "hri_mode") return hri_mode(body);
    if (name == "map") return map(body);
    if (name == "simulation_scene") return simulation_scene(body);
    if (name == "roll") return roll(body);
    if (name == "unbias") return unbias();
    return ApiResult::error(404, "not_found", "no command " + name);
  }

 private:
  static ApiResult bad(const std::string& name, const std::string& why) {
    return ApiResult::error(400, "bad_request", name + ": " + why);
  }
  ApiResult posted(const PluginCommand& c, json body) {
    if (!post_(c))
      return ApiResult::error(
          503, "mailbox_full",
          "the control thread's mailbox for robot '" + robot_.config().name + "' is full; try again");
    return ApiResult::success(std::move(body), 202);
  }

  ApiResult hri_mode(const json& body) {
    const auto it = body.find("mode");
    if (it == body.end() || !it->is_string())
      return bad("hri_mode", "\"mode\" must be \"off\", \"contactless\" or \"contact\"");
    const std::string m = *it;
    PluginCommand c;
    c.id = static_cast<std::uint16_t>(SduCommand::hri_mode);
    c.count = 1;
    if (m == "off")
      c.values[0] = 0;
    else if (m == "contactless")
      c.values[0] = 1;
    else if (m == "contact")
      c.values[0] = 2;
    else
      return bad("hri_mode", "\"mode\" must be \"off\", \"contactless\" or \"contact\", got \"" + m + "\"");
    return posted(c, {{"hri_mode", m},
                      {"note", "the law moves the robot in guidance mode (POST /api/v1/robots/" +
                                   robot_.config().name + "/mode {\"mode\": \"guidance\"})"}});
  }

  ApiResult map(const json& body) {
    const auto it = body.find("action");
    if (it == body.end() || !it->is_string() || (*it != "clear" && *it != "extract"))
      return bad("map", "\"action\" must be \"clear\" or \"extract\"");
    if (*it == "clear") {
      robot_.mapper().clear();
      return ApiResult::success({{"points", 0}, {"planes", 0}});
    }
    const auto e = robot_.mapper().extract();
    if (!e.ok) return ApiResult::error(409, e.error_code, "map extract: " + e.error);
    auto planes = json::array();
    for (const auto& p : e.planes)
      planes.push_back({{"normal", vec3(p.plane.normal)},
                        {"offset_mm", p.plane.offset_mm},
                        {"inliers", p.inliers.size()},
                        {"rms_mm", p.rms_mm}});
    return ApiResult::success({{"points", e.points},
                               {"planes", planes},
                               {"bracing",
                                {{"admissible", e.bracing.admissible},
                                 {"largest_square_mm", e.bracing.largest_square_mm},
                                 {"patch_centre_mm", vec3(e.bracing.patch_centre)},
                                 {"reason", e.bracing.reason}}}});
  }

  ApiResult simulation_scene(const json& body) {
    auto* sim = robot_.simulation();
    if (!sim || !sim->has_arm())
      return ApiResult::error(409, "not_simulated",
                              "robot '" + robot_.config().name +
                                  "' has no SIMULATED arm in its scene (continuum.simulation.arm)");
    const auto it = body.find("action");
    if (it == body.end() || !it->is_string() ||
        (*it != "approach" && *it != "retreat" && *it != "stop" && *it != "reset"))
      return bad("simulation_scene", "\"action\" must be \"approach\", \"retreat\", \"stop\" or \"reset\"");
    double speed = std::numeric_limits<double>::quiet_NaN();
    if (const auto sp = body.find("speed_mm_s"); sp != body.end()) {
      if (!sp->is_number() || !(sp->get<double>() > 0.0) || sp->get<double>() > 200.0)
        return bad("simulation_scene", "\"speed_mm_s\" must be a number in (0, 200] mm/s");
      speed = sp->get<double>();
    }
    if (*it == "reset")
      sim->arm_reset();
    else if (*it == "stop")
      sim->arm_command(SduSimulation::ArmAction::hold, speed);
    else
      sim->arm_command(
          *it == "approach" ? SduSimulation::ArmAction::approach : SduSimulation::ArmAction::retreat, speed);
    return ApiResult::success({{"action", *it}, {"arm_centre_mm", vec3(sim->arm_centre())}}, 202);
  }

  ApiResult roll(const json& body) {
    const auto it = body.find("rate_rad_s");
    if (it == body.end() || !it->is_number() || !std::isfinite(it->get<double>()))
      return bad("roll", "\"rate_rad_s\" must be a finite number (rad/s about the contact)");
    const auto s = robot_.snapshot();
    if (!s.contact)
      return ApiResult::error(409, "no_contact",
                              "roll: the no-slip roll runs about a contact, and robot '" +
                                  robot_.config().name + "' touches nothing now");
    PluginCommand c;
    c.id = static_cast<std::uint16_t>(SduCommand::roll);
    c.count = 1;
    c.values[0] = it->get<double>();
    return posted(c, {{"rate_rad_s", c.values[0]}});
  }

  ApiResult unbias() {
    const auto s = robot_.snapshot();
    if (s.contact)
      return ApiResult::error(409, "in_contact",
                              "unbias: the sleeve is in contact (" + std::string(s.reason) +
                                  "); a baseline taken now would hide the contact");
    PluginCommand c;
    c.id = static_cast<std::uint16_t>(SduCommand::unbias);
    return posted(c, {{"unbiasing", true}});
  }

  SduContinuum& robot_;
  std::function<bool(const PluginCommand&)> post_;
};

}  // namespace

std::unique_ptr<RobotApiExtension> make_sdu_api(SduContinuum& robot,
                                                std::function<bool(const PluginCommand&)> post) {
  return std::make_unique<SduApi>(robot, std::move(post));
}

}  // namespace tendril::server
