// The catheter a plan was made for (issue 31): a plan carries the design it was planned with (segment
// lengths, bend gains, distal plane offset), and path following refuses a plan whose design is not the
// mounted catheter's. Joint values planned for one catheter put another catheter's tip elsewhere, so such a
// plan leaves the vessel whatever its own error figures say (the design optimiser's 5/5 mm segments on the
// mounted 22/18.8 mm catheter held at step 5).
#pragma once

#include <optional>
#include <string>
#include <variant>

#include <nlohmann/json.hpp>

namespace tendril::server {

struct CatheterDesign {
  double L1 = 0.0;      // proximal segment length, mm
  double L2 = 0.0;      // distal segment length, mm
  double k1 = 0.0;      // proximal bend gain, rad/mm of drive
  double k2 = 0.0;      // distal bend gain, rad/mm of drive
  double delta2 = 0.0;  // distal bending plane offset, rad
  double flexure_rad = 0.0;
};

// Two designs are the same catheter when every one of L1, L2, k1, k2, delta2 agrees within this part of
// max(1, |mounted value|): the rule of the console's verdict (web/plan_verdict.js designMismatch), so the
// console and the server agree. A plan made by this server's planner carries the robot file's numbers
// exactly (JSON keeps a double's digits); the tolerance only absorbs numbers copied by hand with fewer
// digits (0.0882353 for 0.088235294…).
inline constexpr double kDesignTolerance = 1e-6;

// The mounted catheter's design from the robot file's "kinematics" (segment_lengths_mm,
// bend_gain_rad_per_mm, plane_offset_rad, flexure_rad); nullopt when the file gives none.
std::optional<CatheterDesign> design_from_kinematics(const nlohmann::json& kinematics);

// The design as GET /robots and the planner's results write it: {L1, L2, k1, k2, delta2, flexure_rad}.
nlohmann::json design_json(const CatheterDesign& design);

struct PlanRefusal {
  std::string code;  // other_catheter | no_design
  std::string message;
};

// Whether a plan ({"design": {...}, "steps": [...]}) may be followed by the mounted catheter: nullopt when
// its design is the mounted one, else the refusal, for the operator, naming both designs (other_catheter).
// A plan without a design, or with one that lacks any of L1, L2, k1, k2, delta2, is refused too
// (no_design): what its joint values do depends on the catheter it was made for, and nothing tells which.
std::optional<PlanRefusal> plan_design_refusal(const nlohmann::json& plan, const CatheterDesign& mounted);

}  // namespace tendril::server
