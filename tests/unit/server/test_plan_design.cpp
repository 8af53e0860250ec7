// A plan carries the catheter design it was made for; path following refuses one made for another
// catheter, naming both designs, and one that does not say (steerable_catheter/plan_design.hpp).
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "steerable_catheter/plan_design.hpp"

namespace tendril::server {
namespace {

using nlohmann::json;

// The shipped srmc.json's "kinematics".
const json kKinematics = {{"model", "constant_curvature_catheter"},
                          {"segment_lengths_mm", {22.0, 18.8}},
                          {"plane_offset_rad", -0.76},
                          {"bend_gain_rad_per_mm", {0.0882, 0.238}}};

CatheterDesign mounted() { return design_from_kinematics(kKinematics).value(); }

json plan_with(const json& design) {
  return {{"design", design}, {"steps", json::array({json{{"q", {10, 0, 0, 0}}}})}};
}

TEST(PlanDesign, MountedDesignFromTheRobotFile) {
  const auto d = mounted();
  EXPECT_EQ(d.L1, 22.0);
  EXPECT_EQ(d.L2, 18.8);
  EXPECT_EQ(d.k1, 0.0882);
  EXPECT_EQ(d.k2, 0.238);
  EXPECT_EQ(d.delta2, -0.76);
  EXPECT_EQ(d.flexure_rad, 0.0);
  EXPECT_FALSE(design_from_kinematics(json{{"model", "constant_curvature_catheter"}}).has_value());
}

TEST(PlanDesign, APlanForTheMountedCatheterIsAccepted) {
  // As the planner writes it (with its extra keys), and as GET /robots gives it.
  json planner = design_json(mounted());
  planner["flexure"] = false;
  EXPECT_FALSE(plan_design_refusal(plan_with(planner), mounted()).has_value());
  // Numbers copied by hand with fewer digits are within the tolerance (1e-6 of max(1, |value|)).
  json copied = design_json(mounted());
  copied["k1"] = 0.0882003;
  EXPECT_FALSE(plan_design_refusal(plan_with(copied), mounted()).has_value());
}

TEST(PlanDesign, APlanForOtherSegmentsIsRefusedNamingBoth) {
  // The design optimiser's 5/5 mm segments (issue 31).
  json other = design_json(mounted());
  other["L1"] = 5.0;
  other["L2"] = 5.0;
  const auto refused = plan_design_refusal(plan_with(other), mounted());
  ASSERT_TRUE(refused.has_value());
  EXPECT_EQ(refused->code, "other_catheter");
  EXPECT_EQ(refused->message,
            "This plan was made for another catheter, with segments of 5 and 5 mm; the mounted catheter has "
            "segments of 22 and 18.8 mm. Compute the plan again for the mounted catheter.");
}

TEST(PlanDesign, EveryComparedQuantityCountsAndADifferenceIsWrittenSoItShows) {
  // The "nominal" planning design: the same lengths, the tip-only bend gains.
  json nominal = design_json(mounted());
  nominal["k1"] = 1.4;
  nominal["k2"] = 1.4;
  auto refused = plan_design_refusal(plan_with(nominal), mounted());
  ASSERT_TRUE(refused.has_value());
  EXPECT_NE(refused->message.find("bend gains of 1.4 and 1.4 rad per mm of drive; the mounted catheter has "
                                  "bend gains of 0.0882 and 0.238 rad per mm of drive"),
            std::string::npos)
      << refused->message;
  EXPECT_EQ(refused->message.find("segments"), std::string::npos) << refused->message;

  json turned = design_json(mounted());
  turned["delta2"] = -0.5;
  refused = plan_design_refusal(plan_with(turned), mounted());
  ASSERT_TRUE(refused.has_value());
  EXPECT_NE(refused->message.find(
                "turned -0.5 rad; the mounted catheter has a distal bending plane turned -0.76 rad"),
            std::string::npos)
      << refused->message;

  // Just past the tolerance: still refused, and written with the digits that tell the two apart.
  json longer = design_json(mounted());
  longer["L1"] = 22.0001;
  refused = plan_design_refusal(plan_with(longer), mounted());
  ASSERT_TRUE(refused.has_value());
  EXPECT_NE(refused->message.find(
                "segments of 22.0001 and 18.8 mm; the mounted catheter has segments of 22 and 18.8 mm"),
            std::string::npos)
      << refused->message;
}

TEST(PlanDesign, APlanThatDoesNotSayItsCatheterIsRefused) {
  json no_design = {{"steps", json::array({json{{"q", {10, 0, 0, 0}}}})}};
  auto refused = plan_design_refusal(no_design, mounted());
  ASSERT_TRUE(refused.has_value());
  EXPECT_EQ(refused->code, "no_design");
  EXPECT_EQ(
      refused->message,
      "This plan does not say which catheter it was made for, so it cannot be checked against the "
      "mounted catheter (segments of 22 and 18.8 mm, bend gains of 0.0882 and 0.238 rad per mm of drive "
      "and a distal bending plane turned -0.76 rad). Compute the plan again for the mounted catheter.");
  EXPECT_EQ(plan_design_refusal(plan_with(nullptr), mounted())->code, "no_design");
  EXPECT_EQ(plan_design_refusal(plan_with("srmc"), mounted())->code, "no_design");

  json partial = {{"L1", 22.0}, {"L2", 18.8}};
  refused = plan_design_refusal(plan_with(partial), mounted());
  ASSERT_TRUE(refused.has_value());
  EXPECT_EQ(refused->code, "no_design");
  EXPECT_EQ(refused->message.rfind("This plan's catheter design lacks k1, k2 and delta2, so", 0), 0u)
      << refused->message;
  json text = design_json(mounted());
  text["L2"] = "18.8";
  EXPECT_EQ(plan_design_refusal(plan_with(text), mounted())->code, "no_design");
}

}  // namespace
}  // namespace tendril::server
