// Shape-error path planner timing (seed 000 §4.8, §4.10): full plan along the synthetic 150 mm ICA
// with ds = 0.5 mm and dq1 = 3 mm (issue target ≤ 50 ms; MATLAB reference 14.5 s), and how the cost
// grows with path length and sample spacing. Reports only; asserts nothing.
#include <benchmark/benchmark.h>

#include "tendril/teleop/shape_error_planner.hpp"

namespace {

using namespace tendril::teleop;

constexpr std::uint32_t kSeed = 1;

void run_plan(benchmark::State& state, double length, double ds) {
  SyntheticIcaOptions ica;
  ica.length = length;
  const auto vessel = VesselCenterline::from_polyline(make_synthetic_ica(kSeed, ica), ds);
  ShapeErrorPlanner planner(ConstantCurvatureCatheter(nominal_planning_design()), {});
  PathPlan plan;
  for (auto _ : state) {
    plan = planner.plan(vessel);
    benchmark::DoNotOptimize(plan.steps.data());
  }
  state.counters["steps"] = static_cast<double>(plan.steps.size());
  state.counters["lm_iterations"] = plan.total_iterations;
  state.counters["mean_pos_err_mm"] = plan.position_error_mean;
  state.counters["max_pos_err_mm"] = plan.position_error_max;
  state.counters["mean_tan_err_deg"] = plan.tangent_error_mean;
  state.counters["max_tan_err_deg"] = plan.tangent_error_max;
}

void BM_FullPlanIca150(benchmark::State& state) { run_plan(state, 150.0, 0.5); }
BENCHMARK(BM_FullPlanIca150)->Unit(benchmark::kMillisecond);

// Arg: path length (mm), ds = 0.5 mm.
void BM_PlanByLength(benchmark::State& state) { run_plan(state, static_cast<double>(state.range(0)), 0.5); }
BENCHMARK(BM_PlanByLength)->Arg(50)->Arg(100)->Arg(150)->Unit(benchmark::kMillisecond);

// Arg: ds in hundredths of a millimetre, 150 mm path.
void BM_PlanBySpacing(benchmark::State& state) {
  run_plan(state, 150.0, static_cast<double>(state.range(0)) / 100.0);
}
BENCHMARK(BM_PlanBySpacing)->Arg(25)->Arg(50)->Arg(100)->Unit(benchmark::kMillisecond);

// Vessel preparation alone: synthetic generation + resampling + tangents/angles.
void BM_ResampleIca150(benchmark::State& state) {
  const auto line = make_synthetic_ica(kSeed);
  for (auto _ : state) benchmark::DoNotOptimize(VesselCenterline::from_polyline(line, 0.5).size());
}
BENCHMARK(BM_ResampleIca150)->Unit(benchmark::kMicrosecond);

}  // namespace
