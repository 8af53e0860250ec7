// The us_arm's ultrasound imaging and reconstruction topics; see the header.
#include "serial_arm/ultrasound_topics.hpp"

#include <pthread.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <utility>

#include "serial_arm/serial_arm_robot.hpp"
#include "tendril/drivers/imaging/image_source.hpp"
#include "tendril/server/http/foxglove_protocol.hpp"

namespace tendril::server {

namespace {

using nlohmann::json;

json stamp(std::uint64_t ns) { return {{"sec", ns / 1'000'000'000ULL}, {"nsec", ns % 1'000'000'000ULL}}; }

// Millimetres to 0.01 mm in JSON: the scene's geometry does not need 17 digits.
double round2(double v) { return std::round(v * 100.0) / 100.0; }

json vec3(const Eigen::Vector3d& v) {
  return {{"x", round2(v.x())}, {"y", round2(v.y())}, {"z", round2(v.z())}};
}

json quat(const Eigen::Matrix3d& r) {
  const Eigen::Quaterniond q(r);
  return {{"x", q.x()}, {"y", q.y()}, {"z", q.z()}, {"w", q.w()}};
}

json pose_json(const Eigen::Isometry3d& p) {
  return {{"position", vec3(p.translation())}, {"orientation", quat(p.linear())}};
}

json identity_pose() { return pose_json(Eigen::Isometry3d::Identity()); }

json color(double r, double g, double b, double a = 1.0) { return {{"r", r}, {"g", g}, {"b", b}, {"a", a}}; }

// foxglove LinePrimitive type: 0 LINE_STRIP, 1 LINE_LOOP, 2 LINE_LIST.
json line(int type, const std::vector<Eigen::Vector3d>& points, const json& rgba, double thickness) {
  json pts = json::array();
  for (const auto& p : points) pts.push_back(vec3(p));
  return {{"type", type},
          {"pose", identity_pose()},
          {"thickness", thickness},
          {"scale_invariant", false},
          {"points", std::move(pts)},
          {"color", rgba},
          {"colors", json::array()},
          {"indices", json::array()}};
}

json sphere(const Eigen::Vector3d& at, double diameter, const json& rgba) {
  Eigen::Isometry3d p = Eigen::Isometry3d::Identity();
  p.translation() = at;
  return {
      {"pose", pose_json(p)}, {"size", {{"x", diameter}, {"y", diameter}, {"z", diameter}}}, {"color", rgba}};
}

json text(const Eigen::Vector3d& at, const std::string& words, const json& rgba) {
  Eigen::Isometry3d p = Eigen::Isometry3d::Identity();
  p.translation() = at;
  return {{"pose", pose_json(p)},    {"billboard", true}, {"font_size", 12.0},
          {"scale_invariant", true}, {"color", rgba},     {"text", words}};
}

json entity(const std::string& id, const std::string& frame, std::uint64_t now_ns) {
  return {{"timestamp", stamp(now_ns)},
          {"frame_id", frame},
          {"id", id},
          {"lifetime", {{"sec", 0}, {"nsec", 0}}},
          {"frame_locked", true},
          {"metadata", json::array()},
          {"arrows", json::array()},
          {"cubes", json::array()},
          {"spheres", json::array()},
          {"cylinders", json::array()},
          {"lines", json::array()},
          {"triangles", json::array()},
          {"texts", json::array()},
          {"models", json::array()}};
}

// The x (red), y (green), z (blue) axes of each pose, `length` mm, as three LINE_LISTs.
void add_axes(json& e, const std::vector<Eigen::Isometry3d>& poses, double length, double thickness) {
  for (int axis = 0; axis < 3; ++axis) {
    std::vector<Eigen::Vector3d> segments;
    for (const auto& p : poses) {
      segments.push_back(p.translation());
      segments.push_back(p.translation() + length * p.linear().col(axis));
    }
    e["lines"].push_back(line(2, segments, color(axis == 0, axis == 1, axis == 2), thickness));
  }
}

json transform(const std::string& parent, const std::string& child, const Eigen::Isometry3d& p,
               std::uint64_t now_ns) {
  return {
      {"timestamp", stamp(now_ns)},
      {"parent_frame_id", parent},
      {"child_frame_id", child},
      {"translation", {{"x", p.translation().x()}, {"y", p.translation().y()}, {"z", p.translation().z()}}},
      {"rotation", quat(p.linear())}};
}

std::string fixed(double v, int digits) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.*f", digits, v);
  return buf;
}

json object_schema(const char* title, const char* description, json properties) {
  return {{"title", title},
          {"description", description},
          {"type", "object"},
          {"properties", std::move(properties)}};
}

const json kTimeSchema = {{"type", "object"},
                          {"properties",
                           {{"sec", {{"type", "integer"}, {"minimum", 0}}},
                            {"nsec", {{"type", "integer"}, {"minimum", 0}, {"maximum", 999999999}}}}}};
const json kArray = {{"type", "array"}, {"items", {{"type", "object"}}}};

std::uint64_t wall_ns() {
  return static_cast<std::uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                        std::chrono::system_clock::now().time_since_epoch())
                                        .count());
}

}  // namespace

