#include "steerable_catheter/planning_service.hpp"

#include <algorithm>
#include <atomic>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <deque>
#include <iomanip>
#include <mutex>
#include <optional>
#include <sstream>
#include <variant>

#include "steerable_catheter/calibration_job.hpp"
#include "steerable_catheter/catheter_settings.hpp"
#include "tendril/drivers/sim/simulated_side_view_camera.hpp"
#include "tendril/server/imaging_worker.hpp"
#include "tendril/server/job_queue.hpp"
#include "tendril/teleop/catheter_configuration.hpp"
#include "tendril/teleop/catheter_kinematics.hpp"
#include "tendril/teleop/design_optimiser.hpp"
#include "tendril/teleop/shape_error_planner.hpp"
#include "tendril/teleop/vessel_centerline.hpp"
#include "tendril/teleop/vessel_mesh.hpp"

namespace tendril::server {

namespace {

using nlohmann::json;
using teleop::CenterlinePolyline;

constexpr double kMinDs = 0.05, kMaxDs = 10.0;     // mm between resampled vessel points
constexpr double kMinDq1 = 0.1, kMaxDq1 = 50.0;    // mm between insertion steps
constexpr std::size_t kMaxVesselPathPoints = 600;  // vessel polyline in a plan result (for display)
constexpr double kBackboneSpacing = 1.0;           // mm between planned backbone points

ApiResult bad_request(const std::string& message) { return ApiResult::error(400, "bad_request", message); }
ApiResult bad_vessel(const std::string& message) { return ApiResult::error(400, "bad_vessel", message); }

std::string media_type(const std::string& content_type) {
  std::string m = content_type.substr(0, content_type.find(';'));
  m.erase(0, m.find_first_not_of(" \t"));
  m.erase(m.find_last_not_of(" \t") + 1);
  std::transform(m.begin(), m.end(), m.begin(), [](unsigned char c) { return std::tolower(c); });
  return m;
}

double polyline_length(const CenterlinePolyline& p) {
  double length = 0.0;
  for (std::size_t i = 1; i < p.points.size(); ++i) length += (p.points[i] - p.points[i - 1]).norm();
  return length;
}

// The first `max_length` mm of the polyline (the last point interpolated on its segment).
CenterlinePolyline truncated(const CenterlinePolyline& p, double max_length) {
  CenterlinePolyline out;
  if (p.points.empty()) return out;
  out.points.push_back(p.points[0]);
  if (!p.radii.empty()) out.radii.push_back(p.radii[0]);
  double length = 0.0;
  for (std::size_t i = 1; i < p.points.size(); ++i) {
    const double segment = (p.points[i] - p.points[i - 1]).norm();
    if (length + segment >= max_length) {
      const double f = segment > 0 ? (max_length - length) / segment : 0.0;
      out.points.push_back(p.points[i - 1] + f * (p.points[i] - p.points[i - 1]));
      if (!p.radii.empty()) out.radii.push_back(p.radii[i - 1] + f * (p.radii[i] - p.radii[i - 1]));
      return out;
    }
    length += segment;
    out.points.push_back(p.points[i]);
    if (!p.radii.empty()) out.radii.push_back(p.radii[i]);
  }
  return out;
}

// The tip cannot go deeper than the insertion joint reaches: the vessel is planned that far, in the
// insertion frame, resampled at ds.
teleop::VesselCenterline reachable_path(const teleop::CenterlinePolyline& branch, const RobotConfig& rc,
                                        double ds) {
  const auto& insertion = rc.joints.at(0).limit;
  const double reach = insertion.upper - insertion.soft_margin;
  return teleop::VesselCenterline::from_polyline(
             polyline_length(branch) > reach ? truncated(branch, reach) : branch, ds)
      .aligned_to_insertion();
}

json point_json(const Eigen::Vector3d& p) { return json::array({p.x(), p.y(), p.z()}); }

// What is kept of one branch for the vessel listings (the JSON is made when asked: a JSON object per
// branch cost about 1 KB, 300 MB for a 30 MB CSV of short branches).
struct BranchSummary {
  std::size_t points = 0;
  double length_mm = 0.0;
  bool has_radius = false;
  Eigen::Vector3d start, end;
};

// A stored vessel keeps its centerline polylines (what plans and GET /vessels/{id} resample) and
// nothing of the uploaded file: an STL mesh is reduced to its centerline before it is stored.
struct StoredVessel {
  std::string id, name, source;
  std::vector<CenterlinePolyline> branches;
  std::vector<BranchSummary> branch_summaries;
  std::size_t bytes = 0;  // memory the store counts for it (stored_bytes())

