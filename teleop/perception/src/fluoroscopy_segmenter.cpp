#include "tendril/teleop/perception/fluoroscopy_segmenter.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

namespace tendril::teleop::perception {

namespace {

constexpr double kLogScale = 100.0;  // difference image units: 100 · ln(reference / frame)
constexpr int kMinRoiSide = 8;
constexpr std::array<int, 8> kRowStep{-1, -1, 0, 1, 1, 1, 0, -1};
constexpr std::array<int, 8> kColStep{0, 1, 1, 1, 0, -1, -1, -1};

// 100 · ln(v + 1): the +1 keeps black pixels finite; at the grey levels a detector shows (tens and
// more) it changes the ratio by a few percent at most.
std::array<float, 256> make_log_table() {
  std::array<float, 256> t{};
  for (int v = 0; v < 256; ++v)
    t[static_cast<std::size_t>(v)] = static_cast<float>(kLogScale * std::log(v + 1.0));
  return t;
}
const std::array<float, 256> kLog = make_log_table();

// The ROI clipped to the image, its size cut to a multiple of the downsampling factor (so that the
// area average is the exact block mean, and OpenCV's fast integer-factor path runs).
cv::Rect resolve_roi(const RegionOfInterest& roi, int width, int height, int downsample) {
  const int w = roi.width > 0 ? roi.width : width - roi.x;
  const int h = roi.height > 0 ? roi.height : height - roi.y;
  cv::Rect r = cv::Rect(roi.x, roi.y, std::max(0, w), std::max(0, h)) & cv::Rect(0, 0, width, height);
  r.width -= r.width % downsample;
  r.height -= r.height % downsample;
  return r;
}

// Cubic B-spline on clamped uniform knots over [0, 1] with `count` control points: the four
// non-zero basis functions at u and the index of the first (NURBS book A2.2).
struct CubicBasis {
  int first = 0;
  std::array<double, 4> value{};
};

CubicBasis cubic_basis(int count, double u) {
  const int spans = count - 3;
  const double x = std::clamp(u, 0.0, 1.0) * spans;
  const int span = std::min(static_cast<int>(x), spans - 1);  // 0-based inner span
  // Knot vector t[k]: 0 for k ≤ 3, (k − 3)/spans inside, 1 for k ≥ count. Span j = span + 3.
  const auto knot = [spans, count](int k) {
    if (k <= 3) return 0.0;
    if (k >= count) return 1.0;
    return static_cast<double>(k - 3) / spans;
  };
  const int j = span + 3;
  const double uu = std::clamp(u, 0.0, 1.0);
  std::array<double, 4> left{}, right{};
  CubicBasis b;
  b.value[0] = 1.0;
  for (std::size_t d = 1; d <= 3; ++d) {
    left[d] = uu - knot(j + 1 - static_cast<int>(d));
    right[d] = knot(j + static_cast<int>(d)) - uu;
    double saved = 0.0;
    for (std::size_t r = 0; r < d; ++r) {
      const double denominator = right[r + 1] + left[d - r];
      const double temp = denominator > 0 ? b.value[r] / denominator : 0.0;
      b.value[r] = saved + right[r + 1] * temp;
      saved = left[d - r] * temp;
    }
    b.value[d] = saved;
  }
  b.first = j - 3;
  return b;
}

}  // namespace

GreyImageView grey_image(std::span<const std::uint8_t> data, int width, int height) noexcept {
  GreyImageView v;
  if (width <= 0 || height <= 0 ||
      data.size() < static_cast<std::size_t>(width) * static_cast<std::size_t>(height))
    return v;  // invalid: segment() reports kInvalidFrame
  v.data = data.data();
  v.width = width;
  v.height = height;
  v.stride = width;
  return v;
}

const char* failure_name(SegmentationFailure failure) noexcept {
  switch (failure) {
    case SegmentationFailure::kNone:
      return "none";
    case SegmentationFailure::kNoRoadmap:
      return "no_roadmap";
    case SegmentationFailure::kInvalidFrame:
      return "invalid_frame";
    case SegmentationFailure::kFrameSizeMismatch:
      return "frame_size_mismatch";
    case SegmentationFailure::kRoiOutsideFrame:
      return "roi_outside_frame";
    case SegmentationFailure::kBlankFrame:
      return "blank_frame";
    case SegmentationFailure::kNoCatheterInRoi:
      return "no_catheter_in_roi";
    case SegmentationFailure::kCatheterTooShort:
      return "catheter_too_short";
  }
  return "none";
}

struct FluoroscopySegmenter::Impl {
  FluoroscopySegmentationParameters params;
  cv::Mat roadmap;  // CV_8U copy
  bool derived_valid = false;
  bool vessel_valid = false;

