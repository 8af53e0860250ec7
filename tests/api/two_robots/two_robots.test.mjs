// Two robots in one tendrild (the set-up of Heunis et al. 2021): the SIMULATED catheter (config/robots/srmc.json) and
// the SIMULATED UR5 arm (config/robots/ur5_arm.json, robot type serial_arm), over REST and WebSocket.
// Each has its own safety state and mode; one e-stop stops both; the arm's Cartesian stream goes over a
// Foxglove client channel /ur5/servo_cv. Run by tests/api/two_robots/run.sh (a server of its own).
import {test, after} from 'node:test';
import assert from 'node:assert/strict';
import wsProtocol from '@foxglove/ws-protocol';
import WebSocket from 'ws';
import {BASE_URL, TOKEN, get, post, call, holdLease, script, assertErrorShape, pollUntil, sleep} from '../helpers.mjs';

const {FoxgloveClient} = wsProtocol;
const WS_URL = BASE_URL.replace(/^http/, 'ws') + '/ws';
const ARM = '/robots/ur5';
const CATHETER = '/robots/srmc';
const open = [];

const state = async (r) => (await get(`${r}/operating_state`)).json;
const pose = async () => (await get(`${ARM}/measured_cp`)).json;

async function enable(r) {
  const res = await post(`${r}/state_command`, {command: 'enable'});
  assert.equal(res.status, 200, res.text);
  const ready = await pollUntil(async () => {
    const s = await state(r);
    return s.state === 'ENABLED' && s.drives_ready && !s.is_busy ? {done: true} : null;
  }, {polls: 200, intervalMs: 25});
  assert.ok(ready && ready.done, `${r} did not become ENABLED with ready drives: ${JSON.stringify(await state(r))}`);
}

async function disable(r) {
  await post(`${r}/state_command`, {command: 'disable'});
  const off = await pollUntil(async () => (await state(r)).state === 'DISABLED', {polls: 200, intervalMs: 25});
  assert.ok(off, `${r} did not disable`);
}

after(async () => {
  for (const c of open) c.close();
  await post('/estop/reset', {});
  await call('DELETE', '/lease');
});

test('GET /robots lists the catheter and the arm, each with its own joints, units and modes', async () => {
  const robots = (await get('/robots')).json;
  const byName = Object.fromEntries(robots.map((r) => [r.name, r]));
  assert.deepEqual(Object.keys(byName).sort(), ['srmc', 'ur5']);
  assert.equal(byName.srmc.kind, 'steerable_catheter');
  assert.equal(byName.ur5.kind, 'serial_arm');
  assert.equal(byName.srmc.joints.length, 4);
  assert.equal(byName.ur5.joints.length, 6);
  assert.ok(byName.ur5.joints.every((j) => j.unit === 'rad'));
  assert.deepEqual(byName.ur5.modes, ['joint', 'cartesian']);
  assert.ok(byName.srmc.modes.includes('path_following'));
  assert.equal(byName.ur5.cartesian, true);
  assert.equal(byName.ur5.arm.simulated, true);
});