UltrasoundTopics::UltrasoundTopics(ultrasound::ReconstructionSessionConfig session,
                                   UltrasoundTopicsSettings settings, ProbeStateReader probe_state)
    : settings_(std::move(settings)), probe_state_(std::move(probe_state)), session_(std::move(session)) {
  for (double hz : {settings_.image_hz, settings_.catheter_hz, settings_.scene_hz}) {
    if (!std::isfinite(hz) || hz <= 0.0 || hz > 1000.0)
      throw std::invalid_argument("ultrasound topics: a rate must be in (0, 1000] Hz, got " + fixed(hz, 3));
  }
  if (!probe_state_) throw std::invalid_argument("ultrasound topics: no probe state reader was given");
  if (settings_.robot.empty()) throw std::invalid_argument("ultrasound topics: the robot name is empty");
  if (settings_.own_thread) {
    worker_ = std::thread([this] { run(); });
    poller_ = std::thread([this] { poll(); });
  }
}

UltrasoundTopics::~UltrasoundTopics() {
  {
    std::lock_guard lock(stop_mutex_);
    stopping_ = true;
  }
  stop_cv_.notify_all();
  if (worker_.joinable()) worker_.join();
  if (poller_.joinable()) poller_.join();
}

void UltrasoundTopics::set_plan(ultrasound::SweepPlan plan) {
  ultrasound::UltrasoundReconstructionSession::check_plan(plan);
  std::lock_guard lock(pending_mutex_);
  pending_plan_ = std::move(plan);
}

void UltrasoundTopics::apply_calibrations() {
  if (settings_.image_calibration_reader) {
    const auto image = settings_.image_calibration_reader();
    if (image && image->first != image_version_.load(std::memory_order_relaxed)) {
      session_.set_image_calibration(image->second);  // a stored calibration is valid: it was checked
      image_version_.store(image->first, std::memory_order_relaxed);
    }
  }
  if (settings_.fiber_calibration_reader) {
    const auto fiber = settings_.fiber_calibration_reader();
    if (fiber && fiber->first != fiber_version_.load(std::memory_order_relaxed)) {
      session_.set_fiber_in_base(fiber->second);
      fiber_version_.store(fiber->first, std::memory_order_relaxed);
    }
  }
}

std::optional<Eigen::Vector3d> UltrasoundTopics::last_slice_centroid() const {
  std::lock_guard lock(topics_mutex_);
  return last_centroid_;
}

void UltrasoundTopics::reset() {
  std::lock_guard lock(pending_mutex_);
  pending_reset_ = true;
  pending_acquisitions_.clear();
  last_latched_via_point_ = -1;
}

// Below the control and simulation threads: a render may wait, the force sensor's stream may not.
static void lower_priority(const char* name) {
  pthread_setname_np(pthread_self(), name);
  setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), 10);  // best effort: nice +10
}

