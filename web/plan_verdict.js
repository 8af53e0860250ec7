// Verdict on a computed plan, per step and for the whole plan, from what the plan job's result
// already carries (POST /plans → GET /jobs/{id}: per step the joint values q and the mean/max position
// and orientation errors against the vessel; for the plan within_joint_limits, limit_violation and
// truncated_to_insertion_range) plus the robot's joint limits (GET /robots) and the vessel's lumen
// radius (GET /vessels/{id}?branch=k). Nothing is invented: where a number is missing the verdict
// says what it could not check.
//
// Bounds (chosen here; Abah 2022 gives the planner's error ranges, not a go/no-go rule):
// - cannot follow: a step's worst position error over OFF_PATH_MM (10 mm, the planner's δ_p,range) or
//   worst orientation error over OFF_PATH_DEG (57.3°, δ_t,range = 1 rad): the planned shape is not in
//   the vessel; or a joint outside its limits (the robot cannot take the step at all).
// - expect contact: a step's worst position error over the lumen radius: the planned backbone leaves
//   the centreline by more than the vessel is wide, so it presses on the wall; the springs deflect
//   and the robot may hold (spring-deflection hold).
// - ok: within both. The optimised designs of Abah 2022 stay at 0.96–1.40 mm and 0.22–0.23 rad worst.

export const OFF_PATH_MM = 10;
export const OFF_PATH_DEG = 57.3;

const RANK = {ok: 0, unknown: 1, contact: 2, unreachable: 3, 'off-path': 3};

// plan: the job result; robot: GET /robots entry; radiusMm: lumen radii of the branch (array) or a
// number; returns {verdict, steps: [{step, verdict, reasons[]}], reasons[], lumenMm}.
// verdict: 'ok' | 'contact' | 'cannot-follow' | 'unknown' (no steps) | 'other-catheter' (the plan's design is
// not the mounted catheter's: designMismatch below).
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
  // A plan for another catheter is refused before anything else (the server refuses to load it too).
  const otherCatheter = designMismatch(plan?.design, robot?.design);
  if (otherCatheter) reasons.unshift(otherCatheter);
  const verdict = otherCatheter ? 'other-catheter' : !result.length ? 'unknown' : bad.length ? 'cannot-follow'
      : contact.length ? 'contact' : 'ok';
  return {verdict, steps: result, reasons, lumenMm, otherCatheter};
}

// ---- The catheter a plan was made for (issue 31) ----
// A plan job's result carries the design it was planned with ({L1, L2, k1, k2, delta2, …}); GET /robots
// gives the mounted catheter's (`design`). A plan for another catheter (the design optimiser's 5/5 mm
// segments, the "nominal" design) puts this catheter's tip elsewhere at the same joint values: it is not
// followable, whatever its own errors say.
export const DESIGN_KEYS = [['L1', 'L1', 'mm'], ['L2', 'L2', 'mm'], ['k1', 'k1', 'rad/mm'], ['k2', 'k2', 'rad/mm'],
                            ['delta2', 'δ2', 'rad']];

export function describeDesign(d) {
  if (!d) return 'unknown';
  return DESIGN_KEYS.filter(([k]) => Number.isFinite(Number(d[k])))
      .map(([k, label, unit]) => `${label} ${Number(d[k]).toFixed(k.startsWith('L') ? 1 : 3)} ${unit}`).join(', ');
}

// null when the plan's design is the mounted one (relative 1e-6 on each key both give), else a sentence
// naming both designs. A plan or robot without a design: null (nothing to compare).
export function designMismatch(planDesign, mountedDesign) {
  if (!planDesign || !mountedDesign) return null;
  const differs = DESIGN_KEYS.some(([k]) => {
    const a = Number(planDesign[k]);
    const b = Number(mountedDesign[k]);
    if (!Number.isFinite(a) || !Number.isFinite(b)) return false;
    return Math.abs(a - b) > 1e-6 * Math.max(1, Math.abs(b));
  });
  return differs ? `made for another catheter (${describeDesign(planDesign)}), not the mounted one (${describeDesign(mountedDesign)})`
      : null;
}

// ---- Moving along a plan (issue 31) ----
// The step whose insertion is nearest `insertion` (mm): where "Next" starts a plan that has not started,
// so that starting never withdraws the catheter far (a plan starts at 3 mm, the catheter may be at 45).
export function nearestStep(steps, insertion) {
  let best = 0;
  let bestD = Infinity;
  (steps || []).forEach((s, k) => {
    const d = Math.abs(Number(s?.q?.[0]) - Number(insertion));
    if (d < bestD) { bestD = d; best = k; }
  });
  return best;
}

