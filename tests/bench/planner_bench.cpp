// Shape-error path planner timing (Abah 2022, §4.6.1, §4.6.3): full plan along the synthetic 150 mm ICA
// with ds = 0.5 mm and dq1 = 3 mm (issue target ≤ 50 ms; MATLAB reference 14.5 s), how the cost
// grows with path length and sample spacing, the design optimiser (target ≤ 0.5 s; MATLAB 17.72 min)
// and STL centerline extraction. Reports only; asserts nothing.
//
// Issue 15 (replanning): full plans and single warm-started steps on three vessels, ds 0.5, dq1 3:
//   ica7       the shipped config/vessels/synthetic_ica.csv (make_synthetic_ica(7), 150 mm; also cut to
//              120 mm, the srmc's insertion range, like the 85–130 mm patient ICAs of the issue);
//   tortuous11, tortuous12  make_synthetic_ica(11 / 12) with 250 mm of path and 4–10 mm bend radii
//              (tighter and longer than the ICA's 5–15 mm).
#include <benchmark/benchmark.h>

#include "siphon_vessels.hpp"
#include "tendril/teleop/design_optimiser.hpp"
#include "tendril/teleop/image_guided_replanner.hpp"
#include "tendril/teleop/shape_error_planner.hpp"
#include "tendril/teleop/vessel_mesh.hpp"