void UltrasoundTopics::latch(const UltrasoundProbeState& state) {
  if (!state.acquiring || !state.in_contact || state.via_point < 0 ||
      !ultrasound::is_rigid(state.world_T_probe) || !ultrasound::is_rigid(state.world_T_limb) ||
      !ultrasound::is_rigid(state.world_T_limb_true))
    return;
  std::lock_guard lock(pending_mutex_);
  if (state.via_point == last_latched_via_point_) return;
  last_latched_via_point_ = state.via_point;
  pending_acquisitions_.push_back(state);
}

void UltrasoundTopics::poll_once() {
  if (const auto state = probe_state_()) latch(*state);
}

void UltrasoundTopics::poll() {
  lower_priority("us-acquire");
  for (;;) {
    try {
      poll_once();
    } catch (const std::exception&) {  // NOLINT(bugprone-empty-catch): the worker reports a bad reader
    }
    std::unique_lock lock(stop_mutex_);
    if (stop_cv_.wait_for(lock, std::chrono::milliseconds(10), [this] { return stopping_; })) return;
  }
}

void UltrasoundTopics::run() {
  lower_priority("us-imaging");
  const auto period = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
      std::chrono::duration<double>(1.0 / settings_.image_hz));
  auto next = std::chrono::steady_clock::now();
  for (;;) {
    const auto t0 = std::chrono::steady_clock::now();
    try {
      step(wall_ns());
    } catch (const std::exception& error) {
      // A step that throws (out of memory, a PNG the encoder refuses) skips this step's messages; the
      // worker goes on with the next state.
      std::lock_guard lock(topics_mutex_);
      last_message_ = std::string("ultrasound worker step failed: ") + error.what();
      ++refusals_;
    }
    {
      std::lock_guard lock(topics_mutex_);
      last_step_s_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    }
    next += period;
    const auto now = std::chrono::steady_clock::now();
    if (next < now) next = now;  // a slow step (rendering under a sanitizer) does not make a burst
    std::unique_lock lock(stop_mutex_);
    if (stop_cv_.wait_until(lock, next, [this] { return stopping_; })) return;
  }
}

