// Image sources a lab has besides the simulated fluoroscope: a video capture device (OpenCV's V4L2
// backend; the dissertation's set-up digitised the C-arm's video output with a Sensoray 2263 encoder), a
// video file, and a folder of image files replayed at a set rate. Every source hands out 8-bit grey frames
// (fluoroscopy is monochrome; colour input is converted) of one fixed size.
//
// A source is used by one thread at a time. grab() may block: a capture device until its next frame
// (OpenCV's own timeout bounds it), a replay until the frame is due. So sources are read on imaging
// threads only, never on the control thread, and a watchdog elsewhere notices frames that stop coming.
// The header is free of OpenCV types so that only this library compiles against OpenCV.
#pragma once

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace tendril::imaging {

// Thrown at set-up: a device or file that cannot be opened, an empty folder, bad options.
class ImageSourceError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// An 8-bit grey image, row-major, width × height bytes (no padding).
struct GreyImage {
  int width = 0;
  int height = 0;
  std::vector<std::uint8_t> pixels;
};

enum class GrabStatus : std::uint8_t {
  kFrame,    // `out` holds a new frame
  kDropped,  // a frame was due but could not be read or decoded (the reason says why); try again
  kEnded,    // a replay without looping reached its end: no more frames will come
};

struct GrabResult {
  GrabStatus status = GrabStatus::kFrame;
  std::string reason;  // for kDropped / kEnded, written for a person
};

class ImageSource {
 public:
  virtual ~ImageSource() = default;
  // Waits for the next frame (at most a few frame periods) and writes it into `out`, resized to the
  // source's output size when one was asked for. Never throws for a bad frame: a frame that cannot be
  // read is kDropped with the reason.
  virtual GrabResult grab(GreyImage& out) = 0;
  // Where frames come from, for messages and metrics ("V4L2 /dev/video0", "files /data/run3 (120)").
  virtual std::string description() const = 0;
  // The nominal frame period in seconds (a device's or file's own rate, or the replay rate).
  virtual double frame_period_s() const = 0;
  // Any thread: a grab() waiting for a replayed frame's time returns within about 50 ms (kEnded,
  // "stopped"), and later grabs at once, so that a slow replay never holds up a shutdown. A device's
  // read is bounded by its driver's timeout instead.
  void cancel() noexcept { cancelled_.store(true, std::memory_order_relaxed); }

 protected:
  bool cancelled() const noexcept { return cancelled_.load(std::memory_order_relaxed); }

 private:
  std::atomic<bool> cancelled_{false};
};

struct VideoCaptureOptions {
  // A V4L2 device path (/dev/videoN) or a video file. A device is opened with OpenCV's V4L2 backend;
  // a file with whatever backend OpenCV has for it (its built-in MJPEG/AVI reader at least).
  std::filesystem::path path;
  bool loop = true;  // files only: start again at the end
  // Files only: replay rate in frames per second; 0 = the file's own rate (its container's fps).
  double fps = 0.0;
  // Output size; 0 = the source's own. Frames of another size are resized (area interpolation).
  int width = 0;
  int height = 0;
};

struct ImageFilesOptions {
  // A folder (every .png .jpg .jpeg .pgm .pbm .bmp .tif .tiff in it, in file-name order) or one file.
  std::filesystem::path path;
  double fps = 10.0;  // replay rate
  bool loop = true;
  int width = 0;  // as in VideoCaptureOptions
  int height = 0;
};

// Throw ImageSourceError with a message naming the path and what is wrong.
std::unique_ptr<ImageSource> open_video_capture(const VideoCaptureOptions& options);
std::unique_ptr<ImageSource> open_image_files(const ImageFilesOptions& options);

// Baseline JPEG of a grey image at `quality` 1..100, written into `out` (cleared first).
void encode_jpeg(const GreyImage& image, int quality, std::vector<std::uint8_t>& out);
// Lossless 8-bit grey PNG (for images whose speckle a JPEG would smear), into `out` (cleared first).
void encode_png(const GreyImage& image, std::vector<std::uint8_t>& out);

}  // namespace tendril::imaging
