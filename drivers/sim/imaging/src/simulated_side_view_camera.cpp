#include "tendril/drivers/sim/simulated_side_view_camera.hpp"

#include <algorithm>
#include <cmath>
#include <random>
#include <string>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace tendril::sim {

SimulatedSideViewCamera::SimulatedSideViewCamera(const teleop::ModalCatheterParameters& shape,
                                                 SideViewCameraOptions options)
    : shape_(shape), options_(options) {
  const auto& o = options_;
  if (o.width < 32 || o.width > 4096 || o.height < 32 || o.height > 4096)
    throw SideViewCameraError("side-view camera: width and height must be 32..4096 pixels");
  if (!(o.mm_per_pixel > 0) || !(o.tube_diameter_mm > 0) || !(o.straight_mm >= 0) ||
      !(o.blur_sigma_px >= 0) || !(o.noise_sigma >= 0) ||
      !std::isfinite(o.background + o.tube_grey + o.vignetting))
    throw SideViewCameraError(
        "side-view camera: mm_per_pixel and tube_diameter_mm must be > 0; straight_mm, blur and noise >= 0");
  if (!(o.base_column >= 0 && o.base_column < o.width))
    throw SideViewCameraError("side-view camera: base_column must lie inside the image");
}

std::vector<Eigen::Vector2d> SimulatedSideViewCamera::true_backbone(teleop::CatheterSegment segment,
                                                                    double actuation_mm,
                                                                    double spacing_mm) const {
  const double length = shape_.length(segment);
  const int straight = static_cast<int>(std::ceil(options_.straight_mm / spacing_mm));
  const int n = std::max(2, static_cast<int>(std::ceil(length / spacing_mm)));
  std::vector<Eigen::Vector2d> points;
  points.reserve(static_cast<std::size_t>(straight) + static_cast<std::size_t>(n) + 1);
  for (int i = 0; i < straight; ++i) points.emplace_back(0.0, -options_.straight_mm + i * spacing_mm);
  for (int i = 0; i <= n; ++i) {
    const Eigen::Vector3d d = shape_.segment_displacement(segment, length * i / n, actuation_mm);
    points.emplace_back(d.x(), d.z());
  }
  return points;
}

std::vector<std::uint8_t> SimulatedSideViewCamera::capture_png(teleop::CatheterSegment segment,
                                                               double actuation_mm) {
  const auto& o = options_;
  // Lit background with vignetting.
  cv::Mat image(o.height, o.width, CV_32F);
  const double cx = 0.5 * (o.width - 1), cy = 0.5 * (o.height - 1), r2max = cx * cx + cy * cy;
  for (int row = 0; row < o.height; ++row) {
    auto* line = image.ptr<float>(row);
    for (int col = 0; col < o.width; ++col) {
      const double r2 = (col - cx) * (col - cx) + (row - cy) * (row - cy);
      line[col] = static_cast<float>(o.background * (1.0 - o.vignetting * r2 / r2max));
    }
  }
  // The tube, anti-aliased at 1/16 pixel: from below the bottom edge, straight, then the segment.
  constexpr int kShift = 4;
  constexpr double kScale = 1 << kShift;
  std::vector<cv::Point> polyline;
  auto to_pixel = [&](const Eigen::Vector2d& xz) {
    const double col = o.base_column + xz.x() / o.mm_per_pixel;
    const double row = (o.height - 1) - (xz.y() + o.straight_mm) / o.mm_per_pixel;
    return cv::Point(static_cast<int>(std::lround(col * kScale)),
                     static_cast<int>(std::lround(row * kScale)));
  };
  polyline.push_back(to_pixel({0.0, -o.straight_mm - 2.0 * o.tube_diameter_mm - 1.0}));
  for (const auto& p : true_backbone(segment, actuation_mm, 0.5 * o.mm_per_pixel))
    polyline.push_back(to_pixel(p));
  cv::Mat coverage(o.height, o.width, CV_8U, cv::Scalar(0));
  const int thickness = std::max(1, static_cast<int>(std::lround(o.tube_diameter_mm / o.mm_per_pixel)));
  cv::polylines(coverage, std::vector<std::vector<cv::Point>>{polyline}, false, cv::Scalar(255), thickness,
                cv::LINE_AA, kShift);
  cv::Mat alpha;
  coverage.convertTo(alpha, CV_32F, 1.0 / 255.0);
  image = image.mul(1.0 - alpha) + alpha * o.tube_grey;
  if (o.blur_sigma_px > 0) {
    const int k = 2 * static_cast<int>(std::ceil(3.0 * o.blur_sigma_px)) + 1;
    cv::GaussianBlur(image, image, cv::Size(k, k), o.blur_sigma_px, o.blur_sigma_px, cv::BORDER_REPLICATE);
  }
  if (o.noise_sigma > 0) {
    std::mt19937_64 rng(o.noise_seed + frames_);
    std::normal_distribution<float> noise(0.0F, static_cast<float>(o.noise_sigma));
    for (int row = 0; row < o.height; ++row) {
      auto* line = image.ptr<float>(row);
      for (int col = 0; col < o.width; ++col) line[col] += noise(rng);
    }
  }
  ++frames_;
  cv::Mat gray;
  image.convertTo(gray, CV_8U);  // saturates to 0..255
  std::vector<std::uint8_t> png;
  cv::imencode(".png", gray, png);
  return png;
}

}  // namespace tendril::sim