void UltrasoundTopics::step(std::uint64_t now_ns) {
  {
    std::optional<ultrasound::SweepPlan> plan;
    bool reset = false;
    {
      std::lock_guard lock(pending_mutex_);
      plan.swap(pending_plan_);
      std::swap(reset, pending_reset_);
    }
    if (settings_.plan_reader) {
      std::shared_ptr<const ultrasound::SweepPlan> polled = settings_.plan_reader();
      if (polled && polled != seen_plan_) {
        seen_plan_ = polled;
        reset = true;
        plan = *polled;
        std::lock_guard lock(pending_mutex_);
        pending_acquisitions_.clear();
        last_latched_via_point_ = -1;
      }
    }
    if (reset) session_.reset();
    if (plan) session_.set_plan(std::move(*plan));
    slices_.store(session_.slices().size(), std::memory_order_relaxed);
    apply_calibrations();
  }
  const std::optional<UltrasoundProbeState> state = probe_state_();
  if (state) latch(*state);
  std::vector<UltrasoundProbeState> acquisitions;
  {
    std::lock_guard lock(pending_mutex_);
    acquisitions.swap(pending_acquisitions_);
  }
  auto to_sample = [](const UltrasoundProbeState& s) {
    ultrasound::ProbeSample sample;
    sample.t = s.t;
    sample.world_T_probe = s.world_T_probe;
    sample.world_T_limb = s.world_T_limb;
    sample.world_T_limb_true = s.world_T_limb_true;  // SIMULATED truth: where the scanner images
    sample.in_contact = s.in_contact;
    sample.acquiring = s.acquiring;
    sample.via_point = s.via_point;
    return sample;
  };
  bool framed = false;
  auto image = [&](const UltrasoundProbeState& s) {
    const ultrasound::SessionOutcome outcome = session_.process(to_sample(s));
    if (outcome.status != ultrasound::SessionStatus::ok &&
        outcome.status != ultrasound::SessionStatus::no_contact) {
      std::lock_guard lock(topics_mutex_);
      last_message_ = outcome.message;
      ++refusals_;
    }
    if (outcome.status == ultrasound::SessionStatus::ok ||
        outcome.status == ultrasound::SessionStatus::no_vessel)
      framed = true;
    if (outcome.stored_slice) {
      std::lock_guard lock(topics_mutex_);
      for (const auto& stored : session_.slices())
        if (stored.via_point == s.via_point) last_centroid_ = stored.slice.centroid;
    }
  };
  // The latched acquisitions first (a slice is stored whether or not anyone looks), then, while the image
  // or annotations topic is watched, the newest state.
  for (const auto& a : acquisitions) image(a);
  if (!state) {
    slices_.store(session_.slices().size(), std::memory_order_relaxed);
    return;
  }
  const bool valid = ultrasound::is_rigid(state->world_T_probe) &&
                     ultrasound::is_rigid(state->world_T_limb) &&
                     ultrasound::is_rigid(state->world_T_limb_true) && std::isfinite(state->t);
  if (!valid) {
    std::lock_guard lock(topics_mutex_);
    last_message_ =
        "the probe state was refused: a pose (probe, tracked or true limb) is not finite or not rigid; "
        "nothing "
        "reconstructed was changed";
    ++refusals_;
  }
  const bool image_wanted = wanted(image_topic()) || wanted(annotations_topic());
  if (valid && state->in_contact && image_wanted && !(state->acquiring && !acquisitions.empty()))
    image(*state);
  if (framed && session_.last_frame()) {
    const ultrasound::SessionFrame& frame = *session_.last_frame();
    if (wanted(image_topic())) publish(image_topic(), image_message(frame, now_ns), now_ns);
    publish(annotations_topic(), annotations_message(frame, now_ns), now_ns);
    std::lock_guard lock(topics_mutex_);
    ++images_;
  }
  slices_.store(session_.slices().size(), std::memory_order_relaxed);
  const ultrasound::ProbeSample sample = to_sample(*state);
  if (valid && session_.has_catheter() && now_ns >= next_catheter_ns_) {
    const ultrasound::SessionOutcome outcome = session_.update_catheter(sample);
    if (!outcome.ok()) {
      std::lock_guard lock(topics_mutex_);
      last_message_ = outcome.message;
      ++refusals_;
    }
    next_catheter_ns_ = now_ns + static_cast<std::uint64_t>(1e9 / settings_.catheter_hz);
  }
  if (wanted(scene_topic()) && (now_ns >= next_scene_ns_ || session_.revision() != scene_revision_)) {
    publish(scene_topic(), scene_message(*state, now_ns), now_ns);
    scene_revision_ = session_.revision();
    next_scene_ns_ = now_ns + static_cast<std::uint64_t>(1e9 / settings_.scene_hz);
  }
  if (valid) publish(tf_topic(), tf_message(*state, now_ns), now_ns);
}

std::string UltrasoundTopics::image_message(const ultrasound::SessionFrame& frame,
                                            std::uint64_t now_ns) const {
  imaging::GreyImage grey;
  grey.width = frame.image.geometry.columns;
  grey.height = frame.image.geometry.rows;
  grey.pixels.resize(frame.image.pixels.size());
  for (std::size_t i = 0; i < grey.pixels.size(); ++i)
    grey.pixels[i] =
        static_cast<std::uint8_t>(std::lround(std::clamp(frame.image.pixels[i], 0.0F, 1.0F) * 255.0F));
  std::vector<std::uint8_t> png;
  imaging::encode_png(grey, png);
  std::string out =
      "{\"timestamp\":" + stamp(now_ns).dump() + ",\"frame_id\":\"" + settings_.robot +
      "_image\",\"format\":\"png\",\"pixel_size_mm\":" + fixed(frame.image.geometry.pixel_size, 4) +
      ",\"via_point\":" + std::to_string(frame.via_point) + ",\"simulated\":true,\"data\":\"";
  http::foxglove::append_base64(png.data(), png.size(), out);
  out += "\"}";
  return out;
}

