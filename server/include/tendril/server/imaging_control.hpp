// ImagingControl: the REST side of the imaging (segmentation parameters and roadmaps, per plane). The
// HTTP front end checks the role and the imaged robot's lease, then calls these; the imaging threads
// apply what is asked at their next frame, so nothing here waits for a frame or shares a lock with
// the real-time thread.
#pragma once

#include <string>

#include <nlohmann/json.hpp>

#include "tendril/server/control_api.hpp"  // ApiResult

namespace tendril::server {

class ImagingControl {
 public:
  virtual ~ImagingControl() = default;
  // The robot whose lease a change needs (the imaged robot).
  virtual std::string imaged_robot() const = 0;
  // GET /imaging/segmentation: per plane its parameters, whether they are applied yet, its roadmap.
  virtual ApiResult segmentation() const = 0;
  // PUT /imaging/segmentation/{plane}: `changes` is a JSON object of the parameters' keys (partial).
  // 404 unknown plane, 422 a bad value (error "field" names it), 409 a plane that is not tracked.
  virtual ApiResult set_segmentation(const std::string& plane, const nlohmann::json& changes) = 0;
  // POST /imaging/roadmap/{plane}: a new empty-vessel roadmap at the plane's next frame.
  virtual ApiResult take_roadmap(const std::string& plane) = 0;
};

}  // namespace tendril::server
