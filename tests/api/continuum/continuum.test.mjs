// The sensing-disk continuum robot (config/robots/sdu_continuum.json, robot "sdu", kind sdu_continuum)
// in a tendrild of its own beside the catheter: its /robots entry, its WebSocket topics (/sdu/continuum,
// /sdu/map, /sdu/planes: advertised and decodable), its commands (hri_mode, map, simulation_scene, roll,
// unbias) and their refusals of bad bodies. Run by tests/api/continuum/run.sh.
import {test, after} from 'node:test';
import assert from 'node:assert/strict';
import wsProtocol from '@foxglove/ws-protocol';
import WebSocket from 'ws';
import {BASE_URL, TOKEN, get, post, call, holdLease, assertErrorShape, pollUntil, sleep} from '../helpers.mjs';

const {FoxgloveClient} = wsProtocol;
const WS_URL = BASE_URL.replace(/^http/, 'ws') + '/ws';
const SDU = '/robots/sdu';
const open = [];

const state = async () => (await get(`${SDU}/operating_state`)).json;

after(async () => {
  for (const c of open) c.close();
  await post(`${SDU}/simulation_scene`, {action: 'reset'});
  await post(`${SDU}/state_command`, {command: 'disable'});
  await call('DELETE', '/lease');
});

test('GET /robots describes the continuum robot: disks, HRI modes, the speed law, the bus', async () => {
  const robots = (await get('/robots')).json;
  const sdu = robots.find((r) => r.name === 'sdu');
  assert.ok(sdu, `robots: ${robots.map((r) => r.name).join(', ')}`);
  assert.equal(sdu.kind, 'sdu_continuum');
  assert.deepEqual(sdu.joints.map((j) => j.name), ['stage_roll', 'bending', 'bending_plane']);
  assert.deepEqual(sdu.modes, ['joint', 'guidance', 'tip']);
  const c = sdu.continuum;
  assert.equal(c.disks.length, 5);
  assert.deepEqual(c.disks.map((d) => d.arc_mm), [74, 148, 222, 296, 370]);
  assert.ok(c.disks.every((d) => d.slots === 8));
  assert.deepEqual(c.hri_modes, ['off', 'contactless', 'contact']);
  assert.deepEqual(c.speed, {max_mm_s: 50, min_mm_s: 0.25, d_max_mm: 130});
  assert.equal(c.simulated, true);
  assert.ok(c.bus.sdu_load > 0.45 && c.bus.sdu_load < 0.5, JSON.stringify(c.bus));
});

test('operating_state carries the continuum object once the disks report', async () => {
  const ready = await pollUntil(async () => {
    const s = await state();
    return s.continuum && s.continuum.supervisor.state === 'normal' ? s : null;
  }, {polls: 200, intervalMs: 25});
  assert.ok(ready, JSON.stringify((await state()).continuum));
  const c = ready.continuum;
  assert.equal(c.hri_mode, 'off');
  assert.equal(c.contact, false);
  assert.equal(c.disks.length, 5);
  for (const d of c.disks) {
    assert.equal(d.position_mm.length, 3);
    assert.equal(d.ranges_mm.length, 8);
    assert.equal(d.force_n.length, 8);
    assert.equal(d.fresh, true);
  }
  assert.ok(c.speed_scale > 0 && c.speed_scale <= 1);
});

