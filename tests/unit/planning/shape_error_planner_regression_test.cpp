// The planner of issue 15 (analytic Jacobian, Nielsen's damping update, stop at a relative improvement
// of 1e-9) against the planner it replaced (central differences, λ/3 and ×4, 1e-12): eq. 4.17's cost
// of every step may not be higher than before (1e-6 relative for rounding). The reference costs were
// printed by the previous planner (commit 1c67fd5, gcc RelWithDebInfo) for the same vessels and options.
#include <gtest/gtest.h>

#include <vector>

#include "tendril/teleop/shape_error_planner.hpp"

namespace tendril::teleop {
namespace {

// make_synthetic_ica(1), ds 0.5, default options (r_tp 0.75, r_seg 1, dq1 3), nominal design.
const std::vector<double> kIca1Costs = {
    0.000000000e+00, 0.000000000e+00, 0.000000000e+00, 0.000000000e+00, 9.855419690e-06, 2.314209481e-02,
    2.278381464e-01, 6.658941007e-01, 9.572270007e-01, 6.651404922e-01, 5.086856750e-02, 6.447293611e-01,
    4.426045766e+00, 1.179055054e+01, 2.081504017e+01, 2.789422717e+01, 2.916218789e+01, 2.285923365e+01,
    1.603558777e+01, 1.299890975e+01, 7.096651616e+00, 2.728582197e+00, 6.748033540e+00, 2.317986790e+01,
    5.586544675e+01, 1.018424538e+02, 1.318007958e+02, 1.030177117e+02, 6.050555349e+01, 7.650890492e+01,
    9.768663155e+01, 5.808393668e+01, 5.648930778e+00, 1.520131073e+01, 4.936101551e+01, 9.719781056e+01,
    1.399872733e+02, 1.558234077e+02, 1.332650221e+02, 8.968960111e+01, 6.674916778e+01, 3.328028251e+01,
    8.800744659e+00, 4.716111961e+01, 4.089717587e+01, 1.902943274e+01, 9.424952180e+00, 5.352111326e+01,
    7.409081174e+01, 4.230909901e+01,
};

// The same with the flexure γ free.
const std::vector<double> kIca1FlexureCosts = {
    0.000000000e+00, 0.000000000e+00, 0.000000000e+00, 0.000000000e+00, 9.793799123e-06, 1.813206653e-02,
    1.791428824e-01, 5.280533225e-01, 7.514874982e-01, 5.212043644e-01, 4.160880607e-02, 5.740530621e-01,
    4.370445122e+00, 6.178913535e+00, 8.155383856e+00, 8.292181899e+00, 6.584026664e+00, 3.607449830e+00,
    2.271728798e+00, 1.279907653e+00, 5.803597281e-01, 1.788388356e+00, 5.536850454e+00, 1.014119683e+01,
    1.293543225e+01, 3.069037414e+01, 7.147312624e+01, 9.769505073e+01, 6.032073432e+01, 7.000270382e+01,
    1.107920674e+02, 1.158746587e+01, 3.612324835e+00, 1.023805538e+01, 1.834633390e+01, 2.914460789e+01,
    6.028750958e+01, 9.760369119e+01, 1.052861079e+02, 7.831501707e+01, 4.114217655e+01, 2.038106205e+01,
    8.178405055e+00, 2.250744619e+01, 2.264117588e+01, 1.276295676e+01, 9.403833114e+00, 2.378499662e+01,
    2.128807944e+01, 1.119068568e+01,
};

// make_synthetic_ica(11) with 250 mm of path and 4–10 mm bend radii (the benchmark's tortuous11).
const std::vector<double> kTortuous11Costs = {
    0.000000000e+00, 5.111582035e-04, 2.729733735e-01, 2.452555349e+00, 7.791884338e+00, 1.044140312e+01,
    4.603194977e+00, 3.862027871e+00, 3.855207261e+01, 1.125232805e+02, 1.850708037e+02, 1.943795669e+02,
    1.164924080e+02, 2.889932710e+01, 3.975846793e+01, 8.709696081e+01, 4.105250985e+01, 1.291654276e+01,
    7.380468420e+01, 7.217666552e+01, 2.121931513e+01, 8.995627013e+00, 2.049195769e+01, 3.804890635e+01,
    6.812499848e+01, 1.174574626e+02, 1.916185751e+02, 1.065189776e+02, 8.048247594e+01, 3.452457264e+01,
    1.023925748e+01, 4.510091432e+01, 4.949875443e+01, 4.615979676e+01, 4.116062883e+01, 5.498380756e+01,
    9.490999490e+01, 1.303602405e+02, 1.245327064e+02, 7.491989565e+01, 1.021502855e+01, 1.434313640e+01,
    2.939074822e+01, 5.358605900e+01, 9.211412202e+01, 1.554055616e+02, 1.725027404e+02, 1.788736702e+02,
    1.904363228e+02, 2.434596668e+02, 2.956534975e+02, 3.255749689e+02, 8.895816868e+00, 1.176294772e+01,
    1.778808047e+01, 4.740960673e+01, 1.348636810e+02, 1.623841987e+02, 1.282926241e+02, 7.734372280e+01,
    3.960055793e+01, 9.339815373e+01, 1.924525609e+02, 2.080496015e+02, 1.526815671e+02, 2.138794039e+01,
    4.875412325e+01, 6.202715308e+01, 4.915327158e+01, 1.365062741e+01, 1.810510786e+00, 1.232105491e+01,
    3.095997956e+01, 5.368187656e+01, 8.242109328e+01, 1.294443748e+02, 6.043937654e+01, 5.512279746e+01,
    8.421092392e+01, 8.542972729e+01, 4.490461595e+01, 1.660933455e+00, 1.539562498e+01,
};

void expect_no_worse(const PathPlan& plan, const std::vector<double>& reference) {
  ASSERT_EQ(plan.steps.size(), reference.size());
  int better = 0;
  for (std::size_t k = 0; k < reference.size(); ++k) {
    // 1e-6 relative: the references are printed to 10 digits and the compilers round differently.
    EXPECT_LE(plan.steps[k].cost, reference[k] * (1.0 + 1e-6) + 1e-9) << "step " << k;
    better += plan.steps[k].cost < reference[k] * (1.0 - 1e-6) ? 1 : 0;
  }
  std::printf("[ regression ] %zu steps no worse than the previous planner, %d better\n", reference.size(),
              better);
}

TEST(ShapeErrorPlannerRegression, NoStepCostsMoreThanWithThePreviousPlanner) {
  const ConstantCurvatureCatheter model(nominal_planning_design());
  const auto ica1 = VesselCenterline::from_polyline(make_synthetic_ica(1), 0.5);
  expect_no_worse(ShapeErrorPlanner(model, {}).plan(ica1), kIca1Costs);
  ShapeErrorPlannerOptions flexure;
  flexure.free_flexure = true;
  expect_no_worse(ShapeErrorPlanner(model, flexure).plan(ica1), kIca1FlexureCosts);
  SyntheticIcaOptions tortuous;
  tortuous.length = 250.0;
  tortuous.min_bend_radius = 4.0;
  tortuous.max_bend_radius = 10.0;
  expect_no_worse(ShapeErrorPlanner(model, {}).plan(
                      VesselCenterline::from_polyline(make_synthetic_ica(11, tortuous), 0.5)),
                  kTortuous11Costs);
}

}  // namespace
}  // namespace tendril::teleop
