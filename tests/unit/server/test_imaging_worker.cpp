// ImagingWorker as a TopicSource: the foxglove.CompressedImage / foxglove.PointCloud messages it
// publishes, its latest-value versions and ready callback, and the "imaging" configuration.
#include <gtest/gtest.h>

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <thread>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "tendril/server/config.hpp"
#include "tendril/server/foxglove_protobuf.hpp"
#include "tendril/server/imaging_worker.hpp"

namespace tendril::server {
namespace {

using nlohmann::json;

std::vector<std::uint8_t> base64_decode(const std::string& text) {
  auto value = [](char c) -> int {
    if (c >= 'A' && c <= 'Z') return c - 'A';
    if (c >= 'a' && c <= 'z') return c - 'a' + 26;
    if (c >= '0' && c <= '9') return c - '0' + 52;
    if (c == '+') return 62;
    if (c == '/') return 63;
    return -1;
  };
  std::vector<std::uint8_t> out;
  std::uint32_t buffer = 0;
  int bits = 0;
  for (char c : text) {
    if (c == '=') break;
    const int v = value(c);
    if (v < 0) throw std::runtime_error("not base64");
    buffer = (buffer << 6) | static_cast<std::uint32_t>(v);
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      out.push_back(static_cast<std::uint8_t>((buffer >> bits) & 0xFF));
    }
  }
  return out;
}

ImagingConfig small_config() {
  ImagingConfig c = parse_imaging_config(json{{"width", 128}, {"height", 96}, {"fps", 20}, {"vessel", false}},
                                         "/nonexistent/server.json");
  return c;
}

BackboneReader straight_catheter() {
  return [](std::vector<Eigen::Vector3d>& out) {
    for (int i = 0; i <= 20; ++i) out.emplace_back(0.0, 0.0, 40.0 + i);
    return true;
  };
}

TEST(Base64, MatchesRfc4648Vectors) {
  const std::pair<std::string, std::string> vectors[] = {{"", ""},
                                                         {"f", "Zg=="},
                                                         {"fo", "Zm8="},
                                                         {"foo", "Zm9v"},
                                                         {"foob", "Zm9vYg=="},
                                                         {"fooba", "Zm9vYmE="},
                                                         {"foobar", "Zm9vYmFy"}};
  for (const auto& [plain, encoded] : vectors) {
    std::string out = "x";
    append_base64(reinterpret_cast<const std::uint8_t*>(plain.data()), plain.size(), out);
    EXPECT_EQ(out, "x" + encoded);
  }
}

TEST(ImagingWorker, TheOverlayLiesOnTheImagedCatheterAndCarriesThePlan) {
  ImagingWorker worker(straight_catheter(), small_config());
  // A plan 10 mm beside the catheter: drawn in the overlay, not in the image.
  worker.set_plan_reader([](std::vector<Eigen::Vector3d>& out) {
    for (int i = 0; i <= 20; ++i) out.emplace_back(10.0, 10.0, 40.0 + i);
    return true;
  });
  worker.capture_once();
  for (const char* topic : {"/imaging/ap", "/imaging/lateral"}) {
    const auto message = worker.latest(topic, 0);
    ASSERT_TRUE(message) << topic;
    const json body = json::parse(*message->payload);
    const auto& catheter = body["overlay"]["robot"];
    const auto& plan = body["overlay"]["plan"];
    ASSERT_EQ(catheter.size(), 21u) << topic;
    ASSERT_EQ(plan.size(), 21u) << topic;
    const auto jpeg = base64_decode(body["data"].get<std::string>());
    const cv::Mat image = cv::imdecode(jpeg, cv::IMREAD_GRAYSCALE);
    ASSERT_FALSE(image.empty());
    // Mean brightness under each polyline: the catheter is radio-opaque (dark), the plan's place is not.
    const auto mean_under = [&](const json& points) {
      double sum = 0.0;
      for (const auto& p : points) {
        const int c = static_cast<int>(std::lround(p[0].get<double>()));
        const int r = static_cast<int>(std::lround(p[1].get<double>()));
        EXPECT_TRUE(c >= 0 && c < image.cols && r >= 0 && r < image.rows) << topic << " " << p.dump();
        sum += image.at<std::uint8_t>(std::clamp(r, 0, image.rows - 1), std::clamp(c, 0, image.cols - 1));
      }
      return sum / static_cast<double>(points.size());
    };
    EXPECT_LT(mean_under(catheter) + 20.0, mean_under(plan))
        << topic << ": the overlay lies on the imaged catheter";
  }
  // Without a plan the field is there and empty.
  ImagingWorker plain(straight_catheter(), small_config());
  plain.capture_once();
  EXPECT_TRUE(json::parse(*plain.latest("/imaging/ap", 0)->payload)["overlay"]["plan"].empty());
}

TEST(ImagingWorker, PublishesCompressedImagesWithCaptureTimestamp) {
  ImagingWorker worker(straight_catheter(), small_config());
  const auto topics = worker.topics();
  // Per plane the JSON image, the protobuf image, the overlay and the overlay as protobuf
  // annotations; then the tracking and the segmentation parameters (no vessel configured: no
  // /maps/vessel).
  ASSERT_EQ(topics.size(), 10u);
  EXPECT_EQ(topics[0].topic, "/imaging/ap");
  EXPECT_EQ(topics[1].topic, "/imaging/ap/compressed");
  EXPECT_EQ(topics[2].topic, "/imaging/ap/overlay");
  EXPECT_EQ(topics[3].topic, "/imaging/ap/annotations");
  EXPECT_EQ(topics[3].schema_name, "foxglove.ImageAnnotations");
  EXPECT_EQ(topics[3].encoding, "protobuf");
  EXPECT_EQ(topics[4].topic, "/imaging/lateral");
  EXPECT_EQ(topics[8].topic, "/imaging/tracking");
  EXPECT_EQ(topics[8].schema_name, "tendril.TipTracking");
  EXPECT_EQ(topics[9].topic, "/imaging/segmentation");
  EXPECT_EQ(topics[9].schema_name, "tendril.SegmentationParameters");
  EXPECT_EQ(topics[0].schema_name, "foxglove.CompressedImage");
  EXPECT_EQ(topics[0].encoding, "json");
  const json schema = json::parse(topics[0].schema);
  EXPECT_EQ(schema["properties"]["data"]["contentEncoding"], "base64");
  EXPECT_EQ(topics[1].schema_name, "foxglove.CompressedImage");
  EXPECT_EQ(topics[1].encoding, "protobuf");
  EXPECT_EQ(topics[1].schema_encoding, "protobuf");
  EXPECT_EQ(topics[1].schema, protobuf::compressed_image_descriptor_set());
  EXPECT_EQ(topics[2].schema_name, "tendril.ImageOverlay");

  EXPECT_FALSE(worker.latest("/imaging/ap", 0)) << "nothing before the first exposure";
  std::atomic<int> ready{0};
  worker.set_ready_callback([&ready] { ++ready; });
  const auto before = std::chrono::system_clock::now();
  worker.capture_once();
  const auto after = std::chrono::system_clock::now();
  EXPECT_EQ(ready.load(), 2);  // one per plane

  for (const char* topic : {"/imaging/ap", "/imaging/lateral"}) {
    const auto message = worker.latest(topic, 0);
    ASSERT_TRUE(message) << topic;
    EXPECT_EQ(message->version, 1u);
    const json body = json::parse(*message->payload);
    EXPECT_EQ(body["format"], "jpeg");
    EXPECT_EQ(body["frame_id"], std::string(topic) == "/imaging/ap" ? "imaging_ap" : "imaging_lateral");
    const std::uint64_t stamp = body["timestamp"]["sec"].get<std::uint64_t>() * 1'000'000'000ULL +
                                body["timestamp"]["nsec"].get<std::uint64_t>();
    EXPECT_GE(message->log_time_ns, stamp) << "logged when ready, after the capture";
    const auto ns = [](auto t) {
      return static_cast<std::uint64_t>(
          std::chrono::duration_cast<std::chrono::nanoseconds>(t.time_since_epoch()).count());
    };
    EXPECT_GE(stamp, ns(before));
    EXPECT_LE(stamp, ns(after));
    EXPECT_LE(message->log_time_ns, ns(after));
    const auto jpeg = base64_decode(body["data"].get<std::string>());
    const cv::Mat image = cv::imdecode(jpeg, cv::IMREAD_UNCHANGED);
    ASSERT_FALSE(image.empty());
    EXPECT_EQ(image.cols, 128);
    EXPECT_EQ(image.rows, 96);
    // The timestamp comes first, so a client can read it without parsing 200 kB of base64.
    EXPECT_EQ(message->payload->rfind("{\"timestamp\":{\"sec\":", 0), 0u);
    // The same frame in protobuf: the JPEG's bytes after the timestamp's field, and the same version.
    const auto binary = worker.latest(std::string(topic) + "/compressed", 0);
    ASSERT_TRUE(binary) << topic;
    EXPECT_EQ(binary->version, 1u);
    const std::string jpeg_bytes(jpeg.begin(), jpeg.end());
    EXPECT_NE(binary->payload->find(jpeg_bytes), std::string::npos) << "the image's bytes, not base64";
    EXPECT_LT(binary->payload->size(), jpeg.size() + 64);
    const auto overlay = worker.latest(std::string(topic) + "/overlay", 0);
    ASSERT_TRUE(overlay) << topic;
    const json overlay_body = json::parse(*overlay->payload);
    EXPECT_EQ(overlay_body["timestamp"], body["timestamp"]) << "the overlay names its frame by time stamp";
    EXPECT_EQ(overlay_body["robot"], body["overlay"]["robot"]);
  }
  EXPECT_FALSE(worker.latest("/imaging/ap", 1)) << "no newer message than version 1";
  worker.capture_once();
  ASSERT_TRUE(worker.latest("/imaging/ap", 1));
  EXPECT_EQ(worker.latest("/imaging/ap", 1)->version, 2u);
  EXPECT_FALSE(worker.latest("/no/such/topic", 0));
  worker.set_ready_callback(nullptr);
  worker.capture_once();
  EXPECT_EQ(ready.load(), 4);
  const std::string metrics = worker.metrics();
  EXPECT_NE(metrics.find("tendril_imaging_frames_total{view=\"ap\"} 3"), std::string::npos) << metrics;
}

TEST(ImagingWorker, ThreadsExposeOnlyThePlanesSomeoneWatches) {
  ImagingWorker worker(straight_catheter(), small_config());  // 20 fps
  std::atomic<int> ready{0};
  worker.set_ready_callback([&ready] { ++ready; });
  worker.start();
  // Unwatched: nothing is rendered (10 exposures' worth of waiting at 20 fps).
  for (int i = 0; i < 10; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  EXPECT_EQ(ready.load(), 0);
  EXPECT_FALSE(worker.latest("/imaging/ap", 0));
  // Watched: the AP plane exposes; the lateral one still does not. Bounded by a count of polls, not
  // a timing assertion.
  worker.set_demand("/imaging/ap", true);
  for (int i = 0; i < 200 && ready.load() < 3; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_GE(ready.load(), 3);
  const auto ap = worker.latest("/imaging/ap", 0);
  ASSERT_TRUE(ap);
  EXPECT_GE(ap->version, 3u);
  EXPECT_FALSE(worker.latest("/imaging/lateral", 0));
  EXPECT_NE(worker.metrics().find("tendril_imaging_frames_total{view=\"lateral\"} 0"), std::string::npos);
  // Only the watched stream is built: the protobuf image and the overlay are not (nobody asked).
  EXPECT_FALSE(worker.latest("/imaging/ap/compressed", 0));
  // Unwatched again: its last frame is dropped and rendering stops.
  worker.set_demand("/imaging/ap", false);
  EXPECT_FALSE(worker.latest("/imaging/ap", 0));
  // The console's pair: the protobuf image and its overlay, without the base64 JSON.
  const int before = ready.load();
  worker.set_demand("/imaging/ap/compressed", true);
  worker.set_demand("/imaging/ap/overlay", true);
  for (int i = 0; i < 200 && ready.load() < before + 2; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_TRUE(worker.latest("/imaging/ap/compressed", 0));
  EXPECT_TRUE(worker.latest("/imaging/ap/overlay", 0));
  // The base64 JSON is not built for nobody: its version stands still while frames go on (one frame
  // exposed as the demand changed may have landed; none after it).
  const auto json_version = [&] {
    const auto m = worker.latest("/imaging/ap", 0);
    return m ? m->version : 0;
  };
  const auto frozen = json_version();
  const int later = ready.load();
  for (int i = 0; i < 200 && ready.load() < later + 2; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_GE(ready.load(), later + 2);
  EXPECT_EQ(json_version(), frozen);
  worker.stop();
  worker.stop();  // twice is fine
}

TEST(ImagingWorker, ShapeFailureStillPublishesAndIsCounted) {
  ImagingWorker worker([](std::vector<Eigen::Vector3d>&) -> bool { throw std::runtime_error("no snapshot"); },
                       small_config());
  worker.capture_once();
  EXPECT_TRUE(worker.latest("/imaging/ap", 0));
  EXPECT_NE(worker.metrics().find("tendril_imaging_shape_errors_total{view=\"ap\"} 1"), std::string::npos);
}

TEST(ImagingWorker, VesselPointCloudHasTheWallPoints) {
  ImagingConfig config = small_config();
  sim::VesselTube tube;
  for (int i = 0; i <= 10; ++i) {
    tube.centerline.emplace_back(0.0, 0.0, 1.0 * i);
    tube.radius_mm.push_back(2.0);
  }
  config.vessels = {tube};
  ImagingWorker worker(straight_catheter(), config);
  const auto topics = worker.topics();
  ASSERT_EQ(topics.size(), 11u);
  EXPECT_EQ(topics[10].topic, "/maps/vessel");
  EXPECT_EQ(topics[10].schema_name, "foxglove.PointCloud");
  const auto cloud = worker.latest("/maps/vessel", 0);
  ASSERT_TRUE(cloud);
  EXPECT_FALSE(worker.latest("/maps/vessel", cloud->version)) << "static map: published once";
  const json body = json::parse(*cloud->payload);
  EXPECT_EQ(body["frame_id"], "world");
  EXPECT_EQ(body["point_stride"], 12);
  ASSERT_EQ(body["fields"].size(), 3u);
  EXPECT_EQ(body["fields"][2]["name"], "z");
  EXPECT_EQ(body["fields"][2]["offset"], 8);
  EXPECT_EQ(body["fields"][2]["type"], 7);  // FLOAT32
  const auto data = base64_decode(body["data"].get<std::string>());
  ASSERT_EQ(data.size(), 21u * 16u * 12u);  // rings every 0.5 mm over 10 mm, 16 points each
  for (std::size_t i = 0; i < data.size(); i += 12) {
    float xyz[3];
    std::memcpy(xyz, &data[i], 12);
    EXPECT_NEAR(std::hypot(xyz[0], xyz[1]), 2.0, 1e-4);
  }
}

TEST(ImagingConfigTest, DefaultsAndErrorsNameTheKey) {
  const auto off = parse_imaging_config(nullptr, "server.json");
  EXPECT_FALSE(off.enabled);
  const auto on = parse_imaging_config(json::object({{"vessel", false}}), "server.json");
  EXPECT_TRUE(on.enabled);
  EXPECT_EQ(on.fluoroscope.geometry.width, 512);
  EXPECT_DOUBLE_EQ(on.fluoroscope.geometry.pixel_spacing_mm, 160.0 / 512);
  EXPECT_EQ(on.fps, 15.0);
  auto error_of = [](const json& j) {
    try {
      parse_imaging_config(j, "config/server.json");
    } catch (const ConfigError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_EQ(error_of({{"fps", 0}}).rfind("config/server.json: imaging.fps: expected a number from", 0), 0u);
  EXPECT_NE(error_of({{"width", 4096}}).find("imaging.width"), std::string::npos);
  EXPECT_NE(error_of({{"jpeg_quality", 0}}).find("imaging.jpeg_quality"), std::string::npos);
  EXPECT_NE(error_of({{"sid_mm", 700}, {"sod_mm", 750}}).find("imaging.sod_mm"), std::string::npos);
  EXPECT_NE(error_of({{"isocentre_mm", {1, 2}}}).find("imaging.isocentre_mm"), std::string::npos);
  EXPECT_NE(error_of({{"vessel", "no_such_file.csv"}}).find("imaging.vessel"), std::string::npos);
  EXPECT_NE(error_of(json::array()).find("imaging: expected an object"), std::string::npos);
}

TEST(ImagingConfigTest, VesselComesFromTheConfiguredCsvOrIsGenerated) {
  const auto dir =
      std::filesystem::temp_directory_path() / ("tendril-imaging-test-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir / "vessels");
  // No vessels/synthetic_ica.csv next to the server file: generated.
  auto generated = parse_imaging_config(json::object(), dir / "server.json");
  ASSERT_EQ(generated.vessels.size(), 1u);
  EXPECT_GT(generated.vessels[0].centerline.size(), 100u);
  EXPECT_NE(generated.vessel_source.find("generated"), std::string::npos);
  // A CSV with radii: used as it is.
  {
    std::ofstream csv(dir / "vessels" / "synthetic_ica.csv");
    csv << "x,y,z,r\n";
    for (int i = 0; i <= 40; ++i) csv << "0,0," << i << ",1.5\n";
  }
  auto from_file = parse_imaging_config(json::object(), dir / "server.json");
  ASSERT_EQ(from_file.vessels.size(), 1u);
  EXPECT_EQ(from_file.vessels[0].centerline.size(), 41u);
  EXPECT_DOUBLE_EQ(from_file.vessels[0].radius_mm[5], 1.5);
  EXPECT_EQ(from_file.vessel_source, (dir / "vessels" / "synthetic_ica.csv").string());
  std::filesystem::remove_all(dir);
}

}  // namespace
TEST(SceneVesselTest, TheSceneNamesTheVesselAndMistakesNameTheKey) {
  const auto dir =
      std::filesystem::temp_directory_path() / ("tendril-scene-test-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  {
    std::ofstream csv(dir / "a.csv");
    csv << "x,y,z,r\n";
    for (int i = 0; i <= 40; ++i) csv << "0,0," << i << ",2.5\n";
    std::ofstream other(dir / "b.csv");
    other << "x,y,z\n";
    for (int i = 0; i <= 20; ++i) other << i << ",0,0\n";
  }
  const auto server = dir / "server.json";
  // The scene's vessel wins over an older imaging.vessel.
  auto scene =
      load_scene_vessel(json{{"vessel", "a.csv"}, {"robot", "srmc"}}, json{{"vessel", "b.csv"}}, server);
  ASSERT_EQ(scene.branches.size(), 1u);
  EXPECT_EQ(scene.branches[0].points.size(), 41u);
  EXPECT_EQ(scene.robot, "srmc");
  // Without a scene, imaging.vessel is the scene's vessel.
  EXPECT_EQ(load_scene_vessel(nullptr, json{{"vessel", "b.csv"}}, server).branches[0].points.size(), 21u);
  EXPECT_TRUE(load_scene_vessel(json{{"vessel", false}}, nullptr, server).branches.empty());
  auto error_of = [&](const json& s) {
    try {
      load_scene_vessel(s, nullptr, server);
    } catch (const ConfigError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(error_of({{"vesel", "a.csv"}}).find("scene.vesel: unknown key"), std::string::npos);
  EXPECT_NE(error_of({{"vessel", "missing.csv"}}).find("scene.vessel: expected an existing file"),
            std::string::npos);
  EXPECT_NE(error_of({{"robot", 3}}).find("scene.robot"), std::string::npos);
  EXPECT_NE(error_of(json::array()).find("scene: expected an object"), std::string::npos);
  std::filesystem::remove_all(dir);
}

}  // namespace tendril::server
