// Writes the sample vessels of config/vessels:
//   synthetic_ica.csv  teleop::make_synthetic_ica(seed 7): a 150 mm ICA-like centerline, bends of 5–15 mm
//                      radius (the planner's benchmark vessel; tighter than the SRMC can follow);
//   scene_vessel.csv   the default scene (config/server.json, issue 31): make_synthetic_ica with the
//                      options of kScene — bends the SRMC's segments can follow, ending within its
//                      insertion range.
// Both with their lumen radius, a point every 0.2 mm, as "x,y,z,r" in mm.
// Usage: make_synthetic_vessel [--scene] [output.csv]   (default: stdout). PathFollowingTest and
// CatheterReachTest check that the shipped files are what this writes.
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>

#include "tendril/teleop/vessel_centerline.hpp"

// The default scene's vessel (seed, mm of path, bend radii in mm).
struct SceneOptions {
  std::uint32_t seed = 2;
  double length = 112.0, min_bend = 25.0, max_bend = 45.0;
};

int main(int argc, char** argv) {
  bool scene = false;
  const char* path = nullptr;
  SceneOptions s;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--scene") == 0)
      scene = true;
    else if (std::strcmp(argv[i], "--seed") == 0 && i + 1 < argc)  // for trying other scenes
      s.seed = static_cast<std::uint32_t>(std::atoi(argv[++i]));
    else if (std::strcmp(argv[i], "--bends") == 0 && i + 2 < argc) {
      s.min_bend = std::atof(argv[++i]);
      s.max_bend = std::atof(argv[++i]);
    } else
      path = argv[i];
  }
  tendril::teleop::SyntheticIcaOptions options;
  options.point_spacing = 0.2;
  std::uint32_t seed = 7;
  if (scene) {
    seed = s.seed;
    options.length = s.length;
    options.min_bend_radius = s.min_bend;
    options.max_bend_radius = s.max_bend;
  }
  const auto ica = tendril::teleop::make_synthetic_ica(seed, options);
  std::ofstream file;
  if (path) {
    file.open(path);
    if (!file) {
      std::cerr << "make_synthetic_vessel: cannot write " << path << "\n";
      return 1;
    }
  }
  std::ostream& out = path ? file : std::cout;
  char header[256];
  std::snprintf(
      header, sizeof header,
      "# synthetic ICA-like centerline: tendril::teleop::make_synthetic_ica(seed %u, point_spacing 0.2 "
      "mm%s)\n",
      seed, scene ? ", length 112 mm, bend radii 25-45 mm: the default scene of issue 31" : "");
  out << header;
  out << "x,y,z,r\n";
  char line[128];
  for (std::size_t i = 0; i < ica.points.size(); ++i) {
    const auto& p = ica.points[i];
    std::snprintf(line, sizeof line, "%.4f,%.4f,%.4f,%.4f\n", p.x(), p.y(), p.z(), ica.radii[i]);
    out << line;
  }
  return out ? 0 : 1;
}
