// BiplaneTipTracker: the catheter tip segmented in both simulated planes, filtered by the tip EKF and
// triangulated into 3D, against the backbone the frames were rendered from; the disagreement warning
// when the model's tip is elsewhere; and the tracking through ImagingWorker (/imaging/tracking, the
// image overlay's segmented backbone and tracked tip).
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <functional>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "tendril/drivers/sim/simulated_fluoroscope.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/image_tracking.hpp"
#include "tendril/server/imaging_worker.hpp"

namespace tendril::server {
namespace {

using nlohmann::json;
namespace perception = teleop::perception;

sim::FluoroscopeOptions options() {
  sim::FluoroscopeOptions o;
  o.geometry.width = 512;
  o.geometry.height = 512;
  o.geometry.pixel_spacing_mm = 160.0 / 512;
  o.geometry.isocentre = {0.0, 0.0, 60.0};
  return o;
}

// A catheter entering from below and bending in x and y: its tip lies off both planes' axes.
std::vector<Eigen::Vector3d> bent_catheter(double insertion_mm) {
  std::vector<Eigen::Vector3d> points;
  for (double s = 0; s <= 20.0 + insertion_mm; s += 0.5) {
    const double bend = std::max(0.0, s - 20.0);
    points.emplace_back(0.004 * bend * bend * bend / 3.0, -0.002 * bend * bend * bend / 3.0, 40.0 + s);
  }
  return points;
}

std::vector<Eigen::Vector3d> shifted(std::vector<Eigen::Vector3d> points, const Eigen::Vector3d& by) {
  for (auto& p : points) p += by;
  return points;
}

struct Captured {
  std::mutex mutex;
  std::vector<std::string> texts;
  TrackingWarning sink() {
    return [this](safety::FaultCode code, const std::string& text) {
      EXPECT_EQ(code, safety::FaultCode::kExternal) << "a disagreement, not a stale sensor";
      std::lock_guard lock(mutex);
      texts.push_back(text);
    };
  }
  int count(const std::string& words) {
    std::lock_guard lock(mutex);
    int n = 0;
    for (const auto& t : texts) n += t.find(words) != std::string::npos ? 1 : 0;
    return n;
  }
};

struct Rig {
  sim::SimulatedFluoroscope ap{sim::FluoroView::kAp, options()};
  sim::SimulatedFluoroscope lateral{sim::FluoroView::kLateral, options()};
  Captured warnings;
  BiplaneTipTracker tracker;
  std::uint64_t t = 1'000'000'000ULL;
  Rig() : tracker(TrackingConfig{}, {&ap, &lateral}, 1.0 / 15, warnings.sink()) {}
  // Renders both planes from `truth` and tracks them with `model` as the model's backbone.
  json frame(const std::vector<Eigen::Vector3d>& truth, const std::vector<Eigen::Vector3d>& model) {
    t += 66'000'000ULL;
    const auto a = ap.render(truth);
    tracker.track(0, perception::grey_image(a, ap.width(), ap.height()), model, t);
    const auto l = lateral.render(truth);
    tracker.track(1, perception::grey_image(l, lateral.width(), lateral.height()), model, t);
    std::uint64_t version = 0, time_ns = 0;
    return json::parse(*tracker.latest(version, time_ns));
  }
};

Eigen::Vector3d vec(const json& j) { return {j[0].get<double>(), j[1].get<double>(), j[2].get<double>()}; }

TEST(BiplaneTipTracker, TheTwoPlanesTriangulateTheRenderedTipAndTheFilterFollowsAnInsertion) {
  Rig rig;
  double worst_raw = 0, worst_filtered = 0;
  for (int i = 0; i <= 20; ++i) {
    const auto truth = bent_catheter(10.0 + 0.5 * i);  // inserting 0.5 mm per frame
    const json m = rig.frame(truth, truth);
    ASSERT_TRUE(m["planes"]["ap"]["found"].get<bool>()) << m.dump();
    ASSERT_TRUE(m["planes"]["lateral"]["found"].get<bool>()) << m.dump();
    ASSERT_FALSE(m["raw_tip_mm"].is_null()) << m.dump();
    worst_raw = std::max(worst_raw, (vec(m["raw_tip_mm"]) - truth.back()).norm());
    worst_filtered = std::max(worst_filtered, (vec(m["tip_mm"]) - truth.back()).norm());
    EXPECT_LT(m["ray_gap_mm"].get<double>(), 1.0) << "the two rays nearly meet";
    EXPECT_NEAR(m["disagreement_mm"].get<double>(), (vec(m["raw_tip_mm"]) - truth.back()).norm(), 1e-3);
  }
  std::cout << "tip error over 21 frames: raw ≤ " << worst_raw << " mm, filtered ≤ " << worst_filtered
            << " mm\n";
  // About a pixel at the isocentre is 0.23 mm; the tip marker and the blur make it ~1 px.
  EXPECT_LT(worst_raw, 1.0);
  EXPECT_LT(worst_filtered, 1.0);
  EXPECT_EQ(rig.warnings.count("imaging:"), 0) << "image and model agree";
}

TEST(BiplaneTipTracker, AModelTipAwayFromTheImagedOneWarnsAfterTheConfiguredFramesAndAgainWhenTheyAgree) {
  Rig rig;
  const auto truth = bent_catheter(20.0);
  const auto model = shifted(truth, {4.0, 0.0, 2.0});  // the plant is 4.5 mm from where the model says
  rig.frame(truth, model);
  rig.frame(truth, model);
  EXPECT_EQ(rig.warnings.count("imaged tip is"), 0) << "not before disagreement_frames (3) evaluations";
  const json m = rig.frame(truth, model);
  EXPECT_NEAR(m["disagreement_mm"].get<double>(), std::hypot(4.0, 2.0), 0.7) << m.dump();
  EXPECT_EQ(rig.warnings.count("imaged tip is"), 1);
  for (int i = 0; i < 5; ++i) rig.frame(truth, model);
  EXPECT_EQ(rig.warnings.count("imaged tip is"), 1) << "one warning per episode";
  for (int i = 0; i < 3; ++i) rig.frame(truth, truth);
  EXPECT_EQ(rig.warnings.count("agrees with the model's again"), 1);
}

TEST(BiplaneTipTracker, NoCatheterInAPlaneIsReportedWithTheReasonAndNoTriangulation) {
  Rig rig;
  const json m = rig.frame({}, bent_catheter(20.0));
  EXPECT_FALSE(m["planes"]["ap"]["found"].get<bool>());
  EXPECT_NE(m["planes"]["ap"]["reason"].get<std::string>(), "");
  EXPECT_TRUE(m["raw_tip_mm"].is_null());
  EXPECT_TRUE(m["disagreement_mm"].is_null());
  EXPECT_EQ(rig.warnings.count("imaging:"), 0) << "no image of the tip is not a disagreement";
}

TEST(TrackingConfig, MistakesNameTheKey) {
  const std::filesystem::path file = "/etc/tendril/server.json";
  EXPECT_TRUE(parse_tracking_config(nullptr, file).enabled);
  const auto c = parse_tracking_config({{"disagreement_mm", 5},
                                        {"disagreement_frames", 2},
                                        {"noise", "vessel"},
                                        {"segmentation", {{"ap", {{"threshold", 50}}}}}},
                                       file);
  EXPECT_EQ(c.disagreement_mm, 5.0);
  EXPECT_EQ(c.disagreement_frames, 2);
  EXPECT_TRUE(c.vessel_scale_noise);
  EXPECT_EQ(c.segmentation.ap.threshold, 50);
  const auto refuses = [&](const json& j, const std::string& words) {
    try {
      parse_tracking_config(j, file);
      ADD_FAILURE() << "accepted " << j.dump();
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
    }
  };
  refuses({{"disagreement_mm", 0}}, "imaging.tracking.disagreement_mm");
  refuses({{"disagreement_mm", std::nan("")}}, "imaging.tracking.disagreement_mm");
  refuses({{"disagreement_frames", 0}}, "imaging.tracking.disagreement_frames");
  refuses({{"noise", "loud"}}, "imaging.tracking.noise");
  refuses({{"segmentation", {{"ap", {{"threshold", 999}}}}}}, "imaging.tracking.segmentation.ap.threshold");
  refuses({{"rate", 1}}, "imaging.tracking.rate: unknown key");
}

TEST(ImagingWorkerTracking, ASubscriberOfTheTrackingMakesBothPlanesRenderAndTheOverlayCarriesTheTrackedTip) {
  auto config = parse_imaging_config(
      json{{"width", 512}, {"height", 512}, {"fps", 15}, {"vessel", false}, {"isocentre_mm", {0, 0, 60}}},
      "/nonexistent/server.json");
  ImagingWorker worker(
      [](std::vector<Eigen::Vector3d>& out) {
        out = bent_catheter(20.0);
        return true;
      },
      config);
  const auto topics = worker.topics();
  ASSERT_TRUE(std::any_of(topics.begin(), topics.end(),
                          [](const auto& t) { return t.topic == "/imaging/tracking"; }));
  worker.capture_once();
  EXPECT_FALSE(json::parse(*worker.latest("/imaging/ap", 0)->payload)["overlay"].contains("segmented"))
      << "no tracking while nobody watches it";
  worker.set_demand("/imaging/tracking", true);
  worker.capture_once();
  const json image = json::parse(*worker.latest("/imaging/ap", 0)->payload);
  ASSERT_TRUE(image["overlay"]["segmented"].is_array());
  EXPECT_GE(image["overlay"]["segmented"].size(), 10u);
  ASSERT_TRUE(image["overlay"]["tip"].is_array()) << image["overlay"].dump();

  worker.start();  // only the tracking is watched (since above)
  std::optional<TopicPayload> tracking;
  for (int i = 0; i < 500; ++i) {
    tracking = worker.latest("/imaging/tracking", 6);
    if (tracking) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ASSERT_TRUE(tracking) << "both planes rendered and were tracked";
  const json m = json::parse(*tracking->payload);
  EXPECT_LT((vec(m["raw_tip_mm"]) - bent_catheter(20.0).back()).norm(), 1.0) << m.dump();
  worker.set_demand("/imaging/tracking", false);
  worker.stop();
}

// A robot that closes a loop on the images (ImageFeedback, e.g. the catheter's image_guided mode): its
// demand makes the tracking run with nobody subscribed, it gets every bi-plane tip, and the simulated
// planes image its true shape (here 3 mm off the model's) while the tracker keeps the model's.
struct FakeFeedback final : ImageFeedback {
  std::function<void(bool)> demand;
  std::mutex mutex;
  std::vector<ImagedTip> tips;
  std::vector<Eigen::Vector3d> truth = shifted(bent_catheter(20.0), {3.0, 0.0, 0.0});
  void tracking_attached(std::function<void(bool)> d) override { demand = std::move(d); }
  void on_tip(const ImagedTip& tip) override {
    std::lock_guard lock(mutex);
    tips.push_back(tip);
  }
  bool imaged_backbone(std::vector<Eigen::Vector3d>& out) const override {
    out = truth;
    return true;
  }
  std::size_t count() {
    std::lock_guard lock(mutex);
    return tips.size();
  }
};

TEST(ImagingWorkerTracking, AnImageFeedbackDemandsTheTrackingGetsEveryTipAndHasItsTrueShapeImaged) {
  auto config = parse_imaging_config(
      json{{"width", 512}, {"height", 512}, {"fps", 15}, {"vessel", false}, {"isocentre_mm", {0, 0, 60}}},
      "/nonexistent/server.json");
  ImagingWorker worker(
      [](std::vector<Eigen::Vector3d>& out) {
        out = bent_catheter(20.0);
        return true;
      },
      config);
  FakeFeedback feedback;
  worker.set_image_feedback(&feedback);
  ASSERT_TRUE(feedback.demand) << "the imaging tells the robot that it tracks";
  worker.capture_once();
  EXPECT_EQ(feedback.count(), 0u) << "no tracking before the robot demands it";
  feedback.demand(true);
  for (int i = 0; i < 4; ++i) worker.capture_once();
  ASSERT_EQ(feedback.count(), 4u) << "one tip per bi-plane exposure";
  const ImagedTip last = feedback.tips.back();
  ASSERT_TRUE(last.found);
  EXPECT_LT((last.position - feedback.truth.back()).norm(), 1.0) << "the true catheter was imaged";
  EXPECT_GT((last.position - bent_catheter(20.0).back()).norm(), 2.0) << "not the model";
  // The overlay still draws the model's backbone.
  const json image = json::parse(*worker.latest("/imaging/ap", 0)->payload);
  ASSERT_FALSE(image["overlay"]["robot"].empty());
  feedback.demand(false);
  worker.capture_once();
  EXPECT_EQ(feedback.count(), 4u) << "the demand ended: no tracking";

  // The demand alone makes both simulated planes' threads run.
  feedback.demand(true);
  worker.start();
  for (int i = 0; i < 500 && feedback.count() < 6; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_GE(feedback.count(), 6u);
  feedback.demand(false);
  worker.stop();
}

// The segmentation editor (ImagingControl): a change is validated when asked (422 naming the field,
// nothing changed), recorded as pending, and applied by the plane's own capture at its next frame, then
// published on /imaging/segmentation; a roadmap likewise. capture_once() stands in for the plane threads.
TEST(ImagingWorkerSegmentation, ChangesAreValidatedWhenAskedAndAppliedAtThePlanesNextFrame) {
  auto config = parse_imaging_config(
      json{{"width", 512}, {"height", 512}, {"fps", 15}, {"vessel", false}, {"isocentre_mm", {0, 0, 60}}},
      "/nonexistent/server.json");
  config.robot = "srmc";
  ImagingWorker worker(
      [](std::vector<Eigen::Vector3d>& out) {
        out = bent_catheter(20.0);
        return true;
      },
      config);
  EXPECT_EQ(worker.imaged_robot(), "srmc");
  const auto topics = worker.topics();
  ASSERT_TRUE(std::any_of(topics.begin(), topics.end(), [](const auto& t) {
    return t.topic == "/imaging/segmentation" && t.schema_name == "tendril.SegmentationParameters";
  }));
  const auto first = worker.latest("/imaging/segmentation", 0);
  ASSERT_TRUE(first) << "the start-up parameters are published";
  const json start = json::parse(*first->payload);
  const int threshold = start["planes"]["ap"]["parameters"]["threshold"].get<int>();

  EXPECT_EQ(worker.set_segmentation("oblique", json{{"threshold", 40}}).status, 404);
  EXPECT_EQ(worker.set_segmentation("ap", json::array()).status, 400);
  for (const auto& [body, field] :
       std::vector<std::pair<json, std::string>>{{json{{"threshold", 0}}, "threshold"},
                                                 {json{{"roi", {{"x", 600}}}}, "roi.x"},
                                                 {json{{"canny_low", 500}, {"canny_high", 100}}, "canny_low"},
                                                 {json{{"nope", 1}}, "nope"}}) {
    const ApiResult r = worker.set_segmentation("ap", body);
    EXPECT_EQ(r.status, 422) << body.dump();
    EXPECT_EQ(r.error_details.value("field", ""), field) << body.dump() << ": " << r.message;
  }
  EXPECT_EQ(worker.segmentation().body["planes"]["ap"]["parameters"]["threshold"].get<int>(), threshold)
      << "refused changes change nothing";

  const ApiResult asked = worker.set_segmentation("ap", json{{"threshold", threshold + 5}});
  ASSERT_EQ(asked.status, 200) << asked.message;
  EXPECT_EQ(asked.body["parameters"]["threshold"].get<int>(), threshold + 5);
  EXPECT_FALSE(asked.body["applied"].get<bool>()) << "not before the plane's next frame";
  EXPECT_FALSE(worker.latest("/imaging/segmentation", first->version))
      << "nothing applied, nothing published";
  EXPECT_EQ(worker.take_roadmap("lateral").status, 202);
  EXPECT_TRUE(worker.segmentation().body["planes"]["lateral"]["roadmap"]["pending"].get<bool>());

  worker.capture_once();  // both planes' next frame
  const json state = worker.segmentation().body["planes"];
  EXPECT_TRUE(state["ap"]["applied"].get<bool>());
  EXPECT_EQ(state["ap"]["parameters"]["threshold"].get<int>(), threshold + 5);
  EXPECT_FALSE(state["lateral"]["roadmap"]["pending"].get<bool>());
  EXPECT_EQ(state["lateral"]["roadmap"]["count"].get<int>(), 2);
  EXPECT_EQ(state["ap"]["roadmap"]["count"].get<int>(), 1);
  const auto published = worker.latest("/imaging/segmentation", first->version);
  ASSERT_TRUE(published);
  const json m = json::parse(*published->payload);
  EXPECT_EQ(m["planes"]["ap"]["parameters"]["threshold"].get<int>(), threshold + 5);
  EXPECT_EQ(m["planes"]["lateral"]["roadmap"]["count"].get<int>(), 2);

  // Tracking still finds the catheter with the new threshold and against the new roadmap.
  worker.set_demand("/imaging/tracking", true);
  worker.capture_once();
  const json tracking = json::parse(*worker.latest("/imaging/tracking", 0)->payload);
  EXPECT_TRUE(tracking["planes"]["ap"]["found"].get<bool>()) << tracking.dump();
  EXPECT_TRUE(tracking["planes"]["lateral"]["found"].get<bool>()) << tracking.dump();
}

}  // namespace
}  // namespace tendril::server
