#include "tendril/teleop/perception/side_view_outline.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <deque>
#include <limits>
#include <optional>
#include <utility>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace tendril::teleop::perception {

namespace {

// 8-neighbours in Zhang–Suen order P2..P9: N, NE, E, SE, S, SW, W, NW.
constexpr std::array<int, 8> kRowStep{-1, -1, 0, 1, 1, 1, 0, -1};
constexpr std::array<int, 8> kColStep{0, 1, 1, 1, 0, -1, -1, -1};

// Zhang–Suen thinning of a 0/1 image whose border pixels are 0. Only foreground pixels are visited.
void thin(cv::Mat& image) {
  std::vector<cv::Point> foreground;
  for (int r = 1; r + 1 < image.rows; ++r)
    for (int c = 1; c + 1 < image.cols; ++c)
      if (image.at<std::uint8_t>(r, c)) foreground.emplace_back(c, r);
  std::vector<cv::Point> remove;
  bool changed = true;
  while (changed) {
    changed = false;
    for (int pass = 0; pass < 2; ++pass) {
      remove.clear();
      for (const auto& pt : foreground) {
        std::array<int, 8> p{};
        for (std::size_t k = 0; k < 8; ++k)
          p[k] = image.at<std::uint8_t>(pt.y + kRowStep[k], pt.x + kColStep[k]);
        const int b = p[0] + p[1] + p[2] + p[3] + p[4] + p[5] + p[6] + p[7];
        if (b < 2 || b > 6) continue;
        int a = 0;
        for (std::size_t k = 0; k < 8; ++k) a += p[k] == 0 && p[(k + 1) % 8] == 1;
        if (a != 1) continue;
        // p[0] = P2 (N), p[2] = P4 (E), p[4] = P6 (S), p[6] = P8 (W).
        const bool first = pass == 0 ? (p[0] * p[2] * p[4] == 0 && p[2] * p[4] * p[6] == 0)
                                     : (p[0] * p[2] * p[6] == 0 && p[0] * p[4] * p[6] == 0);
        if (first) remove.push_back(pt);
      }
      for (const auto& pt : remove) image.at<std::uint8_t>(pt) = 0;
      if (!remove.empty()) {
        changed = true;
        std::erase_if(foreground, [&](const cv::Point& pt) { return image.at<std::uint8_t>(pt) == 0; });
      }
    }
  }
}

// The longest path through the skeleton from `start` (breadth first, 8-connected), start first.
std::vector<cv::Point> longest_path(const cv::Mat& skeleton, cv::Point start) {
  cv::Mat parent(skeleton.size(), CV_32S, cv::Scalar(-1));
  const auto index = [&](cv::Point p) { return p.y * skeleton.cols + p.x; };
  std::deque<cv::Point> queue{start};
  parent.at<int>(start) = index(start);
  cv::Point last = start;
  while (!queue.empty()) {
    const cv::Point p = queue.front();
    queue.pop_front();
    last = p;  // breadth first: the last one reached is (one of) the farthest
    for (std::size_t k = 0; k < 8; ++k) {
      const cv::Point q(p.x + kColStep[k], p.y + kRowStep[k]);
      if (q.x < 0 || q.y < 0 || q.x >= skeleton.cols || q.y >= skeleton.rows) continue;
      if (!skeleton.at<std::uint8_t>(q) || parent.at<int>(q) >= 0) continue;
      parent.at<int>(q) = index(p);
      queue.push_back(q);
    }
  }
  std::vector<cv::Point> path;
  for (cv::Point p = last;;) {
    path.push_back(p);
    const int up = parent.at<int>(p);
    if (up == index(p)) break;
    p = cv::Point(up % skeleton.cols, up / skeleton.cols);
  }
  std::reverse(path.begin(), path.end());
  return path;
}

// (width, height) from a PNG IHDR or a JPEG start-of-frame marker; nullopt for anything else.
std::optional<std::pair<long, long>> image_size(std::span<const std::uint8_t> data) {
  const auto be16 = [&](std::size_t i) { return (long{data[i]} << 8) | data[i + 1]; };
  const auto be32 = [&](std::size_t i) { return (be16(i) << 16) | be16(i + 2); };
  constexpr std::array<std::uint8_t, 8> kPng{0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  if (data.size() >= 24 && std::equal(kPng.begin(), kPng.end(), data.begin())) {
    if (!std::equal(data.begin() + 12, data.begin() + 16, "IHDR")) return std::nullopt;
    return std::pair{be32(16), be32(20)};
  }
  if (data.size() < 4 || data[0] != 0xff || data[1] != 0xd8) return std::nullopt;
  // JPEG: walk the marker segments to the first SOFn (C0–CF but C4 DHT, C8 JPG, CC DAC).
  std::size_t i = 2;
  while (i + 9 < data.size()) {
    if (data[i] != 0xff) return std::nullopt;
    const std::uint8_t marker = data[i + 1];
    if (marker == 0xff) {  // fill byte
      ++i;
      continue;
    }
    if (marker >= 0xc0 && marker <= 0xcf && marker != 0xc4 && marker != 0xc8 && marker != 0xcc)
      return std::pair{be16(i + 7), be16(i + 5)};
    if (marker == 0xd8 || marker == 0x01 || (marker >= 0xd0 && marker <= 0xd7)) {  // no length
      i += 2;
      continue;
    }
    if (marker == 0xd9 || marker == 0xda) return std::nullopt;  // end, or scan data before a frame
    i += 2 + static_cast<std::size_t>(be16(i + 2));
  }
  return std::nullopt;
}

}  // namespace

SideViewOutline extract_side_view_outline(std::span<const std::uint8_t> encoded_image,
                                          const SideViewImageOptions& options) {
  if (!(options.mm_per_pixel > 0) || !std::isfinite(options.mm_per_pixel))
    throw SideViewImageError("mm_per_pixel: expected the image scale in the bending plane, a number > 0");
  if (options.threshold < -1 || options.threshold > 255)
    throw SideViewImageError("threshold: expected a grey level 0..255, or -1 for Otsu's automatic level");
  if (encoded_image.empty()) throw SideViewImageError("the image is empty");
  // Only PNG and JPEG, and their size is read from the header before anything is decoded, so a
  // small file that claims a huge picture cannot make the decoder allocate it.
  const auto size = image_size(encoded_image);
  if (!size)
    throw SideViewImageError(
        "the image is neither PNG nor JPEG, or its header is cut short (send PNG or JPEG)");
  if (size->first <= 0 || size->second <= 0 ||
      static_cast<std::size_t>(size->first) * static_cast<std::size_t>(size->second) > options.max_pixels)
    throw SideViewImageError("the image says it has " + std::to_string(size->first) + "×" +
                             std::to_string(size->second) + " pixels; 1 to " +
                             std::to_string(options.max_pixels) + " are accepted");
  const cv::Mat buffer(1, static_cast<int>(encoded_image.size()), CV_8U,
                       const_cast<std::uint8_t*>(encoded_image.data()));
  cv::Mat gray;
  try {
    gray = cv::imdecode(buffer, cv::IMREAD_GRAYSCALE);
  } catch (const cv::Exception&) {
    gray.release();
  }
  if (gray.empty() || gray.cols != size->first || gray.rows != size->second)
    throw SideViewImageError("the image could not be decoded (a damaged PNG or JPEG)");
  // Normalise: the catheter enters from the bottom, a bend toward +x shows to the right.
  switch (options.entry) {
    case ImageEdge::kBottom:
      break;
    case ImageEdge::kTop:
      cv::rotate(gray, gray, cv::ROTATE_180);
      break;
    case ImageEdge::kLeft:
      cv::rotate(gray, gray, cv::ROTATE_90_COUNTERCLOCKWISE);
      break;
    case ImageEdge::kRight:
      cv::rotate(gray, gray, cv::ROTATE_90_CLOCKWISE);
      break;
  }
  if (options.mirror) cv::flip(gray, gray, 1);

  SideViewOutline out;
  out.width = gray.cols;
  out.height = gray.rows;
  cv::Mat mask;
  const int type = options.dark_catheter ? cv::THRESH_BINARY_INV : cv::THRESH_BINARY;
  out.threshold = static_cast<int>(
      std::lround(options.threshold >= 0 ? cv::threshold(gray, mask, options.threshold, 1, type)
                                         : cv::threshold(gray, mask, 0, 1, type | cv::THRESH_OTSU)));

  // The largest catheter region that reaches the entry (bottom) row.
  cv::Mat labels, stats, centroids;
  const int count = cv::connectedComponentsWithStats(mask, labels, stats, centroids, 8, CV_32S);
  int best = 0;
  for (int label = 1; label < count; ++label) {
    const int bottom = stats.at<int>(label, cv::CC_STAT_TOP) + stats.at<int>(label, cv::CC_STAT_HEIGHT);
    if (bottom != gray.rows) continue;
    if (best == 0 || stats.at<int>(label, cv::CC_STAT_AREA) > stats.at<int>(best, cv::CC_STAT_AREA))
      best = label;
  }
  if (best == 0)
    throw SideViewImageError(std::string("no ") + (options.dark_catheter ? "dark" : "bright") +
                             " region reaches the entry edge at threshold " + std::to_string(out.threshold) +
                             ": check entry, dark_catheter and threshold");
  out.catheter_pixels = static_cast<std::size_t>(stats.at<int>(best, cv::CC_STAT_AREA));
  const cv::Rect box(stats.at<int>(best, cv::CC_STAT_LEFT), stats.at<int>(best, cv::CC_STAT_TOP),
                     stats.at<int>(best, cv::CC_STAT_WIDTH), stats.at<int>(best, cv::CC_STAT_HEIGHT));
  cv::Mat region = (labels(box) == best) / 255;  // 0/1
  // Extend the tube past the entry edge (replicate the bottom row) so thinning does not eat its end
  // there; a one-pixel empty border elsewhere.
  const int extension = std::max(4, 2 * cv::countNonZero(region.row(region.rows - 1)) + 2);
  cv::Mat padded;
  cv::copyMakeBorder(region, padded, 0, extension, 0, 0, cv::BORDER_REPLICATE);
  cv::copyMakeBorder(padded, padded, 1, 1, 1, 1, cv::BORDER_CONSTANT, cv::Scalar(0));
  thin(padded);

  // Start at the lowest skeleton pixel (in the extension), walk to the tip, keep the picture's part.
  cv::Point start(-1, -1);
  for (int r = padded.rows - 1; r >= 0 && start.x < 0; --r)
    for (int c = 0; c < padded.cols; ++c)
      if (padded.at<std::uint8_t>(r, c)) {
        start = cv::Point(c, r);
        break;
      }
  if (start.x < 0) throw SideViewImageError("the catheter region thinned to nothing");
  const int bottom_row = region.rows + 1;  // first padded row of the extension below the picture
  const auto path = longest_path(padded, start);
  // Sub-pixel: each skeleton point moves to the darkness-weighted centroid of a disc slightly wider
  // than the tube (the grey edges carry the sub-pixel position a thresholded mask has lost). Within
  // the disc the tube is nearly straight (its bend radius is hundreds of pixels), so the centroid
  // lies on the axis. Padded (x, y) → picture (x + box.x − 1, y + box.y − 1).
  std::size_t skeleton_length = 0;
  for (const auto& p : path) skeleton_length += p.y < bottom_row ? 1 : 0;
  const double half_width = skeleton_length > 0 ? 0.5 * static_cast<double>(out.catheter_pixels) /
                                                      static_cast<double>(skeleton_length)
                                                : 1.0;
  const int radius = static_cast<int>(std::ceil(half_width)) + 2;
  const double level = out.threshold;
  double column0 = std::numeric_limits<double>::quiet_NaN();
  Eigen::Vector2d previous = Eigen::Vector2d::Zero();
  double length_px = 0.0;
  for (const auto& p : path) {
    if (p.y >= bottom_row) continue;  // extension below the picture
    const int cx = p.x + box.x - 1, cy = p.y + box.y - 1;
    double sx = 0.0, sy = 0.0, sw = 0.0;
    for (int dy = -radius; dy <= radius; ++dy) {
      const int y = cy + dy;
      if (y < 0 || y >= gray.rows) continue;
      const auto* line = gray.ptr<std::uint8_t>(y);
      for (int dx = -radius; dx <= radius; ++dx) {
        const int x = cx + dx;
        if (x < 0 || x >= gray.cols || dx * dx + dy * dy > radius * radius) continue;
        // Darkness beyond the threshold (brightness for a bright catheter): 0 on the background.
        const double w = std::max(0.0, options.dark_catheter ? level - line[x] : line[x] - level);
        sx += w * x;
        sy += w * y;
        sw += w;
      }
    }
    // A disc cut by the entry edge would pull the centroid up: there only its column is used.
    const bool cut = cy + radius >= gray.rows;
    const Eigen::Vector2d pixel = sw <= 0 ? Eigen::Vector2d(cx, cy)
                                  : cut   ? Eigen::Vector2d(sx / sw, cy)
                                          : Eigen::Vector2d(sx / sw, sy / sw);
    if (std::isnan(column0)) column0 = cx;
    const Eigen::Vector2d point((pixel.x() - column0) * options.mm_per_pixel,
                                (gray.rows - 0.5 - pixel.y()) * options.mm_per_pixel);
    if (!out.points.empty()) length_px += (point - previous).norm() / options.mm_per_pixel;
    out.points.push_back(point);
    previous = point;
  }
  if (out.points.size() < 8)
    throw SideViewImageError("the catheter's skeleton has only " + std::to_string(out.points.size()) +
                             " points in the picture; at least 8 are needed");
  out.tube_width_mm =
      length_px > 0 ? static_cast<double>(out.catheter_pixels) / length_px * options.mm_per_pixel : 0.0;
  return out;
}

}  // namespace tendril::teleop::perception
