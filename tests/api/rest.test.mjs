// REST contract tests (server/openapi/openapi.json) against a running tendrild with simulated drives. The tests run in
// order: lease -> enable -> move -> bad input -> e-stop -> reset, as an operator would.
import {test, after, beforeEach} from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import {BASE_URL, ROBOT, robotConfig, get, post, call, script, holdLease, assertErrorShape, pollUntil, sleep, tolerance} from './helpers.mjs';

const R = `/robots/${ROBOT}`;
let joints = [];  // from GET /robots

async function operatingState() {
  const res = await get(`${R}/operating_state`);
  assert.equal(res.status, 200, res.text);
  return res.json;
}

async function measured() {
  const res = await get(`${R}/measured_js`);
  assert.equal(res.status, 200, res.text);
  return res.json;
}

// The calls here are the bearer-token identity (README: plain curl); it holds the lease in every test.
beforeEach(holdLease);

after(async () => {
  // Leave the server as we found it for the other test files: no e-stop, lease given back.
  await post('/lease', {});
  await post('/estop/reset', {});
  await call('DELETE', '/lease');
});

test('GET /health answers without a token', async () => {
  const res = await call('GET', '/health', {token: null, client: null});
  assert.equal(res.status, 200, res.text);
  assert.equal(res.json.status, 'ok');
  assert.equal(typeof res.json.version, 'string');
  assert.equal(typeof res.json.uptime_s, 'number');
});

// The kernel's word on the control thread ("control", server/src/periodic_thread.cpp): its scheduling
// policy and real-time priority, fields 41 and 40 of /proc/<pid>/task/<tid>/stat. TENDRIL_SERVER_PID
// names tendrild where TENDRIL_PID is not it (scripts/test-container.sh: the podman client).
function controlThreadScheduling() {
  const pid = process.env.TENDRIL_SERVER_PID || process.env.TENDRIL_PID;
  assert.ok(pid, 'TENDRIL_PID (tests/api/server.sh) names the server under test');
  for (const tid of fs.readdirSync(`/proc/${pid}/task`)) {
    if (fs.readFileSync(`/proc/${pid}/task/${tid}/comm`, 'utf8').trim() !== 'control') continue;
    const stat = fs.readFileSync(`/proc/${pid}/task/${tid}/stat`, 'utf8');
    const fields = stat.slice(stat.lastIndexOf(')') + 2).split(' ');  // fields[0] is field 3
    return {policy: Number(fields[41 - 3]), priority: Number(fields[40 - 3])};
  }
  assert.fail(`no thread named "control" in process ${pid}`);
}

test('GET /health says whether the control loop got real-time priority, as the kernel has it', async () => {
  const res = await call('GET', '/health', {token: null, client: null});
  assert.equal(res.status, 200, res.text);
  assert.equal(res.json.mode, 'live');
  const rt = res.json.control_realtime;
  assert.equal(rt.requested, true, 'tests/api/server.sh asks for real-time priority');
  const kernel = controlThreadScheduling();
  const SCHED_FIFO = 1;
  assert.equal(rt.granted, kernel.policy === SCHED_FIFO, `health ${JSON.stringify(rt)}, kernel ${JSON.stringify(kernel)}`);
  if (rt.granted) {
    assert.equal(rt.priority, kernel.priority);
    assert.equal(rt.reason, '');
  } else {
    assert.equal(rt.priority, 0);
    assert.ok(rt.reason.length > 0, 'a refusal says why');
  }
});

test('calls without a token or with a wrong token get 401 with the error shape', async () => {
  assertErrorShape(await call('GET', '/robots', {token: null}), 401);
  assertErrorShape(await call('GET', `${R}/measured_js`, {token: 'not-the-token'}), 401);
  assertErrorShape(await call('POST', '/estop/reset', {token: null, body: {}}), 401);
  // A command without a token must not change anything: the robot stays where it is.
  const res = await call('POST', `${R}/state_command`, {token: null, body: {command: 'enable'}});
  assertErrorShape(res, 401);
});

