#include "tendril/drivers/sim/simulated_fluoroscope.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>
#include <random>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace tendril::sim {

namespace {

constexpr int kSubpixelShift = 4;  // cv::line fixed-point coordinates: 1/16 px
constexpr double kSubpixelScale = 1 << kSubpixelShift;
constexpr std::size_t kNormalTableSize = 4096;  // 12-bit index into precomputed N(0,1) samples
constexpr int kVesselBands = 4;
constexpr int kCatheterBands = 3;

void require(bool ok, const std::string& message) {
  if (!ok) throw FluoroscopeError("simulated fluoroscope: " + message);
}

bool finite(const Eigen::Vector3d& v) { return v.allFinite(); }

// xorshift64*: fast, deterministic noise indices (quality far beyond what image noise needs).
std::uint64_t next_random(std::uint64_t& state) {
  state ^= state >> 12;
  state ^= state << 25;
  state ^= state >> 27;
  return state * 0x2545F4914F6CDD1DULL;
}

// Chord length through a tube of radius r at distance d from its axis.
double chord(double r, double d) { return d >= r ? 0.0 : 2.0 * std::sqrt(r * r - d * d); }

}  // namespace

const char* view_name(FluoroView view) noexcept { return view == FluoroView::kAp ? "ap" : "lateral"; }

struct SimulatedFluoroscope::Impl {
  FluoroView view;
  FluoroscopeOptions opts;
  Eigen::Vector3d beam, axis_u, axis_v, source;
  double gain = 0.0;
  int blur_radius = 0;  // Gaussian kernel half-width in pixels

  cv::Mat static_counts;          // CV_32F expected counts without the catheter, unblurred
  cv::Mat blurred_static_counts;  // the same, blurred
  cv::Mat frame_counts;           // this frame's blurred expected counts
  cv::Mat layer;                  // CV_32F catheter line integrals (zero outside last_roi)
  cv::Mat roi_product, roi_transmission, roi_blurred;
  cv::Rect last_roi;  // region of frame_counts that differs from blurred_static_counts
  cv::Mat gray;       // CV_8U output
  std::array<float, kNormalTableSize> normals{};
  std::array<float, 256> noise_sd{};  // standard deviation of the display value at each mean
  std::uint64_t rng = 1;
  std::vector<cv::Point> projected;
  std::vector<double> projected_radius_px;

  DetectorPoint project(const Eigen::Vector3d& p) const {
    const Eigen::Vector3d rel = p - source;
    const double depth = rel.dot(beam);
    DetectorPoint out;
    if (!(depth > 1e-9)) return out;
    const double magnification = opts.geometry.sid_mm / depth;
    const double pitch = opts.geometry.pixel_spacing_mm;
    out.column = 0.5 * (opts.geometry.width - 1) + rel.dot(axis_u) * magnification / pitch;
    out.row = 0.5 * (opts.geometry.height - 1) - rel.dot(axis_v) * magnification / pitch;
    out.magnification = magnification;
    out.in_front = true;
    return out;
  }

  static cv::Point fixed_point(const DetectorPoint& p) {
    return {static_cast<int>(std::lround(p.column * kSubpixelScale)),
            static_cast<int>(std::lround(p.row * kSubpixelScale))};
  }

  // Draws a tube along `points` into `target` as `bands` nested thick lines: band k covers the
  // distances from the axis in [r·(1−(k+1)/n), r·(1−k/n)] with the line integral at the band's
  // middle, so the projected profile follows the chord length of a cylinder. `value_at(r_mm, d_mm)`
  // gives the line integral through the tube (and whatever it wraps) at distance d.
  template <typename ValueAt>
  void draw_tube(cv::Mat& target, std::span<const Eigen::Vector3d> points, std::span<const double> radius_mm,
                 int bands, ValueAt value_at) {
    const double pitch = opts.geometry.pixel_spacing_mm;
    for (int band = 0; band < bands; ++band) {
      const double outer = 1.0 - static_cast<double>(band) / bands;
      const double middle = 1.0 - (band + 0.5) / bands;
      for (std::size_t i = 0; i + 1 < points.size(); ++i) {
        const auto a = project(points[i]);
        const auto b = project(points[i + 1]);
        if (!a.in_front || !b.in_front) continue;
        const double r = 0.5 * (radius_mm[i] + radius_mm[i + 1]);
        const double r_px = r * 0.5 * (a.magnification + b.magnification) / pitch;
        const int thickness = std::max(1, static_cast<int>(std::lround(2.0 * r_px * outer)));
        const double value = value_at(r, r * middle);
        cv::line(target, fixed_point(a), fixed_point(b), cv::Scalar(value), thickness, cv::LINE_8,
                 kSubpixelShift);
      }
    }
  }

