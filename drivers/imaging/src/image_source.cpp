#include "tendril/drivers/imaging/image_source.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <thread>

namespace tendril::imaging {

namespace {

using Clock = std::chrono::steady_clock;

constexpr int kMaxSide = 8192;  // larger frames are refused (a 64-Mpixel fluoroscopy frame is not one)

void check_size(const std::string& what, int width, int height) {
  if (width < 0 || height < 0 || width > kMaxSide || height > kMaxSide)
    throw ImageSourceError(what + ": the output size must be 0 (the source's own) or 1.." +
                           std::to_string(kMaxSide) + " pixels, got " + std::to_string(width) + "×" +
                           std::to_string(height));
  if ((width == 0) != (height == 0))
    throw ImageSourceError(what + ": give both width and height of the output, or neither");
}

// Any decoded frame to 8-bit grey of the output size, into `out`. False (with `reason`) when the frame
// is unusable.
bool to_grey(const cv::Mat& frame, int width, int height, cv::Mat& scratch, GreyImage& out,
             std::string& reason) {
  if (frame.empty()) {
    reason = "the frame is empty";
    return false;
  }
  if (frame.cols > kMaxSide || frame.rows > kMaxSide) {
    reason = "the frame is " + std::to_string(frame.cols) + "×" + std::to_string(frame.rows) +
             " pixels, larger than " + std::to_string(kMaxSide);
    return false;
  }
  const cv::Mat* grey = &frame;
  if (frame.channels() == 3) {
    cv::cvtColor(frame, scratch, cv::COLOR_BGR2GRAY);
    grey = &scratch;
  } else if (frame.channels() == 4) {
    cv::cvtColor(frame, scratch, cv::COLOR_BGRA2GRAY);
    grey = &scratch;
  } else if (frame.channels() != 1) {
    reason = "the frame has " + std::to_string(frame.channels()) + " channels (1, 3 or 4 expected)";
    return false;
  }
  if (grey->depth() != CV_8U) {
    // 16-bit detector output (PGM/TIFF): scale the full range to 8 bits.
    cv::Mat eight;
    const double scale = grey->depth() == CV_16U ? 1.0 / 257.0 : 1.0;
    grey->convertTo(eight, CV_8U, scale);
    scratch = eight;
    grey = &scratch;
  }
  const int w = width > 0 ? width : grey->cols;
  const int h = height > 0 ? height : grey->rows;
  out.width = w;
  out.height = h;
  out.pixels.resize(static_cast<std::size_t>(w) * static_cast<std::size_t>(h));
  cv::Mat target(h, w, CV_8UC1, out.pixels.data());
  if (grey->cols == w && grey->rows == h) {
    grey->copyTo(target);
  } else {
    cv::resize(*grey, target, target.size(), 0, 0, cv::INTER_AREA);
  }
  return true;
}

// Replays at a fixed period from the first grab on; a late reader skips nothing (a replay shows every
// frame), but never bursts: the next frame is due one period after the previous one was handed out
// when the reader fell behind.
class Pacer {
 public:
  explicit Pacer(double period_s)
      : period_(std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(period_s))) {}
  // False when `cancelled` was seen while waiting.
  template <typename Cancelled>
  bool wait(Cancelled cancelled) {
    const auto now = Clock::now();
    if (!started_) {
      started_ = true;
      next_ = now + period_;
      return !cancelled();
    }
    // In slices, so that a cancel is seen within one.
    for (auto t = Clock::now(); t < next_; t = Clock::now()) {
      if (cancelled()) return false;
      std::this_thread::sleep_until(std::min(next_, t + std::chrono::milliseconds(50)));
    }
    next_ = std::max(next_, now) + period_;
    return !cancelled();
  }
  void restart() { started_ = false; }

 private:
  Clock::duration period_;
  Clock::time_point next_{};
  bool started_ = false;
};

class VideoCaptureSource final : public ImageSource {
 public:
  explicit VideoCaptureSource(const VideoCaptureOptions& o)
      : options_(o), device_(o.path.string().rfind("/dev/", 0) == 0), pacer_(1.0) {
    const std::string what = (device_ ? "video device " : "video file ") + o.path.string();
    check_size(what, o.width, o.height);
    if (!std::isfinite(o.fps) || o.fps < 0 || o.fps > 1000)
      throw ImageSourceError(what + ": fps must be 0 (the file's own rate) or up to 1000, got " +
                             std::to_string(o.fps));
    if (!device_ && !std::filesystem::is_regular_file(o.path))
      throw ImageSourceError(what + ": no such file");
    const bool opened =
        device_ ? capture_.open(o.path.string(), cv::CAP_V4L2) : capture_.open(o.path.string());
    if (!opened || !capture_.isOpened())
      throw ImageSourceError(what + ": OpenCV could not open it" +
                             (device_
                                  ? std::string(" (is the device present, readable and a capture device?)")
                                  : std::string(" (no backend reads this format)")));
    if (device_) capture_.set(cv::CAP_PROP_BUFFERSIZE, 1);  // the newest frame, not a queue of old ones
    const double own_fps = capture_.get(cv::CAP_PROP_FPS);
    fps_ = o.fps > 0 ? o.fps : (std::isfinite(own_fps) && own_fps > 0 && own_fps <= 1000 ? own_fps : 25.0);
    pacer_ = Pacer(1.0 / fps_);
    description_ = (device_ ? "V4L2 " : "video file ") + o.path.string();
  }

