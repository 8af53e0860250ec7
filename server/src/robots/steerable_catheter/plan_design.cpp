#include "steerable_catheter/plan_design.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <vector>

namespace tendril::server {

using nlohmann::json;

namespace {

struct Key {
  const char* name;
  double CatheterDesign::*field;
};
constexpr std::array<Key, 5> kCompared = {{{"L1", &CatheterDesign::L1},
                                           {"L2", &CatheterDesign::L2},
                                           {"k1", &CatheterDesign::k1},
                                           {"k2", &CatheterDesign::k2},
                                           {"delta2", &CatheterDesign::delta2}}};

bool same(double plan, double mounted) {
  return std::abs(plan - mounted) <= kDesignTolerance * std::max(1.0, std::abs(mounted));
}

std::string number(double v, int digits) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.*g", digits, v);
  return buf;
}

// The fewest significant digits (3 or more) that tell a from b apart when they differ, so "22 and 22.0001" is
// never written "22 and 22".
int digits_to_tell(double a, double b) {
  if (same(a, b)) return 3;
  for (int d = 3; d < 17; ++d)
    if (number(a, d) != number(b, d)) return d;
  return 17;
}

// One quantity of a design in words: "segments of 22 and 18.8 mm".
enum class Part { segments, gains, plane };
std::string words(Part part, const CatheterDesign& d, int digits) {
  switch (part) {
    case Part::segments:
      return "segments of " + number(d.L1, digits) + " and " + number(d.L2, digits) + " mm";
    case Part::gains:
      return "bend gains of " + number(d.k1, digits) + " and " + number(d.k2, digits) +
             " rad per mm of drive";
    case Part::plane:
      return "a distal bending plane turned " + number(d.delta2, digits) + " rad";
  }
  return {};
}

std::string join(const std::vector<std::string>& parts) {
  std::string out;
  for (std::size_t i = 0; i < parts.size(); ++i) {
    if (i > 0) out += i + 1 == parts.size() ? " and " : ", ";
    out += parts[i];
  }
  return out;
}

std::string describe(const CatheterDesign& d) {
  return join({words(Part::segments, d, 6), words(Part::gains, d, 6), words(Part::plane, d, 6)});
}

}  // namespace

std::optional<CatheterDesign> design_from_kinematics(const json& k) {
  try {
    CatheterDesign d;
    d.L1 = k.at("segment_lengths_mm").at(0).get<double>();
    d.L2 = k.at("segment_lengths_mm").at(1).get<double>();
    d.k1 = k.at("bend_gain_rad_per_mm").at(0).get<double>();
    d.k2 = k.at("bend_gain_rad_per_mm").at(1).get<double>();
    d.delta2 = k.at("plane_offset_rad").get<double>();
    d.flexure_rad = k.value("flexure_rad", 0.0);
    return d;
  } catch (const std::exception&) {
    return std::nullopt;
  }
}

json design_json(const CatheterDesign& d) {
  return {{"L1", d.L1}, {"L2", d.L2}, {"delta2", d.delta2}, {"flexure_rad", d.flexure_rad},
          {"k1", d.k1}, {"k2", d.k2}};
}

std::optional<PlanRefusal> plan_design_refusal(const json& plan, const CatheterDesign& mounted) {
  const auto it = plan.is_object() ? plan.find("design") : plan.end();
  std::vector<std::string> missing;
  CatheterDesign planned;
  for (const auto& key : kCompared) {
    const bool given = it != plan.end() && it->is_object() && it->contains(key.name) &&
                       (*it)[key.name].is_number() && std::isfinite((*it)[key.name].get<double>());
    if (given)
      planned.*key.field = (*it)[key.name].get<double>();
    else
      missing.emplace_back(key.name);
  }
  if (it == plan.end() || it->is_null() || !missing.empty()) {
    const std::string what = it == plan.end() || it->is_null() || !it->is_object()
                                 ? "This plan does not say which catheter it was made for"
                                 : "This plan's catheter design lacks " + join(missing);
    return PlanRefusal{"no_design", what + ", so it cannot be checked against the mounted catheter (" +
                                        describe(mounted) +
                                        "). Compute the plan again for the mounted catheter."};
  }
  std::vector<std::string> theirs, ours;
  const auto differs = [&](Part part, double a1, double b1, double a2, double b2) {
    if (same(a1, b1) && same(a2, b2)) return;
    const int digits = std::max(digits_to_tell(a1, b1), digits_to_tell(a2, b2));
    theirs.push_back(words(part, planned, digits));
    ours.push_back(words(part, mounted, digits));
  };
  differs(Part::segments, planned.L1, mounted.L1, planned.L2, mounted.L2);
  differs(Part::gains, planned.k1, mounted.k1, planned.k2, mounted.k2);
  differs(Part::plane, planned.delta2, mounted.delta2, planned.delta2, mounted.delta2);
  if (theirs.empty()) return std::nullopt;
  return PlanRefusal{"other_catheter", "This plan was made for another catheter, with " + join(theirs) +
                                           "; the mounted catheter has " + join(ours) +
                                           ". Compute the plan again for the mounted catheter."};
}

}  // namespace tendril::server