std::string UltrasoundTopics::annotations_message(const ultrasound::SessionFrame& frame,
                                                  std::uint64_t now_ns) const {
  const ultrasound::BModeGeometry& g = frame.image.geometry;
  // Foxglove's image coordinates: (0, 0) is the top-left corner of the top-left pixel, so a pixel's
  // centre is at (column + 0.5, row + 0.5).
  auto pixel = [&](const Eigen::Vector2d& yz) {
    const Eigen::Vector2d cr = g.pixel_of(yz);
    return json{{"x", round2(cr.x() + 0.5)}, {"y", round2(cr.y() + 0.5)}};
  };
  const ultrasound::SliceSegmentation& s = frame.segmentation;
  json points = json::array();
  json texts = json::array();
  std::string words;
  if (s.valid) {
    json contour = json::array();
    for (const auto& p : s.contour) contour.push_back(pixel(p));
    points.push_back({{"timestamp", stamp(now_ns)},
                      {"type", 2},  // LINE_LOOP
                      {"points", std::move(contour)},
                      {"outline_color", color(1.0, 0.55, 0.0)},
                      {"outline_colors", json::array()},
                      {"fill_color", color(1.0, 0.55, 0.0, 0.0)},
                      {"thickness", 2.0}});
    points.push_back({{"timestamp", stamp(now_ns)},
                      {"type", 1},  // POINTS: the centroid ψ_US
                      {"points", json::array({pixel(s.centre)})},
                      {"outline_color", color(1.0, 0.2, 0.2)},
                      {"outline_colors", json::array()},
                      {"fill_color", color(1.0, 0.2, 0.2)},
                      {"thickness", 6.0}});
    words = "ellipse " + fixed(2.0 * s.ellipse.x(), 1) + " × " + fixed(2.0 * s.ellipse.y(), 1) + " mm, " +
            (s.converged ? "converged" : "not converged") + " in " + std::to_string(s.iterations) +
            " iterations";
  } else {
    words = "no artery boundary found in this slice";
  }
  texts.push_back({{"timestamp", stamp(now_ns)},
                   {"position", {{"x", 8.0}, {"y", 16.0}}},
                   {"text", words},
                   {"font_size", 14.0},
                   {"text_color", color(1.0, 1.0, 1.0)},
                   {"background_color", color(0.0, 0.0, 0.0, 0.5)}});
  return json{{"circles", json::array()}, {"points", std::move(points)}, {"texts", std::move(texts)}}.dump();
}

