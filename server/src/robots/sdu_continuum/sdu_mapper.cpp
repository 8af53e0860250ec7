// The sdu_continuum's mapping thread (never the control thread): every new disk sample's valid ranges
// become points in {0} through the disk poses at the measured joints (Abah 2022, eq. 3.7), the voxel map
// accumulates them, RANSAC extracts planes and the bracing check judges them (periodically and on the
// `map extract` command), and the results go out as /sdu/map (foxglove.PointCloud) and /sdu/planes
// (foxglove.SceneUpdate). The planes also go to the control thread for the supervisor's d_e = d·cos θ.
// Faults do not touch the map: an invalid reading adds nothing, and only `map clear` forgets points.
#include <chrono>
#include <cmath>
#include <cstring>

#include <nlohmann/json.hpp>

#include "sdu_continuum/sdu_robot.hpp"
#include "tendril/server/http/foxglove_protocol.hpp"

namespace tendril::server {

namespace {

namespace cont = tendril::continuum;
using nlohmann::json;

std::uint64_t wall_ns() {
  return static_cast<std::uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                        std::chrono::system_clock::now().time_since_epoch())
                                        .count());
}

json stamp(std::uint64_t ns) { return {{"sec", ns / 1'000'000'000ULL}, {"nsec", ns % 1'000'000'000ULL}}; }

const json kTime = {{"type", "object"},
                    {"properties",
                     {{"sec", {{"type", "integer"}, {"minimum", 0}}},
                      {"nsec", {{"type", "integer"}, {"minimum", 0}, {"maximum", 999999999}}}}}};

std::string point_cloud_schema() {
  const json vector3 = {
      {"type", "object"},
      {"properties",
       {{"x", {{"type", "number"}}}, {"y", {{"type", "number"}}}, {"z", {{"type", "number"}}}}}};
  const json quaternion = {{"type", "object"},
                           {"properties",
                            {{"x", {{"type", "number"}}},
                             {"y", {{"type", "number"}}},
                             {"z", {{"type", "number"}}},
                             {"w", {{"type", "number"}}}}}};
  return json{
      {"title", "foxglove.PointCloud"},
      {"type", "object"},
      {"properties",
       {{"timestamp", kTime},
        {"frame_id", {{"type", "string"}}},
        {"pose", {{"type", "object"}, {"properties", {{"position", vector3}, {"orientation", quaternion}}}}},
        {"point_stride", {{"type", "integer"}, {"minimum", 0}}},
        {"fields", {{"type", "array"}, {"items", {{"type", "object"}}}}},
        {"data", {{"type", "string"}, {"contentEncoding", "base64"}}}}}}
      .dump();
}

std::string scene_update_schema() {
  return json{{"title", "foxglove.SceneUpdate"},
              {"type", "object"},
              {"properties",
               {{"deletions", {{"type", "array"}, {"items", {{"type", "object"}}}}},
                {"entities", {{"type", "array"}, {"items", {{"type", "object"}}}}}}}}
      .dump();
}

}  // namespace

SduMapper::SduMapper(SduContinuum& robot, const SduSettings& settings)
    : robot_(robot), settings_(settings), map_(settings.voxel_mm, settings.map_capacity) {
  status_.reason = "no map extracted yet";
}

SduMapper::~SduMapper() { stop(); }