  json summary() const {
    auto branch_json = json::array();
    for (std::size_t k = 0; k < branch_summaries.size(); ++k) {
      const auto& b = branch_summaries[k];
      branch_json.push_back({{"index", k},
                             {"points", b.points},
                             {"length_mm", b.length_mm},
                             {"has_radius", b.has_radius},
                             {"start", point_json(b.start)},
                             {"end", point_json(b.end)}});
    }
    return {{"id", id},
            {"name", name},
            {"source", source},
            {"stored_bytes", bytes},
            {"branches", std::move(branch_json)}};
  }
};

// The heap memory a stored vessel holds (what the store's byte limit counts).
std::size_t stored_bytes(const StoredVessel& v) {
  std::size_t bytes = sizeof(StoredVessel) + v.id.capacity() + v.name.capacity() + v.source.capacity() +
                      v.branches.capacity() * sizeof(CenterlinePolyline) +
                      v.branch_summaries.capacity() * sizeof(BranchSummary);
  for (const auto& b : v.branches)
    bytes += b.points.capacity() * sizeof(Eigen::Vector3d) + b.radii.capacity() * sizeof(double);
  return bytes;
}

std::string mebibytes(std::size_t bytes) {
  std::ostringstream text;
  text << std::fixed << std::setprecision(1) << static_cast<double>(bytes) / (1024.0 * 1024.0) << " MiB";
  return text.str();
}

// Parses an uploaded vessel file into branches and checks each one is usable as a centerline in mm.
std::variant<std::vector<CenterlinePolyline>, ApiResult> parse_vessel(std::string_view body,
                                                                      const std::string& content_type,
                                                                      const PlanningOptions& options,
                                                                      std::string& source) {
  const std::size_t max_bytes = options.max_vessel_bytes;
  const auto type = media_type(content_type);
  if (type == "text/csv" || type == "application/csv") {
    source = "csv";
  } else if (type == "model/stl" || type == "application/sla" || type == "application/vnd.ms-pki.stl") {
    source = "stl";
  } else {
    return ApiResult::error(415, "unsupported_media_type",
                            "send the vessel file with Content-Type text/csv (centerline x,y,z[,r] in mm) or "
                            "model/stl (vessel surface mesh in mm); got \"" +
                                content_type + "\"");
  }
  if (body.size() > max_bytes)
    return ApiResult::error(413, "body_too_large",
                            "the vessel file has " + std::to_string(body.size()) + " bytes; the limit is " +
                                std::to_string(max_bytes));
  if (body.empty()) return bad_vessel("the request body is empty: send the vessel file itself as the body");
  std::vector<CenterlinePolyline> branches;
  try {
    branches = source == "csv" ? teleop::parse_centerline_csv(body) : teleop::read_stl_centerline(body);
  } catch (const teleop::VesselInputError& e) {
    // The readers name the format and the place themselves ("centerline CSV line 2: …", "binary
    // STL: …"); prefixing it again read "centerline CSV: centerline CSV line 2: …".
    return bad_vessel(e.what());
  }
  if (branches.empty()) return bad_vessel("the file holds no centerline points");
  if (branches.size() > options.max_vessel_branches)
    return bad_vessel("the file splits into " + std::to_string(branches.size()) +
                      " branches (a step more than 5 times the median point spacing starts a new one); at "
                      "most " +
                      std::to_string(options.max_vessel_branches) + " are accepted");
  for (std::size_t k = 0; k < branches.size(); ++k) {
    const double length = polyline_length(branches[k]);
    try {
      // The same checks a plan makes (units, finiteness, enough distinct points).
      (void)teleop::VesselCenterline::from_polyline(branches[k], std::clamp(length / 4.0, 1e-3, 0.5));
    } catch (const teleop::VesselInputError& e) {
      return bad_vessel("branch " + std::to_string(k) + " (" + std::to_string(branches[k].points.size()) +
                        " points): " + e.what());
    }
  }
  return branches;
}

// A number from JSON or from a query string; nullopt when absent.
std::variant<std::optional<double>, ApiResult> read_number(const json& request, const char* key, double lo,
                                                           double hi, const char* unit) {
  if (!request.contains(key) || request[key].is_null()) return std::optional<double>{};
  const auto& v = request[key];
  double value = 0.0;
  if (v.is_number()) {
    value = v.get<double>();
  } else if (v.is_string()) {
    const auto s = v.get<std::string>();
    char* end = nullptr;
    value = std::strtod(s.c_str(), &end);
    if (s.empty() || *end != '\0')
      return bad_request(std::string(key) + ": expected a number, got \"" + s + "\"");
  } else {
    return bad_request(std::string(key) + ": expected a number");
  }
  if (!std::isfinite(value) || value < lo || value > hi) {
    std::ostringstream m;
    m << key << ": expected " << lo << " to " << hi << " " << unit << ", got " << value;
    return ApiResult::error(422, "out_of_range", m.str());
  }
  return std::optional<double>{value};
}

struct PlanRequest {
  std::size_t robot = 0;
  std::size_t branch = 0;
  std::optional<Eigen::Vector3d> end;  // choose the branch whose end is nearest, starting there
  double ds = 0.5;
  double dq1 = 3.0;
  std::string design = "configured";  // configured | nominal | optimise
  bool flexure = false;
};

struct RobotModel {
  RobotConfig config;
  std::optional<teleop::CatheterParameters> design;  // null: not a catheter the planner models
  std::string why_not;
};

teleop::CatheterParameters configured_design(const json& k) {
  teleop::CatheterParameters p;
  const auto& lengths = k.at("segment_lengths_mm");
  const auto& gains = k.at("bend_gain_rad_per_mm");
  p.proximal_length = lengths.at(0).get<double>();
  p.distal_length = lengths.at(1).get<double>();
  p.proximal_curvature_gain = gains.at(0).get<double>();
  p.distal_curvature_gain = gains.at(1).get<double>();
  p.plane_offset = k.at("plane_offset_rad").get<double>();
  p.flexure = k.value("flexure_rad", 0.0);
  return p;
}

json design_json(const teleop::CatheterParameters& p, bool free_flexure) {
  return {{"L1", p.proximal_length},      {"L2", p.distal_length},    {"delta2", p.plane_offset},
          {"flexure", free_flexure},      {"flexure_rad", p.flexure}, {"k1", p.proximal_curvature_gain},
          {"k2", p.distal_curvature_gain}};
}

// How the design optimiser's search went (teleop/design_optimiser.hpp): why it stopped, and with
// flexure whether a plan with γ free beat the best design without it.
json convergence_json(const teleop::DesignResult& r) {
  const auto& c = r.convergence;
  return {{"method", "exploration + NLopt BOBYQA with restarts"},
          {"stop_reason", teleop::to_string(c.stop_reason)},
          {"converged", c.converged},
          {"local_runs", c.local_runs},
          {"search_evaluations", c.search_evaluations},
          {"search_ds", c.search_spacing},
          {"explored_penalty", c.explored_penalty},
          {"subset_penalty", r.flexure ? json(c.subset_penalty) : json()},
          {"flexure_improved", r.flexure ? json(c.flexure_improved) : json()},
          {"best_penalty_history", c.best_penalty_history}};
}

// Planner drive limits = the robot's bend-joint limits less their soft margins.
teleop::ShapeErrorPlannerOptions planner_options(const RobotConfig& rc, double dq1, bool flexure) {
  teleop::ShapeErrorPlannerOptions o;
  o.insertion_step = dq1;
  const auto& prox = rc.joints.at(2).limit;
  const auto& dist = rc.joints.at(3).limit;
  o.proximal_drive_min = prox.lower + prox.soft_margin;
  o.proximal_drive_max = prox.upper - prox.soft_margin;
  o.distal_drive_min = dist.lower + dist.soft_margin;
  o.distal_drive_max = dist.upper - dist.soft_margin;
  o.free_flexure = flexure;
  return o;
}

// The first step outside the robot's joint limits, described for a person; empty when all are inside.
std::string first_limit_violation(const RobotConfig& rc, const teleop::PathPlan& plan) {
  for (std::size_t k = 0; k < plan.steps.size(); ++k) {
    for (std::size_t i = 0; i < 4 && i < rc.joints.size(); ++i) {
      const auto& j = rc.joints[i].limit;
      const double v = plan.steps[k].q[static_cast<Eigen::Index>(i)];
      // Path following holds setpoints inside the soft margins.
      if (v < j.lower + j.soft_margin || v > j.upper - j.soft_margin) {
        std::ostringstream m;
        m << "step " << k << ": joint '" << j.name << "' " << v << " " << j.unit << " is outside ["
          << j.lower + j.soft_margin << ", " << j.upper - j.soft_margin << "] (limits less the soft margin)";
        return m.str();
      }
    }
  }
  return {};
}

json plan_json(const teleop::PathPlan& plan, const RobotConfig& rc, const PlanRequest& p,
               const std::string& vessel_id, const teleop::VesselCenterline& aligned, double vessel_length,
               bool was_truncated, double compute_s) {
  auto steps = json::array();
  // Each step's configuration ψ is what the configuration mode commands to reach its joint values: through
  // the robot's configuration map (loss lines and coupling, eq. 4.21), so move_configuration with it lands
  // on the step (issue 31: the planning model's bends, without the loss offsets, asked for a proximal
  // drive past its limit). Without catheter settings, the planning model's bends.
  std::optional<teleop::CatheterConfigurationMap> map;
  try {
    const auto settings = parse_catheter_settings(rc);
    map.emplace(settings.nominal, settings.rates);
  } catch (const std::exception&) {
    map.reset();
  }
  for (const auto& st : plan.steps) {
    const teleop::ConstantCurvatureCatheter model(st.design);
    const Eigen::Vector4d psi =
        map ? map->configuration(Eigen::Vector4d(st.q[0], st.q[1], st.q[2], st.q[3]))
            : Eigen::Vector4d(st.q[0], st.q[1], model.proximal_bend(st.q), model.distal_bend(st.q));
    auto backbone = json::array();
    for (const auto& b : teleop::planned_backbone(st, kBackboneSpacing)) backbone.push_back(point_json(b));
    steps.push_back(
        {{"q", {st.q[0], st.q[1], st.q[2], st.q[3]}},
         {"configuration",
          {{"insertion", psi[0]}, {"roll", psi[1]}, {"theta_proximal", psi[2]}, {"theta_distal", psi[3]}}},
         {"flexure_rad", st.flexure},
         {"points", st.points},
         {"position_error_mm", st.position_error_mean},
         {"position_error_max_mm", st.position_error_max},
         {"orientation_error_deg", st.tangent_error_mean},
         {"orientation_error_max_deg", st.tangent_error_max},
         {"iterations", st.iterations},
         {"backbone", std::move(backbone)}});
  }
  auto path = json::array();
  const auto& pts = aligned.points();
  const std::size_t stride =
      std::max<std::size_t>(1, (pts.size() + kMaxVesselPathPoints - 1) / kMaxVesselPathPoints);
  for (std::size_t i = 0; i < pts.size(); i += stride) path.push_back(point_json(pts[i]));
  if ((pts.size() - 1) % stride != 0) path.push_back(point_json(pts.back()));
  const auto violation = first_limit_violation(rc, plan);
  return {{"robot", rc.name},
          {"vessel", vessel_id.empty() ? json() : json(vessel_id)},
          {"branch", p.branch},
          {"ds", p.ds},
          {"dq1", p.dq1},
          {"design", design_json(plan.design, plan.free_flexure)},
          {"design_source", p.design},
          {"frame", "insertion: vessel start at the origin, initial tangent +z (mm)"},
          {"vessel_length_mm", vessel_length},
          {"planned_length_mm", aligned.length()},
          {"truncated_to_insertion_range", was_truncated},
          {"within_joint_limits", violation.empty()},
          {"limit_violation", violation.empty() ? json() : json(violation)},
          {"vessel_path", std::move(path)},
          {"steps", std::move(steps)},
          {"summary",
           {{"steps", plan.steps.size()},
            {"mean_position_error_mm", plan.position_error_mean},
            {"max_position_error_mm", plan.position_error_max},
            {"mean_orientation_error_deg", plan.tangent_error_mean},
            {"max_orientation_error_deg", plan.tangent_error_max},
            {"iterations", plan.total_iterations},
            {"compute_s", compute_s}}}};
}

}  // namespace

struct PlanningService::Impl {
  PlanningOptions options;
  std::vector<RobotModel> robots;
  JobQueue queue;
  mutable std::mutex mutex;
  std::map<std::string, std::shared_ptr<const StoredVessel>> vessels;
  std::deque<std::string> vessel_order;  // oldest first
  std::size_t vessel_bytes = 0;          // stored_bytes() of all the vessels kept
  std::uint64_t next_vessel = 1;
  std::atomic<std::uint64_t> side_view_frames{0};  // fresh camera noise for every picture