std::string UltrasoundTopics::scene_message(const UltrasoundProbeState& state, std::uint64_t now_ns) const {
  const std::string frame = "tissue";
  const ultrasound::SweepPlan& plan = session_.plan();
  json entities = json::array();

  json surface = entity("surface", frame, now_ns);
  if (!plan.surface.empty()) {
    const std::size_t stride =
        std::max<std::size_t>(1, (plan.surface.size() + settings_.max_surface_points - 1) /
                                     std::max<std::size_t>(1, settings_.max_surface_points));
    for (std::size_t i = 0; i < plan.surface.size(); i += stride)
      surface["spheres"].push_back(sphere(plan.surface[i], 0.8, color(0.8, 0.7, 0.6, 0.8)));
  }
  entities.push_back(std::move(surface));

  json ct = entity("ct_centerline", frame, now_ns);
  if (plan.centroids.size() >= 2) ct["lines"].push_back(line(0, plan.centroids, color(0.3, 0.5, 1.0), 1.0));
  entities.push_back(std::move(ct));

  json via = entity("via_points", frame, now_ns);
  std::vector<Eigen::Isometry3d> via_poses;
  for (const auto& v : plan.via_points) via_poses.push_back(v.pose());
  if (!via_poses.empty()) add_axes(via, via_poses, 8.0, 0.6);
  entities.push_back(std::move(via));

  // The probe and its image plane, in the tissue frame as the reconstruction maps them.
  json probe = entity("probe", frame, now_ns);
  if (ultrasound::is_rigid(state.world_T_probe) && ultrasound::is_rigid(state.world_T_limb)) {
    const Eigen::Isometry3d tissue_T_probe = state.world_T_limb.inverse() * state.world_T_probe;
    add_axes(probe, {tissue_T_probe}, 20.0, 1.0);
    const Eigen::Isometry3d tissue_T_image = tissue_T_probe * session_.config().image_in_probe;
    const ultrasound::BModeGeometry& g = session_.config().geometry;
    const double w = 0.5 * g.width(), d = g.depth();
    probe["lines"].push_back(
        line(1,
             {tissue_T_image * Eigen::Vector3d(0, -w, 0), tissue_T_image * Eigen::Vector3d(0, w, 0),
              tissue_T_image * Eigen::Vector3d(0, w, d), tissue_T_image * Eigen::Vector3d(0, -w, d)},
             color(0.9, 0.9, 0.9, 0.6), 0.5));
  }
  entities.push_back(std::move(probe));

  json contours = entity("contours", frame, now_ns);
  for (const auto& s : session_.slices())
    contours["lines"].push_back(line(1, s.slice.contour, color(1.0, 0.55, 0.0), 0.8));
  entities.push_back(std::move(contours));

  json mesh = entity("artery_mesh", frame, now_ns);
  const teleop::TriangleMesh& m = session_.mesh();
  if (!m.triangles.empty()) {
    json points = json::array(), indices = json::array();
    for (const auto& v : m.vertices) points.push_back(vec3(v));
    for (const auto& t : m.triangles)
      for (auto i : t) indices.push_back(i);
    mesh["triangles"].push_back({{"pose", identity_pose()},
                                 {"points", std::move(points)},
                                 {"color", color(0.85, 0.2, 0.2, 0.35)},
                                 {"colors", json::array()},
                                 {"indices", std::move(indices)}});
  }
  entities.push_back(std::move(mesh));

  const ultrasound::CatheterState& c = session_.catheter();
  json catheter = entity("catheter", frame, now_ns);
  if (c.valid) catheter["lines"].push_back(line(0, c.tissue, color(0.2, 0.9, 0.3), 1.5));
  entities.push_back(std::move(catheter));

  json contacts = entity("contacts", frame, now_ns);
  if (c.valid) {
    for (const auto& k : c.contacts)
      contacts["spheres"].push_back(sphere(k.position, 2.5, color(1.0, 0.1, 0.1)));
  }
  entities.push_back(std::move(contacts));

  json warnings = entity("curvature_warnings", frame, now_ns);
  if (c.valid) {
    const double limit = session_.config().fiber.max_curvature;
    for (int g : c.over_curvature) {
      const auto i = static_cast<std::size_t>(g);
      if (i >= c.tissue.size()) continue;
      warnings["texts"].push_back(text(c.tissue[i],
                                       "grating " + std::to_string(g + 1) +
                                           ": bent tighter than the fibre's " + fixed(1.0 / limit, 0) +
                                           " mm radius (largest |κ| " + fixed(c.max_curvature, 4) + " /mm)",
                                       color(1.0, 0.8, 0.0)));
    }
  }
  entities.push_back(std::move(warnings));
  return json{{"deletions", json::array()}, {"entities", std::move(entities)}}.dump();
}

std::string UltrasoundTopics::tf_message(const UltrasoundProbeState& state, std::uint64_t now_ns) const {
  const std::string base = settings_.robot + "_base", probe = settings_.robot + "_probe",
                    image = settings_.robot + "_image";
  json transforms = json::array();
  const Eigen::Isometry3d world_T_base =
      settings_.world_T_base_reader ? settings_.world_T_base_reader() : settings_.world_T_base;
  transforms.push_back(transform("world", base, world_T_base, now_ns));
  transforms.push_back(transform(base, probe, world_T_base.inverse() * state.world_T_probe, now_ns));
  transforms.push_back(transform("world", "tissue", state.world_T_limb, now_ns));
  transforms.push_back(transform(probe, image, session_.config().image_in_probe, now_ns));
  const ultrasound::CatheterState& c = session_.catheter();
  if (c.valid) transforms.push_back(transform("world", "fbg", c.world_T_fbg, now_ns));
  return json{{"transforms", std::move(transforms)}}.dump();
}