  void build_static(const std::vector<VesselTube>& vessels) {
    const int w = opts.geometry.width, h = opts.geometry.height;
    cv::Mat attenuation(h, w, CV_32F, cv::Scalar(opts.tissue_attenuation));
    if (opts.anatomy) {
      // A few wide, faint blobs (bone and soft-tissue density differences), deterministic per seed.
      std::mt19937_64 gen(opts.noise_seed ^ (view == FluoroView::kAp ? 0xA9ULL : 0x1A7ULL));
      std::uniform_real_distribution<double> unit(0.0, 1.0);
      for (int blob = 0; blob < 6; ++blob) {
        const double cx = unit(gen) * w, cy = unit(gen) * h;
        const double sigma = (0.12 + 0.2 * unit(gen)) * std::max(w, h);
        const double amplitude = 0.05 + 0.25 * unit(gen);
        for (int y = 0; y < h; ++y) {
          auto* row = attenuation.ptr<float>(y);
          const double dy2 = (y - cy) * (y - cy);
          for (int x = 0; x < w; ++x) {
            const double d2 = (x - cx) * (x - cx) + dy2;
            row[x] += static_cast<float>(amplitude * std::exp(-0.5 * d2 / (sigma * sigma)));
          }
        }
      }
    }
    for (const auto& vessel : vessels) {
      if (vessel.centerline.size() < 2) continue;
      // One layer per branch, added, so that branches crossing in projection add up.
      cv::Mat lumen(h, w, CV_32F, cv::Scalar(0));
      const double mu = opts.contrast_attenuation_per_mm;
      draw_tube(lumen, vessel.centerline, vessel.radius_mm, kVesselBands,
                [mu](double r, double d) { return mu * chord(r, d); });
      attenuation += lumen;
    }
    cv::Mat negative = -attenuation;
    cv::exp(negative, static_counts);
    static_counts *= opts.photons_per_pixel;
    blur(static_counts, blurred_static_counts);
    blurred_static_counts.copyTo(frame_counts);
    layer = cv::Mat(h, w, CV_32F, cv::Scalar(0));
    gray = cv::Mat(h, w, CV_8U, cv::Scalar(0));
  }

  void blur(const cv::Mat& in, cv::Mat& out) const {
    if (blur_radius == 0) {
      in.copyTo(out);
      return;
    }
    const int k = 2 * blur_radius + 1;
    cv::GaussianBlur(in, out, cv::Size(k, k), opts.blur_sigma_px, opts.blur_sigma_px, cv::BORDER_REPLICATE);
  }

  void build_noise_tables() {
    std::mt19937_64 gen(opts.noise_seed);
    std::normal_distribution<double> normal(0.0, 1.0);
    std::array<double, kNormalTableSize> samples{};
    for (auto& s : samples) s = normal(gen);
    // Exactly zero mean and unit variance, so the image statistics depend only on the count.
    const double mean = std::accumulate(samples.begin(), samples.end(), 0.0) / kNormalTableSize;
    double var = 0.0;
    for (double s : samples) var += (s - mean) * (s - mean);
    const double sd = std::sqrt(var / kNormalTableSize);
    for (std::size_t i = 0; i < kNormalTableSize; ++i)
      normals[i] = static_cast<float>((samples[i] - mean) / sd);
    // Display value D = counts·g with counts ~ Poisson(λ): Var(D) = λ·g² = D·g.
    for (int m = 0; m < 256; ++m) noise_sd[m] = static_cast<float>(std::sqrt((m + 0.5) * gain));
    rng = opts.noise_seed | 1U;
  }