  Impl(std::vector<RobotConfig> configs, PlanningOptions o)
      : options(o), queue(JobQueueOptions{o.workers, o.max_pending_jobs, o.max_finished_jobs}) {
    for (auto& rc : configs) {
      RobotModel m;
      const auto kinematics = rc.settings.value("kinematics", json::object());
      if (rc.kind == "steerable_catheter" &&
          kinematics.value("model", std::string{}) == "constant_curvature_catheter" &&
          rc.joints.size() == 4) {
        try {
          m.design = configured_design(kinematics);
        } catch (const std::exception& e) {
          m.why_not = std::string("its kinematics could not be read: ") + e.what();
        }
      } else {
        m.why_not =
            "the planner models the steerable catheter (kind steerable_catheter, kinematics "
            "constant_curvature_catheter) only";
      }
      m.config = std::move(rc);
      robots.push_back(std::move(m));
    }
  }

  struct Stored {
    std::shared_ptr<const StoredVessel> vessel;
    std::vector<std::string> forgotten;  // older vessels let go to make room, oldest first
  };

  // Keeps the vessel, forgetting the oldest ones while more than max_vessels are kept or they take more
  // than max_stored_vessel_bytes together. A vessel larger than that on its own is refused (413).
  std::variant<Stored, ApiResult> store(std::vector<CenterlinePolyline> branches, std::string source,
                                        std::string name) {
    auto v = std::make_shared<StoredVessel>();
    v->source = std::move(source);
    v->branches = std::move(branches);
    for (auto& b : v->branches) {
      // A reader grows its vectors by doubling: up to half of what they hold can be spare capacity.
      b.points.shrink_to_fit();
      b.radii.shrink_to_fit();
      v->branch_summaries.push_back(
          {b.points.size(), polyline_length(b), !b.radii.empty(), b.points.front(), b.points.back()});
    }
    v->branches.shrink_to_fit();
    v->branch_summaries.shrink_to_fit();
    std::lock_guard lock(mutex);
    v->id = "v" + std::to_string(next_vessel++);
    v->name = name.empty() ? v->id : std::move(name);
    v->bytes = stored_bytes(*v);
    if (v->bytes > options.max_stored_vessel_bytes)
      return ApiResult::error(413, "vessel_too_large",
                              "the vessel's centerline takes " + mebibytes(v->bytes) +
                                  " in memory; the vessel store keeps at most " +
                                  mebibytes(options.max_stored_vessel_bytes) +
                                  " of centerlines: send a sparser centerline (a point every 0.05 mm is "
                                  "as fine as a plan resamples)");
    vessels[v->id] = v;
    vessel_order.push_back(v->id);
    vessel_bytes += v->bytes;
    Stored stored{v, {}};
    while (vessel_order.size() > options.max_vessels || vessel_bytes > options.max_stored_vessel_bytes) {
      const auto oldest = vessels.find(vessel_order.front());
      vessel_bytes -= oldest->second->bytes;
      stored.forgotten.push_back(oldest->first);
      vessels.erase(oldest);
      vessel_order.pop_front();
    }
    return stored;
  }

