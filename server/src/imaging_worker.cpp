#include "tendril/server/imaging_worker.hpp"

#include <pthread.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>

#include "tendril/server/config.hpp"
#include "tendril/server/foxglove_protobuf.hpp"
#include "tendril/server/http/foxglove_protocol.hpp"
#include "tendril/teleop/vessel_centerline.hpp"

namespace tendril::server {

namespace {

using SteadyClock = std::chrono::steady_clock;
constexpr std::size_t kTimingWindow = 256;  // recent frames kept for the timing quantiles
constexpr double kDefaultVesselRadiusMm = 2.0;
// A plane's streams (ImagingWorker::Plane::topics).
constexpr std::size_t kJson = 0;         // /imaging/{view}: JSON, base64 image and overlay in one message
constexpr std::size_t kCompressed = 1;   // /imaging/{view}/compressed: protobuf foxglove.CompressedImage
constexpr std::size_t kOverlay = 2;      // /imaging/{view}/overlay: JSON tendril.ImageOverlay
constexpr std::size_t kAnnotations = 3;  // /imaging/{view}/annotations: protobuf foxglove.ImageAnnotations
constexpr std::size_t kStreams = 4;

std::uint64_t wall_ns() {
  return static_cast<std::uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                        std::chrono::system_clock::now().time_since_epoch())
                                        .count());
}

