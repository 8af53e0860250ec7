#include "tendril/server/image_tracking.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <numbers>

#include "tendril/server/config.hpp"

namespace tendril::server {

namespace perception = teleop::perception;

namespace {

constexpr double kCurvatureArcMm = 3.0;

std::uint64_t wall_now_ns() {
  return static_cast<std::uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                        std::chrono::system_clock::now().time_since_epoch())
                                        .count());
}  // the model's tangent turn is measured over its last 3 mm

// Appends [a, b] with one decimal (pixels) or three (mm).
void append_pair(std::string& out, double a, double b, int decimals) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "[%.*f,%.*f]", decimals, a, decimals, b);
  out += buf;
}
void append_vector(std::string& out, const std::optional<Eigen::Vector3d>& v) {
  if (!v) {
    out += "null";
    return;
  }
  char buf[96];
  std::snprintf(buf, sizeof buf, "[%.3f,%.3f,%.3f]", v->x(), v->y(), v->z());
  out += buf;
}
void append_number(std::string& out, std::optional<double> v) {
  if (!v || !std::isfinite(*v)) {
    out += "null";
    return;
  }
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3f", *v);
  out += buf;
}

// The closest point between two rays and their distance (how far the two views disagree).
std::optional<std::pair<Eigen::Vector3d, double>> closest_point(const sim::DetectorRay& a,
                                                                const sim::DetectorRay& b) {
  const Eigen::Vector3d w = a.origin - b.origin;
  const double d_ab = a.direction.dot(b.direction);
  const double denominator = 1.0 - d_ab * d_ab;    // directions are unit vectors
  if (!(denominator > 1e-9)) return std::nullopt;  // parallel rays meet nowhere
  const double ta = (d_ab * b.direction.dot(w) - a.direction.dot(w)) / denominator;
  const double tb = (b.direction.dot(w) - d_ab * a.direction.dot(w)) / denominator;
  const Eigen::Vector3d pa = a.origin + ta * a.direction;
  const Eigen::Vector3d pb = b.origin + tb * b.direction;
  return std::pair{Eigen::Vector3d(0.5 * (pa + pb)), (pa - pb).norm()};
}

}  // namespace

TrackingConfig parse_tracking_config(const nlohmann::json& tracking,
                                     const std::filesystem::path& server_file) {
  TrackingConfig c;
  if (tracking.is_null()) return c;
  const std::string file = server_file.string();
  const auto fail = [&](const std::string& key, const std::string& expected) {
    std::string got = tracking.contains(key) ? tracking.at(key).dump() : "nothing";
    if (got.size() > 60) got = got.substr(0, 57) + "...";
    throw ConfigError(file + ": imaging.tracking." + key + ": expected " + expected + ", got " + got);
  };
  if (!tracking.is_object())
    throw ConfigError(file + ": imaging.tracking: expected an object, got " + tracking.dump());
  for (const auto& item : tracking.items()) {
    const std::string& k = item.key();
    if (k != "enabled" && k != "disagreement_mm" && k != "disagreement_frames" && k != "noise" &&
        k != "segmentation" && k != "note") {
      std::string message = file;
      message += ": imaging.tracking.";
      message += k;
      message +=
          ": unknown key; expected enabled, disagreement_mm, disagreement_frames, noise, segmentation or "
          "note";
      throw ConfigError(message);
    }
  }
  if (tracking.contains("enabled")) {
    if (!tracking.at("enabled").is_boolean()) fail("enabled", "true or false");
    c.enabled = tracking.at("enabled").get<bool>();
  }
  if (tracking.contains("disagreement_mm")) {
    const auto& v = tracking.at("disagreement_mm");
    if (!v.is_number() || !std::isfinite(v.get<double>()) || v.get<double>() <= 0 || v.get<double>() > 100)
      fail("disagreement_mm", "a number above 0 and at most 100 (mm)");
    c.disagreement_mm = v.get<double>();
  }
  if (tracking.contains("disagreement_frames")) {
    const auto& v = tracking.at("disagreement_frames");
    if (!v.is_number_integer() || v.get<long>() < 1 || v.get<long>() > 1000)
      fail("disagreement_frames", "an integer from 1 to 1000");
    c.disagreement_frames = static_cast<int>(v.get<long>());
  }
  if (tracking.contains("noise")) {
    const auto& v = tracking.at("noise");
    if (v == "fine") {
      c.vessel_scale_noise = false;
    } else if (v == "vessel") {
      c.vessel_scale_noise = true;
    } else {
      fail("noise", "\"fine\" (Abah 2022, eq. 4.43) or \"vessel\" (eq. 4.44)");
    }
  }
  if (tracking.contains("segmentation")) {
    try {
      c.segmentation = perception::biplane_segmentation_parameters_from_json(tracking.at("segmentation"));
    } catch (const perception::SegmentationParameterError& e) {
      throw ConfigError(file + ": imaging.tracking.segmentation." + e.field() + ": " + e.what());
    }
  }
  return c;
}

