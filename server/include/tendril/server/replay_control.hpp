// ReplayControl: the REST side of a replay (tendrild --replay). GET /api/v1/replay reads where the
// playback is; PUT /api/v1/replay changes it ({playing, rate, position_ns}). The HTTP front end checks
// the token and the role (a viewer reads only); no lease is needed, since a replay moves no robot.
// While a server replays (HttpOptions::replay set), the front end refuses every robot command with
// 409 replay_mode.
#pragma once

#include <nlohmann/json.hpp>

#include "tendril/server/control_api.hpp"  // ApiResult

namespace tendril::server {

class ReplayControl {
 public:
  virtual ~ReplayControl() = default;
  // {"files":[…],"start_ns","end_ns","position_ns","rate","playing",…}
  virtual ApiResult replay_status() const = 0;
  // {"playing"?: bool, "rate"?: 0.1–10, "position_ns"?: integer within [start_ns, end_ns]}; 400 with a
  // message naming the field for anything else. Success: the new status.
  virtual ApiResult control_replay(const nlohmann::json& body) = 0;
};

}  // namespace tendril::server