void UltrasoundTopics::publish(const std::string& topic, std::string message, std::uint64_t now_ns) {
  std::function<void()> ready;
  {
    std::lock_guard lock(topics_mutex_);
    TopicPayload& p = latest_[topic];
    p.payload = std::make_shared<const std::string>(std::move(message));
    ++p.version;
    p.log_time_ns = now_ns;
    ready = ready_;
  }
  if (ready) ready();
}

bool UltrasoundTopics::wanted(const std::string& topic) const {
  std::lock_guard lock(topics_mutex_);
  const auto it = demand_.find(topic);
  return it != demand_.end() && it->second;
}

std::vector<TopicInfo> UltrasoundTopics::topics() const {
  const json image = object_schema(
      "foxglove.CompressedImage",
      "The SIMULATED B-mode ultrasound slice (PNG), {robot}_image frame: x elevation, y lateral, z depth",
      {{"timestamp", kTimeSchema},
       {"frame_id", {{"type", "string"}}},
       {"data", {{"type", "string"}, {"contentEncoding", "base64"}}},
       {"format", {{"type", "string"}}},
       {"pixel_size_mm", {{"type", "number"}}},
       {"via_point", {{"type", "integer"}}},
       {"simulated", {{"type", "boolean"}}}});
  const json annotations =
      object_schema("foxglove.ImageAnnotations",
                    "The fitted ellipse (LINE_LOOP), its centre (POINTS) and a status text, "
                    "in pixels of the image of the same timestamp",
                    {{"circles", kArray}, {"points", kArray}, {"texts", kArray}});
  const json scene =
      object_schema("foxglove.SceneUpdate",
                    "The ultrasound reconstruction in the tissue frame (Fig. 7 of Heunis et al. 2021)",
                    {{"deletions", kArray}, {"entities", kArray}});
  const json tf = object_schema("foxglove.FrameTransforms", "The ultrasound arm's frame chain (Eqs. 2 and 5)",
                                {{"transforms", kArray}});
  return {{image_topic(), "foxglove.CompressedImage", image.dump()},
          {annotations_topic(), "foxglove.ImageAnnotations", annotations.dump()},
          {scene_topic(), "foxglove.SceneUpdate", scene.dump()},
          {tf_topic(), "foxglove.FrameTransforms", tf.dump()}};
}

std::optional<TopicPayload> UltrasoundTopics::latest(const std::string& topic,
                                                     std::uint64_t since_version) const {
  std::lock_guard lock(topics_mutex_);
  const auto it = latest_.find(topic);
  if (it == latest_.end() || it->second.version <= since_version) return std::nullopt;
  return it->second;
}

void UltrasoundTopics::set_ready_callback(std::function<void()> ready) {
  std::lock_guard lock(topics_mutex_);
  ready_ = std::move(ready);
}

void UltrasoundTopics::set_demand(const std::string& topic, bool wanted) {
  std::lock_guard lock(topics_mutex_);
  demand_[topic] = wanted;
}

std::string UltrasoundTopics::last_message() const {
  std::lock_guard lock(topics_mutex_);
  return last_message_;
}

std::string UltrasoundTopics::metrics() const {
  std::lock_guard lock(topics_mutex_);
  const std::string label = "{robot=\"" + settings_.robot + "\"}";
  return "# HELP tendril_ultrasound_images_total Ultrasound slices imaged and segmented\n"
         "# TYPE tendril_ultrasound_images_total counter\n"
         "tendril_ultrasound_images_total" +
         label + " " + std::to_string(images_) +
         "\n# HELP tendril_ultrasound_slices Slices stored in the reconstruction\n"
         "# TYPE tendril_ultrasound_slices gauge\n"
         "tendril_ultrasound_slices" +
         label + " " + std::to_string(slices_.load(std::memory_order_relaxed)) +
         "\n# HELP tendril_ultrasound_refusals_total Probe states, images or FBG frames refused\n"
         "# TYPE tendril_ultrasound_refusals_total counter\n"
         "tendril_ultrasound_refusals_total" +
         label + " " + std::to_string(refusals_) +
         "\n# HELP tendril_ultrasound_step_seconds Duration of the worker's last step\n"
         "# TYPE tendril_ultrasound_step_seconds gauge\n"
         "tendril_ultrasound_step_seconds" +
         label + " " + fixed(last_step_s_, 6) + "\n";
}