struct BiplaneTipTracker::PlaneState {
  perception::FluoroscopySegmenter segmenter;
  perception::TipEkfState ekf;
  bool started = false;
  std::optional<Eigen::Vector2d> last_model_tip_mm;  // the model's tip in plane mm at the last frame
  PlaneTrack track;
};

BiplaneTipTracker::BiplaneTipTracker(const TrackingConfig& config,
                                     std::array<sim::SimulatedFluoroscope*, 2> planes, double period_s,
                                     TrackingWarning warn, std::array<bool, 2> simulated)
    : config_(config),
      planes_(planes),
      max_skew_ns_(static_cast<std::uint64_t>(1.5 * period_s * 1e9)),
      ekf_(config.vessel_scale_noise ? perception::TipEkfNoise::vessel_scale()
                                     : perception::TipEkfNoise::fine_scale()),
      warn_(std::move(warn)),
      simulated_(simulated) {
  for (int i = 0; i < 2; ++i) {
    state_[i] = std::make_unique<PlaneState>();
    state_[i]->segmenter.set_parameters(i == 0 ? config_.segmentation.ap : config_.segmentation.lateral);
    requests_[i].requested = requests_[i].applied = state_[i]->segmenter.parameters();
    if (!simulated_[i]) {
      requests_[i].roadmaps = 0;  // segments nothing ("no_roadmap") until one is taken from its frames
      continue;
    }
    // The empty-vessel roadmap: the plane's exposure without the catheter, noiseless (as an averaged
    // roadmap acquisition would be).
    auto& fluoroscope = *planes_[i];
    const auto roadmap = fluoroscope.render_noiseless({});
    state_[i]->segmenter.set_roadmap(
        perception::grey_image(roadmap, fluoroscope.width(), fluoroscope.height()));
  }
  const auto now = wall_now_ns();
  std::lock_guard lock(request_mutex_);
  for (auto& r : requests_) r.roadmap_ns = now;
  publish_segmentation(now);
}

BiplaneTipTracker::~BiplaneTipTracker() = default;

Eigen::Vector2d BiplaneTipTracker::to_plane_mm(int plane, const Eigen::Vector2d& px) const {
  const auto& g = planes_[plane]->options().geometry;
  const double mm_per_px = g.pixel_spacing_mm * g.sod_mm / g.sid_mm;  // at the isocentre's depth
  return {(px.x() - 0.5 * (g.width - 1)) * mm_per_px, (0.5 * (g.height - 1) - px.y()) * mm_per_px};
}

Eigen::Vector2d BiplaneTipTracker::to_pixels(int plane, const Eigen::Vector2d& mm) const {
  const auto& g = planes_[plane]->options().geometry;
  const double mm_per_px = g.pixel_spacing_mm * g.sod_mm / g.sid_mm;
  return {0.5 * (g.width - 1) + mm.x() / mm_per_px, 0.5 * (g.height - 1) - mm.y() / mm_per_px};
}