  // The 201 answer of an upload: the vessel, and what the store keeps now and at most.
  json stored_json(const Stored& stored) const {
    json out = stored.vessel->summary();
    std::lock_guard lock(mutex);
    out["store"] = {{"vessels", vessel_order.size()},
                    {"max_vessels", options.max_vessels},
                    {"bytes", vessel_bytes},
                    {"max_bytes", options.max_stored_vessel_bytes},
                    {"forgotten", stored.forgotten},
                    {"policy", "at most " + std::to_string(options.max_vessels) + " vessels and " +
                                   mebibytes(options.max_stored_vessel_bytes) +
                                   " of centerlines are kept; the oldest upload is forgotten first"}};
    return out;
  }

  std::shared_ptr<const StoredVessel> find_vessel(const std::string& id) const {
    std::lock_guard lock(mutex);
    const auto it = vessels.find(id);
    return it == vessels.end() ? nullptr : it->second;
  }

  // Robot, branch, ds, dq1, design from a JSON request or the query of a file upload.
  std::variant<PlanRequest, ApiResult> read_plan_request(const json& r) const {
    PlanRequest p;
    if (!r.is_object()) return bad_request("expected a JSON object");
    // Robot: named, or the only robot the planner models.
    std::string robot;
    if (r.contains("robot")) {
      if (!r["robot"].is_string()) return bad_request("robot: expected a robot name such as \"srmc\"");
      robot = r["robot"].get<std::string>();
    }
    bool found = false;
    for (std::size_t i = 0; i < robots.size(); ++i) {
      if (robot.empty() ? robots[i].design.has_value() : robots[i].config.name == robot) {
        p.robot = i;
        found = true;
        break;
      }
    }
    if (!found)
      return robot.empty()
                 ? ApiResult::error(422, "no_plannable_robot", "no configured robot can be planned for")
                 : ApiResult::error(404, "unknown_robot", "there is no robot named '" + robot + "'");
    if (!robots[p.robot].design)
      return ApiResult::error(
          422, "not_plannable",
          "robot '" + robots[p.robot].config.name + "' cannot be planned for: " + robots[p.robot].why_not);
    if (r.contains("branch") && !r["branch"].is_null()) {
      const auto& b = r["branch"];
      long value = -1;
      if (b.is_number_integer()) {
        value = b.get<long>();
      } else if (b.is_string()) {
        const auto s = b.get<std::string>();
        char* end = nullptr;
        value = std::strtol(s.c_str(), &end, 10);
        if (s.empty() || *end != '\0') value = -1;
      }
      if (value < 0) return bad_request("branch: expected a branch index 0, 1, …");
      p.branch = static_cast<std::size_t>(value);
    }
    if (r.contains("end") && !r["end"].is_null()) {
      const auto& e = r["end"];
      std::vector<double> xyz;
      if (e.is_array()) {
        for (const auto& v : e)
          if (v.is_number()) xyz.push_back(v.get<double>());
        if (xyz.size() != e.size()) xyz.clear();
      } else if (e.is_string()) {
        std::stringstream ss(e.get<std::string>());
        std::string part;
        while (std::getline(ss, part, ',')) {
          char* end = nullptr;
          const double v = std::strtod(part.c_str(), &end);
          if (part.empty() || *end != '\0') {
            xyz.clear();
            break;
          }
          xyz.push_back(v);
        }
      }
      if (xyz.size() != 3 || !std::all_of(xyz.begin(), xyz.end(), [](double v) { return std::isfinite(v); }))
        return bad_request("end: expected the insertion end as three numbers x,y,z in mm");
      if (r.contains("branch") && !r["branch"].is_null())
        return bad_request("give either branch or end, not both");
      p.end = Eigen::Vector3d(xyz[0], xyz[1], xyz[2]);
    }
    auto ds = read_number(r, "ds", kMinDs, kMaxDs, "mm");
    if (auto* err = std::get_if<ApiResult>(&ds)) return *err;
    if (const auto v = std::get<std::optional<double>>(ds)) p.ds = *v;
    auto dq1 = read_number(r, "dq1", kMinDq1, kMaxDq1, "mm");
    if (auto* err = std::get_if<ApiResult>(&dq1)) return *err;
    if (const auto v = std::get<std::optional<double>>(dq1)) p.dq1 = *v;
    if (r.contains("design") && !r["design"].is_null()) {
      if (!r["design"].is_string())
        return bad_request("design: expected \"configured\", \"nominal\" or \"optimise\"");
      p.design = r["design"].get<std::string>();
      if (p.design == "optimize") p.design = "optimise";
      if (p.design != "configured" && p.design != "nominal" && p.design != "optimise")
        return bad_request(
            "design: expected \"configured\" (the robot file's catheter), \"nominal\" (the "
            "planning study's) or \"optimise\" (optimise the design first), got \"" +
            p.design + "\"");
    }
    if (r.contains("flexure") && !r["flexure"].is_null()) {
      const auto& f = r["flexure"];
      if (f.is_boolean()) {
        p.flexure = f.get<bool>();
      } else if (f.is_string() && (f == "true" || f == "false")) {
        p.flexure = f == "true";
      } else {
        return bad_request("flexure: expected true or false");
      }
    }
    return p;
  }