  // Derived from the roadmap and parameters (recomputed when either changes).
  cv::Rect roi;
  cv::Mat reference_log;  // CV_16S, detection scale: 100·(w·ln R + (1 − w)·ln 256)
  cv::Mat log_lut;        // 1 × 256 CV_16S
  cv::Mat open_kernel;
  float reference_weight = 1.0F;  // w, or 0 without background subtraction
  float reference_offset = 0.0F;  // (1 − w) · 100 · ln 256

  // Per-frame buffers.
  cv::Mat small, frame_log, difference16, difference, mask;
  cv::Mat region, padded, skeleton, parent, edges;
  std::vector<int> queue;
  std::vector<std::ptrdiff_t> foreground, removed;
  cv::Mat region_label;
  std::vector<cv::Point> nonzero, order;
  std::vector<cv::Point> path;
  std::vector<Eigen::Vector2d> points;  // refined backbone, full-resolution pixels
  std::vector<double> arc;
  Eigen::MatrixXd normal_matrix;
  Eigen::MatrixXd rhs;
  Eigen::MatrixXd control;
  Eigen::LDLT<Eigen::MatrixXd> solver;
  CatheterSegmentation result;
  VesselCenterlineResult vessel;

  void fail(SegmentationFailure why, std::string message) {
    result.found = false;
    result.failure = why;
    result.message = std::move(message);
    result.polyline.clear();
    result.tip.setZero();
    result.tip_direction.setZero();
    result.quality = result.length_px = result.width_px = result.mean_attenuation = 0.0;
    result.region_pixels = result.other_regions = 0;
  }

  void prepare_derived() {
    if (derived_valid) return;
    const int ds = params.downsample;
    roi = resolve_roi(params.roi, roadmap.cols, roadmap.rows, ds);
    log_lut.create(1, 256, CV_16S);
    for (int v = 0; v < 256; ++v)
      log_lut.at<std::int16_t>(0, v) =
          static_cast<std::int16_t>(std::lround(kLog[static_cast<std::size_t>(v)]));
    reference_weight = params.background_subtraction ? static_cast<float>(params.background_weight) : 0.0F;
    reference_offset = (1.0F - reference_weight) * kLog[255];
    if (roi.width >= kMinRoiSide && roi.height >= kMinRoiSide) {
      downsample_into(roadmap(roi), small);
      cv::Mat log_float;
      small.convertTo(log_float, CV_32F);
      for (int r = 0; r < log_float.rows; ++r) {
        auto* row = log_float.ptr<float>(r);
        for (int c = 0; c < log_float.cols; ++c)
          row[c] = reference_weight * kLog[static_cast<std::size_t>(row[c])] + reference_offset;
      }
      log_float.convertTo(reference_log, CV_16S);
    }
    open_kernel = params.morphology_px > 1
                      ? cv::getStructuringElement(cv::MORPH_ELLIPSE,
                                                  cv::Size(params.morphology_px, params.morphology_px))
                      : cv::Mat();
    derived_valid = true;
  }

  void downsample_into(const cv::Mat& in, cv::Mat& out) const {
    const int ds = params.downsample;
    if (ds == 1) {
      in.copyTo(out);
      return;
    }
    cv::resize(in, out, cv::Size(in.cols / ds, in.rows / ds), 0, 0, cv::INTER_AREA);
  }

  // The full-resolution difference value at a pixel (100 · ln(reference / frame)).
  float difference_at(const cv::Mat& frame, int x, int y) const {
    const float reference = reference_weight * kLog[roadmap.at<std::uint8_t>(y, x)] + reference_offset;
    return reference - kLog[frame.at<std::uint8_t>(y, x)];
  }

  // Thins `labels_box == label` (a region's bounding box) and puts the longest skeleton path, from its
  // end nearer the entry edge, in the box's coordinates, into `path`.
  void longest_skeleton_path(const cv::Mat& labels_box, int label) {
    cv::compare(labels_box, label, region, cv::CMP_EQ);
    cv::copyMakeBorder(region, padded, 1, 1, 1, 1, cv::BORDER_CONSTANT, cv::Scalar(0));
    longest_skeleton_path();
  }