test('the topics /sdu/continuum, /sdu/map and /sdu/planes are advertised and decode', async () => {
  await holdLease();
  const ws = new WebSocket(`${WS_URL}?token=${encodeURIComponent(TOKEN)}`, [FoxgloveClient.SUPPORTED_SUBPROTOCOL],
      {headers: {'X-Tendril-Client': 'api-test'}});
  const client = new FoxgloveClient({ws});
  open.push(client);
  const channels = new Map();
  client.on('advertise', (list) => list.forEach((c) => channels.set(c.topic, c)));
  await new Promise((resolve, reject) => {
    client.on('serverInfo', resolve);
    client.on('error', reject);
  });
  const topics = ['/sdu/continuum', '/sdu/map', '/sdu/planes', '/sdu/operating_state'];
  assert.ok(await pollUntil(() => topics.every((t) => channels.has(t)), {polls: 100, intervalMs: 50}),
      `topics: ${[...channels.keys()].join(', ')}`);
  assert.equal(channels.get('/sdu/continuum').schemaName, 'tendril.ContinuumState');
  assert.equal(channels.get('/sdu/map').schemaName, 'foxglove.PointCloud');
  assert.equal(channels.get('/sdu/planes').schemaName, 'foxglove.SceneUpdate');
  const messages = new Map();
  const bySub = new Map();
  client.on('message', ({subscriptionId, data}) => {
    const topic = bySub.get(subscriptionId);
    if (!messages.has(topic)) messages.set(topic, JSON.parse(new TextDecoder().decode(data)));
  });
  for (const t of ['/sdu/continuum', '/sdu/map', '/sdu/planes']) bySub.set(client.subscribe(channels.get(t).id), t);
  // Map the wall: roll the stage back and forth, then extract.
  const enable = await post(`${SDU}/state_command`, {command: 'enable'});
  assert.equal(enable.status, 200, enable.text);
  assert.ok(await pollUntil(async () => {
    const s = await state();
    return s.state === 'ENABLED' && s.drives_ready && !s.is_busy;
  }, {polls: 200, intervalMs: 25}), JSON.stringify(await state()));
  for (const roll of [0.8, -0.8]) {
    const m = await post(`${SDU}/move_jp`, {goal: [roll, 0.2, -1.570796]});
    assert.equal(m.status, 202, m.text);
    assert.ok(await pollUntil(async () => !(await state()).is_busy, {polls: 400, intervalMs: 25}));
  }
  const extract = await post(`${SDU}/map`, {action: 'extract'});
  assert.equal(extract.status, 200, extract.text);
  assert.ok(extract.json.planes.length >= 1);
  assert.equal(typeof extract.json.bracing.reason, 'string');
  assert.ok(await pollUntil(() => ['/sdu/continuum', '/sdu/map', '/sdu/planes'].every((t) => messages.has(t)),
      {polls: 100, intervalMs: 50}), `got: ${[...messages.keys()].join(', ')}`);
  const live = messages.get('/sdu/continuum');
  assert.ok(live.continuum && typeof live.continuum.speed_scale === 'number', JSON.stringify(live).slice(0, 300));
  const cloud = messages.get('/sdu/map');
  assert.equal(cloud.frame_id, 'sdu_base');
  assert.equal(cloud.point_stride, 12);
  assert.ok(Buffer.from(cloud.data, 'base64').length % 12 === 0);
  assert.ok(Array.isArray(messages.get('/sdu/planes').entities));
});

test('/sdu/scene draws the SIMULATED scene: the wall plate, the cabinet and the arm, which moves on approach', async () => {
  await holdLease();
  await post(`${SDU}/simulation_scene`, {action: 'reset'});
  const ws = new WebSocket(`${WS_URL}?token=${encodeURIComponent(TOKEN)}`, [FoxgloveClient.SUPPORTED_SUBPROTOCOL],
      {headers: {'X-Tendril-Client': 'api-test'}});
  const client = new FoxgloveClient({ws});
  open.push(client);
  const channels = new Map();
  client.on('advertise', (list) => list.forEach((c) => channels.set(c.topic, c)));
  assert.ok(await pollUntil(() => channels.has('/sdu/scene'), {polls: 100, intervalMs: 50}));
  let latest = null;
  client.on('message', ({data}) => {
    const msg = JSON.parse(new TextDecoder().decode(data));
    const e = (msg.entities || []).find((x) => x.id === 'sdu/simulated_scene');
    if (e) latest = e;
  });
  client.subscribe(channels.get('/sdu/scene').id);
  const armY = () => latest?.cylinders?.[0]?.pose?.position?.y;
  assert.ok(await pollUntil(() => latest !== null && Math.abs(armY() + 330) < 1e-6, {polls: 200, intervalMs: 25}),
      JSON.stringify(latest)?.slice(0, 400));
  assert.equal(latest.cubes.length, 2, 'one plate for the wall plane, one cube for the cabinet');
  const cabinet = latest.cubes[1];
  assert.deepEqual([cabinet.size.x, cabinet.size.y, cabinet.size.z], [120, 80, 300]);
  assert.deepEqual([cabinet.pose.position.x, cabinet.pose.position.y, cabinet.pose.position.z], [0, 260, 150]);
  assert.equal(latest.cylinders[0].size.x, 50.8, 'the dissertation\'s 50.8 mm rod');
  assert.ok(latest.metadata.some((m) => m.key === 'simulated' && m.value === 'true'));
  const approach = await post(`${SDU}/simulation_scene`, {action: 'approach', speed_mm_s: 100});
  assert.equal(approach.status, 202, approach.text);
  assert.ok(await pollUntil(() => armY() > -320, {polls: 200, intervalMs: 25}), `arm y ${armY()}`);
  await post(`${SDU}/simulation_scene`, {action: 'reset'});
  assert.ok(await pollUntil(() => Math.abs(armY() + 330) < 1e-6, {polls: 200, intervalMs: 25}), `arm y ${armY()}`);
  client.close();
});