perception::FluoroscopySegmentationParameters BiplaneTipTracker::request_parameters(
    int plane, const nlohmann::json& changes) {
  std::lock_guard lock(request_mutex_);
  auto p = perception::segmentation_parameters_from_json(changes, requests_[plane].requested);
  // The parameters' own validator knows ranges, not this detector's size: an ROI that starts off the
  // frame would leave the plane with no picture to segment.
  const auto& g = planes_[plane]->options().geometry;
  if (p.roi.x >= g.width)
    throw perception::SegmentationParameterError("roi.x", "roi.x must lie inside the frame (0.." +
                                                              std::to_string(g.width - 1) + "), got " +
                                                              std::to_string(p.roi.x));
  if (p.roi.y >= g.height)
    throw perception::SegmentationParameterError("roi.y", "roi.y must lie inside the frame (0.." +
                                                              std::to_string(g.height - 1) + "), got " +
                                                              std::to_string(p.roi.y));
  requests_[plane].requested = p;
  return p;
}

void BiplaneTipTracker::request_roadmap(int plane) {
  std::lock_guard lock(request_mutex_);
  requests_[plane].roadmap_pending = true;
}

void BiplaneTipTracker::apply_requests(int plane, std::uint64_t now_ns,
                                       const perception::GreyImageView* frame) {
  std::optional<perception::FluoroscopySegmentationParameters> parameters;
  bool roadmap = false;
  {
    std::lock_guard lock(request_mutex_);
    auto& r = requests_[plane];
    if (!(r.requested == r.applied)) parameters = r.requested;
    roadmap = r.roadmap_pending;
    r.roadmap_pending = false;
  }
  if (!parameters && !roadmap) return;
  if (roadmap && !simulated_[plane] && frame == nullptr) {
    // A source plane's roadmap is one of its frames: still pending until the next one arrives.
    std::lock_guard lock(request_mutex_);
    requests_[plane].roadmap_pending = true;
    roadmap = false;
    if (!parameters) return;
  }
  auto& segmenter = state_[plane]->segmenter;
  std::string failure;
  try {
    if (parameters) segmenter.set_parameters(*parameters);
    if (roadmap && !simulated_[plane]) {
      segmenter.set_roadmap(*frame);
    } else if (roadmap) {
      auto& fluoroscope = *planes_[plane];
      const auto image = fluoroscope.render_noiseless({});
      segmenter.set_roadmap(perception::grey_image(image, fluoroscope.width(), fluoroscope.height()));
    }
  } catch (const perception::SegmentationParameterError& e) {
    failure = e.what();  // validated when asked; kept for the operator should the frame disagree
  }
  {
    std::lock_guard lock(request_mutex_);
    auto& r = requests_[plane];
    r.applied = segmenter.parameters();
    if (!failure.empty()) r.requested = r.applied;  // what could not be applied is not pending forever
    if (roadmap && failure.empty()) {
      ++r.roadmaps;
      r.roadmap_ns = now_ns;
    }
    publish_segmentation(now_ns);
  }
  if (!failure.empty() && warn_)
    warn_(safety::FaultCode::kExternal, std::string("imaging: segmentation change not applied: ") + failure);
}

nlohmann::json BiplaneTipTracker::segmentation_state() const {
  std::lock_guard lock(request_mutex_);
  nlohmann::json out = nlohmann::json::object();
  for (int i = 0; i < 2; ++i) {
    const auto& r = requests_[i];
    out[i == 0 ? "ap" : "lateral"] = {{"parameters", perception::to_json(r.requested)},
                                      {"applied", r.requested == r.applied},
                                      {"roadmap",
                                       {{"count", r.roadmaps},
                                        {"taken_unix_s", static_cast<double>(r.roadmap_ns) * 1e-9},
                                        {"pending", r.roadmap_pending}}}};
  }
  return out;
}

void BiplaneTipTracker::publish_segmentation(std::uint64_t time_ns) {
  nlohmann::json planes = nlohmann::json::object();
  for (int i = 0; i < 2; ++i) {
    const auto& r = requests_[i];
    planes[i == 0 ? "ap" : "lateral"] = {
        {"parameters", perception::to_json(r.applied)},
        {"roadmap",
         {{"count", r.roadmaps},
          {"taken", {{"sec", r.roadmap_ns / 1'000'000'000ULL}, {"nsec", r.roadmap_ns % 1'000'000'000ULL}}}}}};
  }
  const nlohmann::json message = {
      {"timestamp", {{"sec", time_ns / 1'000'000'000ULL}, {"nsec", time_ns % 1'000'000'000ULL}}},
      {"planes", std::move(planes)}};
  segmentation_message_ = std::make_shared<const std::string>(message.dump());
  ++segmentation_version_;
  segmentation_ns_ = std::max(segmentation_ns_, wall_now_ns());  // ready time, increasing (see fuse)
}