test('each robot has its own state and mode; the lease holder commands both, another client neither', async () => {
  await holdLease();
  await enable(ARM);
  assert.equal((await state(CATHETER)).state, 'DISABLED', 'enabling the arm leaves the catheter alone');
  const switched = await post(`${ARM}/mode`, {mode: 'cartesian'});
  assert.equal(switched.status, 200, switched.text);
  assert.ok(await pollUntil(async () => (await state(ARM)).mode === 'cartesian'));
  assert.equal((await state(CATHETER)).mode, 'joint');
  assertErrorShape(await post(`${CATHETER}/mode`, {mode: 'cartesian'}), 422, 'unknown_mode');
  assertErrorShape(await post(`${CATHETER}/move_cp`, {goal: {position: [0, 0, 0], orientation: [0, 0, 0, 1]}}), 422);
  // POST /lease took every robot's lease: another client is refused on either robot.
  const other = script('two-robots-other');
  assertErrorShape(await other.post(`${ARM}/state_command`, {command: 'disable'}), 409, 'lease_held');
  assertErrorShape(await other.post(`${CATHETER}/state_command`, {command: 'enable'}), 409, 'lease_held');
  await enable(CATHETER);
  // Both move at once: a catheter insertion and an arm move_cp 20 mm up.
  const p0 = await pose();
  const goal = {position: [p0.position[0], p0.position[1], p0.position[2] + 20], orientation: p0.orientation};
  const moveArm = await post(`${ARM}/move_cp`, {goal});
  assert.equal(moveArm.status, 202, moveArm.text);
  const moveCatheter = await post(`${CATHETER}/move_jp`, {goal: [15, 0, 0, 0]});
  assert.equal(moveCatheter.status, 202, moveCatheter.text);
  const arrived = await pollUntil(async () => {
    const [a, c] = [await state(ARM), await state(CATHETER)];
    return {done: !a.is_busy && !c.is_busy, a, c};
  }, {polls: 300, intervalMs: 50});
  assert.ok(arrived.done, `moves did not end: ${JSON.stringify(arrived)}`);
  const p1 = await pose();
  assert.ok(Math.abs(p1.position[2] - goal.position[2]) < 1.0, `arm z ${p1.position[2]}, goal ${goal.position[2]}`);
  const q = (await get(`${CATHETER}/measured_js`)).json.position;
  assert.ok(Math.abs(q[0] - 15) < 0.05, `catheter insertion ${q[0]}`);
  // The arm's force sensor reads free space (the shipped tissue is 100 mm below the start pose).
  const cf = (await get(`${ARM}/measured_cf`)).json;
  assert.equal(cf.frame, 'tool');
  assert.ok(Math.hypot(...cf.force) < 0.2, `force in free space ${cf.force}`);
  assertErrorShape(await get(`${CATHETER}/measured_cf`), 422, 'not_supported');
});

test('servo_cv over a Foxglove client channel /ur5/servo_cv moves the arm; the catheter stays put', async () => {
  const {lease_token: leaseToken} = await holdLease();
  const ws = new WebSocket(`${WS_URL}?token=${encodeURIComponent(TOKEN)}&lease=${leaseToken}`,
      [FoxgloveClient.SUPPORTED_SUBPROTOCOL], {headers: {'X-Tendril-Client': 'api-test'}});
  const client = new FoxgloveClient({ws});
  open.push(client);
  const statuses = [];
  const channels = new Map();
  client.on('status', (s) => statuses.push(s));
  client.on('advertise', (list) => list.forEach((c) => channels.set(c.topic, c)));
  await new Promise((resolve, reject) => {
    client.on('serverInfo', resolve);
    client.on('error', reject);
  });
  // Both robots' topics are advertised.
  const advertised = await pollUntil(() => ['/ur5/operating_state', '/srmc/operating_state', '/ur5/joint_states',
    '/srmc/joint_states', '/ur5/arm'].every((t) => channels.has(t)), {polls: 100, intervalMs: 50});
  assert.ok(advertised, `topics: ${[...channels.keys()].join(', ')}`);
  const catheterBefore = (await get(`${CATHETER}/setpoint_js`)).json.position;
  const p0 = await pose();
  const channel = client.advertise({topic: '/ur5/servo_cv', encoding: 'json', schemaName: 'tendril.Twist'});
  for (let i = 0; i < 40; ++i) {  // about 1 s at 20 mm/s along y
    client.sendMessage(channel, new TextEncoder().encode(JSON.stringify({linear: [0, 20, 0], angular: [0, 0, 0]})));
    await sleep(25);
  }
  const p1 = await pose();
  const dy = p1.position[1] - p0.position[1];
  assert.ok(dy > 5, `the arm moved ${dy} mm along y; statuses ${JSON.stringify(statuses)}`);
  assert.ok(Math.abs(p1.position[0] - p0.position[0]) < 1 && Math.abs(p1.position[2] - p0.position[2]) < 1);
  assert.deepEqual((await get(`${CATHETER}/setpoint_js`)).json.position, catheterBefore, 'the catheter did not move');
  // The stream stopped: after the command timeout the arm's motion ends (it stays ENABLED, as after a
  // servo_jv stream); the catheter is untouched.
  const still = await pollUntil(async () => (await state(ARM)).arm.motion === 'none', {polls: 100, intervalMs: 20});
  assert.ok(still, `arm: ${JSON.stringify(await state(ARM))}`);
  assert.equal((await state(ARM)).state, 'ENABLED');
  assert.equal((await state(CATHETER)).state, 'ENABLED');
  client.close();
});

