// The us_arm's ultrasound topics (server/src/robots/serial_arm/ultrasound_topics.*): a probe state
// stream over a straight phantom artery, stepped by hand (own_thread = false), and the published JSON
// decoded: the PNG image, the ellipse annotation in the image's pixels, the SceneUpdate's entities in
// the tissue frame with their counts, the /tf chain; a refused probe state, images only while watched,
// and the worker thread on its own.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <mutex>
#include <nlohmann/json.hpp>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "serial_arm/ultrasound_probe_state.hpp"
#include "serial_arm/ultrasound_topics.hpp"

namespace tendril::server {
namespace {

using Eigen::Isometry3d;
using Eigen::Vector3d;
using nlohmann::json;
namespace us = tendril::ultrasound;

constexpr double kDepth = 30.0;  // mm: the artery's axis under the flat skin (y = 0 in {P})

// {P}: y up, the artery along x at y = −30 mm, radius 5 mm.
us::ReconstructionSessionConfig phantom() {
  us::ReconstructionSessionConfig c;
  for (double x = -300.0; x <= 150.0; x += 1.0) {
    c.artery.points.emplace_back(x, -kDepth, 0.0);
    c.artery.radii.push_back(5.0);
  }
  // The catheter runs 4.3 mm off the axis (0.7 mm from the wall): in contact wherever the mesh is. Its
  // 32 gratings, 270/31 mm apart from x = −215 mm, end at x = 55 mm: 7 of them (x ≈ 2.8 … 55 mm) lie
  // along the reconstructed stretch (x 0–60 mm).
  for (double x = -215.0; x <= 70.0; x += 0.5) c.catheter_path.emplace_back(x, -kDepth - 4.3, 0.0);
  c.errors.enabled = false;  // exact mapping: the expectations below are geometric
  return c;
}

us::SweepPlan plan() {
  us::SweepPlan p;
  for (double x = 0.0; x <= 60.0; x += 10.0) p.centroids.emplace_back(x, -kDepth, 0.0);
  for (double x = -10.0; x <= 70.0; x += 2.0)
    for (double z = -20.0; z <= 20.0; z += 2.0) p.surface.emplace_back(x, 0.0, z);
  p.via_points = us::probe_via_points(p.surface, p.centroids);
  return p;
}

Isometry3d limb_pose() {
  Isometry3d p = Isometry3d::Identity();
  p.linear() = Eigen::AngleAxisd(0.4, Vector3d::UnitZ()).toRotationMatrix();
  p.translation() = Vector3d(350.0, -120.0, 40.0);
  return p;
}

Isometry3d base_pose() {
  Isometry3d p = Isometry3d::Identity();
  p.translation() = Vector3d(0.0, 0.0, 100.0);
  return p;
}

// The first bytes of a base64 text (enough for the PNG signature and IHDR).
std::vector<unsigned char> base64_prefix(const std::string& text, std::size_t bytes) {
  static const std::string alphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::vector<unsigned char> out;
  unsigned int buffer = 0;
  int bits = 0;
  for (char ch : text) {
    const auto v = alphabet.find(ch);
    if (v == std::string::npos) break;
    buffer = (buffer << 6) | static_cast<unsigned int>(v);
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      out.push_back(static_cast<unsigned char>((buffer >> bits) & 0xFF));
      if (out.size() == bytes) break;
    }
  }
  return out;
}

// What SerialArm::probe_state() hands out, set by the test (a mutex: the worker thread reads it in one test).
struct StateSource {
  mutable std::mutex mutex;
  std::optional<UltrasoundProbeState> state;
  void publish(const UltrasoundProbeState& s) {
    std::lock_guard lock(mutex);
    state = s;
  }
  std::optional<UltrasoundProbeState> latest() const {
    std::lock_guard lock(mutex);
    return state;
  }
};

struct Rig {
  StateSource slot;
  std::unique_ptr<UltrasoundTopics> topics;
  std::uint64_t now = 1'000'000'000ULL;