test('commands: hri_mode, simulation_scene, map clear; bad bodies get clear errors', async () => {
  await holdLease();
  const mode = await post(`${SDU}/hri_mode`, {mode: 'contactless'});
  assert.equal(mode.status, 202, mode.text);
  assert.ok(await pollUntil(async () => (await state()).continuum.hri_mode === 'contactless'));
  assertErrorShape(await post(`${SDU}/hri_mode`, {mode: 'warp'}), 400);
  assertErrorShape(await post(`${SDU}/hri_mode`, {}), 400);
  assertErrorShape(await post(`${SDU}/map`, {action: 'paint'}), 400);
  assertErrorShape(await post(`${SDU}/simulation_scene`, {action: 'approach', speed_mm_s: 'fast'}), 400);
  assertErrorShape(await post(`${SDU}/simulation_scene`, {action: 'teleport'}), 400);
  assertErrorShape(await post(`${SDU}/roll`, {rate_rad_s: 0.1}), 409, 'no_contact');
  // The arm approaches the top disk: the speed limit falls with the distance.
  const before = (await state()).continuum.speed_limit_mm_s;
  const approach = await post(`${SDU}/simulation_scene`, {action: 'approach', speed_mm_s: 100});
  assert.equal(approach.status, 202, approach.text);
  const near = await pollUntil(async () => {
    const c = (await state()).continuum;
    return c.speed_limit_mm_s < before && c.nearest_mm !== null ? c : null;
  }, {polls: 200, intervalMs: 25});
  assert.ok(near, JSON.stringify((await state()).continuum.supervisor));
  await post(`${SDU}/simulation_scene`, {action: 'reset'});
  const cleared = await post(`${SDU}/map`, {action: 'clear'});
  assert.equal(cleared.status, 200, cleared.text);
  // The live mapper refills the cleared map from the wall at once; a few points are not a plane yet.
  const again = await post(`${SDU}/map`, {action: 'extract'});
  assertErrorShape(again, 409);
  assert.ok(['map_empty', 'no_plane'].includes(again.json.error.code), again.text);
  await sleep(10);
});

test('the scenario over the API: the arm approaches, the limit falls, the touch holds the robot with its cause', async () => {
  await holdLease();
  const s0 = await state();
  if (s0.state !== 'ENABLED') {
    const enable = await post(`${SDU}/state_command`, {command: s0.state === 'PAUSED' ? 'resume' : 'enable'});
    assert.equal(enable.status, 200, enable.text);
  }
  assert.ok(await pollUntil(async () => {
    const s = await state();
    return s.state === 'ENABLED' && s.drives_ready && !s.is_busy;
  }, {polls: 200, intervalMs: 25}), JSON.stringify(await state()));
  // The start pose (its top disk is where the arm's end point presses 6 mm into the sleeve).
  const home = await post(`${SDU}/move_jp`, {goal: [0, 0.2, -1.570796]});
  assert.equal(home.status, 202, home.text);
  assert.ok(await pollUntil(async () => !(await state()).is_busy, {polls: 400, intervalMs: 25}));
  await post(`${SDU}/simulation_scene`, {action: 'reset'});
  const approach = await post(`${SDU}/simulation_scene`, {action: 'approach', speed_mm_s: 40});
  assert.equal(approach.status, 202, approach.text);
  let slowest = 50;
  const held = await pollUntil(async () => {
    const s = await state();
    slowest = Math.min(slowest, s.continuum.speed_limit_mm_s);
    return s.state === 'PAUSED' && s.continuum.contact ? s : null;
  }, {polls: 400, intervalMs: 25});
  assert.ok(held, JSON.stringify((await state()).continuum.supervisor));
  assert.ok(slowest < 50, `the limit fell as the arm came: ${slowest}`);
  assert.equal(held.continuum.supervisor.state, 'stopped_contact');
  assert.equal(held.continuum.contact_disk, 4);
  assert.match(held.hold.message, /contact on SDU 4/);
  assertErrorShape(await post(`${SDU}/state_command`, {command: 'resume'}), 409);
  const events = (await get('/faults')).json;
  assert.ok(JSON.stringify(events).includes('contact on SDU 4'), 'the touch is in the event log');
  await post(`${SDU}/simulation_scene`, {action: 'reset'});
  assert.ok(await pollUntil(async () => !(await state()).continuum.contact, {polls: 200, intervalMs: 25}));
  const resume = await post(`${SDU}/state_command`, {command: 'resume'});
  assert.equal(resume.status, 200, resume.text);
});