  // Picks the branch now (so a bad index is a 422 at once) and queues the job.
  ApiResult start_job(const std::string& kind, const std::shared_ptr<const StoredVessel>& vessel,
                      PlanRequest p) {
    CenterlinePolyline branch;
    if (p.end) {
      p.branch = teleop::nearest_branch(vessel->branches, *p.end);
      branch = teleop::orient_from(vessel->branches[p.branch], *p.end);
    } else {
      if (p.branch >= vessel->branches.size())
        return ApiResult::error(422, "unknown_branch",
                                "vessel " + vessel->id + " has " + std::to_string(vessel->branches.size()) +
                                    " branch(es) (0.." + std::to_string(vessel->branches.size() - 1) +
                                    "); branch " + std::to_string(p.branch) + " does not exist");
      branch = vessel->branches[p.branch];
    }
    const RobotModel& robot = robots[p.robot];
    const std::string vessel_id = vessel->source == "inline" ? std::string{} : vessel->id;
    JobQueue::Work work;
    if (kind == "plan") {
      work = [p, branch = std::move(branch), rc = robot.config, base = *robot.design,
              vessel_id](const teleop::JobControl& control) {
        const auto start = std::chrono::steady_clock::now();
        const double length = polyline_length(branch);
        const bool cut =
            length > rc.joints.at(0).limit.upper - rc.joints.at(0).limit.soft_margin;  // said in the result
        const auto aligned = reachable_path(branch, rc, p.ds);
        auto options = planner_options(rc, p.dq1, p.flexure);
        teleop::PathPlan plan;
        if (p.design == "optimise") {
          auto result = teleop::optimise_design(base, aligned, options, {}, control);
          plan = std::move(result.plan);
        } else {
          const teleop::ConstantCurvatureCatheter model(
              p.design == "nominal" ? teleop::nominal_planning_design() : base);
          teleop::ShapeErrorPlanner planner(model, options);
          plan = planner.plan(aligned, control);
        }
        const double compute_s =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        return plan_json(plan, rc, p, vessel_id, aligned, length, cut, compute_s);
      };
    } else {
      work = [p, branch = std::move(branch), rc = robot.config, base = *robot.design,
              vessel_id](const teleop::JobControl& control) {
        const auto start = std::chrono::steady_clock::now();
        const auto aligned = reachable_path(branch, rc, p.ds);
        const auto start_design = p.design == "nominal" ? teleop::nominal_planning_design() : base;
        const auto result = teleop::optimise_design(start_design, aligned,
                                                    planner_options(rc, p.dq1, p.flexure), {}, control);
        const double compute_s =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        return json{{"robot", rc.name},
                    {"vessel", vessel_id.empty() ? json() : json(vessel_id)},
                    {"branch", p.branch},
                    {"ds", p.ds},
                    {"dq1", p.dq1},
                    {"start_design", design_json(start_design, p.flexure)},
                    {"design", design_json(result.design, result.flexure)},
                    {"penalty", result.penalty},
                    {"initial_penalty", result.initial_penalty},
                    {"evaluations", result.evaluations},
                    {"convergence", convergence_json(result)},
                    {"summary",
                     {{"steps", result.plan.steps.size()},
                      {"mean_position_error_mm", result.plan.position_error_mean},
                      {"max_position_error_mm", result.plan.position_error_max},
                      {"mean_orientation_error_deg", result.plan.tangent_error_mean},
                      {"max_orientation_error_deg", result.plan.tangent_error_max},
                      {"mean_tip_error_mm", result.tip_error_mean},
                      {"max_tip_error_mm", result.tip_error_max},
                      {"compute_s", compute_s}}}};
      };
    }
    return queued(kind, std::move(work));
  }