std::shared_ptr<UltrasoundTopics> make_us_arm_topics(const SerialArm& arm) {
  const LimbSimulation* limb = arm.limb();
  if (!limb) return nullptr;
  ultrasound::ReconstructionSessionConfig session;
  session.artery = limb->artery();
  // The catheter [our choice; the us_arm file names none]: straight into the artery along its entry
  // tangent for 200 mm, then along its centerline, so its 270 mm fibre ends inside the artery.
  const auto& axis = limb->artery().points;
  if (axis.size() >= 2) {
    const Eigen::Vector3d entry = axis.front(), tangent = (axis[1] - axis[0]).normalized();
    for (int k = 400; k >= 1; --k) session.catheter_path.push_back(entry - 0.5 * k * tangent);
    // The artery's points are 1 mm apart in x, so a little more along the curve: halve every segment
    // (the fibre's truth needs segments ≤ 1 mm).
    session.catheter_path.push_back(axis.front());
    for (std::size_t i = 1; i < axis.size(); ++i) {
      session.catheter_path.push_back(0.5 * (axis[i - 1] + axis[i]));
      session.catheter_path.push_back(axis[i]);
    }
    double length = 200.0;
    for (std::size_t i = 1; i < axis.size(); ++i) length += (axis[i] - axis[i - 1]).norm();
    if (length < session.fiber.length() + 1.0) session.catheter_path.clear();  // too short: no catheter
  }
  UltrasoundTopicsSettings settings;
  settings.robot = arm.config().name;
  // The SIMULATED scanner and fibre at their true calibrations, the reconstruction mapping with the
  // versions in use (helper uscal's "us" and "catheter").
  if (const UltrasoundCalibrations* calibrations = arm.ultrasound_calibrations())
    use_ultrasound_calibrations(*calibrations, session, settings);
  // The plan as the arm holds it, converted once per new plan (this lambda runs on the worker only).
  settings.plan_reader = [&arm, seen = std::shared_ptr<const SweepPlan>(),
                          converted = std::shared_ptr<const ultrasound::SweepPlan>()]() mutable {
    std::shared_ptr<const SweepPlan> plan = arm.sweep_plan();
    if (plan && plan != seen) {
      seen = plan;
      auto out = std::make_shared<ultrasound::SweepPlan>();
      out->surface = plan->skin;
      out->centroids = plan->centroids;
      for (const auto& pose : plan->via_points) {
        ultrasound::ProbeViaPoint v;
        v.surface_point = pose.translation();
        v.rotation = pose.linear();
        out->via_points.push_back(v);
      }
      converted = std::move(out);
    }
    return converted;
  };
  // "world" is the optical tracker's global frame {G} once the arm has a robot calibration: the arm's
  // base at the calibrated H_B^G, and the probe state (in the base frame) brought into {G} with it, so
  // every world pose the session and /tf use agrees (before a calibration world = the base frame).
  settings.world_T_base_reader = [&arm] {
    return arm.calibrated_global_T_base().value_or(Eigen::Isometry3d::Identity());
  };
  return std::make_shared<UltrasoundTopics>(std::move(session), std::move(settings),
                                            [&arm]() -> std::optional<UltrasoundProbeState> {
                                              UltrasoundProbeState s = arm.probe_state();
                                              if (s.tick == 0) return std::nullopt;  // nothing published yet
                                              if (const auto g = arm.calibrated_global_T_base()) {
                                                s.world_T_probe = *g * s.world_T_probe;
                                                s.world_T_limb = *g * s.world_T_limb;
                                                s.world_T_limb_true = *g * s.world_T_limb_true;
                                              }
                                              return s;
                                            });
}

}  // namespace tendril::server