  void compose_frame(std::span<const Eigen::Vector3d> backbone) {
    const int w = opts.geometry.width, h = opts.geometry.height;
    // Undo the previous frame's catheter.
    if (last_roi.area() > 0) {
      layer(last_roi).setTo(0);
      blurred_static_counts(last_roi).copyTo(frame_counts(last_roi));
      last_roi = {};
    }
    if (backbone.size() < 2) return;
    const double pitch = opts.geometry.pixel_spacing_mm;
    double min_c = 1e300, max_c = -1e300, min_r = 1e300, max_r = -1e300, max_mag = 0.0;
    for (const auto& p : backbone) {
      const auto d = project(p);
      if (!d.in_front) continue;
      min_c = std::min(min_c, d.column), max_c = std::max(max_c, d.column);
      min_r = std::min(min_r, d.row), max_r = std::max(max_r, d.row);
      max_mag = std::max(max_mag, d.magnification);
    }
    if (max_mag == 0.0) return;
    const double widest_mm = std::max(opts.instrument_diameter_mm, opts.tip_marker_diameter_mm);
    const int margin = static_cast<int>(std::ceil(0.5 * widest_mm * max_mag / pitch)) + 2 + blur_radius;
    const cv::Rect image(0, 0, w, h);
    const cv::Rect drawn = cv::Rect(cv::Point(static_cast<int>(std::floor(min_c)) - margin,
                                              static_cast<int>(std::floor(min_r)) - margin),
                                    cv::Point(static_cast<int>(std::ceil(max_c)) + margin + 1,
                                              static_cast<int>(std::ceil(max_r)) + margin + 1)) &
                           image;
    if (drawn.area() == 0) return;

    // Catheter body.
    const double rc = 0.5 * opts.instrument_diameter_mm;
    std::vector<double> radii(backbone.size(), rc);
    const double mu_c = opts.catheter_attenuation_per_mm;
    draw_tube(layer, backbone, radii, kCatheterBands,
              [mu_c](double r, double d) { return mu_c * chord(r, d); });

    // Tip marker band: the last tip_marker_length_mm of the backbone, wrapping the catheter.
    std::vector<Eigen::Vector3d> marker{backbone.back()};
    double remaining = opts.tip_marker_length_mm;
    for (std::size_t i = backbone.size() - 1; i > 0 && remaining > 0; --i) {
      const Eigen::Vector3d step = backbone[i - 1] - backbone[i];
      const double length = step.norm();
      if (length >= remaining) {
        marker.push_back(backbone[i] + step * (remaining / length));
        remaining = 0;
      } else {
        marker.push_back(backbone[i - 1]);
        remaining -= length;
      }
    }
    if (marker.size() >= 2) {
      const double rm = 0.5 * opts.tip_marker_diameter_mm;
      std::vector<double> marker_radii(marker.size(), rm);
      const double mu_m = opts.tip_marker_attenuation_per_mm;
      draw_tube(layer, marker, marker_radii, kCatheterBands,
                [mu_m, mu_c, rc](double r, double d) { return mu_m * chord(r, d) + mu_c * chord(rc, d); });
    }

    // counts = static · exp(−layer) on the drawn region plus the blur kernel's reach, then blurred;
    // outside `drawn` the catheter adds nothing, so the blurred static image is already right there.
    const cv::Rect extended = cv::Rect(drawn.x - blur_radius, drawn.y - blur_radius,
                                       drawn.width + 2 * blur_radius, drawn.height + 2 * blur_radius) &
                              image;
    cv::Mat negative = -layer(extended);
    cv::exp(negative, roi_transmission);
    cv::multiply(static_counts(extended), roi_transmission, roi_product);
    blur(roi_product, roi_blurred);
    const cv::Rect inner = drawn - extended.tl();
    roi_blurred(inner).copyTo(frame_counts(drawn));
    // The layer was written within `drawn` only (margin covers the widest tube), so zeroing it
    // there next frame clears it.
    last_roi = drawn;
  }