  // The same for the region already drawn into `padded` (0/255, one-pixel empty border).
  void longest_skeleton_path() {
    thin(padded);
    skeleton = padded;  // shares the buffer
    // The longest path through the skeleton (its diameter, found by two breadth-first sweeps: the
    // farthest pixel from anywhere is an end of it), so spurs that thinning leaves on a rough outline
    // and side branches are dropped; then it is turned to start at its end nearer the entry edge.
    path.clear();
    cv::Point any(-1, -1);
    for (int r = 0; r < skeleton.rows && any.x < 0; ++r) {
      const auto* row = skeleton.ptr<std::uint8_t>(r);
      for (int c = 0; c < skeleton.cols; ++c)
        if (row[c]) {
          any = {c, r};
          break;
        }
    }
    if (any.x < 0) return;
    const int cols = skeleton.cols;
    const int end_a = farthest_from(any.y * cols + any.x);
    const int end_b = farthest_from(end_a);
    for (int index = end_b;;) {
      path.emplace_back(index % cols - 1, index / cols - 1);  // padded → box coordinates
      const int up = parent.at<int>(index / cols, index % cols);
      if (up == index) break;
      index = up;
    }
    // path runs end_b → end_a; start at the end toward the entry edge.
    const auto toward_entry = [this](const cv::Point& p) {
      switch (params.entry) {
        case ImageEdge::kBottom:
          return p.y;
        case ImageEdge::kTop:
          return -p.y;
        case ImageEdge::kLeft:
          return -p.x;
        case ImageEdge::kRight:
          return p.x;
      }
      return p.y;
    };
    if (toward_entry(path.back()) > toward_entry(path.front())) std::reverse(path.begin(), path.end());
  }

  struct Region {
    cv::Rect box;
    int area = 0;
    std::size_t others = 0;  // further regions of at least the minimum area
  };

  // The largest 8-connected region of a 0/255 mask with at least `min_area` pixels, drawn into
  // `padded` (its box plus a one-pixel empty border). A flood fill from the foreground pixels only:
  // the catheter's mask is sparse, and cv::connectedComponentsWithStats, which labels every pixel of
  // the ROI, took about half of the frame's time (1.8 of 3.9 ms at 1024², downsample 2).
  Region largest_region(const cv::Mat& binary, int min_area) {
    if (region_label.size() != binary.size()) {
      region_label.create(binary.size(), CV_32S);
      region_label.setTo(0);  // kept zero between frames: only the pixels set are cleared after use
    }
    cv::findNonZero(binary, nonzero);
    order.clear();
    Region best;
    std::size_t best_start = 0, large = 0;
    int label = 0;
    for (const cv::Point& seed : nonzero) {
      if (region_label.at<int>(seed)) continue;
      ++label;
      const std::size_t start = order.size();
      order.push_back(seed);
      region_label.at<int>(seed) = label;
      int x0 = seed.x, x1 = seed.x, y0 = seed.y, y1 = seed.y;
      for (std::size_t head = start; head < order.size(); ++head) {
        const cv::Point p = order[head];
        x0 = std::min(x0, p.x), x1 = std::max(x1, p.x), y0 = std::min(y0, p.y), y1 = std::max(y1, p.y);
        for (std::size_t k = 0; k < 8; ++k) {
          const int qx = p.x + kColStep[k], qy = p.y + kRowStep[k];
          if (qx < 0 || qy < 0 || qx >= binary.cols || qy >= binary.rows) continue;
          if (!binary.at<std::uint8_t>(qy, qx) || region_label.at<int>(qy, qx)) continue;
          region_label.at<int>(qy, qx) = label;
          order.emplace_back(qx, qy);
        }
      }
      const int area = static_cast<int>(order.size() - start);
      if (area < min_area) continue;
      ++large;
      if (area > best.area) {
        best.area = area;
        best.box = cv::Rect(x0, y0, x1 - x0 + 1, y1 - y0 + 1);
        best_start = start;
      }
    }
    if (best.area > 0) {
      best.others = large - 1;
      padded.create(best.box.height + 2, best.box.width + 2, CV_8U);
      padded.setTo(0);
      for (std::size_t i = best_start; i < best_start + static_cast<std::size_t>(best.area); ++i)
        padded.at<std::uint8_t>(order[i].y - best.box.y + 1, order[i].x - best.box.x + 1) = 255;
    }
    for (const cv::Point& p : order) region_label.at<int>(p) = 0;
    return best;
  }

