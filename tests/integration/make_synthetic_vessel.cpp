// Writes the sample vessel config/vessels/synthetic_ica.csv: teleop::make_synthetic_ica(seed 7), a
// 150 mm ICA-like centerline with its lumen radius, a point every 0.2 mm, as "x,y,z,r" in mm.
// Usage: make_synthetic_vessel [output.csv]   (default: stdout). PathFollowingTest checks that the
// shipped file is what this writes.
#include <cstdio>
#include <fstream>
#include <iostream>

#include "tendril/teleop/vessel_centerline.hpp"

int main(int argc, char** argv) {
  tendril::teleop::SyntheticIcaOptions options;
  options.point_spacing = 0.2;
  const auto ica = tendril::teleop::make_synthetic_ica(7, options);
  std::ofstream file;
  if (argc > 1) {
    file.open(argv[1]);
    if (!file) {
      std::cerr << "make_synthetic_vessel: cannot write " << argv[1] << "\n";
      return 1;
    }
  }
  std::ostream& out = argc > 1 ? file : std::cout;
  out << "# synthetic ICA-like centerline: tendril::teleop::make_synthetic_ica(seed 7, point_spacing 0.2 "
         "mm)\n";
  out << "x,y,z,r\n";
  char line[128];
  for (std::size_t i = 0; i < ica.points.size(); ++i) {
    const auto& p = ica.points[i];
    std::snprintf(line, sizeof line, "%.4f,%.4f,%.4f,%.4f\n", p.x(), p.y(), p.z(), ica.radii[i]);
    out << line;
  }
  return out ? 0 : 1;
}