  void quantise(bool with_noise) {
    const int w = opts.geometry.width, h = opts.geometry.height;
    const float g = static_cast<float>(gain);
    std::uint64_t bits = 0;
    int bits_left = 0;
    for (int y = 0; y < h; ++y) {
      const float* counts = frame_counts.ptr<float>(y);
      std::uint8_t* out = gray.ptr<std::uint8_t>(y);
      for (int x = 0; x < w; ++x) {
        float mean = std::clamp(counts[x] * g, 0.0f, 255.0f);
        if (with_noise) {
          if (bits_left == 0) {
            bits = next_random(rng);
            bits_left = 5;
          }
          const float z = normals[bits & (kNormalTableSize - 1)];
          bits >>= 12;
          --bits_left;
          mean += noise_sd[static_cast<int>(mean)] * z;
        }
        out[x] = static_cast<std::uint8_t>(std::clamp(mean + 0.5f, 0.0f, 255.0f));
      }
    }
  }
};

SimulatedFluoroscope::SimulatedFluoroscope(FluoroView view, FluoroscopeOptions options,
                                           const std::vector<VesselTube>& vessels)
    : impl_(std::make_unique<Impl>()) {
  const auto& g = options.geometry;
  require(std::isfinite(g.sid_mm) && std::isfinite(g.sod_mm) && g.sod_mm > 0 && g.sid_mm > g.sod_mm,
          "need 0 < SOD < SID (source-to-object and source-to-detector distances in mm), got SOD " +
              std::to_string(g.sod_mm) + ", SID " + std::to_string(g.sid_mm));
  require(std::isfinite(g.pixel_spacing_mm) && g.pixel_spacing_mm > 0,
          "pixel spacing must be a positive number of mm");
  require(g.width >= 16 && g.width <= 4096 && g.height >= 16 && g.height <= 4096,
          "detector size must be 16..4096 pixels per side, got " + std::to_string(g.width) + "x" +
              std::to_string(g.height));
  require(finite(g.isocentre), "isocentre must be finite");
  require(std::isfinite(options.photons_per_pixel) && options.photons_per_pixel >= 1,
          "photons_per_pixel must be at least 1");
  require(std::isfinite(options.blur_sigma_px) && options.blur_sigma_px >= 0 && options.blur_sigma_px <= 20,
          "blur sigma must be 0..20 px");
  for (double v :
       {options.instrument_diameter_mm, options.tip_marker_diameter_mm, options.tip_marker_length_mm,
        options.catheter_attenuation_per_mm, options.tip_marker_attenuation_per_mm,
        options.contrast_attenuation_per_mm, options.tissue_attenuation, options.display_gain})
    require(std::isfinite(v) && v >= 0, "diameters, lengths, attenuations and gain must be finite and >= 0");
  for (const auto& vessel : vessels) {
    require(vessel.centerline.size() == vessel.radius_mm.size(),
            "vessel needs one radius per centerline point (" + std::to_string(vessel.centerline.size()) +
                " points, " + std::to_string(vessel.radius_mm.size()) + " radii)");
    for (std::size_t i = 0; i < vessel.centerline.size(); ++i)
      require(finite(vessel.centerline[i]) && std::isfinite(vessel.radius_mm[i]) && vessel.radius_mm[i] >= 0,
              "vessel point " + std::to_string(i) + " is not finite or has a negative radius");
  }

  Impl& s = *impl_;
  s.view = view;
  s.opts = std::move(options);
  if (view == FluoroView::kAp) {
    s.beam = Eigen::Vector3d::UnitY();
    s.axis_u = Eigen::Vector3d::UnitX();
  } else {
    s.beam = Eigen::Vector3d::UnitX();
    s.axis_u = -Eigen::Vector3d::UnitY();
  }
  s.axis_v = Eigen::Vector3d::UnitZ();
  s.source = s.opts.geometry.isocentre - s.opts.geometry.sod_mm * s.beam;
  s.gain = s.opts.display_gain > 0 ? s.opts.display_gain : 240.0 / s.opts.photons_per_pixel;
  s.blur_radius = s.opts.blur_sigma_px > 0 ? static_cast<int>(std::ceil(3.0 * s.opts.blur_sigma_px)) : 0;
  s.build_noise_tables();
  s.build_static(vessels);
}