test('GET /robots describes the SRMC joints with units and limits from its config', async () => {
  const res = await get('/robots');
  assert.equal(res.status, 200, res.text);
  assert.ok(Array.isArray(res.json), 'robots is an array');
  const srmc = res.json.find((r) => r.name === ROBOT);
  assert.ok(srmc, `robot ${ROBOT} listed: ${res.text}`);
  assert.equal(typeof srmc.kind, 'string');
  assert.ok(Array.isArray(srmc.modes) && srmc.modes.includes('joint'), `modes include joint: ${JSON.stringify(srmc.modes)}`);
  assert.equal(srmc.joints.length, robotConfig.joints.length);
  srmc.joints.forEach((j, i) => {
    const c = robotConfig.joints[i];
    assert.equal(j.name, c.name);
    assert.equal(j.unit, c.unit);
    assert.equal(j.lower, c.lower);
    assert.equal(j.upper, c.upper);
    assert.equal(j.max_velocity, c.max_velocity);
  });
  joints = srmc.joints;
});

test('unknown robot and unknown path answer 404', async () => {
  assertErrorShape(await get('/robots/no_such_robot/measured_js'), 404);
  assertErrorShape(await get('/no_such_endpoint'), 404);
});

test('state endpoints have the documented shapes', async () => {
  for (const p of ['measured_js', 'setpoint_js']) {
    const res = await get(`${R}/${p}`);
    assert.equal(res.status, 200, res.text);
    assert.deepEqual(res.json.name, robotConfig.joints.map((j) => j.name));
    for (const key of ['position', 'velocity', 'effort']) {
      assert.equal(res.json[key].length, 4, `${p}.${key} has 4 values`);
      res.json[key].forEach((v) => assert.ok(Number.isFinite(v), `${p}.${key} finite`));
    }
    assert.equal(typeof res.json.timestamp, 'number');
  }
  const os = await operatingState();
  assert.ok(['DISABLED', 'ENABLED', 'PAUSED', 'FAULT'].includes(os.state), JSON.stringify(os));
  for (const key of ['is_homed', 'is_busy', 'estop']) assert.equal(typeof os[key], 'boolean', key);
  const shape = await get(`${R}/shape`);
  assert.equal(shape.status, 200, shape.text);
  assert.ok(shape.json.points.length >= 2, 'backbone has points');
  shape.json.points.forEach((p) => assert.equal(p.length, 3));
  const cp = await get(`${R}/measured_cp`);
  assert.equal(cp.status, 200, cp.text);
  assert.equal(cp.json.position.length, 3);
  assert.equal(cp.json.orientation.length, 4);
  const q = cp.json.orientation;
  assert.ok(Math.abs(Math.hypot(...q) - 1) < 1e-3, `orientation is a unit quaternion: ${q}`);
});

test('the operator lease: first client gets it, a second client gets 409 lease_held', async () => {
  const mine = await post('/lease', {});
  assert.equal(mine.status, 200, mine.text);
  assert.equal(mine.json.mine, true);
  assert.match(mine.json.lease_token, /^[0-9a-f]{32}$/, 'the grant carries the lease token');
  const other = script('someone-else');
  assertErrorShape(await other.takeLease(), 409, 'lease_held');
  const otherCommand = await other.post(`${R}/state_command`, {command: 'enable'});
  assertErrorShape(otherCommand, 409, 'lease_held');
  // Copying the holder's label gives nothing: X-Tendril-Client is a name, not an identity.
  const copycat = await post(`${R}/state_command`, {command: 'enable'}, {client: 'api-test', lease: 'new'});
  assertErrorShape(copycat, 409, 'lease_held');
  assert.notEqual((await operatingState()).state, 'ENABLED', 'a refused command changed nothing');
});

test('duplicate JSON keys are refused with 400 duplicate_key, and nothing changes', async () => {
  const before = (await operatingState()).mode;
  const res = await call('POST', `${R}/mode`, {raw: '{"mode":[],"mode":"telemanipulation"}'});
  assertErrorShape(res, 400, 'duplicate_key');
  assert.match(res.json.error.message, /"mode"/);
  assert.equal((await operatingState()).mode, before);
});

test('a viewer may watch but not command or take the lease (403 forbidden_role)', async () => {
  const viewer = {client: 'api-viewer', headers: {'X-Tendril-Role': 'viewer'}};
  assert.equal((await get(`${R}/measured_js`, viewer)).status, 200);
  assertErrorShape(await post('/lease', {}, viewer), 403);
  assertErrorShape(await post(`${R}/state_command`, {command: 'enable'}, viewer), 403);
  assert.notEqual((await operatingState()).state, 'ENABLED', 'the refused viewer command changed nothing');
});