std::shared_ptr<const std::string> BiplaneTipTracker::latest_segmentation(std::uint64_t& version,
                                                                          std::uint64_t& time_ns) const {
  std::lock_guard lock(request_mutex_);
  version = segmentation_version_;
  time_ns = segmentation_ns_;
  return segmentation_message_;
}

std::string BiplaneTipTracker::segmentation_schema() {
  const nlohmann::json time = {
      {"type", "object"}, {"properties", {{"sec", {{"type", "integer"}}}, {"nsec", {{"type", "integer"}}}}}};
  const nlohmann::json plane = {
      {"type", "object"},
      {"properties",
       {{"parameters",
         {{"type", "object"},
          {"description",
           "the plane's segmentation parameters in effect (FluoroscopySegmentationParameters)"}}},
        {"roadmap",
         {{"type", "object"},
          {"properties",
           {{"count",
             {{"type", "integer"}, {"description", "roadmaps taken since the start, the first included"}}},
            {"taken", time}}}}}}}};
  return nlohmann::json{
      {"title", "tendril.SegmentationParameters"},
      {"description",
       "The bi-plane segmentation's parameters and empty-vessel roadmaps in effect, published whenever the "
       "imaging threads apply a change (so a recorded session keeps them)"},
      {"type", "object"},
      {"properties",
       {{"timestamp", time},
        {"planes", {{"type", "object"}, {"properties", {{"ap", plane}, {"lateral", plane}}}}}}}}
      .dump();
}

const PlaneTrack& BiplaneTipTracker::track(int plane, perception::GreyImageView frame,
                                           const std::vector<Eigen::Vector3d>& model_backbone,
                                           std::uint64_t capture_ns) {
  auto& s = *state_[plane];
  auto& t = s.track;
  const auto& seg = s.segmenter.segment(frame);
  t.capture_ns = capture_ns;
  t.found = seg.found;
  t.reason = seg.found ? std::string() : seg.message;
  t.quality = seg.quality;
  t.tip_px = seg.tip;
  t.backbone_px = seg.polyline;

  // The process prior from the model backbone projected onto this plane (plane mm).
  double ds = 0.0;
  double kappa = 0.0;
  if (model_backbone.size() >= 2) {
    std::vector<Eigen::Vector2d> projected;
    projected.reserve(model_backbone.size());
    for (const auto& p : model_backbone) {
      const auto d = planes_[plane]->project(p);
      if (d.in_front) projected.push_back(to_plane_mm(plane, {d.column, d.row}));
    }
    if (projected.size() >= 2) {
      const Eigen::Vector2d tip = projected.back();
      // The tangent at the tip, and the one kCurvatureArcMm back along the projected backbone.
      std::size_t k = projected.size() - 1;
      double arc = 0.0;
      while (k > 0 && arc < kCurvatureArcMm) {
        arc += (projected[k] - projected[k - 1]).norm();
        --k;
      }
      const Eigen::Vector2d end_dir = projected.back() - projected[projected.size() - 2];
      const Eigen::Vector2d back_dir = projected[std::min(k + 1, projected.size() - 1)] - projected[k];
      if (end_dir.norm() > 1e-9 && back_dir.norm() > 1e-9 && arc > 1e-6) {
        const double turn =
            std::atan2(back_dir.x() * end_dir.y() - back_dir.y() * end_dir.x(), back_dir.dot(end_dir));
        kappa = turn / arc;
        if (s.last_model_tip_mm) ds = (tip - *s.last_model_tip_mm).dot(end_dir.normalized());
      }
      s.last_model_tip_mm = tip;
    }
  }

  if (seg.found) {
    const Eigen::Vector2d z_mm = to_plane_mm(plane, seg.tip);
    const double heading = std::atan2(-seg.tip_direction.y(), seg.tip_direction.x());  // rows grow downwards
    const Eigen::Vector3d z(z_mm.x(), z_mm.y(), heading);
    if (!s.started) {
      s.ekf = ekf_.start_at(z);
      s.started = true;
    } else if (ekf_.step(s.ekf, ds, kappa, z) != perception::TipEkfStatus::ok) {
      s.ekf = ekf_.start_at(z);  // a state the filter cannot continue from: start again at the image
    }
  } else if (s.started) {
    (void)ekf_.predict(s.ekf, ds, kappa);  // no image of the tip: the estimate runs on the prior
  }
  t.filtered = s.started;
  if (s.started) {
    t.filtered_px = to_pixels(plane, s.ekf.pose.head<2>());
    t.heading_rad = s.ekf.pose.z();
  }
  fuse(plane, model_backbone, capture_ns);
  return t;
}