  GrabResult grab(GreyImage& out) override {
    // A device delivers at its own rate; a file is replayed at fps_.
    if (!device_ && !pacer_.wait([this] { return cancelled(); })) return {GrabStatus::kEnded, "stopped"};
    if (!capture_.read(frame_)) {
      if (device_) return {GrabStatus::kDropped, description_ + ": no frame from the device"};
      if (!options_.loop) return {GrabStatus::kEnded, description_ + ": end of the file"};
      // Back to the start; a file whose first frame cannot be read either is dropped, not looped on.
      capture_.set(cv::CAP_PROP_POS_FRAMES, 0);
      if (!capture_.read(frame_))
        return {GrabStatus::kDropped, description_ + ": cannot read after rewinding"};
    }
    std::string reason;
    if (!to_grey(frame_, options_.width, options_.height, scratch_, out, reason))
      return {GrabStatus::kDropped, description_ + ": " + reason};
    return {};
  }
  std::string description() const override { return description_; }
  double frame_period_s() const override { return 1.0 / fps_; }

 private:
  VideoCaptureOptions options_;
  bool device_;
  cv::VideoCapture capture_;
  cv::Mat frame_, scratch_;
  double fps_ = 25.0;
  Pacer pacer_;
  std::string description_;
};

bool is_image_file(const std::filesystem::path& p) {
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  static constexpr std::array<const char*, 8> kExtensions = {".png", ".jpg", ".jpeg", ".pgm",
                                                             ".pbm", ".bmp", ".tif",  ".tiff"};
  return std::any_of(kExtensions.begin(), kExtensions.end(), [&](const char* e) { return ext == e; });
}

class ImageFilesSource final : public ImageSource {
 public:
  explicit ImageFilesSource(const ImageFilesOptions& o) : options_(o), pacer_(1.0) {
    const std::string what = "image files " + o.path.string();
    check_size(what, o.width, o.height);
    if (!std::isfinite(o.fps) || o.fps <= 0 || o.fps > 1000)
      throw ImageSourceError(what + ": fps must be above 0 and at most 1000, got " + std::to_string(o.fps));
    std::error_code ec;
    if (std::filesystem::is_directory(o.path, ec)) {
      for (const auto& entry : std::filesystem::directory_iterator(o.path, ec))
        if (entry.is_regular_file() && is_image_file(entry.path())) files_.push_back(entry.path());
      if (ec) throw ImageSourceError(what + ": cannot list the folder: " + ec.message());
      std::sort(files_.begin(), files_.end());
      if (files_.empty())
        throw ImageSourceError(
            what + ": the folder holds no image file (.png .jpg .jpeg .pgm .pbm .bmp .tif .tiff)");
    } else if (std::filesystem::is_regular_file(o.path, ec)) {
      if (!is_image_file(o.path))
        throw ImageSourceError(what + ": not an image file (.png .jpg .jpeg .pgm .pbm .bmp .tif .tiff)");
      files_.push_back(o.path);
    } else {
      throw ImageSourceError(what + ": no such file or folder");
    }
    pacer_ = Pacer(1.0 / o.fps);
    description_ = "image files " + o.path.string() + " (" + std::to_string(files_.size()) + ")";
  }

  GrabResult grab(GreyImage& out) override {
    if (next_ >= files_.size()) {
      if (!options_.loop) return {GrabStatus::kEnded, description_ + ": end of the replay"};
      next_ = 0;
    }
    if (!pacer_.wait([this] { return cancelled(); })) return {GrabStatus::kEnded, "stopped"};
    const auto& file = files_[next_++];
    frame_ = cv::imread(file.string(), cv::IMREAD_UNCHANGED);
    if (frame_.empty()) return {GrabStatus::kDropped, file.string() + ": cannot be read or decoded"};
    std::string reason;
    if (!to_grey(frame_, options_.width, options_.height, scratch_, out, reason))
      return {GrabStatus::kDropped, file.string() + ": " + reason};
    return {};
  }
  std::string description() const override { return description_; }
  double frame_period_s() const override { return 1.0 / options_.fps; }

 private:
  ImageFilesOptions options_;
  std::vector<std::filesystem::path> files_;
  std::size_t next_ = 0;
  cv::Mat frame_, scratch_;
  Pacer pacer_;
  std::string description_;
};

}  // namespace

std::unique_ptr<ImageSource> open_video_capture(const VideoCaptureOptions& options) {
  return std::make_unique<VideoCaptureSource>(options);
}

std::unique_ptr<ImageSource> open_image_files(const ImageFilesOptions& options) {
  return std::make_unique<ImageFilesSource>(options);
}

void encode_jpeg(const GreyImage& image, int quality, std::vector<std::uint8_t>& out) {
  out.clear();
  if (image.width <= 0 || image.height <= 0 ||
      image.pixels.size() != static_cast<std::size_t>(image.width) * static_cast<std::size_t>(image.height))
    throw ImageSourceError("encode_jpeg: the image's pixels do not match its size");
  const cv::Mat view(image.height, image.width, CV_8UC1, const_cast<std::uint8_t*>(image.pixels.data()));
  cv::imencode(".jpg", view, out, {cv::IMWRITE_JPEG_QUALITY, std::clamp(quality, 1, 100)});
}

void encode_png(const GreyImage& image, std::vector<std::uint8_t>& out) {
  out.clear();
  if (image.width <= 0 || image.height <= 0 ||
      image.pixels.size() != static_cast<std::size_t>(image.width) * static_cast<std::size_t>(image.height))
    throw ImageSourceError("encode_png: the image's pixels do not match its size");
  const cv::Mat view(image.height, image.width, CV_8UC1, const_cast<std::uint8_t*>(image.pixels.data()));
  // Level 3: a live stream at 15 Hz; the higher levels save a few per cent for several times the CPU.
  cv::imencode(".png", view, out, {cv::IMWRITE_PNG_COMPRESSION, 3});
}

}  // namespace tendril::imaging