test('one e-stop stops both robots, over REST, and its reset leaves both DISABLED', async () => {
  await holdLease();
  for (const r of [ARM, CATHETER]) if ((await state(r)).state !== 'ENABLED') await enable(r);
  if ((await state(ARM)).mode !== 'joint') {
    assert.equal((await post(`${ARM}/mode`, {mode: 'joint'})).status, 200);
    assert.ok(await pollUntil(async () => (await state(ARM)).mode === 'joint'));
  }
  const qa = (await get(`${ARM}/measured_js`)).json.position;
  assert.equal((await post(`${ARM}/move_jp`, {goal: [qa[0] + 1.0, ...qa.slice(1)]})).status, 202);
  assert.equal((await post(`${CATHETER}/move_jp`, {goal: [60, 0, 0, 0]})).status, 202);
  const moving = await pollUntil(async () => {
    const a = (await get(`${ARM}/measured_js`)).json.velocity[0];
    const c = (await get(`${CATHETER}/measured_js`)).json.velocity[0];
    return {done: Math.abs(a) > 0.2 && Math.abs(c) > 1, a, c};
  }, {polls: 100, intervalMs: 20});
  assert.ok(moving.done, `both moving: ${JSON.stringify(moving)}`);
  const estop = await post('/estop', {});
  assert.equal(estop.status, 200, estop.text);
  for (const r of [ARM, CATHETER]) {
    const s = await state(r);
    assert.equal(s.estop, true, `${r} e-stop`);
  }
  const stopped = await pollUntil(async () => {
    const a = (await get(`${ARM}/measured_js`)).json.velocity;
    const c = (await get(`${CATHETER}/measured_js`)).json.velocity;
    return {done: [...a, ...c].every((v) => Math.abs(v) < 0.01), a, c};
  }, {polls: 100, intervalMs: 20});
  assert.ok(stopped.done, `both stopped: ${JSON.stringify(stopped)}`);
  for (const r of [ARM, CATHETER]) {
    assert.notEqual((await state(r)).state, 'ENABLED', r);
    assertErrorShape(await post(`${r}/move_jp`, {goal: (await get(`${r}/measured_js`)).json.position}), 409);
  }
  assert.equal((await post('/estop/reset', {})).status, 200);
  const off = await pollUntil(async () => (await state(ARM)).state === 'DISABLED' && (await state(CATHETER)).state === 'DISABLED');
  assert.ok(off, 'both DISABLED after the reset');
});