  explicit Rig(bool own_thread = false) {
    UltrasoundTopicsSettings settings;
    settings.world_T_base = base_pose();
    settings.own_thread = own_thread;
    topics = std::make_unique<UltrasoundTopics>(phantom(), settings, [this] { return slot.latest(); });
  }
  void at_via_point(std::size_t i, bool acquiring) {
    UltrasoundProbeState s;
    s.t = static_cast<double>(now) * 1e-9;
    s.world_T_limb = limb_pose();
    s.world_T_limb_true = limb_pose();
    s.world_T_probe = limb_pose() * plan().via_points[i].pose();
    s.in_contact = true;
    s.acquiring = acquiring;
    s.via_point = static_cast<int>(i);
    slot.publish(s);
  }
  void step() {
    now += 100'000'000ULL;  // 10 Hz of test time
    topics->step(now);
  }
  std::optional<json> message(const std::string& topic, std::uint64_t since = 0) const {
    const auto p = topics->latest(topic, since);
    if (!p) return std::nullopt;
    return json::parse(*p->payload);
  }
};

const json& entity(const json& scene, const std::string& id) {
  for (const auto& e : scene.at("entities"))
    if (e.at("id") == id) return e;
  throw std::runtime_error("no entity " + id);
}

TEST(UltrasoundTopics, AdvertisesItsFourTopics) {
  Rig rig;
  std::set<std::string> names;
  for (const auto& t : rig.topics->topics()) {
    names.insert(t.topic + " " + t.schema_name);
    EXPECT_EQ(t.encoding, "json");
    EXPECT_NO_THROW((void)json::parse(t.schema)) << t.topic;
  }
  EXPECT_EQ(names, (std::set<std::string>{"/us_arm/ultrasound/image foxglove.CompressedImage",
                                          "/us_arm/ultrasound/annotations foxglove.ImageAnnotations",
                                          "/us_arm/reconstruction foxglove.SceneUpdate",
                                          "/tf foxglove.FrameTransforms"}));
  // Nothing before a probe state exists.
  rig.step();
  for (const auto& t : rig.topics->topics()) EXPECT_FALSE(rig.topics->latest(t.topic, 0)) << t.topic;
}

TEST(UltrasoundTopics, ImageAndEllipseAnnotationOfTheSlice) {
  Rig rig;
  rig.topics->set_plan(plan());
  rig.topics->set_demand("/us_arm/ultrasound/image", true);
  rig.topics->set_demand("/us_arm/ultrasound/annotations", true);
  rig.at_via_point(2, false);
  const auto t0 = std::chrono::steady_clock::now();
  rig.step();
  const double step_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  const auto image = rig.message("/us_arm/ultrasound/image");
  ASSERT_TRUE(image);
  std::printf("one worker step with an image: %.1f ms (render, EKF, PNG, JSON); image message %zu bytes\n",
              step_ms, rig.topics->latest("/us_arm/ultrasound/image", 0)->payload->size());
  EXPECT_EQ(image->at("format"), "png");
  EXPECT_EQ(image->at("frame_id"), "us_arm_image");
  EXPECT_EQ(image->at("simulated"), true);
  EXPECT_DOUBLE_EQ(image->at("pixel_size_mm").get<double>(), 0.125);
  const auto png = base64_prefix(image->at("data").get<std::string>(), 24);
  ASSERT_EQ(png.size(), 24u);
  EXPECT_EQ(png[1], 'P');
  EXPECT_EQ(png[2], 'N');
  EXPECT_EQ(png[3], 'G');
  EXPECT_EQ((png[16] << 24) | (png[17] << 16) | (png[18] << 8) | png[19], 320);  // IHDR width
  EXPECT_EQ((png[20] << 24) | (png[21] << 16) | (png[22] << 8) | png[23], 400);  // IHDR height

  const auto notes = rig.message("/us_arm/ultrasound/annotations");
  ASSERT_TRUE(notes);
  ASSERT_EQ(notes->at("points").size(), 2u);
  const json& loop = notes->at("points")[0];
  EXPECT_EQ(loop.at("type"), 2);  // LINE_LOOP
  ASSERT_EQ(loop.at("points").size(), 30u);
  // The artery's axis is 30 mm under the skin, the image plane 0.5 mm under the probe face: its centre
  // is at column 159.5 + 0.5, row 29.5 / 0.125 + 0.5 = 236.5; the lumen 10 mm = 80 px across.
  const json& centre = notes->at("points")[1].at("points")[0];
  EXPECT_NEAR(centre.at("x").get<double>(), 160.0, 4.0);
  EXPECT_NEAR(centre.at("y").get<double>(), 236.5, 4.0);
  double min_x = 1e9, max_x = -1e9;
  for (const auto& p : loop.at("points")) {
    min_x = std::min(min_x, p.at("x").get<double>());
    max_x = std::max(max_x, p.at("x").get<double>());
  }
  EXPECT_NEAR(max_x - min_x, 80.0, 6.0);
  EXPECT_NE(notes->at("texts")[0].at("text").get<std::string>().find("ellipse"), std::string::npos);
  EXPECT_EQ(rig.topics->slices(), 0u);  // not acquiring: nothing stored
}

TEST(UltrasoundTopics, SceneInTheTissueFrameWithSlicesMeshCatheterAndContacts) {
  Rig rig;
  rig.topics->set_plan(plan());
  rig.topics->set_demand("/us_arm/reconstruction", true);
  // Acquisitions are made even though nobody watches the image.
  for (std::size_t i = 0; i < plan().via_points.size(); ++i) {
    rig.at_via_point(i, true);
    rig.step();
    rig.step();  // the gate still open: no second slice
  }
  EXPECT_EQ(rig.topics->slices(), 7u);
  EXPECT_FALSE(rig.topics->latest("/us_arm/ultrasound/image", 0));
  const auto scene = rig.message("/us_arm/reconstruction");
  ASSERT_TRUE(scene);
  std::printf("scene message %zu bytes (7 slices, 600 surface points)\n",
              rig.topics->latest("/us_arm/reconstruction", 0)->payload->size());
  std::set<std::string> ids;
  for (const auto& e : scene->at("entities")) {
    ids.insert(e.at("id").get<std::string>());
    EXPECT_EQ(e.at("frame_id"), "tissue");
  }
  EXPECT_EQ(ids, (std::set<std::string>{"surface", "ct_centerline", "via_points", "probe", "contours",
                                        "artery_mesh", "catheter", "contacts", "curvature_warnings"}));
  EXPECT_EQ(entity(*scene, "ct_centerline").at("lines")[0].at("points").size(), 7u);
  const json& via = entity(*scene, "via_points").at("lines");
  ASSERT_EQ(via.size(), 3u);
  EXPECT_EQ(via[0].at("points").size(), 14u);  // 7 via-points × 2 ends
  EXPECT_EQ(via[0].at("type"), 2);
  EXPECT_LE(entity(*scene, "surface").at("spheres").size(), 600u);
  EXPECT_GT(entity(*scene, "surface").at("spheres").size(), 300u);
  const json& contours = entity(*scene, "contours").at("lines");
  ASSERT_EQ(contours.size(), 7u);
  for (const auto& c : contours) {
    EXPECT_EQ(c.at("type"), 1);
    ASSERT_EQ(c.at("points").size(), 30u);
    // In {P}: each contour point 5 mm from the axis (y = −30, z = 0), within the segmentation's error.
    for (const auto& p : c.at("points")) {
      const double r = std::hypot(p.at("y").get<double>() + kDepth, p.at("z").get<double>());
      EXPECT_NEAR(r, 5.0, 0.5);
    }
  }
  const json& mesh = entity(*scene, "artery_mesh").at("triangles");
  ASSERT_EQ(mesh.size(), 1u);
  EXPECT_EQ(mesh[0].at("points").size(), 7u * 30u);
  EXPECT_EQ(mesh[0].at("indices").size(), 6u * 30u * 2u * 3u);
  ASSERT_EQ(entity(*scene, "catheter").at("lines").size(), 1u);
  EXPECT_EQ(entity(*scene, "catheter").at("lines")[0].at("points").size(), 32u);
  // The catheter is 0.7 mm from the wall along the reconstructed stretch: exactly those 7 gratings.
  const json& contacts = entity(*scene, "contacts").at("spheres");
  EXPECT_EQ(contacts.size(), 7u);
  for (const auto& s : contacts) {
    const double x = s.at("pose").at("position").at("x").get<double>();
    EXPECT_GE(x, -1.0);
    EXPECT_LE(x, 61.0);
  }
  EXPECT_TRUE(entity(*scene, "curvature_warnings").at("texts").empty());  // a straight catheter
  // The probe sits on the last via-point: its origin in {P} is that via-point's surface point.
  const json& probe_x = entity(*scene, "probe").at("lines")[0].at("points")[0];
  EXPECT_NEAR(probe_x.at("x").get<double>(), plan().via_points.back().surface_point.x(), 0.01);
  EXPECT_NEAR(probe_x.at("y").get<double>(), plan().via_points.back().surface_point.y(), 0.01);
}

TEST(UltrasoundTopics, FrameTransformsChain) {
  Rig rig;
  rig.at_via_point(0, false);
  rig.step();
  const auto tf = rig.message("/tf");
  ASSERT_TRUE(tf);
  std::set<std::string> edges;
  for (const auto& t : tf->at("transforms"))
    edges.insert(t.at("parent_frame_id").get<std::string>() + ">" +
                 t.at("child_frame_id").get<std::string>());
  EXPECT_EQ(edges, (std::set<std::string>{"world>us_arm_base", "us_arm_base>us_arm_probe", "world>tissue",
                                          "us_arm_probe>us_arm_image", "world>fbg"}));
  for (const auto& t : tf->at("transforms")) {
    const json& p = t.at("translation");
    const Vector3d v(p.at("x"), p.at("y"), p.at("z"));
    if (t.at("child_frame_id") == "tissue") EXPECT_LT((v - limb_pose().translation()).norm(), 1e-9);
    if (t.at("child_frame_id") == "us_arm_probe") {
      const Isometry3d expected = base_pose().inverse() * limb_pose() * plan().via_points[0].pose();
      EXPECT_LT((v - expected.translation()).norm(), 1e-9);
    }
    if (t.at("child_frame_id") == "us_arm_image") EXPECT_NEAR(v.z(), 0.5, 1e-12);
  }
}

TEST(UltrasoundTopics, RefusesABadProbeStateAndKeepsTheSlices) {
  Rig rig;
  rig.topics->set_plan(plan());
  rig.at_via_point(0, true);
  rig.step();
  rig.at_via_point(1, true);
  rig.step();
  ASSERT_EQ(rig.topics->slices(), 2u);
  const auto tf_before = rig.topics->latest("/tf", 0);
  ASSERT_TRUE(tf_before);
  UltrasoundProbeState bad;
  bad.world_T_limb = limb_pose();
  bad.world_T_limb_true = limb_pose();
  bad.world_T_probe = limb_pose() * plan().via_points[2].pose();
  bad.world_T_probe.translation().y() = std::numeric_limits<double>::quiet_NaN();
  bad.in_contact = true;
  bad.acquiring = true;
  bad.via_point = 2;
  rig.slot.publish(bad);
  EXPECT_NO_THROW(rig.step());
  EXPECT_EQ(rig.topics->slices(), 2u);
  EXPECT_NE(rig.topics->last_message().find("not finite"), std::string::npos) << rig.topics->last_message();
  EXPECT_NE(rig.topics->metrics().find("tendril_ultrasound_refusals_total{robot=\"us_arm\"} 1"),
            std::string::npos)
      << rig.topics->metrics();
  EXPECT_FALSE(rig.topics->latest("/tf", tf_before->version));  // no /tf from a bad pose
  // A plan the session would refuse is refused on the caller's thread.
  us::SweepPlan broken = plan();
  broken.centroids.pop_back();
  EXPECT_THROW(rig.topics->set_plan(broken), us::PlanningInputError);
  // The next good state goes on.
  rig.at_via_point(2, true);
  rig.step();
  EXPECT_EQ(rig.topics->slices(), 3u);
  // reset() (a new sweep) forgets them at the next step.
  rig.topics->reset();
  rig.at_via_point(3, false);
  rig.step();
  rig.topics->set_demand("/us_arm/reconstruction", true);
  rig.step();
  EXPECT_TRUE(entity(*rig.message("/us_arm/reconstruction"), "contours").at("lines").empty());
}

// An acquisition shorter than a worker step is not lost: the poller latched it, the next step stores it.
TEST(UltrasoundTopics, AcquisitionLatchedBetweenStepsIsStored) {
  Rig rig;
  rig.topics->set_plan(plan());
  rig.at_via_point(4, true);
  rig.topics->poll_once();     // the poller sees the gate open…
  rig.at_via_point(5, false);  // …and it closed again before the worker's next step
  rig.topics->poll_once();
  rig.step();
  EXPECT_EQ(rig.topics->slices(), 1u);
  rig.topics->set_demand("/us_arm/reconstruction", true);
  rig.step();
  const auto scene = rig.message("/us_arm/reconstruction");
  ASSERT_TRUE(scene);
  ASSERT_EQ(entity(*scene, "contours").at("lines").size(), 1u);
  // The stored contour is at via-point 4's centroid (x = 40 mm), not at via-point 5's.
  double x = 0.0;
  for (const auto& p : entity(*scene, "contours").at("lines")[0].at("points"))
    x += p.at("x").get<double>() / 30.0;
  EXPECT_NEAR(x, 40.0, 1.0);
}

TEST(UltrasoundTopics, ImagesOnlyWhileWatched) {
  Rig rig;
  rig.at_via_point(0, false);
  rig.step();
  EXPECT_FALSE(rig.topics->latest("/us_arm/ultrasound/image", 0));
  EXPECT_FALSE(rig.topics->latest("/us_arm/ultrasound/annotations", 0));
  rig.topics->set_demand("/us_arm/ultrasound/image", true);
  rig.step();
  const auto first = rig.topics->latest("/us_arm/ultrasound/image", 0);
  ASSERT_TRUE(first);
  rig.topics->set_demand("/us_arm/ultrasound/image", false);
  rig.step();
  EXPECT_FALSE(rig.topics->latest("/us_arm/ultrasound/image", first->version));
}

TEST(UltrasoundTopics, RefusesABadSetUp) {
  UltrasoundTopicsSettings slow;
  slow.image_hz = 0.0;
  slow.own_thread = false;
  EXPECT_THROW(UltrasoundTopics(phantom(), slow, [] { return std::optional<UltrasoundProbeState>(); }),
               std::invalid_argument);
  UltrasoundTopicsSettings fine;
  fine.own_thread = false;
  EXPECT_THROW(UltrasoundTopics(phantom(), fine, nullptr), std::invalid_argument);
  us::ReconstructionSessionConfig short_catheter = phantom();
  short_catheter.catheter_path.resize(20);
  EXPECT_THROW(UltrasoundTopics(short_catheter, fine, [] { return std::optional<UltrasoundProbeState>(); }),
               us::UltrasoundSetupError);
}

TEST(UltrasoundTopics, WorkerThreadPublishesAndStops) {
  Rig rig(true);
  std::atomic<int> ready{0};
  rig.topics->set_ready_callback([&ready] { ready.fetch_add(1); });
  rig.at_via_point(0, false);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (!rig.topics->latest("/tf", 0) && std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  EXPECT_TRUE(rig.topics->latest("/tf", 0));
  EXPECT_GT(ready.load(), 0);
  rig.topics->set_ready_callback(nullptr);
  rig.topics.reset();  // joins the worker
}

}  // namespace
}  // namespace tendril::server
