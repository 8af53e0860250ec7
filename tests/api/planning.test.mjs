// Planning and path following over REST: vessel upload, plan jobs with
// progress, cancellation, bad input, loading a plan into path following, mode switches and steps.
// Runs in order against the shared server; leaves the robot disabled, in joint mode, lease released.
import {test, after} from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import {API, TOKEN, CLIENT_ID, REPO_ROOT, ROBOT, get, post, call, script, holdLease, assertErrorShape, pollUntil, sleep} from './helpers.mjs';
import {planVerdict, designMismatch, stepRoute, nearestStep, movePreview} from '../../web/plan_verdict.js';

const R = `/robots/${ROBOT}`;
const icaCsv = fs.readFileSync(path.join(REPO_ROOT, 'config/vessels/synthetic_ica.csv'));

// A request whose body is a file (not JSON).
async function upload(urlPath, body, contentType, {client = CLIENT_ID, headers = {}} = {}) {
  const h = {Authorization: `Bearer ${TOKEN}`, 'X-Tendril-Client': client, 'Content-Type': contentType, ...headers};
  const response = await fetch(API + urlPath, {method: 'POST', headers: h, body});
  const text = await response.text();
  let json = null;
  try {
    json = text ? JSON.parse(text) : null;
  } catch {
    json = null;
  }
  return {status: response.status, json, text, headers: response.headers};
}

async function waitForJob(id, polls = 1200) {
  const seen = new Set();
  const last = await pollUntil(async () => {
    const res = await get(`/jobs/${id}`);
    assert.equal(res.status, 200, res.text);
    seen.add(res.json.state);
    return {done: !['queued', 'running'].includes(res.json.state), job: res.json};
  }, {polls, intervalMs: 100});
  return {job: last.job, seen};
}

// A plan carries the design it was made for (issue 31): by default the mounted one, as GET /robots gives it.
async function mountedDesign() {
  const robots = await get('/robots');
  assert.equal(robots.status, 200, robots.text);
  return robots.json.find((r) => r.name === ROBOT).design;
}

function inlinePlan(design) {
  const steps = [];
  for (let k = 0; k < 4; k++) steps.push({q: [10 + 2 * k, 0.05 * k, 0.4 * k, -0.2 * k]});
  return {design, steps};
}

after(async () => {
  await post('/lease', {});
  await post(`${R}/state_command`, {command: 'disable'});
  await sleep(100);
  await post(`${R}/mode`, {mode: 'joint'});
  await call('DELETE', '/lease');
});

let vesselId;
let planJob;

