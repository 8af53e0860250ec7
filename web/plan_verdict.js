// Verdict on a computed plan, per step and for the whole plan, from what the plan job's result
// already carries (POST /plans → GET /jobs/{id}: per step the joint values q and the mean/max position
// and orientation errors against the vessel; for the plan within_joint_limits, limit_violation and
// truncated_to_insertion_range) plus the robot's joint limits (GET /robots) and the vessel's lumen
// radius (GET /vessels/{id}?branch=k). Nothing is invented: where a number is missing the verdict
// says what it could not check.
//
// Bounds (chosen here; the seeds give the planner's error ranges, not a go/no-go rule):
// - cannot follow: a step's worst position error over OFF_PATH_MM (10 mm, the planner's δ_p,range) or
//   worst orientation error over OFF_PATH_DEG (57.3°, δ_t,range = 1 rad): the planned shape is not in
//   the vessel; or a joint outside its limits (the robot cannot take the step at all).
// - expect contact: a step's worst position error over the lumen radius: the planned backbone leaves
//   the centreline by more than the vessel is wide, so it presses on the wall; the springs deflect
//   and the robot may hold (spring-deflection hold).
// - ok: within both. The seeds' optimised designs stay at 0.96–1.40 mm and 0.22–0.23 rad worst.

export const OFF_PATH_MM = 10;
export const OFF_PATH_DEG = 57.3;

const RANK = {ok: 0, unknown: 1, contact: 2, unreachable: 3, 'off-path': 3};

// plan: the job result; robot: GET /robots entry; radiusMm: lumen radii of the branch (array) or a
// number; returns {verdict, steps: [{step, verdict, reasons[]}], reasons[], lumenMm}.
// verdict: 'ok' | 'contact' | 'cannot-follow' | 'unknown' (no steps).
export function planVerdict(plan, robot, radiusMm) {
  const steps = Array.isArray(plan?.steps) ? plan.steps : [];
  const radii = Array.isArray(radiusMm) ? radiusMm.map(Number).filter((r) => Number.isFinite(r) && r > 0)
      : Number.isFinite(Number(radiusMm)) && Number(radiusMm) > 0 ? [Number(radiusMm)] : [];
  // The narrowest lumen along the branch: a plan is judged where the vessel is tightest.
  const lumenMm = radii.length ? Math.min(...radii) : NaN;
  const joints = Array.isArray(robot?.joints) ? robot.joints : [];
  const violationStep = /^step (\d+):/.exec(String(plan?.limit_violation || ''));
  const result = steps.map((s, k) => {
    const reasons = [];
    let verdict = 'ok';
    const raise = (v) => { if (RANK[v] > RANK[verdict]) verdict = v; };
    const pos = Number(s.position_error_max_mm ?? s.position_error_mm);
    const ang = Number(s.orientation_error_max_deg ?? s.orientation_error_deg);
    if (Array.isArray(s.q)) {
      s.q.forEach((v, i) => {
        const j = joints[i];
        if (!j) return;
        if (Number(v) < Number(j.lower) || Number(v) > Number(j.upper)) {
          raise('unreachable');
          reasons.push(`${j.name.replace(/_/g, ' ')} ${Number(v).toFixed(2)} ${j.unit} outside ${j.lower}…${j.upper} ${j.unit}`);
        }
      });
    }
    if (violationStep && Number(violationStep[1]) === k && verdict !== 'unreachable') {
      raise('unreachable');
      reasons.push(String(plan.limit_violation).replace(/^step \d+: /, ''));
    }
    if (pos > OFF_PATH_MM || ang > OFF_PATH_DEG) {
      raise('off-path');
      reasons.push(`leaves the vessel: worst error ${pos.toFixed(1)} mm / ${ang.toFixed(0)}° (bounds ${OFF_PATH_MM} mm / ${OFF_PATH_DEG.toFixed(0)}°)`);
    } else if (Number.isFinite(lumenMm) && pos > lumenMm) {
      raise('contact');
      reasons.push(`expect wall contact: ${pos.toFixed(1)} mm off the centreline, lumen radius ${lumenMm.toFixed(1)} mm`);
    } else if (!Number.isFinite(pos) || !Number.isFinite(ang)) {
      raise('unknown');
      reasons.push('no error figures for this step');
    }
    return {step: k, verdict, reasons, positionMm: pos, orientationDeg: ang};
  });
  const bad = result.filter((s) => s.verdict === 'off-path' || s.verdict === 'unreachable');
  const contact = result.filter((s) => s.verdict === 'contact');
  const reasons = [];
  if (bad.length) {
    reasons.push(`cannot be followed from step ${bad[0].step}: ${bad[0].reasons[0]}` +
                 (bad.length > 1 ? ` (${bad.length} of ${result.length} steps)` : ''));
  }
  if (contact.length) {
    reasons.push(`expect wall contact at ${contact.length} of ${result.length} steps, first at step ${contact[0].step}` +
                 ' (the springs deflect; the robot may hold)');
  }
  if (plan?.truncated_to_insertion_range) {
    const planned = Number(plan.planned_length_mm);
    const vessel = Number(plan.vessel_length_mm);
    reasons.push(`ends before the vessel does: the insertion range reaches ${Number.isFinite(planned) ? planned.toFixed(0) : '?'} of ` +
                 `${Number.isFinite(vessel) ? vessel.toFixed(0) : '?'} mm`);
  }
  if (!Number.isFinite(lumenMm)) reasons.push('wall contact not checked: the vessel has no radius');
  const verdict = !result.length ? 'unknown' : bad.length ? 'cannot-follow' : contact.length ? 'contact' : 'ok';
  return {verdict, steps: result, reasons, lumenMm};
}