// The steps to go through from step `from` (−1: not started) to step `to`, in order, ending with `to`:
// along the plan, one step at a time, never one joint-space jump across the vessel's bends. Not started:
// first the step nearest the current insertion. [] when `to` is outside the plan.
export function stepRoute(steps, from, to, insertion) {
  const n = Array.isArray(steps) ? steps.length : 0;
  if (!Number.isInteger(to) || to < 0 || to >= n) return [];
  let at = from;
  const route = [];
  if (!Number.isInteger(at) || at < 0 || at >= n) {
    at = nearestStep(steps, insertion);
    route.push(at);
  }
  const dir = to >= at ? 1 : -1;
  for (let k = at + dir; dir > 0 ? k <= to : k >= to; k += dir) route.push(k);
  return route.length ? route : [to];
}

const JOINT_WORDS = ['insertion', 'roll', 'proximal bend', 'distal bend'];

// "will move: insertion 45.0 → 48.0 mm, distal bend 0.10 → 0.40 mm · unchanged: roll, proximal bend" from
// the joint values now (`from`) to the plan step's q; joints: GET /robots joints (names, units).
export function movePreview(from, to, joints = []) {
  const parts = [];
  const still = [];
  (to || []).forEach((v, i) => {
    const j = joints[i] || {};
    const name = j.name ? String(j.name).replace(/_/g, ' ') : JOINT_WORDS[i] || `joint ${i}`;
    const unit = j.unit || (i === 1 ? 'rad' : 'mm');
    const a = Number(from?.[i]);
    const b = Number(v);
    const digits = unit === 'rad' ? 2 : 1;
    if (!Number.isFinite(a)) parts.push(`${name} → ${b.toFixed(digits)} ${unit}`);
    else if (Math.abs(a - b) < (unit === 'rad' ? 0.005 : 0.05)) still.push(name);
    else parts.push(`${name} ${a.toFixed(digits)} → ${b.toFixed(digits)} ${unit} (${b - a >= 0 ? '+' : '−'}${Math.abs(b - a).toFixed(digits)})`);
  });
  if (!parts.length) return `will move: nothing${still.length ? ` · unchanged: ${still.join(', ')}` : ''}`;
  return `will move: ${parts.join(', ')}${still.length ? ` · unchanged: ${still.join(', ')}` : ''}`;
}

// ---- The plan's target (issue 31) ----
// Where the plan ends (its vessel path's last point: the vessel's end unless the plan was truncated to the
// insertion range), in the robot's frame through the robot's vessel_entry (position, orientation [x, y, z, w]),
// and the tip's distance from it. Reached: the tip within the lumen radius there (the last of the branch's
// radii, or its one radius), i.e. inside the vessel at its end: Abah 2022 gives no tolerance, and a tip
// closer than the wall is where the vessel ends. null when a number is missing (nothing is guessed).
export function targetReach(plan, entry, radiusMm, tip) {
  const path = Array.isArray(plan?.vessel_path) ? plan.vessel_path : [];
  const end = path[path.length - 1];
  const p = Array.isArray(end) ? end : end && [end.x, end.y, end.z];
  const radii = Array.isArray(radiusMm) ? radiusMm : [radiusMm];
  const toleranceMm = Number(radii[radii.length - 1]);
  if (!p || !Array.isArray(entry?.position) || !Array.isArray(tip) || !(toleranceMm > 0)) return null;
  const [qx, qy, qz, qw] = Array.isArray(entry.orientation) && entry.orientation.length === 4 ? entry.orientation.map(Number) : [0, 0, 0, 1];
  // v' = v + 2 w (u × v) + 2 u × (u × v), u = (qx, qy, qz): the unit quaternion's rotation.
  const [vx, vy, vz] = p.map(Number);
  const cx = qy * vz - qz * vy, cy = qz * vx - qx * vz, cz = qx * vy - qy * vx;
  const dx = qy * cz - qz * cy, dy = qz * cx - qx * cz, dz = qx * cy - qy * cx;
  const target = [vx + 2 * (qw * cx + dx) + Number(entry.position[0]), vy + 2 * (qw * cy + dy) + Number(entry.position[1]),
                  vz + 2 * (qw * cz + dz) + Number(entry.position[2])];
  const distanceMm = Math.hypot(tip[0] - target[0], tip[1] - target[1], tip[2] - target[2]);
  if (!Number.isFinite(distanceMm)) return null;
  return {target, distanceMm, toleranceMm, reached: distanceMm <= toleranceMm, truncated: !!plan.truncated_to_insertion_range};
}
