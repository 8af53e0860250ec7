// The command-line reading the DDS tools share (tendril-dds-probe, tendril-dds-latency): an option's
// value, a number >= 0 and a DDS domain id, each refused with a sentence through the tool's own usage
// error (which names the tool and exits with status 2).
#pragma once

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <string>

namespace tendril::dds::tools {

class ArgumentCursor {
 public:
  using UsageError = void (*)(const std::string& message);  // must not return

  ArgumentCursor(int argc, char** argv, UsageError usage_error)
      : argc_(argc), argv_(argv), usage_error_(usage_error) {}

  // Steps to the next argument: false after the last.
  bool next() { return ++i_ < argc_; }
  std::string current() const { return argv_[i_]; }

  // The value after the current option `name`.
  std::string value(const char* name) {
    if (i_ + 1 >= argc_) fail(std::string(name) + " needs a value");
    return argv_[++i_];
  }

  double number(const char* name) {
    const std::string text = value(name);
    char* end = nullptr;
    const double v = std::strtod(text.c_str(), &end);
    if (text.empty() || end != text.c_str() + text.size() || !std::isfinite(v) || v < 0)
      fail(std::string(name) + " expects a number >= 0, got '" + text + "'");
    return v;
  }

  // --domain: Cyclone DDS takes domain ids 0 to 232.
  std::uint32_t domain() {
    const double d = number("--domain");
    if (d > 232 || d != std::floor(d)) fail("--domain expects 0 to 232");
    return static_cast<std::uint32_t>(d);
  }

 private:
  [[noreturn]] void fail(const std::string& message) const {
    usage_error_(message);
    std::exit(2);  // a usage error that returned
  }

  int argc_;
  char** argv_;
  int i_ = 0;
  UsageError usage_error_;
};

}  // namespace tendril::dds::tools