test('enable brings the robot to ENABLED', async () => {
  const os0 = await operatingState();
  // The simulated drives must not fault by themselves.
  assert.notEqual(os0.state, 'FAULT', `robot in FAULT before enabling: ${JSON.stringify((await get('/faults')).json)}`);
  const res = await post(`${R}/state_command`, {command: 'enable'});
  assert.equal(res.status, 200, res.text);
  const last = await pollUntil(async () => {
    const os = await operatingState();
    return {done: os.state === 'ENABLED', os};
  }, {polls: 100});
  assert.equal(last.os.state, 'ENABLED', `state after enable: ${JSON.stringify(last.os)}`);
  assert.equal(last.os.estop, false);
});

test('move_jp answers 202 and the robot reaches the goal', async () => {
  const goal = joints.map((j) => {
    // A goal a quarter into the range from the lower limit: inside the limits and away from zero.
    const v = j.lower + (j.upper - j.lower) * 0.25;
    return Math.round(v * 1000) / 1000;
  });
  const res = await post(`${R}/move_jp`, {goal});
  assert.equal(res.status, 202, res.text);
  assert.equal(typeof res.json.duration_s, 'number');
  assert.ok(res.json.duration_s > 0, 'a move to a new goal takes time');
  const polls = Math.ceil((res.json.duration_s + 5) / 0.05);
  const last = await pollUntil(async () => {
    const m = await measured();
    const within = m.position.every((v, i) => Math.abs(v - goal[i]) <= tolerance(joints[i].unit));
    return {done: within, m};
  }, {polls, intervalMs: 50});
  if (!last.done) {
    // Say why: a fault (and its cause) or a setpoint that stopped short.
    const state = await operatingState();
    const faults = (await get('/faults?max=3')).json;
    const setpoint = (await get(`${R}/setpoint_js`)).json.position;
    assert.fail(`measured ${JSON.stringify(last.m.position)} did not reach goal ${JSON.stringify(goal)}; ` +
      `setpoint ${JSON.stringify(setpoint)}, state ${JSON.stringify(state)}, recent faults ${JSON.stringify(faults)}`);
  }
  const sp = await get(`${R}/setpoint_js`);
  sp.json.position.forEach((v, i) => assert.ok(Math.abs(v - goal[i]) <= tolerance(joints[i].unit), 'setpoint at goal'));
});

test('move_jp outside the limits is refused with 422 and nothing moves', async () => {
  // Let the previous move finish (is_busy false), so any later setpoint change would be ours.
  const idle = await pollUntil(async () => {
    const os = await operatingState();
    return {done: !os.is_busy, os};
  }, {polls: 100});
  assert.equal(idle.os.is_busy, false, `the previous move finished: ${JSON.stringify(idle.os)}`);
  const before = (await get(`${R}/setpoint_js`)).json.position;
  const goal = joints.map((j) => j.lower + (j.upper - j.lower) / 2);
  goal[0] = joints[0].upper + 10;
  assertErrorShape(await post(`${R}/move_jp`, {goal}), 422);
  const below = joints.map((j) => j.lower + (j.upper - j.lower) / 2);
  below[2] = joints[2].lower - 1;
  assertErrorShape(await post(`${R}/move_jp`, {goal: below}), 422);
  await sleep(200);
  const after = (await get(`${R}/setpoint_js`)).json.position;
  after.forEach((v, i) => assert.ok(Math.abs(v - before[i]) < 1e-6,
                                    `setpoint ${i} changed after refused moves: ${before[i]} -> ${v}`));
});

test('malformed input: broken JSON 400, NaN 400, wrong size 422, wrong type 4xx', async () => {
  assertErrorShape(await call('POST', `${R}/move_jp`, {raw: '{"goal": [1, 2'}), 400);
  assertErrorShape(await call('POST', `${R}/move_jp`, {raw: '{"goal": [NaN, 0, 0, 0]}'}), 400);
  assertErrorShape(await post(`${R}/move_jp`, {goal: [1, 2, 3]}), 422);
  assertErrorShape(await post(`${R}/move_jp`, {goal: [1, 0, 0, 0, 0]}), 422);
  const wrongType = await post(`${R}/move_jp`, {goal: 'far'});
  assert.ok(wrongType.status === 400 || wrongType.status === 422, `goal as a string: ${wrongType.status}`);
  assertErrorShape(wrongType, wrongType.status);
  const badCommand = await post(`${R}/state_command`, {command: 'explode'});
  assert.ok(badCommand.status === 400 || badCommand.status === 422, `unknown command: ${badCommand.status}`);
  assertErrorShape(badCommand, badCommand.status);
  assert.equal((await operatingState()).state, 'ENABLED', 'bad input left the robot enabled and holding');
});

