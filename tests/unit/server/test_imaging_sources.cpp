// The image sources a lab has (imaging::open_video_capture, imaging::open_image_files) and the
// ImagingWorker fed by them: frames replayed at their rate and brought to the detector size, and the
// watchdog's warnings for stale, dropped and ended images. No V4L2 device exists on the test machines:
// the device path is covered by its refusal; video files go through the same VideoCapture code.
#include <gtest/gtest.h>

#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <functional>
#include <mutex>
#include <span>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "tendril/drivers/imaging/image_source.hpp"
#include "tendril/drivers/sim/simulated_fluoroscope.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/imaging_worker.hpp"

namespace tendril::server {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

struct TempDir {
  fs::path path;
  TempDir() {
    path = fs::temp_directory_path() /
           ("tendril-imaging-sources-" + std::to_string(::getpid()) + "-" + std::to_string(counter()++));
    fs::create_directories(path);
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
  static int& counter() {
    static int n = 0;
    return n;
  }
};

// A frame whose mean brightness encodes its index, so that order and identity survive JPEG/resizing.
cv::Mat numbered_frame(int index, int width, int height) {
  cv::Mat m(height, width, CV_8UC1, cv::Scalar(20 + 40 * index));
  cv::rectangle(m, {width / 4, height / 4}, {width / 2, height / 2}, cv::Scalar(255), cv::FILLED);
  return m;
}

double mean_of(const imaging::GreyImage& image) {
  const cv::Mat m(image.height, image.width, CV_8UC1, const_cast<std::uint8_t*>(image.pixels.data()));
  return cv::mean(m)[0];
}

TEST(ImageFiles, ReplaysAFolderInNameOrderAtTheDetectorSizeAndLoops) {
  TempDir dir;
  // Written out of order, one of them 16-bit, one in colour: all come out 8-bit grey, in name order.
  cv::imwrite((dir.path / "frame_002.png").string(), numbered_frame(2, 64, 48));
  cv::Mat sixteen;
  numbered_frame(0, 64, 48).convertTo(sixteen, CV_16U, 257.0);
  cv::imwrite((dir.path / "frame_000.png").string(), sixteen);
  cv::Mat colour;
  cv::cvtColor(numbered_frame(1, 64, 48), colour, cv::COLOR_GRAY2BGR);
  cv::imwrite((dir.path / "frame_001.png").string(), colour);
  std::ofstream(dir.path / "notes.txt") << "not an image";

  auto source = imaging::open_image_files({dir.path, 200.0, true, 32, 24});
  EXPECT_NE(source->description().find("(3)"), std::string::npos) << source->description();
  EXPECT_DOUBLE_EQ(source->frame_period_s(), 1.0 / 200.0);
  imaging::GreyImage image;
  std::vector<double> means;
  for (int i = 0; i < 4; ++i) {
    const auto r = source->grab(image);
    ASSERT_EQ(r.status, imaging::GrabStatus::kFrame) << r.reason;
    EXPECT_EQ(image.width, 32);
    EXPECT_EQ(image.height, 24);
    EXPECT_EQ(image.pixels.size(), 32u * 24u);
    means.push_back(mean_of(image));
  }
  EXPECT_LT(means[0], means[1]);
  EXPECT_LT(means[1], means[2]);
  EXPECT_NEAR(means[3], means[0], 1.0) << "the fourth frame is the first again (loop)";
}

TEST(ImageFiles, WithoutLoopTheReplayEndsAndBadFilesAreDroppedWithTheirName) {
  TempDir dir;
  cv::imwrite((dir.path / "a.png").string(), numbered_frame(0, 16, 16));
  std::ofstream(dir.path / "b.png") << "this is not a PNG";
  auto source = imaging::open_image_files({dir.path, 500.0, false, 0, 0});
  imaging::GreyImage image;
  auto r = source->grab(image);
  ASSERT_EQ(r.status, imaging::GrabStatus::kFrame);
  EXPECT_EQ(image.width, 16) << "0 × 0 keeps the file's own size";
  r = source->grab(image);
  EXPECT_EQ(r.status, imaging::GrabStatus::kDropped);
  EXPECT_NE(r.reason.find("b.png"), std::string::npos) << r.reason;
  r = source->grab(image);
  EXPECT_EQ(r.status, imaging::GrabStatus::kEnded);
  EXPECT_NE(r.reason.find("end of the replay"), std::string::npos) << r.reason;
}

TEST(ImageFiles, RefusesWhatCannotBeReplayedNamingThePath) {
  TempDir dir;
  const auto refuses = [](const imaging::ImageFilesOptions& o, const std::string& words) {
    try {
      imaging::open_image_files(o);
      ADD_FAILURE() << "accepted " << o.path;
    } catch (const imaging::ImageSourceError& e) {
      EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(o.path.string()), std::string::npos) << e.what();
    }
  };
  refuses({dir.path, 10.0, true, 0, 0}, "no image file");
  refuses({dir.path / "missing", 10.0, true, 0, 0}, "no such file or folder");
  cv::imwrite((dir.path / "a.png").string(), numbered_frame(0, 16, 16));
  refuses({dir.path, 0.0, true, 0, 0}, "fps");
  refuses({dir.path, std::nan(""), true, 0, 0}, "fps");
  refuses({dir.path, 10.0, true, 32, 0}, "both width and height");
  refuses({dir.path, 10.0, true, -1, -1}, "output size");
}

TEST(ImageFiles, CancelEndsAWaitForASlowReplaysNextFrame) {
  TempDir dir;
  cv::imwrite((dir.path / "a.png").string(), numbered_frame(0, 16, 16));
  auto source = imaging::open_image_files({dir.path, 0.001, true, 0, 0});  // one frame every 1000 s
  imaging::GreyImage image;
  ASSERT_EQ(source->grab(image).status, imaging::GrabStatus::kFrame) << "the first frame comes at once";
  imaging::GrabResult second;
  std::thread reader([&] { second = source->grab(image); });  // waits for the next one, 1000 s away
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  source->cancel();
  reader.join();  // without the cancel this would wait 1000 s (the test's timeout fails it first)
  EXPECT_EQ(second.status, imaging::GrabStatus::kEnded);
  EXPECT_EQ(second.reason, "stopped");
  EXPECT_EQ(source->grab(image).status, imaging::GrabStatus::kEnded) << "and at once afterwards";
}

TEST(VideoCapture, ReplaysAVideoFileAtItsOwnRateAndAMissingDeviceIsRefused) {
  TempDir dir;
  const auto file = dir.path / "run.avi";
  {
    cv::VideoWriter writer(file.string(), cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), 50.0, {64, 48}, false);
    ASSERT_TRUE(writer.isOpened()) << "OpenCV's built-in MJPEG writer";
    for (int i = 0; i < 3; ++i) writer.write(numbered_frame(i, 64, 48));
  }
  auto source = imaging::open_video_capture({file, true, 0.0, 32, 24});
  EXPECT_NEAR(source->frame_period_s(), 1.0 / 50.0, 1e-6) << "the file's own rate";
  imaging::GreyImage image;
  std::vector<double> means;
  for (int i = 0; i < 4; ++i) {
    const auto r = source->grab(image);
    ASSERT_EQ(r.status, imaging::GrabStatus::kFrame) << r.reason;
    EXPECT_EQ(image.width, 32);
    means.push_back(mean_of(image));
  }
  EXPECT_LT(means[0], means[1]);
  EXPECT_LT(means[1], means[2]);
  EXPECT_NEAR(means[3], means[0], 2.0) << "looped";