test('an e-stop over the WebSocket (the estop service) stops both robots too', async () => {
  await holdLease();
  for (const r of [ARM, CATHETER]) await enable(r);
  const ws = new WebSocket(`${WS_URL}?token=${encodeURIComponent(TOKEN)}`, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
  const client = new FoxgloveClient({ws});
  open.push(client);
  const services = new Promise((resolve) => client.on('advertiseServices', resolve));
  await new Promise((resolve, reject) => {
    client.on('serverInfo', resolve);
    client.on('error', reject);
  });
  const estop = (await services).find((s) => s.name === 'estop');
  assert.ok(estop, 'an estop service is advertised');
  const response = new Promise((resolve) => client.on('serviceCallResponse', resolve));
  client.sendServiceCallRequest({serviceId: estop.id, callId: 7, encoding: 'json',
    data: new TextEncoder().encode(JSON.stringify({}))});
  await response;
  const both = await pollUntil(async () => (await state(ARM)).estop && (await state(CATHETER)).estop);
  assert.ok(both, 'both robots report the e-stop');
  for (const r of [ARM, CATHETER]) assert.notEqual((await state(r)).state, 'ENABLED', r);
  client.close();
  assert.equal((await post('/estop/reset', {})).status, 200);
  for (const r of [ARM, CATHETER]) await disable(r);
});

test('each robot has its own lease: one script drives the catheter while another drives the arm', async () => {
  await call('DELETE', '/lease');
  const surgeon = script('surgeon-console');
  const engineer = script('lab-engineer');
  const take = async (who, r) => {
    const res = await who.post(`${r}/lease`, {});
    assert.equal(res.status, 200, `${r}/lease: ${res.text}`);
    who.leaseToken = res.json.lease_token;
    return res.json;
  };
  try {
    const catheterLease = await take(surgeon, CATHETER);
    assert.equal(catheterLease.mine, true);
    assert.deepEqual(Object.keys(catheterLease.robots), ['srmc']);
    await take(engineer, ARM);
    // Each commands its own robot, and neither the other's.
    assert.equal((await surgeon.post(`${CATHETER}/state_command`, {command: 'enable'})).status, 200);
    assert.equal((await engineer.post(`${ARM}/state_command`, {command: 'enable'})).status, 200);
    const refused = await engineer.post(`${CATHETER}/state_command`, {command: 'disable'});
    assertErrorShape(refused, 409, 'lease_held');
    assert.match(refused.json.error.message, /the operator lease of srmc is held by client:surgeon-console/);
    assert.match(refused.json.error.message, /POST \/api\/v1\/robots\/srmc\/lease/);
    assert.equal(refused.json.error.robot, 'srmc');
    assertErrorShape(await surgeon.post(`${ARM}/move_jp`, {goal: (await get(`${ARM}/setpoint_js`)).json.position}),
        409, 'lease_held');
    // GET /lease shows every robot's lease as the caller sees it.
    const all = (await surgeon.get('/lease')).json;
    assert.equal(all.robots.srmc.mine, true);
    assert.equal(all.robots.ur5.mine, false);
    assert.equal(all.robots.ur5.holder, 'client:lab-engineer');
    assert.equal(all.mine, false, 'mine means every robot');
    // Taking every lease is refused while another holds one; the takeover offer names that robot only.
    const grab = await surgeon.post('/lease', {});
    assertErrorShape(grab, 409, 'lease_held');
    assert.deepEqual(grab.json.error.robots, ['ur5']);
    assert.ok(grab.json.error.takeover_token);
    assertErrorShape(await surgeon.post(`${ARM}/lease`, {}), 409, 'lease_held');
    // An e-stop stops both; its reset needs every held lease: not while the engineer holds the arm.
    assert.equal((await post('/estop', {})).status, 200);
    const reset = await surgeon.post('/estop/reset', {});
    assertErrorShape(reset, 409, 'lease_held');
    assert.match(reset.json.error.message, /ur5 is held by client:lab-engineer/);
    assert.equal((await state(CATHETER)).estop, true, 'a refused reset leaves the e-stop latched');
    assert.equal((await engineer.call('DELETE', `${ARM}/lease`)).status, 200);
    assert.equal((await surgeon.post('/estop/reset', {})).status, 200);
    // One holder, one token: the arm's lease comes with the token the surgeon already has.
    const before = surgeon.leaseToken;
    const armLease = await take(surgeon, ARM);
    assert.equal(armLease.lease_token, before);
    assert.equal((await surgeon.get('/lease')).json.mine, true);
    assert.equal((await surgeon.post(`${ARM}/state_command`, {command: 'disable'})).status, 200);
  } finally {
    await surgeon.call('DELETE', '/lease');
    await engineer.call('DELETE', '/lease');
  }
});