// Issue 31: a plan carries the design it was made for; the console's verdict refuses one made for another
// catheter, naming both (the design optimiser's 5/5 mm segments against the mounted 22/18.8 mm).
test('GET /robots gives the mounted design; a plan for another design is "made for another catheter"', async () => {
  const robots = await get('/robots');
  assert.equal(robots.status, 200, robots.text);
  const robot = robots.json.find((r) => r.name === ROBOT);
  assert.ok(robot.design, JSON.stringify(robot));
  assert.equal(robot.design.L1, 22);
  assert.equal(robot.design.L2, 18.8);
  const step = {q: [10, 0, 0, 0], position_error_mm: 0.2, position_error_max_mm: 0.4, orientation_error_deg: 2,
                orientation_error_max_deg: 4};
  const mine = planVerdict({design: {...robot.design}, steps: [step]}, robot, [2.5]);
  assert.equal(mine.verdict, 'ok', mine.reasons.join('; '));
  const other = planVerdict({design: {...robot.design, L1: 5, L2: 5}, steps: [step]}, robot, [2.5]);
  assert.equal(other.verdict, 'other-catheter');
  assert.match(other.reasons[0], /made for another catheter \(L1 5\.0 mm, L2 5\.0 mm.*not the mounted one \(L1 22\.0 mm, L2 18\.8 mm/);
  assert.equal(designMismatch({L1: 22, L2: 18.8}, {L1: 22, L2: 18.8, k1: 0.0882}), null);
});

// Issue 31: moving along a plan goes through the steps between, and a plan not started begins at the
// step nearest the insertion; the preview says what will move.
test('plan step routes: along the plan, from the step nearest the insertion; "will move" preview', () => {
  const steps = [3, 6, 9, 12, 15, 18, 45, 48].map((z) => ({q: [z, 0, 0, 0]}));
  assert.equal(nearestStep(steps, 45), 6);
  assert.deepEqual(stepRoute(steps, -1, 7, 45), [6, 7]);    // not started at 45 mm: no withdrawal to 3 mm
  assert.deepEqual(stepRoute(steps, 1, 5, 6), [2, 3, 4, 5]);  // Go from 1 to 5: through 2, 3, 4
  assert.deepEqual(stepRoute(steps, 5, 2, 15), [4, 3, 2]);
  assert.deepEqual(stepRoute(steps, 2, 2, 9), [2]);
  assert.deepEqual(stepRoute(steps, 2, 9, 9), []);
  const joints = [{name: 'insertion', unit: 'mm'}, {name: 'roll', unit: 'rad'}, {name: 'proximal_bend', unit: 'mm'},
                  {name: 'distal_bend', unit: 'mm'}];
  assert.equal(movePreview([45, 0, 0, 0], [3, 0, 0.5, 0], joints),
               'will move: insertion 45.0 → 3.0 mm (−42.0), proximal bend 0.0 → 0.5 mm (+0.5) · unchanged: roll, distal bend');
});

test('POST /vessels stores a CSV centerline and lists its branches', async () => {
  const res = await upload('/vessels?name=ica', icaCsv, 'text/csv');
  assert.equal(res.status, 201, res.text);
  assert.match(res.json.id, /^v\d+$/);
  assert.equal(res.json.name, 'ica');
  assert.equal(res.json.source, 'csv');
  assert.equal(res.json.branches.length, 1);
  assert.ok(Math.abs(res.json.branches[0].length_mm - 150) < 2, `length ${res.json.branches[0].length_mm}`);
  assert.equal(res.headers.get('location'), `/api/v1/vessels/${res.json.id}`);
  vesselId = res.json.id;
  const list = await get('/vessels');
  assert.ok(list.json.some((v) => v.id === vesselId));
  const one = await get(`/vessels/${vesselId}?branch=0&ds=1`);
  assert.equal(one.status, 200, one.text);
  assert.ok(one.json.points.length > 140 && one.json.points.length < 160, `${one.json.points.length} points`);
  assert.equal(one.json.radius.length, one.json.points.length);
});

test('bad vessel files get 400/415 with a clear message', async () => {
  let res = await upload('/vessels', '', 'text/csv');
  assertErrorShape(res, 400, 'bad_vessel');
  assert.match(res.json.error.message, /empty/);
  res = await upload('/vessels', '0,0,0\n0,0,0.0001\n0,0,0.0002\n0,0,0.0003\n', 'text/csv');
  assertErrorShape(res, 400, 'bad_vessel');
  assert.match(res.json.error.message, /metres|mm/);
  res = await upload('/vessels', '1,2,nan\n', 'text/csv');
  assertErrorShape(res, 400, 'bad_vessel');
  res = await upload('/vessels', 'hello', 'application/pdf');
  assertErrorShape(res, 415, 'unsupported_media_type');
  assertErrorShape(await get('/vessels/v999'), 404, 'unknown_vessel');
});

test('a viewer may list vessels and jobs but not upload or plan', async () => {
  const viewer = {headers: {'X-Tendril-Role': 'viewer'}};
  assert.equal((await get('/vessels', viewer)).status, 200);
  assert.equal((await get('/jobs', viewer)).status, 200);
  assertErrorShape(await upload('/vessels', icaCsv, 'text/csv', viewer), 403, 'forbidden_role');
  assertErrorShape(await post('/plans', {vessel: vesselId}, viewer), 403, 'forbidden_role');
});

test('POST /plans with the CSV as body runs a job from queued/running to succeeded', async () => {
  const started = Date.now();
  const res = await upload(`/plans?robot=${ROBOT}&branch=0&ds=0.5&dq1=3`, icaCsv, 'text/csv');
  assert.equal(res.status, 202, res.text);
  assert.equal(res.json.kind, 'plan');
  assert.ok(['queued', 'running'].includes(res.json.state), res.text);
  assert.equal(res.headers.get('location'), `/api/v1/jobs/${res.json.id}`);
  const {job, seen} = await waitForJob(res.json.id);
  const elapsed = (Date.now() - started) / 1000;
  assert.equal(job.state, 'succeeded', JSON.stringify({state: job.state, message: job.message}));
  assert.equal(job.progress, 1);
  assert.ok(seen.has('succeeded'));
  const result = job.result;
  assert.equal(result.robot, ROBOT);
  assert.ok(result.steps.length >= 30, `${result.steps.length} steps`);
  const step = result.steps[3];
  assert.equal(step.q.length, 4);
  for (const key of ['insertion', 'roll', 'theta_proximal', 'theta_distal']) assert.equal(typeof step.configuration[key], 'number');
  assert.ok(step.backbone.length > 2);
  assert.equal(typeof result.summary.mean_position_error_mm, 'number');
  assert.equal(typeof result.design.L1, 'number');
  console.log(`# plan job (synthetic ICA, ds 0.5, dq1 3) through REST: ${elapsed.toFixed(2)} s wall, compute ${result.summary.compute_s.toFixed(2)} s, ${result.steps.length} steps, mean error ${result.summary.mean_position_error_mm.toFixed(2)} mm`);
  planJob = job;
  const list = await get('/jobs');
  assert.ok(list.json.some((j) => j.id === job.id));
});

test('POST /plans with JSON naming an uploaded vessel; bad parameters are 400/404/422', async () => {
  assertErrorShape(await post('/plans', {vessel: 'v999'}), 404, 'unknown_vessel');
  assertErrorShape(await post('/plans', {vessel: vesselId, ds: 'fine'}), 400, 'bad_request');
  assertErrorShape(await post('/plans', {vessel: vesselId, dq1: -1}), 422, 'out_of_range');
  assertErrorShape(await post('/plans', {vessel: vesselId, branch: 3}), 422, 'unknown_branch');
  assertErrorShape(await post('/plans', {vessel: vesselId, robot: 'nope'}), 404, 'unknown_robot');
  assertErrorShape(await post('/plans', {vessel: vesselId, design: 'best'}), 400, 'bad_request');
  assertErrorShape(await get('/jobs/j999'), 404, 'unknown_job');
});

test('DELETE /jobs/{id} cancels a plan job', async () => {
  // A fine plan takes a while; cancel it while queued or running.
  const res = await post('/plans', {robot: ROBOT, vessel: vesselId, ds: 0.1, dq1: 0.5});
  assert.equal(res.status, 202, res.text);
  const cancelled = await call('DELETE', `/jobs/${res.json.id}`);
  assert.equal(cancelled.status, 200, cancelled.text);
  if (cancelled.json.state !== 'cancelled') {
    // It may have finished in between on a fast machine; then its final state is returned.
    assert.equal(cancelled.json.state, 'succeeded', cancelled.text);
  }
  const {job} = await waitForJob(res.json.id, 100);
  assert.equal(job.state, cancelled.json.state);
});

// Issue 31, server side: a plan made for another catheter is refused naming both designs, whether it
// comes from a plan job or is written inline; so is a plan that does not say its catheter.
test('path following refuses a plan made for another catheter, naming both designs', async () => {
  const design = await mountedDesign();
  // A plan job for the planning study's nominal catheter (tip-only bend gains 1.4 rad/mm).
  const res = await post('/plans', {robot: ROBOT, vessel: vesselId, ds: 0.5, dq1: 3, design: 'nominal'});
  assert.equal(res.status, 202, res.text);
  const {job} = await waitForJob(res.json.id);
  assert.equal(job.state, 'succeeded', JSON.stringify(job));
  assert.equal(job.result.design.k1, 1.4);
  await holdLease();
  const loadedPlan = async () => {
    const {loaded, steps, plan} = (await get(`${R}/path_following`)).json;
    return {loaded, steps, plan};
  };
  const before = await loadedPlan();
  const nominal = await post(`${R}/path_following`, {plan: job.id});
  assertErrorShape(nominal, 422, 'other_catheter');
  assert.equal(nominal.json.error.message,
               'This plan was made for another catheter, with bend gains of 1.4 and 1.4 rad per mm of drive; ' +
               'the mounted catheter has bend gains of 0.0882 and 0.238 rad per mm of drive. ' +
               'Compute the plan again for the mounted catheter.');
  // The design optimiser's 5/5 mm segments (the plan), inline.
  const other = await post(`${R}/path_following`, {plan: inlinePlan({...design, L1: 5, L2: 5})});
  assertErrorShape(other, 422, 'other_catheter');
  assert.match(other.json.error.message, /with segments of 5 and 5 mm; the mounted catheter has segments of 22 and 18\.8 mm\./);
  const unsaid = await post(`${R}/path_following`, {plan: {steps: inlinePlan(design).steps}});
  assertErrorShape(unsaid, 422, 'no_design');
  assert.match(unsaid.json.error.message, /^This plan does not say which catheter it was made for, so it cannot be checked against the mounted catheter \(segments of 22 and 18\.8 mm, /);
  // Nothing was loaded by any of them.
  assert.deepEqual(await loadedPlan(), before);
});

test('path following: load needs the lease; mode switch needs a plan; steps move the robot', async () => {
  // Taken here, not earlier: the plan jobs before may take longer than the lease lasts unused (30 s).
  await holdLease();
  const design = await mountedDesign();
  assertErrorShape(await script('not-the-holder').post(`${R}/path_following`, {plan: inlinePlan(design)}), 409, 'lease_held');
  // Start from joint mode with no plan of an earlier run: a fresh server has none.
  const before = await get(`${R}/path_following`);
  assert.equal(before.status, 200, before.text);
  if (!before.json.loaded) assertErrorShape(await post(`${R}/mode`, {mode: 'path_following'}), 409, 'no_plan');

  const bad = inlinePlan(design);
  bad.steps[2].q[3] = 9;  // distal_bend limit is 5 mm
  const refused = await post(`${R}/path_following`, {plan: bad});
  assertErrorShape(refused, 422, 'out_of_limits');
  assert.match(refused.json.error.message, /^step 2: /);
  assertErrorShape(await post(`${R}/path_following`, {plan: 'j999'}), 404, 'unknown_job');
  assertErrorShape(await post(`${R}/path_following`, {}), 400, 'bad_request');

  // The plan job from above: loaded when inside the joint limits, else refused naming the step.
  const fromJob = await post(`${R}/path_following`, {plan: planJob.id});
  if (planJob.result.within_joint_limits) {
    assert.equal(fromJob.status, 200, fromJob.text);
    assert.equal(fromJob.json.steps, planJob.result.steps.length);
  } else {
    assertErrorShape(fromJob, 422, 'out_of_limits');
    assert.match(fromJob.json.error.message, /^step \d+: /);
  }

  const loaded = await post(`${R}/path_following`, {plan: inlinePlan(design)});
  assert.equal(loaded.status, 200, loaded.text);
  assert.deepEqual(loaded.json, {steps: 4, step: -1, plan: null});

  assert.equal((await post(`${R}/state_command`, {command: 'enable'})).status, 200);
  const ready = await pollUntil(async () => {
    const os = (await get(`${R}/operating_state`)).json;
    return {done: os.state === 'ENABLED' && os.drives_ready && !os.is_busy, os};
  });
  assert.ok(ready.done, JSON.stringify(ready.os));

  assertErrorShape(await post(`${R}/path_following/step`, {advance: 1}), 409, 'wrong_mode');
  const switched = await post(`${R}/mode`, {mode: 'path_following'});
  assert.equal(switched.status, 200, switched.text);
  const os = await pollUntil(async () => {
    const s = (await get(`${R}/operating_state`)).json;
    return {done: s.mode === 'path_following', s};
  });
  assert.ok(os.done, JSON.stringify(os.s));
  assertErrorShape(await post(`${R}/move_jp`, {goal: [12, 0, 0, 0]}), 409, 'wrong_mode');

  const step = await post(`${R}/path_following/step`, {advance: 1});
  assert.equal(step.status, 202, step.text);
  assert.equal(step.json.step, 0);
  assert.ok(step.json.duration_s > 0);
  // While it moves, switching mode or stepping again is refused with the reason.
  const busySwitch = await post(`${R}/mode`, {mode: 'joint'});
  if (busySwitch.status !== 200) {
    assertErrorShape(busySwitch, 409, 'not_holding');
    assert.match(busySwitch.json.error.message, /moving/);
  }
  const reached = await pollUntil(async () => {
    const s = (await get(`${R}/path_following`)).json;
    return {done: s.step === 0 && !s.moving, s};
  }, {polls: 400});
  assert.ok(reached.done, JSON.stringify(reached.s));
  const second = await post(`${R}/path_following/step`, {step: 1});
  assert.equal(second.status, 202, second.text);
  const reached1 = await pollUntil(async () => {
    const s = (await get(`${R}/path_following`)).json;
    return {done: s.step === 1 && !s.moving, s};
  }, {polls: 400});
  assert.ok(reached1.done, JSON.stringify(reached1.s));
  const sp = (await get(`${R}/setpoint_js`)).json.position;
  inlinePlan(design).steps[1].q.forEach((v, i) => assert.ok(Math.abs(sp[i] - v) < 1e-6, `joint ${i}: ${sp[i]} vs ${v}`));
  assertErrorShape(await post(`${R}/path_following/step`, {step: 9}), 422, 'out_of_range');
  assertErrorShape(await post(`${R}/path_following/step`, {advance: 2}), 400, 'bad_request');

  assert.equal((await post(`${R}/mode`, {mode: 'joint'})).status, 200);
  // Back to where the simulated robot starts, for the test files that follow.
  await pollUntil(async () => ({done: (await get(`${R}/operating_state`)).json.mode === 'joint'}));
  const home = await post(`${R}/move_jp`, {goal: [10, 0, 0, 0]});
  assert.equal(home.status, 202, home.text);
  const back = await pollUntil(async () => ({done: !(await get(`${R}/operating_state`)).json.is_busy}), {polls: 400});
  assert.ok(back.done);
});

test('DELETE /vessels/{id} forgets a vessel', async () => {
  assert.equal((await call('DELETE', `/vessels/${vesselId}`)).status, 200);
  assertErrorShape(await get(`/vessels/${vesselId}`), 404, 'unknown_vessel');
});

// A binary STL of an open tube (radius 2.5 mm, 24 sides) around a centerline that runs straight for
// 20 mm along +z and then bends through a 40 mm radius arc in the x–z plane for 60 mm.
function tubeStl() {
  const centre = (s) => {
    if (s <= 20) return {p: [0, 0, s], t: [0, 0, 1], n: [1, 0, 0]};
    const a = (s - 20) / 40;
    return {p: [40 * (1 - Math.cos(a)), 0, 20 + 40 * Math.sin(a)], t: [Math.sin(a), 0, Math.cos(a)], n: [Math.cos(a), 0, -Math.sin(a)]};
  };
  const sides = 24;
  const rings = [];
  for (let s = 0; s <= 80 + 1e-9; s += 0.5) {
    const {p, n} = centre(s);
    const b = [0, 1, 0];
    const ring = [];
    for (let k = 0; k < sides; k++) {
      const phi = (2 * Math.PI * k) / sides;
      ring.push(p.map((v, i) => v + 2.5 * (Math.cos(phi) * n[i] + Math.sin(phi) * b[i])));
    }
    rings.push(ring);
  }
  const triangles = [];
  for (let r = 0; r + 1 < rings.length; r++) {
    for (let k = 0; k < sides; k++) {
      const a = rings[r][k], b = rings[r][(k + 1) % sides], c = rings[r + 1][k], d = rings[r + 1][(k + 1) % sides];
      triangles.push([a, b, d], [a, d, c]);
    }
  }
  const buffer = Buffer.alloc(84 + 50 * triangles.length);
  buffer.write('tendril api test tube', 0, 'ascii');
  buffer.writeUInt32LE(triangles.length, 80);
  triangles.forEach((tri, i) => {
    let offset = 84 + 50 * i + 12;  // zero normal
    for (const v of tri) for (const x of v) { buffer.writeFloatLE(x, offset); offset += 4; }
  });
  return buffer;
}

test('POST /vessels with a binary STL mesh extracts its centerline (model/stl)', async () => {
  const res = await upload('/vessels?name=tube', tubeStl(), 'model/stl');
  assert.equal(res.status, 201, res.text);
  assert.equal(res.json.source, 'stl');
  assert.equal(res.json.branches.length, 1);
  const length = res.json.branches[0].length_mm;
  assert.ok(length > 70 && length <= 81, `centerline length ${length} mm of an 80 mm tube`);
  const one = await get(`/vessels/${res.json.id}?branch=0&ds=1`);
  assert.equal(one.status, 200, one.text);
  // Every extracted point lies on the true centerline: within 0.5 mm of the straight part or the arc.
  for (const [x, y, z] of one.json.points) {
    const onStraight = z <= 20 ? Math.hypot(x, y) : Infinity;
    const onArc = z >= 20 ? Math.abs(Math.hypot(x - 40, z - 20) - 40) + Math.abs(y) : Infinity;
    assert.ok(Math.min(onStraight, onArc) < 0.5, `point ${[x, y, z].map((v) => v.toFixed(2))} is off the centerline`);
  }
  for (const r of one.json.radius) assert.ok(Math.abs(r - 2.5) < 0.25, `radius ${r}`);

  const broken = await upload('/vessels', tubeStl().subarray(0, 500), 'model/stl');
  assertErrorShape(broken, 400, 'bad_vessel');
});

test('POST /designs optimises L1, L2, δ2 as a job and lowers the design penalty', async () => {
  const up = await upload('/vessels?name=ica-design', icaCsv, 'text/csv');
  assert.equal(up.status, 201, up.text);
  const res = await post('/designs', {vessel: up.json.id, branch: 0, flexure: false});
  assert.equal(res.status, 202, res.text);
  assert.equal(res.json.kind, 'design');
  const {job} = await waitForJob(res.json.id);
  assert.equal(job.state, 'succeeded', job.message);
  const result = job.result;
  assert.ok(result.penalty < result.initial_penalty, `g(χ) ${result.penalty} must fall below ${result.initial_penalty}`);
  for (const key of ['L1', 'L2', 'delta2']) assert.ok(Number.isFinite(result.design[key]), key);
  assert.ok(result.summary.mean_position_error_mm >= 0);
});
