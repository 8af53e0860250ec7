// Pure helpers of the HTTP front end: JSON body parsing with limits, request-target and cookie parsing,
// constant-time token comparison, static-file path resolution and MIME types. No sockets, no state, so
// they are unit-tested and fuzzed directly.
#pragma once

#include <cstddef>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <nlohmann/json.hpp>

#include "tendril/server/control_api.hpp"

namespace tendril::server::http {

// Deeper JSON nesting than this is refused (keeps parser and printer stacks small).
inline constexpr int kMaxJsonDepth = 32;

// Parses a REST request body. An empty body counts as `{}`. Answers in the API's error shape:
// 413 `body_too_large` when over `max_bytes`, 400 `malformed_json` for bad JSON, too deep nesting or a
// body that is not a JSON object, 400 `duplicate_key` for an object with the same key twice. On
// success `body` holds the object. Linear in the body's size (teleop::parse_strict_json). Never throws
// (but std::bad_alloc).
ApiResult parse_json_body(std::string_view body, std::size_t max_bytes);

// Parses JSON text like nlohmann::json::parse without exceptions, but refuses an object that has the
// same key twice (teleop/strict_json.hpp says why) and nesting deeper than kMaxJsonDepth. Returns a
// discarded value for invalid JSON, too deep nesting and a duplicate key; `duplicate_key` then names
// the key (empty for other errors).
nlohmann::json parse_json_unique_keys(std::string_view text, std::string& duplicate_key);

// True when `text` nests arrays/objects deeper than `max_depth` (strings are skipped correctly). A
// cheap scan for callers that want to say "too deep" before parsing (the Foxglove client messages).
bool json_nesting_exceeds(std::string_view text, int max_depth) noexcept;

struct RequestTarget {
  std::string path;                          // percent-decoded
  std::map<std::string, std::string> query;  // percent-decoded; the last value of a repeated key wins
  bool valid = true;                         // false for broken percent escapes or a NUL byte
};
RequestTarget parse_target(std::string_view target);
std::optional<std::string> percent_decode(std::string_view text, bool plus_is_space);

// "/api/v1/robots/srmc/move_jp" -> {"api","v1","robots","srmc","move_jp"}; empty segments skipped.
std::vector<std::string> split_path(std::string_view path);

// Value of cookie `name` in a Cookie header ("a=1; b=2").
std::optional<std::string> cookie_value(std::string_view cookie_header, std::string_view name);

// Comma-separated header list (Sec-WebSocket-Protocol), items trimmed.
std::vector<std::string> split_header_list(std::string_view value);

// Token after "Bearer " (case-insensitive scheme), if that is the scheme.
std::optional<std::string> bearer_token(std::string_view authorization);

// Compares secrets without an early exit, so timing does not reveal a matching prefix.
bool constant_time_equal(std::string_view a, std::string_view b) noexcept;

// MIME type by file extension (application/octet-stream when unknown).
std::string_view mime_type(std::string_view path) noexcept;

// Maps a decoded URL path below `url_prefix` onto a file under `root`. Refuses "..", backslashes, NUL
// and hidden segments (".git"), so nothing outside `root` is reachable. A trailing "/" gives index.html.
std::optional<std::filesystem::path> resolve_static_path(const std::filesystem::path& root,
                                                         std::string_view url_path,
                                                         std::string_view url_prefix);

// Origin check: exact match against the allowlist (scheme://host:port, no trailing slash).
bool origin_allowed(std::string_view origin, const std::vector<std::string>& allowlist) noexcept;

}  // namespace tendril::server::http
