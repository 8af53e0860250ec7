// Fuzz target: REST request bodies, request targets, cookies and static paths.
#include <cstdint>
#include <cstdlib>
#include <string>
#include <string_view>

#include "tendril/server/http/request_codec.hpp"

using namespace tendril::server::http;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view input(reinterpret_cast<const char*>(data), size);
  const auto body = parse_json_body(input, 64 * 1024);
  // Success means a JSON object; failure always carries the API error shape.
  if (body.ok() ? !body.body.is_object() : (body.code.empty() || body.message.empty())) std::abort();
  if (body.ok()) {
    // An accepted body survives a round trip (its keys are unique, so nothing was silently dropped).
    std::string duplicate_key;
    if (parse_json_unique_keys(body.body.dump(), duplicate_key) != body.body || !duplicate_key.empty())
      std::abort();
  }
  const auto target = parse_target(input);
  (void)split_path(target.path);
  (void)cookie_value(input, "tendril_session");
  (void)split_header_list(input);
  (void)bearer_token(input);
  if (const auto path = resolve_static_path("/srv/web", target.path, "/")) {
    // Nothing outside the root is ever reachable.
    for (const auto& part : *path) {
      if (part == "..") std::abort();
    }
    if (path->string().rfind("/srv/web/", 0) != 0) std::abort();
  }
  return 0;
}