namespace {

using namespace tendril::teleop;

constexpr std::uint32_t kSeed = 1;

void report(benchmark::State& state, const PathPlan& plan) {
  state.counters["steps"] = static_cast<double>(plan.steps.size());
  state.counters["lm_iterations"] = plan.total_iterations;
  state.counters["mean_pos_err_mm"] = plan.position_error_mean;
  state.counters["max_pos_err_mm"] = plan.position_error_max;
  state.counters["mean_tan_err_deg"] = plan.tangent_error_mean;
  state.counters["max_tan_err_deg"] = plan.tangent_error_max;
}

void run_plan(benchmark::State& state, double length, double ds, bool flexure = false) {
  SyntheticIcaOptions ica;
  ica.length = length;
  const auto vessel = VesselCenterline::from_polyline(make_synthetic_ica(kSeed, ica), ds);
  ShapeErrorPlannerOptions options;
  options.free_flexure = flexure;
  ShapeErrorPlanner planner(ConstantCurvatureCatheter(nominal_planning_design()), options);
  PathPlan plan;
  for (auto _ : state) {
    plan = planner.plan(vessel);
    benchmark::DoNotOptimize(plan.steps.data());
  }
  report(state, plan);
}

void BM_FullPlanIca150(benchmark::State& state) { run_plan(state, 150.0, 0.5); }
BENCHMARK(BM_FullPlanIca150)->Unit(benchmark::kMillisecond);

// Same with the flexure angle γ solved per step (4 unknowns instead of 3).
void BM_FullPlanIca150Flexure(benchmark::State& state) { run_plan(state, 150.0, 0.5, true); }
BENCHMARK(BM_FullPlanIca150Flexure)->Unit(benchmark::kMillisecond);

// Arg: path length (mm), ds = 0.5 mm.
void BM_PlanByLength(benchmark::State& state) { run_plan(state, static_cast<double>(state.range(0)), 0.5); }
BENCHMARK(BM_PlanByLength)->Arg(50)->Arg(100)->Arg(150)->Arg(300)->Unit(benchmark::kMillisecond);

// Arg: ds in hundredths of a millimetre, 150 mm path.
void BM_PlanBySpacing(benchmark::State& state) {
  run_plan(state, 150.0, static_cast<double>(state.range(0)) / 100.0);
}
BENCHMARK(BM_PlanBySpacing)->Arg(100)->Arg(50)->Arg(25)->Unit(benchmark::kMillisecond);

// Arg: 0 = ica7 (150 mm), 1 = ica7 cut to 120 mm, 2 = tortuous11, 3 = tortuous12 (see the top).
VesselCenterline issue15_vessel(std::int64_t which) {
  SyntheticIcaOptions o;
  o.point_spacing = 0.2;  // as the shipped file
  std::uint32_t seed = 7;
  if (which == 1) o.length = 120.0;
  if (which >= 2) {
    seed = which == 2 ? 11 : 12;
    o.length = 250.0;
    o.min_bend_radius = 4.0;
    o.max_bend_radius = 10.0;
  }
  return VesselCenterline::from_polyline(make_synthetic_ica(seed, o), 0.5);
}

void BM_FullPlan(benchmark::State& state) {
  const auto vessel = issue15_vessel(state.range(0));
  ShapeErrorPlanner planner(ConstantCurvatureCatheter(nominal_planning_design()), {});
  PathPlan plan;
  for (auto _ : state) {
    plan = planner.plan(vessel);
    benchmark::DoNotOptimize(plan.steps.data());
  }
  report(state, plan);
  state.counters["us_per_step"] =
      benchmark::Counter(static_cast<double>(plan.steps.size()) * 1e-6,
                         benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_FullPlan)->DenseRange(0, 3)->Unit(benchmark::kMillisecond);

// One replanned insertion step (load the step's samples + Levenberg–Marquardt), warm-started from the
// previous step's planned solution, cycling over all steps of the vessel: what a live replan costs.
void BM_PlanStep(benchmark::State& state) {
  const auto vessel = issue15_vessel(state.range(0));
  ShapeErrorPlanner planner(ConstantCurvatureCatheter(nominal_planning_design()), {});
  const PathPlan plan = planner.plan(vessel);
  auto ws = planner.make_workspace();
  PlanStep step;
  std::size_t k = 1;
  std::int64_t iterations = 0;
  for (auto _ : state) {
    const PlanStep& previous = plan.steps[k - 1];
    planner.load_step(plan.steps[k].q[0], Eigen::Vector3d::Zero(), ws);
    planner.solve_loaded(ws, {previous.q[1], previous.q[2], previous.q[3], previous.flexure}, step);
    benchmark::DoNotOptimize(step.cost);
    iterations += step.iterations;
    k = k + 1 < plan.steps.size() ? k + 1 : 1;
  }
  state.counters["lm_iterations_per_step"] =
      static_cast<double>(iterations) / static_cast<double>(state.iterations());
}
BENCHMARK(BM_PlanStep)->DenseRange(0, 3)->Unit(benchmark::kMicrosecond);

// One live replan (ImageGuidedReplanner::replan: prediction, error filter, step solve) with the tip
// measured 0.5 mm off the model, walking the vessel 3 mm per call and starting over at its end.
void BM_ReplanStep(benchmark::State& state) {
  const auto vessel = issue15_vessel(state.range(0));
  const ImageGuidedReplanner replanner(ConstantCurvatureCatheter(nominal_planning_design()), {}, vessel);
  ReplannerState replanner_state = replanner.make_state();
  ReplanInput in;
  for (auto _ : state) {
    const ReplanResult next = replanner.replan(replanner_state, in);
    benchmark::DoNotOptimize(next.configuration.data());
    if (next.target_insertion + 1e-9 >= replanner.vessel_length()) {
      replanner_state = replanner.make_state();
      in = ReplanInput{};
      continue;
    }
    in.commanded_configuration = next.configuration;
    in.measured_insertion = next.target_insertion;
    in.measured_tip =
        replanner.predicted_tip(next.configuration, next.target_insertion) + Eigen::Vector3d(0.3, -0.4, 0.0);
  }
}
BENCHMARK(BM_ReplanStep)->DenseRange(0, 3)->Unit(benchmark::kMicrosecond);

// Design optimisation (§4.6.2, design_optimiser.hpp; issue 15 target ≤ 0.5 s) at the dissertation's ds 0.5
// and dq1 3 with the default budget. Args: vessel (0 = synthetic ICA seed 1, 150 mm; 1–3 = the tortuous
// siphons of tests/support/siphon_vessels.hpp, c_siphon, s_siphon, double_loop), flexure (0/1), start
// (0 = the planning study's nominal catheter, k = 1.4 rad/mm; 1 = the robot file's catheter with the
// assembled gains and drive limits, which POST /designs starts from).
void BM_DesignOptimisation(benchmark::State& state) {
  const auto vessel_index = static_cast<std::size_t>(state.range(0));
  const auto line = vessel_index == 0
                        ? make_synthetic_ica(kSeed)
                        : tendril::test::make_siphon(tendril::test::siphon_shapes()[vessel_index - 1]);
  const auto vessel = VesselCenterline::from_polyline(line, 0.5);
  ShapeErrorPlannerOptions options;
  options.free_flexure = state.range(1) != 0;
  CatheterParameters start = nominal_planning_design();
  if (state.range(2) != 0) {  // config/robots/srmc.json
    start.proximal_curvature_gain = 0.0882;
    start.distal_curvature_gain = 0.238;
    options.proximal_drive_min = -5.9;
    options.proximal_drive_max = 9.9;
    options.distal_drive_min = -4.9;
    options.distal_drive_max = 4.9;
  }
  DesignResult result;
  for (auto _ : state) {
    result = optimise_design(start, vessel, options);
    benchmark::DoNotOptimize(result.penalty);
  }
  state.counters["evaluations"] = result.evaluations;
  state.counters["penalty"] = result.penalty;
  state.counters["initial_penalty"] = result.initial_penalty;
  state.counters["converged"] = result.convergence.converged ? 1.0 : 0.0;
  state.counters["flexure_improved"] = result.convergence.flexure_improved ? 1.0 : 0.0;
  state.counters["mean_tip_err_mm"] = result.tip_error_mean;
  report(state, result.plan);
}
BENCHMARK(BM_DesignOptimisation)
    ->ArgsProduct({{0, 1, 2, 3}, {0, 1}, {0, 1}})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(1)
    ->Repetitions(5)
    ->ReportAggregatesOnly(true);

// Vessel preparation alone: resampling + tangents/angles.
void BM_ResampleIca150(benchmark::State& state) {
  const auto line = make_synthetic_ica(kSeed);
  for (auto _ : state) benchmark::DoNotOptimize(VesselCenterline::from_polyline(line, 0.5).size());
}
BENCHMARK(BM_ResampleIca150)->Unit(benchmark::kMicrosecond);

// STL: parse only, and parse + centerline extraction, for a 150 mm tube mesh with a ring of 24
// vertices every Arg/100 mm (50 → 14 352 triangles, 25 → 28 752).
void BM_StlParse(benchmark::State& state) {
  const std::string stl = write_binary_stl(
      make_tube_mesh(make_synthetic_ica(kSeed), static_cast<double>(state.range(0)) / 100.0, 24));
  for (auto _ : state) benchmark::DoNotOptimize(parse_stl(stl).vertices.size());
  state.counters["triangles"] = static_cast<double>((stl.size() - 84) / 50);
}
BENCHMARK(BM_StlParse)->Arg(50)->Arg(25)->Unit(benchmark::kMillisecond);

void BM_StlCenterline(benchmark::State& state) {
  const std::string stl = write_binary_stl(
      make_tube_mesh(make_synthetic_ica(kSeed), static_cast<double>(state.range(0)) / 100.0, 24));
  for (auto _ : state) benchmark::DoNotOptimize(read_stl_centerline(stl).front().points.size());
  state.counters["triangles"] = static_cast<double>((stl.size() - 84) / 50);
}
BENCHMARK(BM_StlCenterline)->Arg(50)->Arg(25)->Unit(benchmark::kMillisecond);

}  // namespace
