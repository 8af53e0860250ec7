// Kept apart from the OpenCV code: the request reader (and its fuzz target) needs only this.
#include "tendril/teleop/perception/side_view_outline.hpp"

namespace tendril::teleop::perception {

ImageEdge parse_image_edge(const std::string& name) {
  if (name == "bottom") return ImageEdge::kBottom;
  if (name == "top") return ImageEdge::kTop;
  if (name == "left") return ImageEdge::kLeft;
  if (name == "right") return ImageEdge::kRight;
  throw SideViewImageError(
      "entry: expected \"bottom\", \"top\", \"left\" or \"right\" (the edge the catheter "
      "enters the picture from), got \"" +
      name + "\"");
}

}  // namespace tendril::teleop::perception