test('e-stop latches FAULT with estop=true and stops all motion', async () => {
  // Start a long move, then stop in the middle of it.
  const start = (await measured()).position;
  const goal = joints.map((j, i) => (i === 0 ? j.upper - 5 : start[i]));
  const move = await post(`${R}/move_jp`, {goal});
  assert.equal(move.status, 202, move.text);
  await sleep(300);
  const res = await post('/estop', {});
  assert.equal(res.status, 200, res.text);
  const os = await operatingState();
  assert.equal(os.estop, true, JSON.stringify(os));
  assert.equal(os.state, 'FAULT', JSON.stringify(os));
  // Give the drives a moment to come to rest, then the position must stay put.
  await sleep(300);
  const a = (await measured()).position;
  await sleep(500);
  const b = (await measured()).position;
  a.forEach((v, i) => assert.ok(Math.abs(b[i] - v) <= tolerance(joints[i].unit), `joint ${i} moved during e-stop: ${v} -> ${b[i]}`));
  assert.ok(b[0] < goal[0] - 1, 'the move was cut short by the e-stop');
  // Commands are refused while the e-stop is latched.
  const again = await post(`${R}/move_jp`, {goal});
  assert.ok(again.status >= 400 && again.status < 500, `move during e-stop answered ${again.status}`);
  assertErrorShape(again, again.status);
  const enable = await post(`${R}/state_command`, {command: 'enable'});
  assert.ok(enable.status >= 400 && enable.status < 500, `enable during e-stop answered ${enable.status}`);
  await sleep(300);
  const c = (await measured()).position;
  c.forEach((v, i) => assert.ok(Math.abs(v - b[i]) <= tolerance(joints[i].unit), `joint ${i} moved after refused commands`));
});

test('e-stop reset brings the robot back DISABLED', async () => {
  const res = await post('/estop/reset', {});
  assert.equal(res.status, 200, res.text);
  const last = await pollUntil(async () => {
    const os = await operatingState();
    return {done: os.state === 'DISABLED' && os.estop === false, os};
  }, {polls: 40});
  assert.equal(last.os.state, 'DISABLED', JSON.stringify(last.os));
  assert.equal(last.os.estop, false);
});

test('GET /faults lists the e-stop, newest first', async () => {
  const res = await get('/faults');
  assert.equal(res.status, 200, res.text);
  const list = Array.isArray(res.json) ? res.json : res.json.events || res.json.faults;
  assert.ok(Array.isArray(list) && list.length > 0, `faults list: ${res.text.slice(0, 300)}`);
  assert.ok(list.some((e) => /estop|e-stop|emergency/i.test(`${e.kind} ${e.message}`)), 'an e-stop event is listed');
  // Issue 12: the event says who pressed it (the X-Tendril-Client of this script, an operator).
  const estop = list.find((e) => e.kind === 'estop');
  assert.match(estop.message, /e-stop (latched|pressed) by client:api-test \(operator\)/, JSON.stringify(estop));
});

test('GET /metrics is Prometheus text', async () => {
  const res = await call('GET', `${BASE_URL}/metrics`);
  assert.equal(res.status, 200, res.text);
  assert.match(res.headers.get('content-type') || '', /text\/plain/);
  assert.match(res.text, /^# (HELP|TYPE) /m);
});

test('the lease can be given back', async () => {
  const res = await call('DELETE', '/lease');
  assert.ok(res.status === 200 || res.status === 204, `DELETE /lease: ${res.status} ${res.text}`);
  const other = script('someone-else');
  const taken = await other.takeLease();
  assert.equal(taken.status, 200, `after release another client gets the lease: ${taken.text}`);
  await other.call('DELETE', '/lease');
});