SimulatedFluoroscope::~SimulatedFluoroscope() = default;
SimulatedFluoroscope::SimulatedFluoroscope(SimulatedFluoroscope&&) noexcept = default;
SimulatedFluoroscope& SimulatedFluoroscope::operator=(SimulatedFluoroscope&&) noexcept = default;

FluoroView SimulatedFluoroscope::view() const noexcept { return impl_->view; }
const FluoroscopeOptions& SimulatedFluoroscope::options() const noexcept { return impl_->opts; }
int SimulatedFluoroscope::width() const noexcept { return impl_->opts.geometry.width; }
int SimulatedFluoroscope::height() const noexcept { return impl_->opts.geometry.height; }
double SimulatedFluoroscope::display_gain() const noexcept { return impl_->gain; }

DetectorPoint SimulatedFluoroscope::project(const Eigen::Vector3d& world_mm) const noexcept {
  return impl_->project(world_mm);
}

DetectorRay SimulatedFluoroscope::ray(double column, double row) const noexcept {
  const auto& s = *impl_;
  const auto& g = s.opts.geometry;
  // The detector point in the world: SID along the beam from the source, offset in the detector plane.
  const Eigen::Vector3d on_detector = s.source + g.sid_mm * s.beam +
                                      (column - 0.5 * (g.width - 1)) * g.pixel_spacing_mm * s.axis_u +
                                      (0.5 * (g.height - 1) - row) * g.pixel_spacing_mm * s.axis_v;
  return {s.source, (on_detector - s.source).normalized()};
}

std::span<const std::uint8_t> SimulatedFluoroscope::render(std::span<const Eigen::Vector3d> backbone) {
  impl_->compose_frame(backbone);
  impl_->quantise(true);
  return {impl_->gray.data, impl_->gray.total()};
}

std::span<const std::uint8_t> SimulatedFluoroscope::render_noiseless(
    std::span<const Eigen::Vector3d> backbone) {
  impl_->compose_frame(backbone);
  impl_->quantise(false);
  return {impl_->gray.data, impl_->gray.total()};
}

void SimulatedFluoroscope::encode_jpeg(int quality, std::vector<std::uint8_t>& out) const {
  if (quality < 1 || quality > 100)
    throw FluoroscopeError("simulated fluoroscope: JPEG quality must be 1..100, got " +
                           std::to_string(quality));
  out.clear();
  if (!cv::imencode(".jpg", impl_->gray, out, {cv::IMWRITE_JPEG_QUALITY, quality}))
    throw FluoroscopeError("simulated fluoroscope: OpenCV could not encode the JPEG");
}

std::vector<Eigen::Vector3f> vessel_wall_points(const VesselTube& vessel, double spacing_mm,
                                                int points_per_ring) {
  std::vector<Eigen::Vector3f> out;
  const auto& c = vessel.centerline;
  if (c.size() < 2 || vessel.radius_mm.size() != c.size() || !(spacing_mm > 0) || points_per_ring < 3)
    return out;
  double next_sample = 0.0, travelled = 0.0;
  for (std::size_t i = 0; i + 1 < c.size(); ++i) {
    const Eigen::Vector3d step = c[i + 1] - c[i];
    const double length = step.norm();
    if (!(length > 0)) continue;
    const Eigen::Vector3d t = step / length;
    // Any unit vector not parallel to t gives the ring's plane.
    const Eigen::Vector3d helper =
        std::abs(t.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
    const Eigen::Vector3d n1 = t.cross(helper).normalized();
    const Eigen::Vector3d n2 = t.cross(n1);
    while (next_sample <= travelled + length) {
      const double f = (next_sample - travelled) / length;
      const Eigen::Vector3d centre = c[i] + f * step;
      const double r = vessel.radius_mm[i] + f * (vessel.radius_mm[i + 1] - vessel.radius_mm[i]);
      for (int k = 0; k < points_per_ring; ++k) {
        const double a = 2.0 * M_PI * k / points_per_ring;
        out.push_back((centre + r * (std::cos(a) * n1 + std::sin(a) * n2)).cast<float>());
      }
      next_sample += spacing_mm;
    }
    travelled += length;
  }
  return out;
}

}  // namespace tendril::sim