  auto once = imaging::open_video_capture({file, false, 500.0, 0, 0});
  for (int i = 0; i < 3; ++i) ASSERT_EQ(once->grab(image).status, imaging::GrabStatus::kFrame);
  EXPECT_EQ(once->grab(image).status, imaging::GrabStatus::kEnded);

  try {
    imaging::open_video_capture({"/dev/video-tendril-none", true, 0.0, 0, 0});
    ADD_FAILURE() << "a missing device was opened";
  } catch (const imaging::ImageSourceError& e) {
    EXPECT_NE(std::string(e.what()).find("/dev/video-tendril-none"), std::string::npos) << e.what();
  }
  EXPECT_THROW(imaging::open_video_capture({dir.path / "none.avi", true, 0.0, 0, 0}),
               imaging::ImageSourceError);
}

// ---- ImagingWorker with sources --------------------------------------------------------------

struct Warnings {
  std::mutex mutex;
  std::vector<std::string> texts;
  ImagingWarningSink sink() {
    return [this](safety::FaultCode code, const std::string& text) {
      EXPECT_EQ(code, safety::FaultCode::kSensorStale);
      std::lock_guard lock(mutex);
      texts.push_back(text);
    };
  }
  bool any(const std::string& words) {
    std::lock_guard lock(mutex);
    for (const auto& t : texts)
      if (t.find(words) != std::string::npos) return true;
    return false;
  }
  // Polls up to 10 s (a count of polls, not a timing assertion).
  bool wait_for(const std::string& words) {
    for (int i = 0; i < 500; ++i) {
      if (any(words)) return true;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return false;
  }
};

BackboneReader straight_catheter() {
  return [](std::vector<Eigen::Vector3d>& out) {
    for (int i = 0; i <= 20; ++i) out.emplace_back(0.0, 0.0, 40.0 + i);
    return true;
  };
}

ImagingConfig config_with(const json& sources, double stale_after_s, const fs::path& dir) {
  return parse_imaging_config(json{{"width", 64},
                                   {"height", 48},
                                   {"vessel", false},
                                   {"stale_after_s", stale_after_s},
                                   {"sources", sources}},
                              dir / "server.json");
}

TEST(ImagingWorkerSources, AReplayedPlaneIsPublishedAtTheDetectorSizeBesideASimulatedOne) {
  TempDir dir;
  fs::create_directories(dir.path / "frames");
  for (int i = 0; i < 3; ++i)
    cv::imwrite((dir.path / "frames" / ("f" + std::to_string(i) + ".png")).string(),
                numbered_frame(i, 160, 120));
  auto config =
      config_with({{"lateral", {{"kind", "files"}, {"path", "frames"}, {"fps", 50}}}}, 5.0, dir.path);
  EXPECT_EQ(config.sources[0].kind, ImageSourceKind::kSimulated);
  EXPECT_EQ(config.sources[1].kind, ImageSourceKind::kFiles);
  EXPECT_EQ(config.sources[1].path, dir.path / "frames") << "relative to the server file";
  ImagingWorker worker(straight_catheter(), config);
  EXPECT_NE(worker.describe_sources().find("AP: SIMULATED"), std::string::npos) << worker.describe_sources();
  EXPECT_NE(worker.describe_sources().find("lateral: image files"), std::string::npos);
  Warnings warnings;
  worker.set_warning_sink(warnings.sink());
  worker.start();
  worker.set_demand("/imaging/lateral", true);
  std::optional<TopicPayload> message;
  for (int i = 0; i < 500 && !(message = worker.latest("/imaging/lateral", 2)); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  ASSERT_TRUE(message) << "three replayed frames published";
  const json body = json::parse(*message->payload);
  EXPECT_EQ(body["frame_id"], "imaging_lateral");
  EXPECT_TRUE(body["overlay"]["robot"].is_array()) << "the overlay uses the configured geometry";
  std::string data = body["data"].get<std::string>();
  // Decoded: the 160 × 120 files arrive at the configured 64 × 48 detector size.
  static constexpr char kAlphabet[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::vector<std::uint8_t> jpeg;
  std::uint32_t buffer = 0;
  int bits = 0;
  for (char c : data) {
    if (c == '=') break;
    buffer = (buffer << 6) | static_cast<std::uint32_t>(std::string_view(kAlphabet).find(c));
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      jpeg.push_back(static_cast<std::uint8_t>((buffer >> bits) & 0xFF));
    }
  }
  const cv::Mat decoded = cv::imdecode(jpeg, cv::IMREAD_UNCHANGED);
  ASSERT_FALSE(decoded.empty());
  EXPECT_EQ(decoded.cols, 64);
  EXPECT_EQ(decoded.rows, 48);
  EXPECT_FALSE(worker.latest("/imaging/ap", 0)) << "the simulated plane is not watched";
  worker.stop();
  EXPECT_FALSE(warnings.any("stale")) << "frames came in time";
}

TEST(ImagingWorkerSources, StaleImagesWarnAndTheirReturnIsReported) {
  TempDir dir;
  cv::imwrite((dir.path / "only.png").string(), numbered_frame(1, 64, 48));
  // One frame every 0.6 s, stale after 0.15 s: every gap between frames is a stale episode.
  auto config =
      config_with({{"ap", {{"kind", "files"}, {"path", "only.png"}, {"fps", 1.0 / 0.6}}}}, 0.15, dir.path);
  ImagingWorker worker(straight_catheter(), config);
  Warnings warnings;
  worker.set_warning_sink(warnings.sink());
  worker.start();
  worker.set_demand("/imaging/ap", true);
  EXPECT_TRUE(warnings.wait_for("no AP image for"));
  EXPECT_TRUE(warnings.wait_for("AP images again after"));
  EXPECT_EQ(worker.metrics().find("tendril_imaging_stale_total{view=\"ap\"} 0"), std::string::npos);
  worker.set_demand("/imaging/ap", false);
  worker.stop();
}

TEST(ImagingWorkerSources, StopDoesNotWaitForASlowReplaysNextFrame) {
  TempDir dir;
  cv::imwrite((dir.path / "only.png").string(), numbered_frame(1, 64, 48));
  auto config =
      config_with({{"ap", {{"kind", "files"}, {"path", "only.png"}, {"fps", 0.1}}}}, 60.0, dir.path);
  ImagingWorker worker(straight_catheter(), config);
  Warnings warnings;
  worker.set_warning_sink(warnings.sink());
  worker.start();
  worker.set_demand("/imaging/ap", true);
  for (int i = 0; i < 500 && !worker.latest("/imaging/ap", 0); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  ASSERT_TRUE(worker.latest("/imaging/ap", 0));
  worker.stop();  // the plane's thread is waiting 10 s for the next frame: stop() cancels that wait
  EXPECT_FALSE(warnings.any("replay ended")) << "a stop is not the end of the replay";
}

TEST(ImagingWorkerSources, DroppedFramesAndTheEndOfAReplayAreWarnedNotStale) {
  TempDir dir;
  cv::imwrite((dir.path / "a.png").string(), numbered_frame(0, 64, 48));
  std::ofstream(dir.path / "b.png") << "broken";
  auto config =
      config_with({{"ap", {{"kind", "files"}, {"path", "."}, {"fps", 100}, {"loop", false}}}}, 0.2, dir.path);
  ImagingWorker worker(straight_catheter(), config);
  Warnings warnings;
  worker.set_warning_sink(warnings.sink());
  worker.start();
  worker.set_demand("/imaging/ap", true);
  EXPECT_TRUE(warnings.wait_for("frame(s) dropped"));
  EXPECT_TRUE(warnings.any("b.png"));
  EXPECT_TRUE(warnings.wait_for("AP replay ended"));
  // After the end nothing more is expected: no stale warning follows (waited well past stale_after_s).
  std::this_thread::sleep_for(std::chrono::milliseconds(600));
  EXPECT_FALSE(warnings.any("no AP image")) << "an ended replay is not a stale view";
  EXPECT_NE(worker.metrics().find("tendril_imaging_dropped_frames_total{view=\"ap\"} 1"), std::string::npos);
  EXPECT_TRUE(worker.latest("/imaging/ap", 0)) << "the last frame stays";
  worker.stop();
}

TEST(ImagingWorkerSources, ConfigurationMistakesNameTheKey) {
  TempDir dir;
  const auto refuses = [&](const json& sources, const std::string& words) {
    try {
      auto c = config_with(sources, 1.0, dir.path);
      ImagingWorker worker(straight_catheter(), c);  // opening the source is part of setting up
      ADD_FAILURE() << "accepted " << sources.dump();
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
    }
  };
  refuses({{"front", {{"kind", "files"}}}}, "imaging.sources.front: unknown plane");
  refuses({{"ap", {{"kind", "camera"}}}}, "imaging.sources.ap.kind");
  refuses({{"ap", {{"kind", "files"}}}}, "imaging.sources.ap.path");
  refuses({{"ap", {{"kind", "simulated"}, {"path", "x"}}}}, "takes no path");
  refuses({{"ap", {{"kind", "files"}, {"path", "x"}, {"fps", -1}}}}, "imaging.sources.ap.fps");
  refuses({{"ap", {{"kind", "files"}, {"path", "x"}, {"loop", "yes"}}}}, "imaging.sources.ap.loop");
  refuses({{"ap", {{"kind", "files"}, {"path", "x"}, {"rate", 3}}}}, "imaging.sources.ap.rate: unknown key");
  refuses({{"ap", {{"kind", "files"}, {"path", "missing"}}}}, "imaging.sources.ap: image files");
  refuses({{"lateral", {{"kind", "video"}, {"path", "/dev/video-tendril-none"}}}},
          "imaging.sources.lateral: video device /dev/video-tendril-none");
  EXPECT_THROW(config_with(json::array(), 1.0, dir.path), ConfigError);
  EXPECT_THROW(config_with({{"ap", {{"kind", "simulated"}}}}, 0.0, dir.path), ConfigError) << "stale_after_s";
}

// Issue 15: segmentation on the images a lab has. A plane fed by image files (here frames the simulator
// rendered beforehand, written as PNG: the empty vessel, then a bent catheter) segments nothing until a
// roadmap is taken from its own frames; taken from the empty-vessel frame, it finds the catheter in the
// frames after, and with the simulated AP plane the 3D tip lands on the catheter's.
std::vector<Eigen::Vector3d> bent_catheter() {
  std::vector<Eigen::Vector3d> points;
  for (double s = 0; s <= 40.0; s += 0.5) {
    const double bend = std::max(0.0, s - 20.0);
    points.emplace_back(0.004 * bend * bend * bend / 3.0, -0.002 * bend * bend * bend / 3.0, 40.0 + s);
  }
  return points;
}

ImagingConfig tracked_files_config(const fs::path& dir) {
  return parse_imaging_config(
      json{{"width", 512},
           {"height", 512},
           {"fps", 15},
           {"vessel", false},
           {"isocentre_mm", {0, 0, 60}},
           {"stale_after_s", 5.0},
           {"sources", {{"lateral", {{"kind", "files"}, {"path", "frames"}, {"fps", 15}}}}}},
      dir / "server.json");
}

// Polls the tracking message until `pred` holds for it (a count of polls: up to 15 s, not a timing test).
json wait_tracking(ImagingWorker& worker, const std::function<bool(const json&)>& pred) {
  json last;
  for (int i = 0; i < 750; ++i) {
    if (const auto m = worker.latest("/imaging/tracking", 0)) {
      last = json::parse(*m->payload);
      if (pred(last)) return last;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ADD_FAILURE() << "the tracking never showed it; last " << last.dump();
  return last;
}

TEST(ImagingWorkerSources, AFilesPlaneIsTrackedOnceARoadmapIsTakenFromItsOwnFrames) {
  TempDir dir;
  fs::create_directories(dir.path / "frames");
  {
    const auto probe = tracked_files_config(dir.path);
    sim::SimulatedFluoroscope lateral(sim::FluoroView::kLateral, probe.fluoroscope, {});
    const auto write = [&](const std::string& name, std::span<const std::uint8_t> pixels) {
      const cv::Mat image(lateral.height(), lateral.width(), CV_8U, const_cast<std::uint8_t*>(pixels.data()));
      ASSERT_TRUE(cv::imwrite((dir.path / "frames" / name).string(), image));
    };
    write("a_empty.png", lateral.render_noiseless({}));
    const auto catheter = bent_catheter();
    for (int i = 0; i < 40; ++i)
      write("b_catheter_" + std::to_string(10 + i) + ".png", lateral.render(catheter));
  }
  const BackboneReader model = [](std::vector<Eigen::Vector3d>& out) {
    out = bent_catheter();
    return true;
  };
  {
    // No roadmap asked for: the files plane segments nothing and says why.
    ImagingWorker worker(model, tracked_files_config(dir.path));
    const json state = worker.segmentation().body;
    EXPECT_EQ(state["planes"]["lateral"]["roadmap_from"], "source_frame");
    EXPECT_EQ(state["planes"]["lateral"]["roadmap"]["count"], 0);
    EXPECT_EQ(state["planes"]["ap"]["roadmap_from"], "simulation");
    worker.set_demand("/imaging/tracking", true);
    worker.start();
    const json m = wait_tracking(worker, [](const json& t) {
      return t["planes"]["lateral"]["reason"].get<std::string>().find("roadmap") != std::string::npos;
    });
    EXPECT_FALSE(m["planes"]["lateral"]["found"].get<bool>());
    worker.stop();
  }
  // The roadmap asked for before the first frame: the empty-vessel frame becomes it.
  ImagingWorker worker(model, tracked_files_config(dir.path));
  const auto asked = worker.take_roadmap("lateral");
  EXPECT_EQ(asked.status, 202) << asked.message;
  worker.set_demand("/imaging/tracking", true);
  worker.start();
  const json found = wait_tracking(worker, [](const json& t) {
    return t["planes"]["lateral"]["found"].get<bool>() && t["raw_tip_mm"].is_array();
  });
  const auto& tip = found["raw_tip_mm"];
  ASSERT_TRUE(tip.is_array()) << found.dump();
  const Eigen::Vector3d imaged(tip[0].get<double>(), tip[1].get<double>(), tip[2].get<double>());
  EXPECT_LT((imaged - bent_catheter().back()).norm(), 1.5) << found.dump();
  EXPECT_EQ(worker.segmentation().body["planes"]["lateral"]["roadmap"]["count"], 1);
  worker.stop();
}

}  // namespace
}  // namespace tendril::server