  // Zhang–Suen thinning in place of a 0/255 image with a zero border, visiting only the foreground
  // (cv::ximgproc::thinning sweeps the whole box on every pass: with it the vessel centerline of a
  // 1024² roadmap took 11 ms of CPU, with this 5).
  void thin(cv::Mat& image) {
    const auto step = static_cast<std::ptrdiff_t>(image.step);
    std::array<std::ptrdiff_t, 8> offset{};
    for (std::size_t k = 0; k < 8; ++k) offset[k] = kRowStep[k] * step + kColStep[k];
    std::uint8_t* data = image.data;
    foreground.clear();
    for (int r = 1; r + 1 < image.rows; ++r)
      for (int c = 1; c + 1 < image.cols; ++c)
        if (data[r * step + c]) foreground.push_back(r * step + c);
    bool changed = true;
    while (changed) {
      changed = false;
      for (int pass = 0; pass < 2; ++pass) {
        removed.clear();
        for (const std::ptrdiff_t index : foreground) {
          std::array<int, 8> p{};
          for (std::size_t k = 0; k < 8; ++k) p[k] = data[index + offset[k]] ? 1 : 0;
          const int b = p[0] + p[1] + p[2] + p[3] + p[4] + p[5] + p[6] + p[7];
          if (b < 2 || b > 6) continue;
          int a = 0;
          for (std::size_t k = 0; k < 8; ++k) a += (p[k] == 0 && p[(k + 1) % 8] == 1) ? 1 : 0;
          if (a != 1) continue;
          // p[0] = N, p[2] = E, p[4] = S, p[6] = W.
          const bool remove = pass == 0 ? (p[0] * p[2] * p[4] == 0 && p[2] * p[4] * p[6] == 0)
                                        : (p[0] * p[2] * p[6] == 0 && p[0] * p[4] * p[6] == 0);
          if (remove) removed.push_back(index);
        }
        for (const std::ptrdiff_t index : removed) data[index] = 0;
        if (!removed.empty()) {
          changed = true;
          std::erase_if(foreground, [data](std::ptrdiff_t index) { return data[index] == 0; });
        }
      }
    }
  }

  // Breadth-first sweep over the 8-connected skeleton from pixel `start` (index row·cols + col):
  // fills `parent` and returns the last pixel reached (one of the farthest).
  int farthest_from(int start) {
    parent.create(skeleton.size(), CV_32S);
    parent.setTo(-1);
    const int cols = skeleton.cols;
    queue.clear();
    queue.push_back(start);
    parent.at<int>(start / cols, start % cols) = start;
    int last = start;
    for (std::size_t head = 0; head < queue.size(); ++head) {
      const int index = queue[head];
      last = index;
      const int x = index % cols, y = index / cols;
      for (std::size_t k = 0; k < 8; ++k) {
        const int qx = x + kColStep[k], qy = y + kRowStep[k];
        if (qx < 0 || qy < 0 || qx >= cols || qy >= skeleton.rows) continue;
        if (!skeleton.at<std::uint8_t>(qy, qx) || parent.at<int>(qy, qx) >= 0) continue;
        parent.at<int>(qy, qx) = index;
        queue.push_back(qy * cols + qx);
      }
    }
    return last;
  }

  // Least-squares cubic B-spline through `points` (chord-length parameter), sampled at `count` points.
  void fit_spline(const std::vector<Eigen::Vector2d>& in, std::vector<Eigen::Vector2d>& out, double& length) {
    const int n = static_cast<int>(in.size());
    arc.resize(in.size());
    arc[0] = 0.0;
    for (int i = 1; i < n; ++i)
      arc[static_cast<std::size_t>(i)] =
          arc[static_cast<std::size_t>(i - 1)] +
          (in[static_cast<std::size_t>(i)] - in[static_cast<std::size_t>(i - 1)]).norm();
    const double total = arc.back();
    const int samples = params.spline_points;
    out.resize(static_cast<std::size_t>(samples));
    if (n < 4 || !(total > 0)) {
      // Too few points for a cubic: straight line between the ends.
      for (int k = 0; k < samples; ++k) {
        const double f = static_cast<double>(k) / (samples - 1);
        out[static_cast<std::size_t>(k)] = (1 - f) * in.front() + f * in.back();
      }
      length = (in.back() - in.front()).norm();
      return;
    }
    const int count = std::clamp(static_cast<int>(std::lround(total / params.spline_knot_spacing_px)) + 3, 4,
                                 std::min(n, 256));
    normal_matrix.setZero(count, count);
    rhs.setZero(count, 2);
    for (int i = 0; i < n; ++i) {
      const auto b = cubic_basis(count, arc[static_cast<std::size_t>(i)] / total);
      // The end points weigh more: the tip is what the user steers by, and a least-squares spline
      // otherwise rounds a curled end off toward its inside.
      const double weight = (i == 0 || i == n - 1) ? 8.0 : 1.0;
      for (int a = 0; a < 4; ++a) {
        const double wa = weight * b.value[static_cast<std::size_t>(a)];
        rhs.row(b.first + a) += wa * in[static_cast<std::size_t>(i)].transpose();
        for (int c = 0; c < 4; ++c)
          normal_matrix(b.first + a, b.first + c) += wa * b.value[static_cast<std::size_t>(c)];
      }
    }
    // A whisper of ridge keeps spans without data (uneven sampling) solvable.
    normal_matrix.diagonal().array() += 1e-9 * normal_matrix.diagonal().maxCoeff();
    solver.compute(normal_matrix);
    control = solver.solve(rhs);
    length = 0.0;
    for (int k = 0; k < samples; ++k) {
      const auto b = cubic_basis(count, static_cast<double>(k) / (samples - 1));
      Eigen::Vector2d p = Eigen::Vector2d::Zero();
      for (int a = 0; a < 4; ++a)
        p += b.value[static_cast<std::size_t>(a)] * control.row(b.first + a).transpose();
      if (k > 0) length += (p - out[static_cast<std::size_t>(k - 1)]).norm();
      out[static_cast<std::size_t>(k)] = p;
    }
  }