void SduMapper::start() {
  if (thread_.joinable()) return;
  {
    std::lock_guard lock(wake_mutex_);
    stopping_ = false;
  }
  thread_ = std::thread([this] {
    const auto t0 = std::chrono::steady_clock::now();
    std::unique_lock lock(wake_mutex_);
    while (!stopping_) {
      lock.unlock();
      poll(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
      lock.lock();
      // 50 Hz: twice the disks' sample rate of 100 Hz is not needed; each pass takes every disk's
      // newest sample, and a sample missed between passes is one of many of the same surface.
      wake_.wait_for(lock, std::chrono::milliseconds(20), [this] { return stopping_; });
    }
  });
}

void SduMapper::stop() {
  {
    std::lock_guard lock(wake_mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void SduMapper::poll(double now_s) {
  const SduSamples samples = robot_.samples();
  const SduSnapshot snap = robot_.snapshot();
  const auto poses = cont::disk_poses(settings_.model, segment_configuration(snap.q));
  std::vector<Eigen::Vector3d> cloud;
  bool cloud_due = false, extract_due = false;
  {
    std::lock_guard lock(mutex_);
    std::uint64_t added = 0;
    for (std::size_t i = 0; i < kSdus; ++i) {
      const auto& s = samples.disk[i];
      if (!s.received || s.stamp_ns == last_stamp_[i]) continue;
      last_stamp_[i] = s.stamp_ns;
      // Only ranges the sensor vouches for: the usable span (130 mm), valid status, finite.
      const std::size_t n = cont::sample_points(settings_.model, poses[i], s,
                                                settings_.supervisor.proximity.d_max_mm, scratch_);
      for (std::size_t k = 0; k < n; ++k) map_.insert(scratch_[k]);
      added += n;
    }
    if (rate_window_start_ < 0.0) rate_window_start_ = now_s;
    rate_window_points_ += added;
    if (now_s - rate_window_start_ >= 1.0) {
      status_.points_per_s = static_cast<double>(rate_window_points_) / (now_s - rate_window_start_);
      rate_window_start_ = now_s;
      rate_window_points_ = 0;
    }
    status_.points = map_.size();
    status_.points_in = map_.points_in();
    status_.refused_full = map_.refused_full();
    if (now_s >= next_cloud_ && map_.size() != published_points_) {
      next_cloud_ = now_s + settings_.map_publish_period_s;
      published_points_ = map_.size();
      cloud = map_.points();
      cloud_due = true;
    }
    if (now_s >= next_extract_) {
      next_extract_ = now_s + settings_.extract_period_s;
      extract_due = map_.size() >= settings_.ransac.min_inliers;
    }
  }
  if (cloud_due) publish_cloud(cloud);
  if (extract_due) extract();
}

SduMapper::Extraction SduMapper::extract() {
  // One extraction at a time (the mapping thread's periodic one and the API's): the planes' slot to the
  // control thread has a single writer.
  std::lock_guard serial(extract_mutex_);
  Extraction e;
  std::vector<Eigen::Vector3d> points;
  {
    std::lock_guard lock(mutex_);
    points = map_.points();
  }
  e.points = points.size();
  const auto fits = cont::extract_planes(points, settings_.ransac, settings_.max_planes);
  if (const auto* err = std::get_if<cont::MapError>(&fits)) {
    e.error_code = *err == cont::MapError::kNoPoints ? "map_empty" : "no_plane";
    e.error = *err == cont::MapError::kNoPoints
                  ? std::string("the map has no points: no disk has measured a surface within ") +
                        std::to_string(static_cast<int>(settings_.supervisor.proximity.d_max_mm)) +
                        " mm yet (move the segment near a surface, then extract again)"
                  : std::string("no plane could be fitted to the map's ") + std::to_string(points.size()) +
                        " points (" + cont::to_string(*err) + "); map more of the surface";
    std::lock_guard lock(mutex_);
    status_.reason = e.error;
    return e;
  }
  e.planes = std::get<std::vector<cont::PlaneFit>>(fits);
  // The bracing verdict: the first plane that carries the patch, or the largest's reason.
  for (const auto& fit : e.planes) {
    auto b = cont::check_bracing(points, fit, settings_.bracing);
    if (b.admissible || e.bracing.reason.empty() || b.largest_square_mm > e.bracing.largest_square_mm)
      e.bracing = b;
    if (b.admissible) break;
  }
  e.ok = true;
  // The planes to the control thread (the supervisor's (3.5)).
  SduPlaneSet set;
  set.count = std::min(e.planes.size(), set.plane.size());
  set.inlier_mm = settings_.ransac.inlier_distance_mm;
  for (std::size_t k = 0; k < set.count; ++k) {
    const auto& p = e.planes[k].plane;
    set.plane[k] = {p.normal.x(), p.normal.y(), p.normal.z(), p.offset_mm};
  }
  robot_.planes_.store(set);
  {
    std::lock_guard lock(mutex_);
    status_.planes = e.planes.size();
    status_.extracted = true;
    status_.admissible = e.bracing.admissible;
    status_.reason = e.bracing.reason;
  }
  publish_planes(e, points);
  return e;
}

void SduMapper::clear() {
  std::lock_guard serial(extract_mutex_);
  {
    std::lock_guard lock(mutex_);
    map_ = cont::VoxelMap(settings_.voxel_mm, settings_.map_capacity);
    status_ = Status{};
    status_.reason = "the map was cleared";
    published_points_ = static_cast<std::size_t>(-1);
  }
  robot_.planes_.store(SduPlaneSet{});
  publish_cloud({});
  publish_planes(Extraction{}, {});
}

SduMapper::Status SduMapper::status() const {
  std::lock_guard lock(mutex_);
  return status_;
}

void SduMapper::publish_cloud(const std::vector<Eigen::Vector3d>& points) {
  const auto now = wall_ns();
  std::string out = "{\"timestamp\":" + stamp(now).dump() + ",\"frame_id\":\"" + robot_.kinematics().frame() +
                    "\",\"pose\":{\"position\":{\"x\":0,\"y\":0,\"z\":0},"
                    "\"orientation\":{\"x\":0,\"y\":0,\"z\":0,\"w\":1}},\"point_stride\":12,\"fields\":["
                    "{\"name\":\"x\",\"offset\":0,\"type\":7},{\"name\":\"y\",\"offset\":4,\"type\":7},"
                    "{\"name\":\"z\",\"offset\":8,\"type\":7}],\"data\":\"";
  std::vector<std::uint8_t> bytes(points.size() * 12);
  for (std::size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3f p = points[i].cast<float>();
    std::memcpy(&bytes[i * 12], p.data(), 12);
  }
  http::foxglove::append_base64(bytes.data(), bytes.size(), out);
  out += "\"}";
  put("/" + robot_.config().name + "/map", std::move(out));
}

void SduMapper::publish_planes(const Extraction& e, const std::vector<Eigen::Vector3d>& points) {
  const auto now = wall_ns();
  const json empty = json::array();
  auto entities = json::array();
  const std::string frame = robot_.kinematics().frame();
  const std::string& robot = robot_.config().name;
  for (std::size_t k = 0; k < e.planes.size(); ++k) {
    const auto& fit = e.planes[k];
    // A thin plate over the inliers' extent in the plane.
    const Eigen::Vector3d n = fit.plane.normal;
    const Eigen::Quaterniond q = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), n);
    const Eigen::Matrix3d R = q.toRotationMatrix();
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e18), hi = Eigen::Vector3d::Constant(-1e18);
    for (const auto i : fit.inliers) {
      const Eigen::Vector3d local = R.transpose() * points[i];
      lo = lo.cwiseMin(local);
      hi = hi.cwiseMax(local);
    }
    Eigen::Vector3d centre_local = 0.5 * (lo + hi);
    centre_local.z() = fit.plane.offset_mm;  // on the plane
    const Eigen::Vector3d centre = R * centre_local;
    const bool admissible = e.bracing.admissible && k == 0;
    const json colour = admissible ? json{{"r", 0.2}, {"g", 0.8}, {"b", 0.3}, {"a", 0.6}}
                                   : json{{"r", 0.95}, {"g", 0.65}, {"b", 0.1}, {"a", 0.6}};
    const json pose = {{"position", {{"x", centre.x()}, {"y", centre.y()}, {"z", centre.z()}}},
                       {"orientation", {{"x", q.x()}, {"y", q.y()}, {"z", q.z()}, {"w", q.w()}}}};
    json entity = {
        {"timestamp", stamp(now)},
        {"frame_id", frame},
        {"id", robot + "/plane_" + std::to_string(k)},
        {"lifetime", {{"sec", 0}, {"nsec", 0}}},
        {"frame_locked", false},
        {"metadata",
         {{{"key", "inliers"}, {"value", std::to_string(fit.inliers.size())}},
          {{"key", "rms_mm"}, {"value", std::to_string(fit.rms_mm)}}}},
        {"arrows", empty},
        {"cubes",
         {{{"pose", pose},
           {"size",
            {{"x", std::max(1.0, hi.x() - lo.x())}, {"y", std::max(1.0, hi.y() - lo.y())}, {"z", 2.0}}},
           {"color", colour}}}},
        {"spheres", empty},
        {"cylinders", empty},
        {"lines", empty},
        {"triangles", empty},
        {"texts",
         {{{"pose", pose},
           {"billboard", true},
           {"font_size", 12.0},
           {"scale_invariant", true},
           {"color", {{"r", 1}, {"g", 1}, {"b", 1}, {"a", 1}}},
           {"text", (k == 0 ? e.bracing.reason
                            : std::string("plane ") + std::to_string(k) + ": " +
                                  std::to_string(fit.inliers.size()) + " points")}}}},
        {"models", empty}};
    entities.push_back(std::move(entity));
  }
  // Planes of an earlier extraction that this one no longer has are deleted (by id).
  auto deletions = json::array();
  for (std::size_t k = e.planes.size(); k < 8; ++k)
    deletions.push_back(
        {{"timestamp", stamp(now)}, {"type", 0}, {"id", robot + "/plane_" + std::to_string(k)}});
  put("/" + robot + "/planes", json{{"deletions", deletions}, {"entities", entities}}.dump());
}

void SduMapper::put(const std::string& topic, std::string payload) {
  std::function<void()> ready;
  {
    std::lock_guard lock(mutex_);
    Slot& slot = topic.ends_with("/map") ? cloud_ : planes_;
    slot.payload = std::make_shared<const std::string>(std::move(payload));
    ++slot.version;
    slot.log_time_ns = wall_ns();
    ready = ready_;
  }
  if (ready) ready();
}

std::vector<TopicInfo> SduMapper::topics() const {
  const std::string& robot = robot_.config().name;
  return {{"/" + robot + "/map", "foxglove.PointCloud", point_cloud_schema()},
          {"/" + robot + "/planes", "foxglove.SceneUpdate", scene_update_schema()}};
}

std::optional<TopicPayload> SduMapper::latest(const std::string& topic, std::uint64_t since_version) const {
  std::lock_guard lock(mutex_);
  const std::string& robot = robot_.config().name;
  const Slot* slot =
      topic == "/" + robot + "/map" ? &cloud_ : (topic == "/" + robot + "/planes" ? &planes_ : nullptr);
  if (!slot || !slot->payload || slot->version <= since_version) return std::nullopt;
  return TopicPayload{slot->payload, slot->version, slot->log_time_ns};
}

void SduMapper::set_ready_callback(std::function<void()> ready) {
  std::lock_guard lock(mutex_);
  ready_ = std::move(ready);
}

}  // namespace tendril::server
