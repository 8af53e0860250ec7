#include "tendril/server/http/request_codec.hpp"

#include <algorithm>
#include <cctype>
#include <utility>
#include <vector>

#include "tendril/teleop/strict_json.hpp"

namespace tendril::server::http {

bool json_nesting_exceeds(std::string_view text, int max_depth) noexcept {
  int depth = 0;
  bool in_string = false;
  bool escaped = false;
  for (const char c : text) {
    if (in_string) {
      if (escaped) {
        escaped = false;
      } else if (c == '\\') {
        escaped = true;
      } else if (c == '"') {
        in_string = false;
      }
      continue;
    }
    if (c == '"') {
      in_string = true;
    } else if (c == '[' || c == '{') {
      if (++depth > max_depth) return true;
    } else if (c == ']' || c == '}') {
      --depth;
    }
  }
  return false;
}

nlohmann::json parse_json_unique_keys(std::string_view text, std::string& duplicate_key) {
  auto parsed = teleop::parse_strict_json(text, kMaxJsonDepth);
  duplicate_key = std::move(parsed.duplicate_key);
  return std::move(parsed.value);
}

ApiResult parse_json_body(std::string_view body, std::size_t max_bytes) {
  using teleop::StrictJsonError;
  if (body.size() > max_bytes) {
    return ApiResult::error(413, "body_too_large",
                            "request body is " + std::to_string(body.size()) + " bytes; the limit is " +
                                std::to_string(max_bytes) + " bytes");
  }
  const bool blank = std::all_of(body.begin(), body.end(),
                                 [](char c) { return std::isspace(static_cast<unsigned char>(c)); });
  if (blank) return ApiResult::success(nlohmann::json::object());
  auto parsed = teleop::parse_strict_json(body, kMaxJsonDepth);
  switch (parsed.error) {
    case StrictJsonError::kNone:
      break;
    case StrictJsonError::kDuplicateKey:
      return ApiResult::error(400, "duplicate_key",
                              "request body has the key \"" + parsed.duplicate_key +
                                  "\" twice in one object; send each key once");
    case StrictJsonError::kTooDeep:
      return ApiResult::error(400, "malformed_json",
                              "request body nests deeper than " + std::to_string(kMaxJsonDepth) + " levels");
    case StrictJsonError::kSyntax:
      return ApiResult::error(400, "malformed_json",
                              "request body is not valid JSON at byte " + std::to_string(parsed.byte));
    case StrictJsonError::kNumberOutOfRange:
      // e.g. 1e999, too large for a double (found by fuzz_rest_body).
      return ApiResult::error(400, "malformed_json",
                              "request body is not valid JSON: " + parsed.parser_message);
  }
  if (!parsed.value.is_object()) {
    return ApiResult::error(
        400, "malformed_json",
        std::string("request body must be a JSON object, got ") + parsed.value.type_name());
  }
  return ApiResult::success(std::move(parsed.value));
}

static int hex_value(char c) noexcept {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

std::optional<std::string> percent_decode(std::string_view text, bool plus_is_space) {
  std::string out;
  out.reserve(text.size());
  for (std::size_t i = 0; i < text.size(); ++i) {
    char c = text[i];
    if (c == '%') {
      if (i + 2 >= text.size()) return std::nullopt;
      const int hi = hex_value(text[i + 1]);
      const int lo = hex_value(text[i + 2]);
      if (hi < 0 || lo < 0) return std::nullopt;
      c = static_cast<char>(hi * 16 + lo);
      i += 2;
    } else if (c == '+' && plus_is_space) {
      c = ' ';
    }
    if (c == '\0') return std::nullopt;
    out.push_back(c);
  }
  return out;
}

RequestTarget parse_target(std::string_view target) {
  RequestTarget result;
  const auto question = target.find('?');
  const std::string_view raw_path = target.substr(0, question);
  if (auto path = percent_decode(raw_path, false)) {
    result.path = std::move(*path);
  } else {
    result.valid = false;
  }
  if (question == std::string_view::npos) return result;
  std::string_view query = target.substr(question + 1);
  const auto hash = query.find('#');
  if (hash != std::string_view::npos) query = query.substr(0, hash);
  while (!query.empty()) {
    const auto amp = query.find('&');
    const std::string_view pair = query.substr(0, amp);
    query = amp == std::string_view::npos ? std::string_view{} : query.substr(amp + 1);
    if (pair.empty()) continue;
    const auto eq = pair.find('=');
    auto key = percent_decode(pair.substr(0, eq), true);
    auto value = eq == std::string_view::npos ? std::optional<std::string>("")
                                              : percent_decode(pair.substr(eq + 1), true);
    if (!key || !value) {
      result.valid = false;
      continue;
    }
    result.query[*key] = std::move(*value);
  }
  return result;
}

std::vector<std::string> split_path(std::string_view path) {
  std::vector<std::string> segments;
  while (!path.empty()) {
    const auto slash = path.find('/');
    const std::string_view segment = path.substr(0, slash);
    if (!segment.empty()) segments.emplace_back(segment);
    if (slash == std::string_view::npos) break;
    path.remove_prefix(slash + 1);
  }
  return segments;
}

static std::string_view trim(std::string_view s) noexcept {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

std::optional<std::string> cookie_value(std::string_view header, std::string_view name) {
  while (!header.empty()) {
    const auto semi = header.find(';');
    const std::string_view item = trim(header.substr(0, semi));
    header = semi == std::string_view::npos ? std::string_view{} : header.substr(semi + 1);
    const auto eq = item.find('=');
    if (eq == std::string_view::npos) continue;
    if (trim(item.substr(0, eq)) == name) {
      std::string_view value = trim(item.substr(eq + 1));
      if (value.size() >= 2 && value.front() == '"' && value.back() == '"')
        value = value.substr(1, value.size() - 2);
      return std::string(value);
    }
  }
  return std::nullopt;
}

std::vector<std::string> split_header_list(std::string_view value) {
  std::vector<std::string> items;
  while (!value.empty()) {
    const auto comma = value.find(',');
    const std::string_view item = trim(value.substr(0, comma));
    if (!item.empty()) items.emplace_back(item);
    if (comma == std::string_view::npos) break;
    value.remove_prefix(comma + 1);
  }
  return items;
}

std::optional<std::string> bearer_token(std::string_view authorization) {
  authorization = trim(authorization);
  constexpr std::string_view kScheme = "bearer ";
  if (authorization.size() < kScheme.size()) return std::nullopt;
  for (std::size_t i = 0; i < kScheme.size(); ++i) {
    if (std::tolower(static_cast<unsigned char>(authorization[i])) != kScheme[i]) return std::nullopt;
  }
  return std::string(trim(authorization.substr(kScheme.size())));
}

bool constant_time_equal(std::string_view a, std::string_view b) noexcept {
  // Walk the longer length in full; a length difference still fails, without an early return.
  const std::size_t n = std::max(a.size(), b.size());
  unsigned char diff = a.size() == b.size() ? 0 : 1;
  for (std::size_t i = 0; i < n; ++i) {
    const unsigned char x = i < a.size() ? static_cast<unsigned char>(a[i]) : 0;
    const unsigned char y = i < b.size() ? static_cast<unsigned char>(b[i]) : 0;
    diff |= static_cast<unsigned char>(x ^ y);
  }
  return diff == 0;
}

std::string_view mime_type(std::string_view path) noexcept {
  const auto dot = path.rfind('.');
  if (dot == std::string_view::npos) return "application/octet-stream";
  std::string_view ext = path.substr(dot + 1);
  struct Entry {
    std::string_view ext, type;
  };
  static constexpr Entry kTypes[] = {
      {"html", "text/html; charset=utf-8"},
      {"htm", "text/html; charset=utf-8"},
      {"css", "text/css; charset=utf-8"},
      {"js", "text/javascript; charset=utf-8"},
      {"mjs", "text/javascript; charset=utf-8"},
      {"cjs", "text/javascript; charset=utf-8"},
      {"json", "application/json"},
      {"map", "application/json"},
      {"txt", "text/plain; charset=utf-8"},
      {"md", "text/markdown; charset=utf-8"},
      {"svg", "image/svg+xml"},
      {"png", "image/png"},
      {"jpg", "image/jpeg"},
      {"jpeg", "image/jpeg"},
      {"gif", "image/gif"},
      {"webp", "image/webp"},
      {"ico", "image/vnd.microsoft.icon"},
      {"wasm", "application/wasm"},
      {"woff", "font/woff"},
      {"woff2", "font/woff2"},
      {"ttf", "font/ttf"},
      {"glb", "model/gltf-binary"},
      {"gltf", "model/gltf+json"},
      {"stl", "model/stl"},
      {"obj", "text/plain; charset=utf-8"},
  };
  for (const auto& entry : kTypes) {
    if (entry.ext.size() != ext.size()) continue;
    bool same = true;
    for (std::size_t i = 0; i < ext.size() && same; ++i) {
      same = std::tolower(static_cast<unsigned char>(ext[i])) == entry.ext[i];
    }
    if (same) return entry.type;
  }
  return "application/octet-stream";
}

std::optional<std::filesystem::path> resolve_static_path(const std::filesystem::path& root,
                                                         std::string_view url_path,
                                                         std::string_view url_prefix) {
  if (root.empty() || url_path.substr(0, url_prefix.size()) != url_prefix) return std::nullopt;
  std::string_view rest = url_path.substr(url_prefix.size());
  std::filesystem::path result = root;
  const bool wants_index = rest.empty() || rest.back() == '/';
  while (!rest.empty()) {
    const auto slash = rest.find('/');
    const std::string_view segment = rest.substr(0, slash);
    rest = slash == std::string_view::npos ? std::string_view{} : rest.substr(slash + 1);
    if (segment.empty()) continue;
    // ".." escapes; "." and hidden names (.git, .env) are never part of a console bundle.
    if (segment.front() == '.') return std::nullopt;
    if (segment.find('\\') != std::string_view::npos || segment.find('\0') != std::string_view::npos ||
        segment.find(':') != std::string_view::npos) {
      return std::nullopt;
    }
    result /= std::string(segment);
  }
  if (wants_index) result /= "index.html";
  return result;
}

bool origin_allowed(std::string_view origin, const std::vector<std::string>& allowlist) noexcept {
  for (const auto& allowed : allowlist) {
    if (allowed == origin) return true;
  }
  return false;
}

}  // namespace tendril::server::http