  // The skeleton stops short of the tip (thinning eats the ends, by about half the tube's width). From
  // the last backbone point, march on along the backbone's direction on full-resolution pixels to
  // where the attenuation falls to half its peak across the tube (the end of the imaged catheter, at
  // half maximum so the blur does not move it), then step back by the tube's half-width there: the
  // tip is rounded, so the backbone ends at the centre of the end's curvature. The point joins the
  // backbone before the spline fit.
  Eigen::Vector2d direction_at_end(double radius) const {
    const Eigen::Vector2d last = points.back();
    Eigen::Vector2d mean = Eigen::Vector2d::Zero();
    int near = 0;
    for (const auto& p : points)
      if ((p - last).norm() <= radius) mean += p, ++near;
    Eigen::Vector2d direction = last - points.front();
    if (near >= 2) {
      mean /= near;
      Eigen::Matrix2d scatter = Eigen::Matrix2d::Zero();
      for (const auto& p : points)
        if ((p - last).norm() <= radius) scatter += (p - mean) * (p - mean).transpose();
      const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eigen(scatter);
      direction = eigen.eigenvectors().col(1);                     // the largest eigenvalue's
      if (direction.dot(last - mean) < 0) direction = -direction;  // the nearby points lie behind the end
    }
    return direction.norm() > 0 ? Eigen::Vector2d(direction.normalized()) : Eigen::Vector2d::Zero();
  }

  void extend_to_tip(const cv::Mat& frame, const Eigen::Vector2d& direction) {
    if (points.size() < 2 || !(direction.norm() > 0)) return;
    const Eigen::Vector2d last = points.back();
    const Eigen::Vector2d normal(-direction.y(), direction.x());
    const auto sample = [&](const Eigen::Vector2d& q) {
      const int x = static_cast<int>(std::lround(q.x())), y = static_cast<int>(std::lround(q.y()));
      if (x < roi.x || y < roi.y || x >= roi.x + roi.width || y >= roi.y + roi.height) return 0.0F;
      return difference_at(frame, x, y);
    };
    // Width at half maximum across the tube at the last point (0.5 px steps, 3 samples along).
    const int reach = static_cast<int>(std::ceil(2.0 * (result.width_px + 4.0)));  // half pixels
    float peak = 0.0F;
    for (int step = -reach; step <= reach; ++step) {
      const double t = 0.5 * step;
      float v = 0.0F;
      for (int a = -1; a <= 1; ++a) v += sample(last + t * normal + a * direction);
      peak = std::max(peak, v / 3.0F);
    }
    if (peak <= static_cast<float>(params.threshold)) return;
    const float half_level = 0.5F * peak;
    int above = 0;
    for (int step = -reach; step <= reach; ++step) {
      const double t = 0.5 * step;
      float v = 0.0F;
      for (int a = -1; a <= 1; ++a) v += sample(last + t * normal + a * direction);
      above += v / 3.0F >= half_level ? 1 : 0;
    }
    const double half_width = 0.25 * above;  // samples are 0.5 px apart
    // Along the direction: the first half-maximum crossing (mean of 3 samples across the axis).
    float previous = peak;
    for (int step = 1; step <= 3 * reach; ++step) {
      const double t = 0.5 * step;
      float v = 0.0F;
      for (int a = -1; a <= 1; ++a) v += sample(last + t * direction + a * normal);
      v /= 3.0F;
      if (v < half_level) {
        const double crossing = t - 0.5 + 0.5 * (previous - half_level) / std::max(1e-3F, previous - v);
        const double tip = crossing - half_width;
        if (tip > 0.5) points.push_back(last + tip * direction);
        return;
      }
      previous = v;
    }
  }