  // 202 with the job, or 503 when the queue is full.
  ApiResult queued(const std::string& kind, JobQueue::Work work) {
    const auto info = queue.submit(kind, std::move(work));
    if (!info)
      return ApiResult::error(503, "queue_full",
                              "the job queue is full (" + std::to_string(queue.options().max_pending) +
                                  " jobs queued or running); wait for one to finish or cancel one");
    return ApiResult::success(info->to_json(true), 202);
  }

  const RobotModel* find_robot(const std::string& name) const {
    for (const auto& m : robots)
      if (m.config.name == name) return &m;
    return nullptr;
  }
};

PlanningService::PlanningService(std::vector<RobotConfig> robots, PlanningOptions options)
    : impl_(std::make_unique<Impl>(std::move(robots), options)) {}

PlanningService::~PlanningService() { shutdown(); }

void PlanningService::shutdown() { impl_->queue.shutdown(); }

std::size_t PlanningService::max_vessel_bytes() const { return impl_->options.max_vessel_bytes; }

ApiResult PlanningService::upload_vessel(std::string_view body, const std::string& content_type,
                                         const QueryParameters& query) {
  std::string source;
  auto parsed = parse_vessel(body, content_type, impl_->options, source);
  if (auto* err = std::get_if<ApiResult>(&parsed)) return *err;
  std::string name;
  if (const auto it = query.find("name"); it != query.end()) {
    name = it->second;
    if (name.size() > 128) return bad_request("name: at most 128 characters");
  }
  auto stored = impl_->store(std::move(std::get<std::vector<CenterlinePolyline>>(parsed)), source, name);
  if (auto* err = std::get_if<ApiResult>(&stored)) return *err;
  return ApiResult::success(impl_->stored_json(std::get<Impl::Stored>(stored)), 201);
}

ApiResult PlanningService::vessels() const {
  auto out = json::array();
  std::lock_guard lock(impl_->mutex);
  for (const auto& id : impl_->vessel_order) out.push_back(impl_->vessels.at(id)->summary());
  return ApiResult::success(out);
}

ApiResult PlanningService::vessel(const std::string& id, const QueryParameters& query) const {
  const auto v = impl_->find_vessel(id);
  if (!v)
    return ApiResult::error(404, "unknown_vessel", "there is no vessel '" + id + "' (GET /api/v1/vessels)");
  json q = json::object();
  for (const auto& [k, value] : query) q[k] = value;
  std::size_t branch = 0;
  if (q.contains("branch")) {
    char* end = nullptr;
    const auto s = q["branch"].get<std::string>();
    const long b = std::strtol(s.c_str(), &end, 10);
    if (s.empty() || *end != '\0' || b < 0) return bad_request("branch: expected a branch index 0, 1, …");
    branch = static_cast<std::size_t>(b);
  }
  if (branch >= v->branches.size())
    return ApiResult::error(404, "unknown_branch",
                            "vessel " + id + " has " + std::to_string(v->branches.size()) + " branch(es)");
  auto ds = read_number(q, "ds", kMinDs, kMaxDs, "mm");
  if (auto* err = std::get_if<ApiResult>(&ds)) return *err;
  const double spacing = std::get<std::optional<double>>(ds).value_or(1.0);
  try {
    const auto c = teleop::VesselCenterline::from_polyline(v->branches[branch], spacing);
    auto points = json::array();
    for (const auto& p : c.points()) points.push_back(point_json(p));
    return ApiResult::success({{"id", id},
                               {"branch", branch},
                               {"ds", spacing},
                               {"length_mm", c.length()},
                               {"points", std::move(points)},
                               {"radius", c.has_radius() ? json(c.radii()) : json()}});
  } catch (const teleop::VesselInputError& e) {
    return ApiResult::error(422, "bad_vessel",
                            std::string("branch cannot be resampled at this ds: ") + e.what());
  }
}

ApiResult PlanningService::delete_vessel(const std::string& id) {
  std::lock_guard lock(impl_->mutex);
  const auto it = impl_->vessels.find(id);
  if (it == impl_->vessels.end())
    return ApiResult::error(404, "unknown_vessel", "there is no vessel '" + id + "'");
  impl_->vessel_bytes -= it->second->bytes;
  impl_->vessels.erase(it);
  auto& order = impl_->vessel_order;
  order.erase(std::remove(order.begin(), order.end(), id), order.end());
  return ApiResult::success({{"deleted", id}});
}

ApiResult PlanningService::submit_plan_file(std::string_view body, const std::string& content_type,
                                            const QueryParameters& query) {
  json r = json::object();
  for (const auto& [k, v] : query) r[k] = v;
  auto request = impl_->read_plan_request(r);
  if (auto* err = std::get_if<ApiResult>(&request)) return *err;
  std::string source;
  auto parsed = parse_vessel(body, content_type, impl_->options, source);
  if (auto* err = std::get_if<ApiResult>(&parsed)) return *err;
  // The file is also stored, so the console can show it and later plans can name it.
  const auto it = query.find("name");
  auto stored = impl_->store(std::move(std::get<std::vector<CenterlinePolyline>>(parsed)), source,
                             it == query.end() ? std::string{} : it->second.substr(0, 128));
  if (auto* err = std::get_if<ApiResult>(&stored)) return *err;
  return impl_->start_job("plan", std::get<Impl::Stored>(stored).vessel, std::get<PlanRequest>(request));
}

ApiResult PlanningService::submit_plan(const json& body) {
  auto request = impl_->read_plan_request(body);
  if (auto* err = std::get_if<ApiResult>(&request)) return *err;
  if (!body.contains("vessel") || !body["vessel"].is_string())
    return bad_request(
        "expected {\"vessel\": \"<id from POST /api/v1/vessels>\", \"robot\", \"branch\", \"ds\", "
        "\"dq1\", \"design\"}, or the vessel file itself as the body (Content-Type text/csv or "
        "model/stl)");
  const auto id = body["vessel"].get<std::string>();
  const auto v = impl_->find_vessel(id);
  if (!v)
    return ApiResult::error(404, "unknown_vessel", "there is no vessel '" + id + "' (GET /api/v1/vessels)");
  return impl_->start_job("plan", v, std::get<PlanRequest>(request));
}

ApiResult PlanningService::submit_design(const json& body) {
  auto request = impl_->read_plan_request(body);
  if (auto* err = std::get_if<ApiResult>(&request)) return *err;
  if (!body.contains("vessel") || !body["vessel"].is_string())
    return bad_request("expected {\"vessel\": \"<id from POST /api/v1/vessels>\", \"branch\", \"flexure\"}");
  const auto id = body["vessel"].get<std::string>();
  const auto v = impl_->find_vessel(id);
  if (!v)
    return ApiResult::error(404, "unknown_vessel", "there is no vessel '" + id + "' (GET /api/v1/vessels)");
  auto p = std::get<PlanRequest>(request);
  if (p.design == "optimise") p.design = "configured";  // the start design of the optimisation
  return impl_->start_job("design", v, p);
}

ApiResult PlanningService::jobs() const {
  auto out = json::array();
  for (const auto& j : impl_->queue.list()) out.push_back(j.to_json(false));
  return ApiResult::success(out);
}

ApiResult PlanningService::job(const std::string& id) const {
  const auto j = impl_->queue.get(id);
  if (!j)
    return ApiResult::error(
        404, "unknown_job",
        "there is no job '" + id + "' (finished jobs are kept for a while, the oldest is forgotten first)");
  return ApiResult::success(j->to_json(true));
}

ApiResult PlanningService::cancel_job(const std::string& id) {
  const auto j = impl_->queue.cancel(id);
  if (!j) return ApiResult::error(404, "unknown_job", "there is no job '" + id + "'");
  return ApiResult::success(j->to_json(true));
}

ApiResult PlanningService::plan_result(const std::string& job_id) const {
  const auto j = impl_->queue.get(job_id);
  if (!j) return ApiResult::error(404, "unknown_job", "there is no job '" + job_id + "'");
  if (j->kind != "plan")
    return ApiResult::error(422, "not_a_plan", "job " + job_id + " is a " + j->kind + " job, not a plan");
  if (j->state != JobState::kSucceeded || !j->result)
    return ApiResult::error(409, "plan_not_ready",
                            "plan job " + job_id + " is " + to_string(j->state) +
                                (j->state == JobState::kFailed ? " (" + j->message + ")" : std::string{}) +
                                "; only a succeeded plan can be loaded");
  return ApiResult::success(*j->result);
}

ApiResult PlanningService::submit_calibration(const std::string& robot, const json& request) {
  const RobotModel* it = impl_->find_robot(robot);
  if (it == nullptr)
    return ApiResult::error(404, "unknown_robot",
                            "no robot named \"" + robot + "\"; GET /api/v1/robots lists them");
  auto work = make_calibration_job(it->config, request);
  if (auto* err = std::get_if<ApiResult>(&work)) return *err;
  return impl_->queued("calibration", std::move(std::get<JobQueue::Work>(work)));
}

ApiResult PlanningService::simulated_side_view(const std::string& robot, const QueryParameters& query) {
  const RobotModel* it = impl_->find_robot(robot);
  if (it == nullptr)
    return ApiResult::error(404, "unknown_robot",
                            "no robot named \"" + robot + "\"; GET /api/v1/robots lists them");
  const RobotConfig& rc = it->config;
  const bool simulated =
      !rc.buses.empty() && std::all_of(rc.buses.begin(), rc.buses.end(),
                                       [](const BusConfig& b) { return b.interface == "virtual"; });
  if (!rc.settings.contains("catheter") || !simulated)
    return ApiResult::error(
        409, "not_simulated",
        "robot '" + robot +
            "' has no SIMULATED calibration camera (only a steerable catheter on a "
            "virtual bus has one); photograph the real segment and send the pictures instead");
  json q = json::object();
  for (const auto& [k, v] : query) q[k] = v;
  const auto segment = q.value("segment", std::string("proximal"));
  if (segment != "proximal" && segment != "distal")
    return bad_request("segment: expected proximal or distal");
  auto actuation = read_number(q, "actuation_mm", -2.0, 2.0, "mm (the bare tip's calibration range)");
  if (auto* err = std::get_if<ApiResult>(&actuation)) return *err;
  const double q_mm = std::get<std::optional<double>>(actuation).value_or(0.0);
  // The bare tip's true shape in simulation: the robot file's tip-only (nominal or calibrated) model.
  const CatheterSettings settings = parse_catheter_settings(rc);
  sim::SideViewCameraOptions o;
  // 800×1100 pixels at 0.025 mm: 3 mm of straight tube and the 22 mm proximal segment bent ±160°.
  o.base_column = q_mm >= 0 ? 150.0 : o.width - 150.0;
  o.noise_seed += impl_->side_view_frames.fetch_add(1);
  sim::SimulatedSideViewCamera camera(settings.nominal, o);
  const auto png = camera.capture_png(
      segment == "proximal" ? teleop::CatheterSegment::kProximal : teleop::CatheterSegment::kDistal, q_mm);
  std::string data;
  append_base64(png.data(), png.size(), data);
  return ApiResult::success({{"simulated", true},
                             {"segment", segment},
                             {"actuation_mm", q_mm},
                             {"format", "png"},
                             {"width", o.width},
                             {"height", o.height},
                             {"mm_per_pixel", o.mm_per_pixel},
                             {"straight_mm", o.straight_mm},
                             {"entry", "bottom"},
                             {"data", std::move(data)}});
}

}  // namespace tendril::server
