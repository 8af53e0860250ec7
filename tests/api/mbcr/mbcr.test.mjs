// The variable-diameter continuum robot (config/robots/mbcr_vd.json, robot type mbcr_vd) in a tendrild
// next to the catheter, over REST and WebSocket: /robots, the trajectory and diameter commands with bad
// bodies, and the /mbcr/actuation topic while the dissertation's circle runs. Run by tests/api/mbcr/run.sh (a
// server of its own).
import {test, after} from 'node:test';
import assert from 'node:assert/strict';
import wsProtocol from '@foxglove/ws-protocol';
import WebSocket from 'ws';
import {BASE_URL, TOKEN, get, post, call, holdLease, assertErrorShape, pollUntil} from '../helpers.mjs';

const {FoxgloveClient} = wsProtocol;
const WS_URL = BASE_URL.replace(/^http/, 'ws') + '/ws';
const MBCR = '/robots/mbcr';
const open = [];

const state = async () => (await get(`${MBCR}/operating_state`)).json;

async function enableTaskMode() {
  await holdLease();
  const res = await post(`${MBCR}/state_command`, {command: 'enable'});
  assert.equal(res.status, 200, res.text);
  const ready = await pollUntil(async () => {
    const s = await state();
    return s.state === 'ENABLED' && s.drives_ready && !s.is_busy ? {done: true} : null;
  }, {polls: 200, intervalMs: 25});
  assert.ok(ready && ready.done, `not ENABLED with ready drives: ${JSON.stringify(await state())}`);
  const switched = await post(`${MBCR}/mode`, {mode: 'task'});
  assert.equal(switched.status, 200, switched.text);
  assert.ok(await pollUntil(async () => (await state()).mode === 'task'));
}

after(async () => {
  for (const c of open) c.close();
  await post(`${MBCR}/trajectory`, {action: 'stop'});
  await post(`${MBCR}/state_command`, {command: 'disable'});
  await call('DELETE', '/lease');
});

test('GET /robots lists the mbcr with seven joints in mm, a task mode and its model', async () => {
  const robots = (await get('/robots')).json;
  const mbcr = robots.find((r) => r.name === 'mbcr');
  assert.ok(mbcr, `robots: ${robots.map((r) => r.name)}`);
  assert.equal(mbcr.kind, 'mbcr_vd');
  assert.equal(mbcr.joints.length, 7);
  assert.ok(mbcr.joints.every((j) => j.unit === 'mm'));
  assert.deepEqual(mbcr.modes, ['joint', 'task']);
  assert.equal(mbcr.cartesian, true);
  assert.equal(mbcr.mbcr.simulated, true);
  assert.ok(Math.abs(mbcr.mbcr.linkage.inner_radius_mm[0] - 2.613) < 1e-3, 'a_min of the Table 2.3 geometry');
  assert.ok(Math.abs(mbcr.mbcr.linkage.inner_radius_mm[1] - 47.224) < 1e-3, 'a_max of the Table 2.3 geometry');
  assert.equal(mbcr.mbcr.trajectories.seed_circle.radius_mm, 70);
  const commands = JSON.stringify(mbcr.commands);
  assert.ok(commands.includes('trajectory') && commands.includes('diameter'), `commands: ${commands}`);
});

test('the trajectory command refuses bad bodies, and needs the task mode', async () => {
  await holdLease();
  assertErrorShape(await post(`${MBCR}/trajectory`, {}), 400);
  assertErrorShape(await post(`${MBCR}/trajectory`, {action: 'jump'}), 400);
  assertErrorShape(await post(`${MBCR}/trajectory`, {action: 'start', name: 'square'}), 400);
  assertErrorShape(await post(`${MBCR}/trajectory`, {action: 'start', diameter: 'huge'}), 400);
  assertErrorShape(await post(`${MBCR}/diameter`, {mode: 3}), 400);
  assertErrorShape(await post(`${MBCR}/trajectory`, {action: 'start'}), 409, 'wrong_mode');
  assertErrorShape(await post(`${MBCR}/move_cp`, {goal: {position: [0, 0, 500], orientation: [0, 0, 0, 1]}}), 409);
  assert.equal((await state()).mbcr.motion, 'none');
});

test('the reference circle runs from the API and /mbcr/actuation streams the diameter and forces', async () => {
  await enableTaskMode();
  const {lease_token: leaseToken} = await holdLease();
  const ws = new WebSocket(`${WS_URL}?token=${encodeURIComponent(TOKEN)}&lease=${leaseToken}`,
      [FoxgloveClient.SUPPORTED_SUBPROTOCOL], {headers: {'X-Tendril-Client': 'api-test'}});
  const client = new FoxgloveClient({ws});
  open.push(client);
  const channels = new Map();
  client.on('advertise', (list) => list.forEach((c) => channels.set(c.topic, c)));
  await new Promise((resolve, reject) => {
    client.on('serverInfo', resolve);
    client.on('error', reject);
  });
  assert.ok(await pollUntil(() => channels.has('/mbcr/actuation'), {polls: 100, intervalMs: 50}),
      `topics: ${[...channels.keys()].join(', ')}`);
  const channel = channels.get('/mbcr/actuation');
  assert.equal(channel.schemaName, 'tendril.VariableDiameterState');
  const messages = [];
  client.on('message', ({data}) => messages.push(JSON.parse(new TextDecoder().decode(data))));
  client.subscribe(channel.id);

  const started = await post(`${MBCR}/trajectory`, {action: 'start', name: 'seed_circle', diameter: 'variable'});
  assert.equal(started.status, 202, started.text);
  assert.ok(started.json.duration_s > 20);
  // Into the circle (after the approach to its start), then about 3 s of it: the diameter grows.
  const inCircle = await pollUntil(async () => (await state()).mbcr.motion === 'circle', {polls: 600, intervalMs: 50});
  assert.ok(inCircle, `not in the circle: ${JSON.stringify((await state()).mbcr)}`);
  const grown = await pollUntil(async () => {
    const a = (await state()).mbcr.actuation;
    return a.inner_radius_mm > 10 ? a : null;
  }, {polls: 200, intervalMs: 50});
  assert.ok(grown, `the diameter did not grow: ${JSON.stringify((await state()).mbcr)}`);
  const stopped = await post(`${MBCR}/trajectory`, {action: 'stop'});
  assert.equal(stopped.status, 202, stopped.text);
  assert.ok(await pollUntil(async () => (await state()).mbcr.motion === 'none'));

  const live = messages.filter((m) => m.mbcr && m.mbcr.actuation);
  assert.ok(live.length > 10, `${messages.length} messages on /mbcr/actuation`);
  const last = live[live.length - 1].mbcr.actuation;
  assert.equal(last.backbone_forces_n.length, 12);
  assert.ok(last.backbone_forces_n.every(Number.isFinite));
  assert.ok(last.rms_force_n > 0, JSON.stringify(last));
  assert.ok(Array.isArray(last.limits_active));
  assert.equal(last.null_space_gain, 0.05);
  const diameters = live.map((m) => m.mbcr.actuation.diameter_mm);
  assert.ok(Math.max(...diameters) - Math.min(...diameters) > 5, `diameters ${Math.min(...diameters)}..${Math.max(...diameters)}`);
  // The state topic leaves the live values out.
  const s = await state();
  assert.equal(s.state, 'ENABLED');
  assert.ok(s.mbcr.actuation, 'GET operating_state has them');
  client.close();
});