  const CatheterSegmentation& segment(GreyImageView view) {
    if (roadmap.empty()) {
      fail(SegmentationFailure::kNoRoadmap, "no roadmap (empty-vessel image) has been set for this view");
      return result;
    }
    if (view.data == nullptr || view.width <= 0 || view.height <= 0 || view.stride < view.width) {
      fail(SegmentationFailure::kInvalidFrame,
           "the frame has no pixels (null data, or a size or stride ≤ 0)");
      return result;
    }
    if (view.width != roadmap.cols || view.height != roadmap.rows) {
      fail(SegmentationFailure::kFrameSizeMismatch,
           "the frame is " + std::to_string(view.width) + "×" + std::to_string(view.height) +
               " pixels, the roadmap " + std::to_string(roadmap.cols) + "×" + std::to_string(roadmap.rows));
      return result;
    }
    prepare_derived();
    if (roi.width < kMinRoiSide || roi.height < kMinRoiSide) {
      fail(SegmentationFailure::kRoiOutsideFrame,
           "the region of interest (x " + std::to_string(params.roi.x) + ", y " +
               std::to_string(params.roi.y) + ", " + std::to_string(params.roi.width) + "×" +
               std::to_string(params.roi.height) + ") leaves less than 8×8 pixels of the " +
               std::to_string(view.width) + "×" + std::to_string(view.height) + " frame");
      return result;
    }
    const cv::Mat frame(view.height, view.width, CV_8U, const_cast<std::uint8_t*>(view.data),
                        static_cast<std::size_t>(view.stride));
    const int ds = params.downsample;
    downsample_into(frame(roi), small);
    double lo = 0, hi = 0;
    cv::minMaxLoc(small, &lo, &hi);
    if (hi - lo < 1.0) {
      fail(SegmentationFailure::kBlankFrame,
           "the frame is blank: one grey level (" + std::to_string(static_cast<int>(lo)) +
               ") over the whole region of interest; is the source sending?");
      return result;
    }
    cv::LUT(small, log_lut, frame_log);
    cv::subtract(reference_log, frame_log, difference16);
    difference16.convertTo(difference, CV_8U);  // saturates: brighter than the reference → 0
    cv::threshold(difference, mask, params.threshold - 1, 255, cv::THRESH_BINARY);
    if (!open_kernel.empty()) cv::morphologyEx(mask, mask, cv::MORPH_OPEN, open_kernel);
    const Region found = largest_region(mask, std::max(1, params.min_blob_px / (ds * ds)));
    if (found.area == 0) {
      fail(SegmentationFailure::kNoCatheterInRoi,
           "no catheter in the region of interest: nothing there is darker than the roadmap by the threshold "
           "(" +
               std::to_string(params.threshold) + ") over at least " + std::to_string(params.min_blob_px) +
               " pixels");
      return result;
    }
    const cv::Rect box = found.box;
    const int area = found.area;
    longest_skeleton_path();
    if (path.size() < 3) {
      fail(SegmentationFailure::kCatheterTooShort, "a region of " + std::to_string(area * ds * ds) +
                                                       " pixels was found, but its skeleton is only " +
                                                       std::to_string(path.size()) + " points long");
      return result;
    }
    result.found = true;
    result.failure = SegmentationFailure::kNone;
    result.message.clear();
    result.region_pixels = static_cast<std::size_t>(area) * static_cast<std::size_t>(ds * ds);
    result.other_regions = found.others;
    const double width_small = static_cast<double>(area) / static_cast<double>(path.size());
    result.width_px = width_small * ds;

    // Outline: Canny on the difference image around the region; a backbone point is supported when
    // outline lies within the expected half-width plus 2 px on both sides.
    const cv::Rect around = cv::Rect(box.x - 2, box.y - 2, box.width + 4, box.height + 4) &
                            cv::Rect(0, 0, difference.cols, difference.rows);
    cv::Canny(difference(around), edges, params.canny_low, params.canny_high, 3, true);
    const int reach = static_cast<int>(std::ceil(0.5 * width_small)) + 2;
    std::size_t supported = 0;

    // Refinement on full-resolution pixels: each skeleton point moves across the catheter to the
    // attenuation-weighted centre of the profile (above half the threshold, so noise adds nothing).
    const int half = static_cast<int>(std::ceil(0.5 * result.width_px)) + 2;
    const float floor_level = 0.5F * static_cast<float>(params.threshold);
    points.clear();
    double attenuation_sum = 0.0;
    const int n = static_cast<int>(path.size());
    constexpr int kTangentStep = 2;
    for (int i = 0; i < n; ++i) {
      const cv::Point a = path[static_cast<std::size_t>(std::max(0, i - kTangentStep))];
      const cv::Point b = path[static_cast<std::size_t>(std::min(n - 1, i + kTangentStep))];
      Eigen::Vector2d tangent(b.x - a.x, b.y - a.y);
      if (tangent.norm() == 0) tangent = Eigen::Vector2d(0, 1);
      tangent.normalize();
      const Eigen::Vector2d normal(-tangent.y(), tangent.x());
      const cv::Point p = path[static_cast<std::size_t>(i)];
      // Outline support (detection pixels, `edges` is offset by `around`).
      bool plus = false, minus = false;
      for (int t = 1; t <= reach && !(plus && minus); ++t) {
        for (const int sign : {1, -1}) {
          const int ex = static_cast<int>(std::lround(p.x + box.x - around.x + sign * t * normal.x()));
          const int ey = static_cast<int>(std::lround(p.y + box.y - around.y + sign * t * normal.y()));
          if (ex < 0 || ey < 0 || ex >= edges.cols || ey >= edges.rows || !edges.at<std::uint8_t>(ey, ex))
            continue;
          (sign > 0 ? plus : minus) = true;
        }
      }
      supported += plus && minus ? 1 : 0;
      // Full-resolution centre of the detection pixel.
      const Eigen::Vector2d centre(roi.x + (p.x + box.x + 0.5) * ds - 0.5,
                                   roi.y + (p.y + box.y + 0.5) * ds - 0.5);
      double sw = 0.0, st = 0.0;
      float peak = 0.0F;
      for (int t = -half; t <= half; ++t) {
        const Eigen::Vector2d q = centre + t * normal;
        const int x = static_cast<int>(std::lround(q.x())), y = static_cast<int>(std::lround(q.y()));
        if (x < roi.x || y < roi.y || x >= roi.x + roi.width || y >= roi.y + roi.height) continue;
        const float d = difference_at(frame, x, y);
        if (std::abs(t) <= 1) peak = std::max(peak, d);
        const double w = std::max(0.0F, d - floor_level);
        sw += w;
        st += w * t;
      }
      attenuation_sum += peak;
      points.push_back(sw > 0 ? Eigen::Vector2d(centre + (st / sw) * normal) : centre);
    }
    result.mean_attenuation = attenuation_sum / n;
    const double support = static_cast<double>(supported) / n;
    const double margin = std::clamp(
        (result.mean_attenuation - params.threshold) / static_cast<double>(params.threshold), 0.0, 1.0);
    result.quality = support * margin;

    // Direction: the principal axis of the refined backbone points within 1.5 tube widths of the last
    // one (a local straight-line fit; the spline's end tangent swings with its last span). On the
    // tightest tip bend imaged here (≈ 120 px radius) a fit over 16 px turns ≈ 2° from the tangent.
    const Eigen::Vector2d end_direction = direction_at_end(std::max(6.0, 1.5 * result.width_px));
    extend_to_tip(frame, end_direction);
    fit_spline(points, result.polyline, result.length_px);
    result.tip = result.polyline.back();
    result.tip_direction = end_direction;
    return result;
  }