void BiplaneTipTracker::fuse(int plane, const std::vector<Eigen::Vector3d>& model_backbone,
                             std::uint64_t capture_ns) {
  std::string warning;
  std::optional<ImagedTip> evaluated;
  {
    std::lock_guard lock(fuse_mutex_);
    shared_[plane] = state_[plane]->track;
    const PlaneTrack& ap = shared_[0];
    const PlaneTrack& lateral = shared_[1];
    const bool in_step =
        ap.capture_ns > 0 && lateral.capture_ns > 0 &&
        (ap.capture_ns > lateral.capture_ns ? ap.capture_ns - lateral.capture_ns
                                            : lateral.capture_ns - ap.capture_ns) <= max_skew_ns_;
    std::optional<Eigen::Vector3d> raw_tip, filtered_tip, model_tip;
    std::optional<double> ray_gap, disagreement;
    if (!model_backbone.empty()) model_tip = model_backbone.back();
    if (in_step && ap.found && lateral.found) {
      if (auto p = closest_point(planes_[0]->ray(ap.tip_px.x(), ap.tip_px.y()),
                                 planes_[1]->ray(lateral.tip_px.x(), lateral.tip_px.y()))) {
        raw_tip = p->first;
        ray_gap = p->second;
      }
    }
    if (in_step && ap.filtered && lateral.filtered) {
      if (auto p = closest_point(planes_[0]->ray(ap.filtered_px.x(), ap.filtered_px.y()),
                                 planes_[1]->ray(lateral.filtered_px.x(), lateral.filtered_px.y())))
        filtered_tip = p->first;
    }
    if (raw_tip && model_tip) disagreement = (*raw_tip - *model_tip).norm();
    // One evaluation per pair of new frames (one from each plane), so that disagreement_frames counts
    // bi-plane exposures, not the planes' calls.
    ++updates_[plane];
    const bool fresh_pair = updates_[0] > evaluated_at_[0] && updates_[1] > evaluated_at_[1];
    if (fresh_pair) {
      evaluated_at_ = updates_;
      ImagedTip tip;
      // The raw triangulation of this exposure (see ImagedTip), and the filtered tip beside it.
      tip.found = raw_tip.has_value() && ap.found && lateral.found;
      if (raw_tip) tip.position = *raw_tip;
      tip.has_filtered = filtered_tip.has_value();
      if (filtered_tip) tip.filtered = *filtered_tip;
      tip.capture_ns = capture_ns;
      evaluated = tip;
    }
    if (fresh_pair && disagreement) {
      if (*disagreement > config_.disagreement_mm) {
        agreeing_ = 0;
        if (++disagreeing_ >= config_.disagreement_frames && !warned_) {
          warned_ = true;
          char buf[96];
          std::snprintf(buf, sizeof buf,
                        "imaging: the imaged tip is %.1f mm from the model's (bound %.1f mm)", *disagreement,
                        config_.disagreement_mm);
          warning = buf;
        }
      } else {
        disagreeing_ = 0;
        if (++agreeing_ >= config_.disagreement_frames && warned_) {
          warned_ = false;
          char buf[96];
          std::snprintf(buf, sizeof buf, "imaging: the imaged tip agrees with the model's again (%.1f mm)",
                        *disagreement);
          warning = buf;
        }
      }
    }
    // /imaging/tracking: both planes' latest results and the 3D tips.
    auto message = std::make_shared<std::string>();
    std::string& out = *message;
    out.reserve(1024);
    out += "{\"timestamp\":{\"sec\":";
    out += std::to_string(capture_ns / 1'000'000'000ULL);
    out += ",\"nsec\":";
    out += std::to_string(capture_ns % 1'000'000'000ULL);
    out += "},\"frame_id\":\"world\",\"planes\":{";
    for (int i = 0; i < 2; ++i) {
      const PlaneTrack& p = shared_[i];
      out += i == 0 ? "\"ap\":{" : ",\"lateral\":{";
      out += "\"found\":";
      out += p.found ? "true" : "false";
      out += ",\"reason\":";
      out += nlohmann::json(p.reason).dump();
      out += ",\"tip_px\":";
      if (p.found) {
        append_pair(out, p.tip_px.x(), p.tip_px.y(), 1);
      } else {
        out += "null";
      }
      out += ",\"filtered_px\":";
      if (p.filtered) {
        append_pair(out, p.filtered_px.x(), p.filtered_px.y(), 1);
      } else {
        out += "null";
      }
      out += ",\"heading_deg\":";
      append_number(
          out, p.filtered ? std::optional<double>(p.heading_rad * 180.0 / std::numbers::pi) : std::nullopt);
      out += ",\"quality\":";
      append_number(out, p.quality);
      out += "}";
    }
    out += "},\"tip_mm\":";
    append_vector(out, filtered_tip);
    out += ",\"raw_tip_mm\":";
    append_vector(out, raw_tip);
    out += ",\"model_tip_mm\":";
    append_vector(out, model_tip);
    out += ",\"disagreement_mm\":";
    append_number(out, disagreement);
    out += ",\"ray_gap_mm\":";
    append_number(out, ray_gap);
    out += ",\"disagreement_bound_mm\":";
    append_number(out, config_.disagreement_mm);
    out += "}";
    message_ = std::move(message);
    ++version_;
    // The log time is when the message is ready, never earlier than the last one's: the planes finish
    // in any order, so their capture times (inside the message) do not increase with each message, and
    // a recording read in log-time order would see the messages shuffled.
    message_ns_ = std::max(message_ns_, wall_now_ns());
  }
  // Not a stale sensor: the images and the model disagree, a cause reported from outside the loop.
  if (!warning.empty() && warn_) warn_(safety::FaultCode::kExternal, warning);
  if (evaluated && listener_) listener_(*evaluated);
}

std::shared_ptr<const std::string> BiplaneTipTracker::latest(std::uint64_t& version,
                                                             std::uint64_t& time_ns) const {
  std::lock_guard lock(fuse_mutex_);
  version = version_;
  time_ns = message_ns_;
  return message_;
}

std::string BiplaneTipTracker::schema() {
  const nlohmann::json point2 = {{"type", {"array", "null"}}, {"items", {{"type", "number"}}}};
  const nlohmann::json& point3 = point2;  // [x, y, z] or null: the same schema
  const nlohmann::json plane = {
      {"type", "object"},
      {"properties",
       {{"found", {{"type", "boolean"}}},
        {"reason", {{"type", "string"}, {"description", "why no instrument was found (empty when found)"}}},
        {"tip_px", point2},
        {"filtered_px", point2},
        {"heading_deg", {{"type", {"number", "null"}}}},
        {"quality", {{"type", {"number", "null"}}}}}}};
  return nlohmann::json{
      {"title", "tendril.TipTracking"},
      {"description",
       "The instrument tip in the images: per plane the segmented and EKF-filtered tip (pixels, row 0 at the "
       "top), and in 3D (world mm) the two planes' rays intersected, beside the model's tip"},
      {"type", "object"},
      {"properties",
       {{"frame_id", {{"type", "string"}}},
        {"planes", {{"type", "object"}, {"properties", {{"ap", plane}, {"lateral", plane}}}}},
        {"tip_mm", point3},
        {"raw_tip_mm", point3},
        {"model_tip_mm", point3},
        {"disagreement_mm", {{"type", {"number", "null"}}}},
        {"ray_gap_mm", {{"type", {"number", "null"}}}},
        {"disagreement_bound_mm", {{"type", "number"}}}}}}
      .dump();
}

}  // namespace tendril::server