void append_timestamp(std::uint64_t ns, std::string& out) {
  out += "{\"sec\":";
  out += std::to_string(ns / 1'000'000'000ULL);
  out += ",\"nsec\":";
  out += std::to_string(ns % 1'000'000'000ULL);
  out += '}';
}

const nlohmann::json kTimeSchema = {
    {"type", "object"},
    {"properties",
     {{"sec", {{"type", "integer"}, {"minimum", 0}}},
      {"nsec", {{"type", "integer"}, {"minimum", 0}, {"maximum", 999999999}}}}}};

std::string compressed_image_schema() {
  return nlohmann::json{
      {"title", "foxglove.CompressedImage"},
      {"description", "A compressed image"},
      {"type", "object"},
      {"properties",
       {{"timestamp", kTimeSchema},
        {"frame_id", {{"type", "string"}}},
        {"data", {{"type", "string"}, {"contentEncoding", "base64"}}},
        {"format", {{"type", "string"}}},
        {"overlay",
         {{"type", "object"},
          {"description",
           "tendril: the imaged robot's model backbone and the plan's path projected onto this "
           "frame, [[column, row], …] in pixels (row 0 at the top)"},
          {"properties", {{"robot", {{"type", "array"}}}, {"plan", {{"type", "array"}}}}}}}}}}
      .dump();
}

// The overlay of one frame by itself: its capture time (the frame's) and what is drawn on it.
std::string image_overlay_schema() {
  const nlohmann::json pixels = {{"type", "array"},
                                 {"items", {{"type", "array"}, {"items", {{"type", "number"}}}}}};
  return nlohmann::json{
      {"title", "tendril.ImageOverlay"},
      {"description",
       "What the console draws over the frame of the same timestamp on /imaging/{view}/compressed: the "
       "imaged robot's model backbone and the plan's path projected with the plane's geometry, and "
       "while the tip is tracked the segmented instrument and the filtered tip; pixels [column, row], row 0 "
       "at the top"},
      {"type", "object"},
      {"properties",
       {{"timestamp", kTimeSchema},
        {"frame_id", {{"type", "string"}}},
        {"robot", pixels},
        {"plan", pixels},
        {"segmented", pixels},
        {"tip", {{"type", {"array", "null"}}, {"items", {{"type", "number"}}}}}}}}
      .dump();
}

std::string point_cloud_schema() {
  const nlohmann::json vector3 = {
      {"type", "object"},
      {"properties",
       {{"x", {{"type", "number"}}}, {"y", {{"type", "number"}}}, {"z", {{"type", "number"}}}}}};
  const nlohmann::json quaternion = {{"type", "object"},
                                     {"properties",
                                      {{"x", {{"type", "number"}}},
                                       {"y", {{"type", "number"}}},
                                       {"z", {{"type", "number"}}},
                                       {"w", {{"type", "number"}}}}}};
  return nlohmann::json{
      {"title", "foxglove.PointCloud"},
      {"description", "A collection of N-dimensional points"},
      {"type", "object"},
      {"properties",
       {{"timestamp", kTimeSchema},
        {"frame_id", {{"type", "string"}}},
        {"pose", {{"type", "object"}, {"properties", {{"position", vector3}, {"orientation", quaternion}}}}},
        {"point_stride", {{"type", "integer"}, {"minimum", 0}}},
        {"fields",
         {{"type", "array"},
          {"items",
           {{"type", "object"},
            {"properties",
             {{"name", {{"type", "string"}}},
              {"offset", {{"type", "integer"}, {"minimum", 0}}},
              {"type", {{"type", "integer"}}}}}}}}},
        {"data", {{"type", "string"}, {"contentEncoding", "base64"}}}}}}
      .dump();
}

// foxglove.PointCloud of float32 x, y, z (NumericType FLOAT32 = 7).
std::string vessel_cloud_message(const std::vector<Eigen::Vector3f>& points, std::uint64_t time_ns) {
  std::string out = "{\"timestamp\":";
  append_timestamp(time_ns, out);
  out +=
      ",\"frame_id\":\"world\",\"pose\":{\"position\":{\"x\":0,\"y\":0,\"z\":0},"
      "\"orientation\":{\"x\":0,\"y\":0,\"z\":0,\"w\":1}},\"point_stride\":12,\"fields\":["
      "{\"name\":\"x\",\"offset\":0,\"type\":7},{\"name\":\"y\",\"offset\":4,\"type\":7},"
      "{\"name\":\"z\",\"offset\":8,\"type\":7}],\"data\":\"";
  std::vector<std::uint8_t> bytes(points.size() * 12);
  for (std::size_t i = 0; i < points.size(); ++i) std::memcpy(&bytes[i * 12], points[i].data(), 12);
  append_base64(bytes.data(), bytes.size(), out);
  out += "\"}";
  return out;
}

// Reads the imaging keys with the same kind of messages as the rest of the configuration.
struct KeyReader {
  const nlohmann::json& j;
  std::string file;
  [[noreturn]] void fail(const std::string& key, const std::string& expected) const {
    std::string got = j.contains(key) ? j.at(key).dump() : "nothing";
    if (got.size() > 60) got = got.substr(0, 57) + "...";
    throw ConfigError(file + ": imaging." + key + ": expected " + expected + ", got " + got);
  }
  double number(const std::string& key, double fallback, double lo, double hi) const {
    if (!j.contains(key)) return fallback;
    const auto& v = j.at(key);
    if (!v.is_number() || !std::isfinite(v.get<double>()) || v.get<double>() < lo || v.get<double>() > hi)
      fail(key, "a number from " + std::to_string(lo) + " to " + std::to_string(hi));
    return v.get<double>();
  }
  int integer(const std::string& key, int fallback, int lo, int hi) const {
    if (!j.contains(key)) return fallback;
    const auto& v = j.at(key);
    if (!v.is_number_integer() || v.get<long>() < lo || v.get<long>() > hi)
      fail(key, "an integer from " + std::to_string(lo) + " to " + std::to_string(hi));
    return static_cast<int>(v.get<long>());
  }
  bool boolean(const std::string& key, bool fallback) const {
    if (!j.contains(key)) return fallback;
    if (!j.at(key).is_boolean()) fail(key, "true or false");
    return j.at(key).get<bool>();
  }
};

// Points projected onto the plane's detector as [[column, row], …] (pixels, one decimal); points at
// or behind the source are left out.
// The points in front of the plane that project to finite pixels, [column, row].
std::vector<std::array<double, 2>> projected(const sim::SimulatedFluoroscope& fluoroscope,
                                             const std::vector<Eigen::Vector3d>& points) {
  std::vector<std::array<double, 2>> out;
  out.reserve(points.size());
  for (const auto& p : points) {
    const auto d = fluoroscope.project(p);
    if (!d.in_front || !std::isfinite(d.column) || !std::isfinite(d.row)) continue;
    out.push_back({d.column, d.row});
  }
  return out;
}

void append_pixels(const std::vector<std::array<double, 2>>& pixels, std::string& out) {
  out += '[';
  char buf[64];
  for (std::size_t i = 0; i < pixels.size(); ++i) {
    std::snprintf(buf, sizeof buf, "%s[%.1f,%.1f]", i ? "," : "", pixels[i][0], pixels[i][1]);
    out += buf;
  }
  out += ']';
}

PlaneSourceConfig parse_plane_source(const nlohmann::json& j, const std::string& key,
                                     const std::filesystem::path& server_file) {
  const std::string file = server_file.string();
  const auto fail = [&](const std::string& what) { throw ConfigError(file + ": " + key + what); };
  if (!j.is_object())
    fail(": expected an object such as {\"kind\": \"files\", \"path\": \"frames/\", \"fps\": 10}");
  PlaneSourceConfig c;
  for (const auto& item : j.items()) {
    const std::string& k = item.key();
    if (k != "kind" && k != "path" && k != "fps" && k != "loop" && k != "note")
      fail("." + k + ": unknown key; expected kind, path, fps, loop or note");
  }
  const std::string kind =
      j.contains("kind") && j.at("kind").is_string() ? j.at("kind").get<std::string>() : "";
  if (kind == "simulated") {
    c.kind = ImageSourceKind::kSimulated;
  } else if (kind == "video") {
    c.kind = ImageSourceKind::kVideo;
  } else if (kind == "files") {
    c.kind = ImageSourceKind::kFiles;
  } else {
    fail(".kind: expected \"simulated\", \"video\" or \"files\", got " +
         (j.contains("kind") ? j.at("kind").dump() : std::string("nothing")));
  }
  if (c.kind != ImageSourceKind::kSimulated) {
    if (!j.contains("path") || !j.at("path").is_string() || j.at("path").get<std::string>().empty())
      fail(".path: expected a device (/dev/videoN), a file or a folder");
    c.path = j.at("path").get<std::string>();
    if (c.path.is_relative()) c.path = (server_file.parent_path() / c.path).lexically_normal();
  } else if (j.contains("path")) {
    fail(".path: a simulated plane takes no path");
  }
  c.fps = c.kind == ImageSourceKind::kFiles ? 10.0 : 0.0;
  if (j.contains("fps")) {
    const auto& v = j.at("fps");
    const double lo = c.kind == ImageSourceKind::kFiles ? 0.1 : 0.0;
    if (!v.is_number() || !std::isfinite(v.get<double>()) || v.get<double>() < lo || v.get<double>() > 1000.0)
      fail(".fps: expected a number from " + std::to_string(lo) + " to 1000, got " + v.dump());
    c.fps = v.get<double>();
  }
  if (j.contains("loop")) {
    if (!j.at("loop").is_boolean()) fail(".loop: expected true or false, got " + j.at("loop").dump());
    c.loop = j.at("loop").get<bool>();
  }
  return c;
}

}  // namespace

const char* source_kind_name(ImageSourceKind kind) noexcept {
  switch (kind) {
    case ImageSourceKind::kSimulated:
      return "simulated";
    case ImageSourceKind::kVideo:
      return "video";
    case ImageSourceKind::kFiles:
      return "files";
  }
  return "unknown";
}

std::vector<sim::VesselTube> vessel_tubes(const std::vector<teleop::CenterlinePolyline>& branches) {
  std::vector<sim::VesselTube> tubes;
  for (const auto& branch : branches) {
    sim::VesselTube tube;
    tube.centerline = branch.points;
    tube.radius_mm = branch.radii.size() == branch.points.size()
                         ? branch.radii
                         : std::vector<double>(branch.points.size(), kDefaultVesselRadiusMm);
    tubes.push_back(std::move(tube));
  }
  return tubes;
}

void append_base64(const std::uint8_t* data, std::size_t size, std::string& out) {
  http::foxglove::append_base64(data, size, out);
}

ImagingConfig parse_imaging_config(const nlohmann::json& imaging, const std::filesystem::path& server_file) {
  ImagingConfig c;
  if (imaging.is_null()) return c;
  const std::string file = server_file.string();
  if (!imaging.is_object()) throw ConfigError(file + ": imaging: expected an object, got " + imaging.dump());
  const KeyReader r{imaging, file};
  c.enabled = r.boolean("enabled", true);
  if (imaging.contains("robot")) {
    if (!imaging.at("robot").is_string()) r.fail("robot", "a robot name");
    c.robot = imaging.at("robot").get<std::string>();
  }
  c.fps = r.number("fps", 15.0, 0.1, 60.0);
  c.jpeg_quality = r.integer("jpeg_quality", 80, 1, 100);
  auto& f = c.fluoroscope;
  auto& g = f.geometry;
  g.width = r.integer("width", 512, 16, 2048);
  g.height = r.integer("height", 512, 16, 2048);
  g.sid_mm = r.number("sid_mm", 1000.0, 1.0, 5000.0);
  g.sod_mm = r.number("sod_mm", 750.0, 1.0, 5000.0);
  if (g.sod_mm >= g.sid_mm)
    r.fail("sod_mm", "less than sid_mm (the object lies between source and detector)");
  // Without an explicit pitch the field of view stays the same at every resolution.
  const double detector_mm = r.number("detector_mm", 160.0, 1.0, 1000.0);
  g.pixel_spacing_mm = r.number("pixel_spacing_mm", detector_mm / std::max(g.width, g.height), 1e-3, 10.0);
  if (imaging.contains("isocentre_mm")) {
    const auto& v = imaging.at("isocentre_mm");
    if (!v.is_array() || v.size() != 3 || !std::all_of(v.begin(), v.end(), [](const auto& x) {
          return x.is_number() && std::isfinite(x.template get<double>());
        }))
      r.fail("isocentre_mm", "[x, y, z] in mm");
    g.isocentre = {v[0].get<double>(), v[1].get<double>(), v[2].get<double>()};
  } else {
    g.isocentre = {0.0, 0.0, 50.0};
  }
  f.photons_per_pixel = r.number("photons_per_pixel", f.photons_per_pixel, 1.0, 1e7);
  f.blur_sigma_px = r.number("blur_sigma_px", f.blur_sigma_px, 0.0, 20.0);
  // Any flexible radio-opaque instrument in the vessel is drawn the same way.
  f.instrument_diameter_mm = r.number("instrument_diameter_mm", f.instrument_diameter_mm, 0.05, 20.0);
  f.contrast_attenuation_per_mm =
      r.number("contrast_attenuation_per_mm", f.contrast_attenuation_per_mm, 0, 10);
  f.anatomy = r.boolean("anatomy", true);

  c.stale_after_s = r.number("stale_after_s", 1.0, 0.05, 60.0);
  c.tracking = parse_tracking_config(imaging.contains("tracking") ? imaging.at("tracking") : nlohmann::json(),
                                     server_file);
  if (imaging.contains("sources")) {
    const auto& sources = imaging.at("sources");
    if (!sources.is_object()) r.fail("sources", "an object {\"ap\": {…}, \"lateral\": {…}}");
    for (const auto& item : sources.items()) {
      const std::string& plane = item.key();
      const std::size_t index = plane == "ap" ? 0 : plane == "lateral" ? 1 : 2;
      if (index == 2) {
        std::string message = file;
        message += ": imaging.sources.";
        message += plane;
        message += ": unknown plane; expected ap or lateral";
        throw ConfigError(message);
      }
      c.sources[index] = parse_plane_source(item.value(), "imaging.sources." + plane, server_file);
    }
  }

  auto scene = load_scene_vessel(nullptr, imaging, server_file);
  c.vessels = vessel_tubes(scene.branches);
  c.vessel_source = std::move(scene.source);
  return c;
}

SceneVessel load_scene_vessel(const nlohmann::json& scene, const nlohmann::json& imaging,
                              const std::filesystem::path& server_file) {
  SceneVessel out;
  const std::string file = server_file.string();
  // The scene's keys, or the older imaging.vessel.
  const bool in_scene = scene.is_object();
  if (!scene.is_null() && !in_scene)
    throw ConfigError(file + ": scene: expected an object, got " + scene.dump());
  const nlohmann::json& holder = in_scene ? scene : (imaging.is_object() ? imaging : scene);
  const std::string key = in_scene ? "scene.vessel" : "imaging.vessel";
  const auto fail = [&](const std::string& expected) {
    std::string got = holder.contains("vessel") ? holder.at("vessel").dump() : "nothing";
    if (got.size() > 60) got = got.substr(0, 57) + "...";
    throw ConfigError(file + ": " + key + ": expected " + expected + ", got " + got);
  };
  if (in_scene) {
    for (const auto& item : scene.items()) {
      const std::string& k = item.key();
      if (k != "vessel" && k != "robot" && k != "note") {
        std::string message = file;
        message += ": scene.";
        message += k;
        message += ": unknown key; expected vessel, robot or note";
        throw ConfigError(message);
      }
    }
    if (scene.contains("robot")) {
      if (!scene.at("robot").is_string() || scene.at("robot").get<std::string>().empty())
        throw ConfigError(file + ": scene.robot: expected a robot's name, got " + scene.at("robot").dump());
      out.robot = scene.at("robot").get<std::string>();
    }
  }
  const auto dir = server_file.parent_path();
  std::filesystem::path vessel_file;
  bool generate = false;
  if (holder.is_object() && holder.contains("vessel")) {
    const auto& v = holder.at("vessel");
    if (v.is_boolean() && !v.get<bool>()) {
      out.source = "none";
      return out;
    }
    if (!v.is_string() || v.get<std::string>().empty()) fail("a CSV file (x,y,z[,r] mm) or false");
    vessel_file = v.get<std::string>();
    if (vessel_file.is_relative()) vessel_file = (dir / vessel_file).lexically_normal();
    if (!std::filesystem::exists(vessel_file)) fail("an existing file (" + vessel_file.string() + ")");
  } else {
    vessel_file = (dir / "vessels" / "synthetic_ica.csv").lexically_normal();
    generate = !std::filesystem::exists(vessel_file);
  }
  if (generate) {
    out.branches = {teleop::make_synthetic_ica(1)};
    out.source = "synthetic ICA generated at start-up (teleop::make_synthetic_ica, seed 1; " +
                 vessel_file.string() + " not found)";
    return out;
  }
  std::ifstream in(vessel_file);
  std::stringstream text;
  text << in.rdbuf();
  if (!in) fail("a readable file (" + vessel_file.string() + ")");
  try {
    out.branches = teleop::parse_centerline_csv(text.str());
  } catch (const teleop::VesselInputError& e) {
    throw ConfigError(file + ": " + key + ": " + vessel_file.string() + ": " + e.what());
  }
  out.source = vessel_file.string();
  return out;
}

struct ImagingWorker::Plane {
  Plane(sim::FluoroView v, const sim::FluoroscopeOptions& options,
        const std::vector<sim::VesselTube>& vessels)
      : view(v),
        topic(std::string("/imaging/") + sim::view_name(v)),
        frame_id(std::string("imaging_") + sim::view_name(v)),
        label(v == sim::FluoroView::kAp ? "AP" : "lateral"),
        fluoroscope(v, options, vessels) {
    topics[kJson] = topic;
    topics[kCompressed] = topic + "/compressed";
    topics[kOverlay] = topic + "/overlay";
    topics[kAnnotations] = topic + "/annotations";
  }

  const sim::FluoroView view;
  const std::string topic;
  // The plane's four streams: kJson the JSON image with its overlay inside (the first form, for
  // clients that read JSON only), kCompressed the image alone as protobuf foxglove.CompressedImage
  // (no base64: what the console and Foxglove read), kOverlay the overlay alone as small JSON, and
  // kAnnotations the same overlay as protobuf foxglove.ImageAnnotations (what Foxglove's Image panel
  // draws over the image of the same timestamp).
  std::array<std::string, kStreams> topics;
  const std::string frame_id;
  const char* label;
  // Renders the simulated plane; for every plane, its geometry projects the overlay.
  sim::SimulatedFluoroscope fluoroscope;         // the plane's thread only
  std::unique_ptr<imaging::ImageSource> source;  // null: simulated
  imaging::GreyImage frame;                      // the source's last frame (the plane's thread only)
  std::vector<std::uint8_t> jpeg;
  std::vector<Eigen::Vector3d> backbone;
  // What a simulated plane renders when it is not the model's backbone (ImageFeedback::imaged_backbone).
  std::vector<Eigen::Vector3d> imaged;
  std::vector<Eigen::Vector3d> plan;

  mutable std::mutex slot_mutex;  // the latest-value slots the front end reads, one per stream
  std::array<std::shared_ptr<const std::string>, kStreams> payloads;
  std::array<std::uint64_t, kStreams> versions{};
  std::uint64_t ready_ns = 0;  // when the message was ready: its log time (the capture time is inside)

  // Written under ImagingWorker::run_mutex_: someone subscribes to a stream (stream_wanted; read by the
  // plane's thread to build only those), and the plane runs (wanted: a stream or, for a simulated
  // plane, the tracking is watched).
  std::array<std::atomic<bool>, kStreams> stream_wanted{};
  bool wanted = false;

  mutable std::mutex stats_mutex;
  std::array<double, kTimingWindow> render_s{}, encode_s{}, track_s{};
  std::uint64_t frames = 0, skipped = 0, shape_errors = 0, dropped = 0, stale_episodes = 0;
  std::size_t jpeg_bytes = 0;
  // The watchdog's view (stats_mutex): when the last frame came, or when watching began.
  SteadyClock::time_point last_frame{};
  bool watching = false;  // wanted, and frames can still come (a replay has not ended)
  bool stale = false;
  bool ended = false;
  std::uint64_t drops_unreported = 0;
  SteadyClock::time_point last_drop_warning{};
  std::string last_drop_reason;
};

BackboneReader backbone_from(const RobotService& service, std::string robot) {
  if (robot.empty()) {
    const auto robots = service.robots();
    if (!robots.empty()) robot = robots[0].name;
  }
  if (!service.has_robot(robot))
    throw ConfigError("imaging.robot: no robot named '" + robot + "' is configured");
  return [&service, robot](std::vector<Eigen::Vector3d>& out) {
    const auto shape = service.shape(robot);
    if (!shape) return false;
    out.insert(out.end(), shape->points.begin(), shape->points.end());
    return true;
  };
}

ImagingWorker::ImagingWorker(BackboneReader read_backbone, ImagingConfig config)
    : read_backbone_(std::move(read_backbone)), config_(std::move(config)) {
  if (!(config_.fps > 0)) throw sim::FluoroscopeError("imaging: fps must be greater than 0");
  if (config_.jpeg_quality < 1 || config_.jpeg_quality > 100)
    throw sim::FluoroscopeError("imaging: jpeg_quality must be 1..100");
  if (!(config_.stale_after_s > 0))
    throw sim::FluoroscopeError("imaging: stale_after_s must be greater than 0");
  planes_[0] = std::make_unique<Plane>(sim::FluoroView::kAp, config_.fluoroscope, config_.vessels);
  planes_[1] = std::make_unique<Plane>(sim::FluoroView::kLateral, config_.fluoroscope, config_.vessels);
  const auto& g = config_.fluoroscope.geometry;
  for (std::size_t i = 0; i < planes_.size(); ++i) {
    const auto& sc = config_.sources[i];
    if (sc.kind == ImageSourceKind::kSimulated) continue;
    // Frames are brought to the configured detector size, so that the overlay's geometry applies.
    try {
      if (sc.kind == ImageSourceKind::kVideo) {
        planes_[i]->source = imaging::open_video_capture({sc.path, sc.loop, sc.fps, g.width, g.height});
      } else {
        planes_[i]->source = imaging::open_image_files({sc.path, sc.fps, sc.loop, g.width, g.height});
      }
    } catch (const imaging::ImageSourceError& e) {
      throw ConfigError(std::string("imaging.sources.") + sim::view_name(planes_[i]->view) + ": " + e.what());
    }
  }
  if (config_.tracking.enabled) {
    // Segmentation needs an empty-vessel roadmap: a simulated plane renders its own; a plane fed by a
    // source takes one of its frames when the operator asks (POST /imaging/roadmap/{plane}), and
    // segments nothing before ("no_roadmap"). Either way the configured geometry maps its pixels.
    tracker_ = std::make_unique<BiplaneTipTracker>(
        config_.tracking,
        std::array<sim::SimulatedFluoroscope*, 2>{&planes_[0]->fluoroscope, &planes_[1]->fluoroscope},
        1.0 / config_.fps, [this](safety::FaultCode code, const std::string& text) { warn(code, text); },
        std::array<bool, 2>{!planes_[0]->source, !planes_[1]->source});
  }
  if (!config_.vessels.empty()) {
    std::vector<Eigen::Vector3f> wall;
    for (const auto& tube : config_.vessels) {
      const auto ring = sim::vessel_wall_points(tube, 0.5, 16);
      wall.insert(wall.end(), ring.begin(), ring.end());
    }
    vessel_time_ns_ = wall_ns();
    vessel_cloud_ = std::make_shared<const std::string>(vessel_cloud_message(wall, vessel_time_ns_));
    vessel_wall_ = std::move(wall);
  }
}

ImagingWorker::~ImagingWorker() { stop(); }

std::string ImagingWorker::describe_sources() const {
  std::string out;
  for (const auto& p : planes_) {
    if (!out.empty()) out += "; ";
    out += p->label;
    out += ": ";
    out += p->source ? p->source->description() : std::string("SIMULATED fluoroscope");
  }
  return out;
}

void ImagingWorker::start() {
  std::lock_guard lock(run_mutex_);
  if (!threads_.empty()) return;
  stopping_ = false;
  const auto first = SteadyClock::now();
  for (auto& plane : planes_) {
    threads_.emplace_back([this, &plane, first] {
      Plane& p = *plane;
      // Named so that tools (and the image_stream_bench) can tell imaging CPU from serving CPU.
      pthread_setname_np(pthread_self(), p.view == sim::FluoroView::kAp ? "imaging-ap" : "imaging-lateral");
      if (p.source) {
        run_source(p);
      } else {
        run_simulated(p, first);
      }
    });
  }
  threads_.emplace_back([this] {
    pthread_setname_np(pthread_self(), "imaging-watch");
    watch();
  });
}

void ImagingWorker::run_simulated(Plane& p, SteadyClock::time_point first) {
  const auto period =
      std::chrono::duration_cast<SteadyClock::duration>(std::chrono::duration<double>(1.0 / config_.fps));
  auto next = first;  // both planes expose on the same schedule
  while (true) {
    {
      std::unique_lock wait(run_mutex_);
      if (!p.wanted) {
        // Nobody watches this plane: sleep until someone does (no timer, no wake-ups).
        run_wake_.wait(wait, [&] { return stopping_ || p.wanted; });
        if (stopping_) return;
        // Back on the common schedule, at its next exposure (at once if one is due).
        const auto now = SteadyClock::now();
        if (next < now) next += ((now - next) / period) * period;
      }
      if (run_wake_.wait_until(wait, next, [this, &p] { return stopping_ || !p.wanted; })) {
        if (stopping_) return;
        continue;  // unsubscribed while waiting for the exposure
      }
    }
    capture(p, wall_ns());
    next += period;
    const auto now = SteadyClock::now();
    if (next < now) {
      // Rendering fell behind: skip the missed exposures rather than bursting to catch up.
      const auto missed = (now - next) / period + 1;
      next += missed * period;
      std::lock_guard stats(p.stats_mutex);
      p.skipped += static_cast<std::uint64_t>(missed);
    }
  }
}

void ImagingWorker::run_source(Plane& p) {
  const auto period = std::chrono::duration_cast<SteadyClock::duration>(
      std::chrono::duration<double>(p.source->frame_period_s()));
  while (true) {
    {
      std::unique_lock wait(run_mutex_);
      run_wake_.wait(wait, [&] { return stopping_ || p.wanted; });
      if (stopping_) return;
    }
    // May block for up to a few frame periods (a device waits for its next frame): that is why each
    // plane has a thread of its own and the watchdog watches from another.
    const auto t0 = SteadyClock::now();
    const auto result = p.source->grab(p.frame);
    const std::uint64_t received_ns = wall_ns();
    {
      std::lock_guard lock(run_mutex_);
      if (stopping_) return;  // a grab cut short by stop() is not the end of a replay
    }
    if (result.status == imaging::GrabStatus::kFrame) {
      bool shape_ok = false;
      read_overlay(p, shape_ok);
      // The operator's segmentation changes and roadmap (this frame, when one was asked for), then the
      // tracking of this frame while someone watches it, as for a simulated plane.
      const int index = p.view == sim::FluoroView::kAp ? 0 : 1;
      const auto view = teleop::perception::grey_image(p.frame.pixels, p.frame.width, p.frame.height);
      const PlaneTrack* track = nullptr;
      if (tracker_) {
        tracker_->apply_requests(index, received_ns, &view);
        bool tracking = false;
        {
          std::lock_guard lock(run_mutex_);
          tracking = tracking_wanted_ || feedback_wanted_;
        }
        if (tracking) track = &tracker_->track(index, view, p.backbone, received_ns);
      }
      const auto t1 = SteadyClock::now();
      imaging::encode_jpeg(p.frame, config_.jpeg_quality, p.jpeg);
      publish(p, received_ns, p.jpeg, shape_ok, std::chrono::duration<double>(t1 - t0).count(),
              std::chrono::duration<double>(SteadyClock::now() - t1).count(), track);
      continue;
    }
    if (result.status == imaging::GrabStatus::kEnded) {
      {
        std::lock_guard stats(p.stats_mutex);
        p.ended = true;
        p.watching = false;
      }
      warn(safety::FaultCode::kSensorStale,
           std::string("imaging: ") + p.label + " replay ended; no new images");
      std::unique_lock wait(run_mutex_);
      run_wake_.wait(wait, [&] { return stopping_; });
      return;
    }
    // Dropped: counted; a warning at most once a second, with how many since the last one.
    std::string text;
    {
      std::lock_guard stats(p.stats_mutex);
      ++p.dropped;
      ++p.drops_unreported;
      p.last_drop_reason = result.reason;
      const auto now = SteadyClock::now();
      if (now - p.last_drop_warning >= std::chrono::seconds(1)) {
        text = std::string("imaging: ") + p.label + ": " + std::to_string(p.drops_unreported) +
               " frame(s) dropped: " + result.reason;
        p.drops_unreported = 0;
        p.last_drop_warning = now;
      }
    }
    if (!text.empty()) warn(safety::FaultCode::kSensorStale, text);
    // A source that fails at once (a device gone) must not spin: wait out the rest of a frame period.
    std::unique_lock wait(run_mutex_);
    run_wake_.wait_until(wait, t0 + period, [this] { return stopping_; });
    if (stopping_) return;
  }
}

void ImagingWorker::watch() {
  const auto stale_after =
      std::chrono::duration_cast<SteadyClock::duration>(std::chrono::duration<double>(config_.stale_after_s));
  const auto tick = std::min<SteadyClock::duration>(stale_after / 4, std::chrono::milliseconds(100));
  const auto any_wanted = [this] {
    return std::any_of(planes_.begin(), planes_.end(), [](const auto& p) { return p->wanted; });
  };
  std::unique_lock wait(run_mutex_);
  while (true) {
    // Nothing watched: no ticks at all until a plane is wanted (an idle server stays idle).
    run_wake_.wait(wait, [&] { return stopping_ || any_wanted(); });
    if (stopping_ || run_wake_.wait_for(wait, tick, [this] { return stopping_; })) return;
    const auto now = SteadyClock::now();
    for (auto& plane : planes_) {
      Plane& p = *plane;
      std::string text;
      {
        std::lock_guard stats(p.stats_mutex);
        const bool watch_now = p.wanted && !p.ended;       // p.wanted: run_mutex_ is held
        if (watch_now && !p.watching) p.last_frame = now;  // watching begins: the clock starts now
        p.watching = watch_now;
        if (!watch_now) {
          p.stale = false;
          continue;
        }
        if (!p.stale && now - p.last_frame > stale_after) {
          p.stale = true;
          ++p.stale_episodes;
          char buf[96];
          std::snprintf(buf, sizeof buf, "imaging: no %s image for %.1f s; the view is stale", p.label,
                        std::chrono::duration<double>(now - p.last_frame).count());
          text = buf;
        }
      }
      if (!text.empty()) {
        wait.unlock();  // the sink may take a while (it posts to the runtime); never under our lock
        warn(safety::FaultCode::kSensorStale, text);
        wait.lock();
      }
    }
  }
}

void ImagingWorker::warn(safety::FaultCode code, const std::string& text) const {
  if (warn_) warn_(code, text);
}

void ImagingWorker::set_image_feedback(ImageFeedback* feedback) {
  feedback_ = feedback;
  if (!feedback_ || !tracker_) return;
  tracker_->set_tip_listener([feedback](const ImagedTip& tip) { feedback->on_tip(tip); });
  feedback_->tracking_attached([this](bool wanted) {
    {
      std::lock_guard lock(run_mutex_);
      if (feedback_wanted_ == wanted) return;
      feedback_wanted_ = wanted;
      update_wanted();
    }
    run_wake_.notify_all();
  });
}

void ImagingWorker::update_wanted() {
  for (auto& plane : planes_) {
    bool wanted = (tracking_wanted_ || feedback_wanted_) && tracker_;
    for (const auto& stream : plane->stream_wanted) wanted = wanted || stream.load(std::memory_order_relaxed);
    if (wanted && !plane->wanted) {
      std::lock_guard stats(plane->stats_mutex);
      plane->last_frame = SteadyClock::now();  // the stale clock starts when watching starts
    }
    plane->wanted = wanted;
  }
}

void ImagingWorker::set_demand(const std::string& topic, bool wanted) {
  if (topic == "/imaging/tracking" && tracker_) {
    {
      std::lock_guard lock(run_mutex_);
      tracking_wanted_ = wanted;
      update_wanted();
    }
    run_wake_.notify_all();
    return;
  }
  for (auto& plane : planes_) {
    for (std::size_t k = 0; k < kStreams; ++k) {
      if (plane->topics[k] != topic) continue;
      {
        std::lock_guard lock(run_mutex_);
        plane->stream_wanted[k].store(wanted, std::memory_order_relaxed);
        update_wanted();
      }
      if (!wanted) {
        std::lock_guard slot(plane->slot_mutex);
        plane->payloads[k].reset();  // the version stays, so nobody mistakes the next frame for this one
      }
      run_wake_.notify_all();
    }
  }
}

void ImagingWorker::stop() {
  {
    std::lock_guard lock(run_mutex_);
    stopping_ = true;
  }
  run_wake_.notify_all();
  for (auto& plane : planes_)
    if (plane->source) plane->source->cancel();  // a slow replay's wait ends now
  for (auto& t : threads_) t.join();
  threads_.clear();
}

void ImagingWorker::capture_once() {
  const auto now = wall_ns();
  for (auto& plane : planes_)
    if (!plane->source) capture(*plane, now);
}

void ImagingWorker::read_overlay(Plane& p, bool& shape_ok) {
  p.backbone.clear();
  shape_ok = false;
  try {
    shape_ok = read_backbone_(p.backbone);
  } catch (const std::exception&) {
    shape_ok = false;  // counted; the frame shows no instrument rather than a stale one
  }
  if (!shape_ok) p.backbone.clear();
  p.plan.clear();
  if (read_plan_) {
    try {
      if (!read_plan_(p.plan)) p.plan.clear();
    } catch (const std::exception&) {
      p.plan.clear();  // no plan drawn rather than a stale one
    }
  }
}

void ImagingWorker::capture(Plane& p, std::uint64_t capture_ns) {
  // The operator's segmentation changes and roadmap, on this plane's own thread, before its frame.
  if (tracker_) tracker_->apply_requests(p.view == sim::FluoroView::kAp ? 0 : 1, capture_ns);
  // The exposure: the backbone as the runtime snapshot has it now.
  bool shape_ok = false;
  read_overlay(p, shape_ok);
  // A simulated plane images the instrument as it is: the simulated plant's true backbone where the
  // robot's simulation differs from its model (the overlay and the tracker keep the model's).
  p.imaged.clear();
  bool true_shape = false;
  if (feedback_) {
    try {
      true_shape = feedback_->imaged_backbone(p.imaged);
    } catch (const std::exception&) {
      true_shape = false;
    }
  }
  const auto t0 = SteadyClock::now();
  const auto frame = p.fluoroscope.render(true_shape ? p.imaged : p.backbone);
  const auto t1 = SteadyClock::now();
  // The tracking sees the frame as rendered (before JPEG), as a frame grabber would deliver it.
  // Only while someone watches the tracking (segmentation costs CPU; an unwatched result is waste).
  const PlaneTrack* track = nullptr;
  bool tracking = false;
  {
    std::lock_guard lock(run_mutex_);
    tracking = tracking_wanted_ || feedback_wanted_;
  }
  if (tracker_ && tracking) {
    track =
        &tracker_->track(p.view == sim::FluoroView::kAp ? 0 : 1,
                         teleop::perception::grey_image(frame, p.fluoroscope.width(), p.fluoroscope.height()),
                         p.backbone, capture_ns);
  }
  const auto t2 = SteadyClock::now();
  p.fluoroscope.encode_jpeg(config_.jpeg_quality, p.jpeg);
  publish(p, capture_ns, p.jpeg, shape_ok, std::chrono::duration<double>(t1 - t0).count(),
          std::chrono::duration<double>(SteadyClock::now() - t2).count(), track);
  if (track) {
    std::lock_guard stats(p.stats_mutex);
    p.track_s[(p.frames - 1) % kTimingWindow] = std::chrono::duration<double>(t2 - t1).count();
  }
}

void ImagingWorker::publish(Plane& p, std::uint64_t capture_ns, const std::vector<std::uint8_t>& jpeg,
                            bool shape_ok, double render_s, double encode_s, const PlaneTrack* track) {
  const auto t0 = SteadyClock::now();
  // The overlay's members, shared by the JSON image and the overlay stream.
  const auto robot_px = projected(p.fluoroscope, p.backbone);
  const auto plan_px = projected(p.fluoroscope, p.plan);
  std::vector<std::array<double, 2>> segmented_px;
  if (track && track->found) {
    segmented_px.reserve(track->backbone_px.size());
    for (const auto& q : track->backbone_px) segmented_px.push_back({q.x(), q.y()});
  }
  std::string overlay = "\"robot\":";
  append_pixels(robot_px, overlay);
  overlay += ",\"plan\":";
  append_pixels(plan_px, overlay);
  if (track) {
    char buf[64];
    overlay += ",\"segmented\":";
    append_pixels(segmented_px, overlay);
    overlay += ",\"tip\":";
    if (track->filtered) {
      std::snprintf(buf, sizeof buf, "[%.1f,%.1f]", track->filtered_px.x(), track->filtered_px.y());
      overlay += buf;
    } else {
      overlay += "null";
    }
  }
  // Only the streams someone reads are built (the base64 JSON costs a third more bytes and the CPU);
  // all of them when nobody said (an exposure on request, capture_once, or only the tracking watched).
  std::array<bool, kStreams> build{};
  bool any = false;
  for (std::size_t k = 0; k < kStreams; ++k)
    any = (build[k] = p.stream_wanted[k].load(std::memory_order_relaxed)) || any;
  if (!any) build.fill(true);
  std::array<std::shared_ptr<const std::string>, kStreams> built;
  if (build[kJson]) {
    auto message = std::make_shared<std::string>();
    message->reserve(jpeg.size() * 4 / 3 + overlay.size() + 160);
    *message += "{\"timestamp\":";
    append_timestamp(capture_ns, *message);
    *message += ",\"frame_id\":\"" + p.frame_id + "\",\"format\":\"jpeg\",\"data\":\"";
    append_base64(jpeg.data(), jpeg.size(), *message);
    *message += "\",\"overlay\":{" + overlay + "}}";
    built[kJson] = std::move(message);
  }
  if (build[kCompressed]) {
    auto message = std::make_shared<std::string>();
    protobuf::append_compressed_image(capture_ns, p.frame_id, jpeg, "jpeg", *message);
    built[kCompressed] = std::move(message);
  }
  if (build[kOverlay]) {
    auto message = std::make_shared<std::string>();
    *message += "{\"timestamp\":";
    append_timestamp(capture_ns, *message);
    *message += ",\"frame_id\":\"" + p.frame_id + "\"," + overlay + "}";
    built[kOverlay] = std::move(message);
  }
  if (build[kAnnotations]) {
    // The console's colours: the model backbone amber, the plan cyan, the segmented instrument
    // magenta, the filtered tip a magenta ring.
    std::vector<protobuf::PointsAnnotation> lines;
    lines.push_back({protobuf::PointsType::kLineStrip, robot_px, {0.96, 0.75, 0.25, 0.9}, 2.0});
    if (!plan_px.empty())
      lines.push_back({protobuf::PointsType::kLineStrip, plan_px, {0.2, 0.8, 0.9, 0.9}, 2.0});
    if (!segmented_px.empty())
      lines.push_back({protobuf::PointsType::kLineStrip, segmented_px, {0.95, 0.3, 0.8, 1.0}, 2.0});
    std::vector<protobuf::CircleAnnotation> circles;
    if (track && track->filtered) {
      protobuf::CircleAnnotation tip;
      tip.position = {track->filtered_px.x(), track->filtered_px.y()};
      tip.diameter = 12.0;
      tip.thickness = 2.0;
      tip.outline = {0.95, 0.3, 0.8, 1.0};
      circles.push_back(tip);
    }
    auto message = std::make_shared<std::string>();
    protobuf::append_image_annotations(capture_ns, circles, lines, *message);
    built[kAnnotations] = std::move(message);
  }
  encode_s += std::chrono::duration<double>(SteadyClock::now() - t0).count();
  {
    std::lock_guard lock(p.slot_mutex);
    for (std::size_t k = 0; k < kStreams; ++k) {
      if (!built[k]) continue;
      p.payloads[k] = std::move(built[k]);
      ++p.versions[k];
    }
    p.ready_ns = wall_ns();
  }
  std::string text;
  {
    std::lock_guard lock(p.stats_mutex);
    const std::size_t slot = p.frames % kTimingWindow;
    p.render_s[slot] = render_s;
    p.encode_s[slot] = encode_s;
    ++p.frames;
    if (!shape_ok) ++p.shape_errors;
    p.jpeg_bytes = jpeg.size();
    const auto now = SteadyClock::now();
    if (p.stale) {
      char buf[96];
      std::snprintf(buf, sizeof buf, "imaging: %s images again after %.1f s", p.label,
                    std::chrono::duration<double>(now - p.last_frame).count());
      text = buf;
      p.stale = false;
    }
    p.last_frame = now;
  }
  if (!text.empty()) warn(safety::FaultCode::kSensorStale, text);
  announce();
}

void ImagingWorker::announce() {
  std::lock_guard lock(ready_mutex_);
  if (ready_) ready_();
}

void ImagingWorker::set_ready_callback(std::function<void()> ready) {
  std::lock_guard lock(ready_mutex_);
  ready_ = std::move(ready);
}

std::vector<TopicInfo> ImagingWorker::topics() const {
  std::vector<TopicInfo> out;
  const std::string image_schema = compressed_image_schema();
  const std::string descriptors = protobuf::compressed_image_descriptor_set();
  const std::string annotations = protobuf::image_annotations_descriptor_set();
  for (const auto& plane : planes_) {
    out.push_back({plane->topics[kJson], "foxglove.CompressedImage", image_schema});
    out.push_back(
        {plane->topics[kCompressed], "foxglove.CompressedImage", descriptors, "protobuf", "protobuf"});
    out.push_back({plane->topics[kOverlay], "tendril.ImageOverlay", image_overlay_schema()});
    out.push_back(
        {plane->topics[kAnnotations], "foxglove.ImageAnnotations", annotations, "protobuf", "protobuf"});
  }
  if (tracker_) {
    out.push_back({"/imaging/tracking", "tendril.TipTracking", BiplaneTipTracker::schema()});
    out.push_back({"/imaging/segmentation", "tendril.SegmentationParameters",
                   BiplaneTipTracker::segmentation_schema()});
  }
  if (vessel_cloud_) out.push_back({"/maps/vessel", "foxglove.PointCloud", point_cloud_schema()});
  return out;
}

std::optional<TopicPayload> ImagingWorker::latest(const std::string& topic,
                                                  std::uint64_t since_version) const {
  if (topic == "/imaging/tracking" && tracker_) {
    std::uint64_t version = 0, time_ns = 0;
    auto payload = tracker_->latest(version, time_ns);
    if (!payload || version <= since_version) return std::nullopt;
    return TopicPayload{std::move(payload), version, time_ns};
  }
  if (topic == "/imaging/segmentation" && tracker_) {
    std::uint64_t version = 0, time_ns = 0;
    auto payload = tracker_->latest_segmentation(version, time_ns);
    if (!payload || version <= since_version) return std::nullopt;
    return TopicPayload{std::move(payload), version, time_ns};
  }
  if (topic == "/maps/vessel") {
    if (!vessel_cloud_ || since_version >= 1) return std::nullopt;
    return TopicPayload{vessel_cloud_, 1, vessel_time_ns_};
  }
  for (const auto& plane : planes_) {
    for (std::size_t k = 0; k < kStreams; ++k) {
      if (plane->topics[k] != topic) continue;
      std::lock_guard lock(plane->slot_mutex);
      if (!plane->payloads[k] || plane->versions[k] <= since_version) return std::nullopt;
      return TopicPayload{plane->payloads[k], plane->versions[k], plane->ready_ns};
    }
  }
  return std::nullopt;
}

namespace {
ApiResult unknown_plane(const std::string& plane) {
  return ApiResult::error(404, "unknown_plane",
                          "no imaging plane \"" + plane + "\"; the planes are ap and lateral");
}
ApiResult no_tracking() {
  return ApiResult::error(
      503, "tracking_unavailable",
      "the tip tracking is off (imaging.tracking.enabled is false): nothing is segmented");
}
int plane_index(const std::string& plane) { return plane == "ap" ? 0 : plane == "lateral" ? 1 : -1; }
}  // namespace

ApiResult ImagingWorker::segmentation() const {
  if (!tracker_) return no_tracking();
  auto planes = tracker_->segmentation_state();
  // Every plane is tracked; a source plane's roadmap is one of its own frames (none until asked for).
  for (const auto& p : planes_) {
    planes[sim::view_name(p->view)]["tracked"] = true;
    planes[sim::view_name(p->view)]["roadmap_from"] = p->source ? "source_frame" : "simulation";
  }
  return ApiResult::success({{"robot", config_.robot}, {"planes", std::move(planes)}});
}

ApiResult ImagingWorker::set_segmentation(const std::string& plane, const nlohmann::json& changes) {
  const int index = plane_index(plane);
  if (index < 0) return unknown_plane(plane);
  if (!tracker_) return no_tracking();
  if (!changes.is_object())
    return ApiResult::error(400, "bad_request",
                            "expected a JSON object of segmentation parameters, e.g. {\"threshold\": 40}");
  try {
    tracker_->request_parameters(index, changes);
  } catch (const teleop::perception::SegmentationParameterError& e) {
    ApiResult r = ApiResult::error(422, "invalid_parameter", e.what());
    r.error_details = {{"field", e.field()}};
    return r;
  }
  return ApiResult::success(tracker_->segmentation_state()[plane]);
}

ApiResult ImagingWorker::take_roadmap(const std::string& plane) {
  const int index = plane_index(plane);
  if (index < 0) return unknown_plane(plane);
  if (!tracker_) return no_tracking();
  tracker_->request_roadmap(index);
  return ApiResult::success(tracker_->segmentation_state()[plane]["roadmap"], 202);
}

std::string ImagingWorker::metrics() const {
  std::ostringstream out;
  auto quantile = [](std::array<double, kTimingWindow> values, std::size_t n, double q) {
    n = std::min(n, kTimingWindow);
    if (n == 0) return 0.0;
    auto end = values.begin() + static_cast<std::ptrdiff_t>(n);
    auto at = values.begin() + static_cast<std::ptrdiff_t>(
                                   std::min(n - 1, static_cast<std::size_t>(q * static_cast<double>(n))));
    std::nth_element(values.begin(), at, end);
    return *at;
  };
  out << "# HELP tendril_imaging_frames_total Frames published (rendered or received), by plane.\n"
         "# TYPE tendril_imaging_frames_total counter\n";
  for (const auto& p : planes_) {
    std::lock_guard lock(p->stats_mutex);
    out << "tendril_imaging_frames_total{view=\"" << sim::view_name(p->view) << "\"} " << p->frames << '\n';
  }
  out << "# HELP tendril_imaging_skipped_frames_total Exposures skipped because rendering fell behind fps.\n"
         "# TYPE tendril_imaging_skipped_frames_total counter\n";
  for (const auto& p : planes_) {
    std::lock_guard lock(p->stats_mutex);
    out << "tendril_imaging_skipped_frames_total{view=\"" << sim::view_name(p->view) << "\"} " << p->skipped
        << '\n';
  }
  out << "# HELP tendril_imaging_shape_errors_total Frames rendered without a backbone (shape unavailable).\n"
         "# TYPE tendril_imaging_shape_errors_total counter\n";
  for (const auto& p : planes_) {
    std::lock_guard lock(p->stats_mutex);
    out << "tendril_imaging_shape_errors_total{view=\"" << sim::view_name(p->view) << "\"} "
        << p->shape_errors << '\n';
  }
  out << "# HELP tendril_imaging_dropped_frames_total Frames a source could not deliver (unreadable, "
         "undecodable), by plane.\n"
         "# TYPE tendril_imaging_dropped_frames_total counter\n";
  for (const auto& p : planes_) {
    std::lock_guard lock(p->stats_mutex);
    out << "tendril_imaging_dropped_frames_total{view=\"" << sim::view_name(p->view) << "\"} " << p->dropped
        << '\n';
  }
  out << "# HELP tendril_imaging_stale_total Times a watched plane went without a frame for longer than "
         "stale_after_s.\n"
         "# TYPE tendril_imaging_stale_total counter\n";
  for (const auto& p : planes_) {
    std::lock_guard lock(p->stats_mutex);
    out << "tendril_imaging_stale_total{view=\"" << sim::view_name(p->view) << "\"} " << p->stale_episodes
        << '\n';
  }
  out << "# HELP tendril_imaging_jpeg_bytes Size of the last JPEG, by plane.\n"
         "# TYPE tendril_imaging_jpeg_bytes gauge\n";
  for (const auto& p : planes_) {
    std::lock_guard lock(p->stats_mutex);
    out << "tendril_imaging_jpeg_bytes{view=\"" << sim::view_name(p->view) << "\"} " << p->jpeg_bytes << '\n';
  }
  for (const auto& [name, help, field] :
       {std::tuple{"tendril_imaging_render_seconds", "Time to render one frame (projection, blur, noise)",
                   &Plane::render_s},
        std::tuple{"tendril_imaging_encode_seconds", "Time to JPEG-encode and serialise one frame",
                   &Plane::encode_s},
        std::tuple{"tendril_imaging_tracking_seconds",
                   "Time to segment one frame and step its tip filter (simulated planes with tracking)",
                   &Plane::track_s}}) {
    out << "# HELP " << name << ' ' << help << ", over the last " << kTimingWindow << " frames.\n# TYPE "
        << name << " summary\n";
    for (const auto& p : planes_) {
      std::lock_guard lock(p->stats_mutex);
      for (double q : {0.5, 0.95})
        out << name << "{view=\"" << sim::view_name(p->view) << "\",quantile=\"" << q << "\"} "
            << quantile((*p).*field, p->frames, q) << '\n';
    }
  }
  return out.str();
}

}  // namespace tendril::server