  const VesselCenterlineResult& vessel_centerline() {
    if (vessel_valid) return vessel;
    vessel = {};
    vessel_valid = true;
    if (roadmap.empty()) {
      vessel.message = "no roadmap (empty-vessel image) has been set for this view";
      return vessel;
    }
    prepare_derived();
    if (roi.width < kMinRoiSide || roi.height < kMinRoiSide) {
      vessel.message = "the region of interest leaves less than 8×8 pixels of the roadmap";
      return vessel;
    }
    const int ds = params.downsample;
    cv::Mat reduced, log16, hat;
    downsample_into(roadmap(roi), reduced);
    cv::LUT(reduced, log_lut, log16);
    // Black-hat with a rectangle wider than the widest lumen: the closing fills the vessel in, the
    // smooth background (tissue, anatomy) stays, so closing − image is the contrast alone.
    const int side = static_cast<int>(std::ceil(params.vessel_max_width_px / ds)) | 1;
    cv::morphologyEx(log16, hat, cv::MORPH_BLACKHAT,
                     cv::getStructuringElement(cv::MORPH_RECT, cv::Size(side + 2, side + 2)));
    cv::Mat hat8, vessel_mask;
    hat.convertTo(hat8, CV_8U);
    cv::threshold(hat8, vessel_mask, params.vessel_threshold - 1, 255, cv::THRESH_BINARY);
    if (!open_kernel.empty()) cv::morphologyEx(vessel_mask, vessel_mask, cv::MORPH_OPEN, open_kernel);
    cv::Mat vessel_labels, vessel_stats, vessel_centroids;
    const int count = cv::connectedComponentsWithStats(vessel_mask, vessel_labels, vessel_stats,
                                                       vessel_centroids, 8, CV_32S);
    int best = 0;
    for (int label = 1; label < count; ++label)
      if (best == 0 ||
          vessel_stats.at<int>(label, cv::CC_STAT_AREA) > vessel_stats.at<int>(best, cv::CC_STAT_AREA))
        best = label;
    if (best == 0 || vessel_stats.at<int>(best, cv::CC_STAT_AREA) * ds * ds < params.min_blob_px) {
      vessel.message = "no vessel in the roadmap: nothing has contrast above vessel_threshold (" +
                       std::to_string(params.vessel_threshold) + ") over at least " +
                       std::to_string(params.min_blob_px) + " pixels";
      return vessel;
    }
    const cv::Rect box(
        vessel_stats.at<int>(best, cv::CC_STAT_LEFT), vessel_stats.at<int>(best, cv::CC_STAT_TOP),
        vessel_stats.at<int>(best, cv::CC_STAT_WIDTH), vessel_stats.at<int>(best, cv::CC_STAT_HEIGHT));
    longest_skeleton_path(vessel_labels(box), best);
    if (path.size() < 3) {
      vessel.message = "the vessel region thinned to fewer than 3 points";
      return vessel;
    }
    std::vector<Eigen::Vector2d> centre;
    centre.reserve(path.size());
    for (const auto& p : path)
      centre.emplace_back(roi.x + (p.x + box.x + 0.5) * ds - 0.5, roi.y + (p.y + box.y + 0.5) * ds - 0.5);
    vessel.region_pixels = static_cast<std::size_t>(vessel_stats.at<int>(best, cv::CC_STAT_AREA)) *
                           static_cast<std::size_t>(ds * ds);
    fit_spline(centre, vessel.polyline, vessel.length_px);
    vessel.found = true;
    return vessel;
  }
};

FluoroscopySegmenter::FluoroscopySegmenter(const FluoroscopySegmentationParameters& parameters)
    : impl_(std::make_unique<Impl>()) {
  parameters.validate();
  impl_->params = parameters;
  impl_->fail(SegmentationFailure::kNoRoadmap, "no frame has been segmented yet");
}

FluoroscopySegmenter::~FluoroscopySegmenter() = default;
FluoroscopySegmenter::FluoroscopySegmenter(FluoroscopySegmenter&&) noexcept = default;
FluoroscopySegmenter& FluoroscopySegmenter::operator=(FluoroscopySegmenter&&) noexcept = default;

void FluoroscopySegmenter::set_parameters(const FluoroscopySegmentationParameters& parameters) {
  parameters.validate();
  impl_->params = parameters;
  impl_->derived_valid = false;
  impl_->vessel_valid = false;
}

const FluoroscopySegmentationParameters& FluoroscopySegmenter::parameters() const noexcept {
  return impl_->params;
}

void FluoroscopySegmenter::set_roadmap(GreyImageView roadmap) {
  if (roadmap.data == nullptr || roadmap.width <= 0 || roadmap.height <= 0 || roadmap.stride < roadmap.width)
    throw SegmentationParameterError("roadmap",
                                     "roadmap: the image has no pixels (null data, or a size or stride ≤ 0)");
  const cv::Rect roi =
      resolve_roi(impl_->params.roi, roadmap.width, roadmap.height, impl_->params.downsample);
  if (roi.width < kMinRoiSide || roi.height < kMinRoiSide)
    throw SegmentationParameterError(
        "roi", "roi: the region of interest leaves less than 8×8 pixels of the " +
                   std::to_string(roadmap.width) + "×" + std::to_string(roadmap.height) + " roadmap");
  const cv::Mat view(roadmap.height, roadmap.width, CV_8U, const_cast<std::uint8_t*>(roadmap.data),
                     static_cast<std::size_t>(roadmap.stride));
  view.copyTo(impl_->roadmap);
  impl_->derived_valid = false;
  impl_->vessel_valid = false;
}

bool FluoroscopySegmenter::has_roadmap() const noexcept { return !impl_->roadmap.empty(); }

const CatheterSegmentation& FluoroscopySegmenter::segment(GreyImageView frame) {
  return impl_->segment(frame);
}

const VesselCenterlineResult& FluoroscopySegmenter::vessel_centerline() { return impl_->vessel_centerline(); }

}  // namespace tendril::teleop::perception
