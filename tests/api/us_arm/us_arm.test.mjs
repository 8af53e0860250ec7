// The ultrasound arm (robot us_arm: config/robots/us_arm.json) beside the catheter in one tendrild, in
// simulated time (tendrild --simulated-time, set by run.sh: a stall of this shared machine slips
// simulated time and can neither fault nor hold the arm, so any FAULT or hold here fails the test with
// its cause; the real-time loop has its own test, ctest -L timing): GET /robots, the sweep command's refusals with reasons (no sweep without a robot
// calibration), the robot and image calibration routines, plan, pre_position, start while the catheter
// moves, the /us_arm/sweep and /us_arm/force topics, abort. Run by tests/api/us_arm/run.sh (with a
// calibration store of its own).
import {test, after} from 'node:test';
import assert from 'node:assert/strict';
import wsProtocol from '@foxglove/ws-protocol';
import WebSocket from 'ws';
import {BASE_URL, TOKEN, get, post, call, holdLease, assertErrorShape, pollUntil} from '../helpers.mjs';

const {FoxgloveClient} = wsProtocol;
const WS_URL = BASE_URL.replace(/^http/, 'ws') + '/ws';
const ARM = '/robots/us_arm';
const CATHETER = '/robots/srmc';
const open = [];

const state = async (r) => (await get(`${r}/operating_state`)).json;
const sweep = (action) => post(`${ARM}/sweep`, {action});

async function enable(r) {
  const res = await post(`${r}/state_command`, {command: 'enable'});
  assert.equal(res.status, 200, res.text);
  const ready = await pollUntil(async () => {
    const s = await state(r);
    return s.state === 'ENABLED' && s.drives_ready && !s.is_busy ? {done: true} : null;
  }, {polls: 200, intervalMs: 25});
  assert.ok(ready && ready.done, `${r} did not become ENABLED: ${JSON.stringify(await state(r))}`);
}

// Fails at once, with the cause, when the robot is not ENABLED (a hold or a fault: in simulated time
// neither can come from a stall of the machine, so either is a failure of the logic under test).
// The newest holds and faults of the event log (GET /faults) carry the full text: which device went
// silent for how long, or how late the control loop ran.
async function assertEnabled(s, when) {
  if (s.state === 'ENABLED') return;
  const events = ((await get('/faults')).json ?? []).filter((e) => ['hold', 'fault'].includes(e.kind)).slice(0, 3);
  assert.fail(`${when}: the robot is ${s.state}; hold: ${JSON.stringify(s.hold ?? null)}, ` +
      `fault: ${JSON.stringify(s.fault ?? null)}, loop timing: ${JSON.stringify(s.loop_timing)}; ` +
      `newest holds and faults: ${JSON.stringify(events)}`);
}

// A mode switch, tried again while the arm settles after enable (each refusal printed); a hold or a
// fault fails the test with its cause: it is never resumed here.
async function switchMode(r, mode) {
  for (let i = 0; i < 40; i++) {
    const s = await state(r);
    await assertEnabled(s, `switching to ${mode}`);
    if (s.mode === mode) return;
    if (i % 20 === 0) await holdLease();
    const res = await post(`${r}/mode`, {mode});
    if (res.status !== 200) console.log(`switching to ${mode}: ${res.status} ${res.text}`);
    await new Promise((res) => setTimeout(res, 250));
  }
  assert.equal((await state(r)).mode, mode, JSON.stringify(await state(r)));
}

// Stops the whole server for `ms` (SIGSTOP, then SIGCONT): a stall of the machine, made on purpose.
async function stallServer(ms) {
  const pid = Number(process.env.TENDRIL_PID);
  assert.ok(pid > 0, 'TENDRIL_PID (tests/api/server.sh) names the server');
  process.kill(pid, 'SIGSTOP');
  try {
    await new Promise((res) => setTimeout(res, ms));
  } finally {
    process.kill(pid, 'SIGCONT');
  }
}

after(async () => {
  for (const c of open) c.close();
  await post(`${ARM}/state_command`, {command: 'disable'});
  await post(`${CATHETER}/state_command`, {command: 'disable'});
  await call('DELETE', '/lease');
});

test('GET /robots describes us_arm with the sweep mode, the sweep command and its ultrasound section', async () => {
  const robots = (await get('/robots')).json;
  const arm = robots.find((r) => r.name === 'us_arm');
  assert.ok(arm, JSON.stringify(robots.map((r) => r.name)));
  assert.equal(arm.kind, 'serial_arm');
  // The server says it runs in simulated time (run.sh), so nobody takes this for a real-time run.
  for (const r of robots) assert.match(r.description, /\[SIMULATED TIME: /, `${r.name}: ${r.description}`);
  assert.deepEqual(arm.modes, ['joint', 'cartesian', 'sweep']);
  assert.deepEqual(arm.commands, ['calibrate', 'sweep']);
  assert.deepEqual(arm.calibrations.kinds.includes('robot'), true);
  assert.deepEqual(arm.calibrations.required.includes('robot'), true);
  const calibration = (await state(ARM)).calibration;
  assert.equal(calibration.robot, null, JSON.stringify(calibration));
  assert.equal(calibration.running, null);
  assert.equal(arm.ultrasound.via_points, 16);
  assert.equal(arm.ultrasound.force_target_n, 0.8);
  assert.equal(arm.ultrasound.gate.position_mm, 0.5);
  assert.equal(arm.ultrasound.gate.angle_rad, 0.01);
  assert.equal(arm.ultrasound.compensation_hz, 120);
  assert.equal(arm.ultrasound.simulated, true);
  assert.equal((await state(ARM)).sweep.phase, 'idle');
});

test('the sweep is refused out of order, each time with the reason', async () => {
  await holdLease();
  let r = await sweep('start');
  assertErrorShape(r, 409, 'conflict');
  assert.match(r.json.error.message, /sweep mode/);
  await enable(ARM);
  assert.equal((await post(`${ARM}/mode`, {mode: 'sweep'})).status, 200);
  assert.ok(await pollUntil(async () => (await state(ARM)).mode === 'sweep'));
  r = await sweep('start');
  assertErrorShape(r, 409, 'conflict');
  assert.match(r.json.error.message, /no plan/);
  assertErrorShape(await sweep('preview'), 409, 'conflict');
  assertErrorShape(await sweep('fly'), 400, 'bad_request');
  // No plan without a robot calibration; the routine runs in cartesian mode.
  r = await sweep('plan');
  assertErrorShape(r, 409, 'conflict');
  assert.match(r.json.error.message, /no valid robot, us calibration.*calibrate \{"kind":"robot"\}.*calibrate \{"kind":"us"\}/);
  r = await post(`${ARM}/calibrate`, {kind: 'robot'});
  assertErrorShape(r, 409, 'conflict');
  assert.match(r.json.error.message, /switch to cartesian mode/);
  assertErrorShape(await post(`${ARM}/calibrate`, {kind: 'laser'}), 400, 'bad_request');
  await switchMode(ARM, 'cartesian');
  // About 65 s of motion through 12 poses at the 0.1 rad/s cap, then the solve: once. A hold or a fault
  // ends the routine and fails the test with its cause. Meanwhile the whole server is stopped for 300 ms
  // (a stall of the machine, six times the arm's 50 ms lost-control bound): in simulated time it slips
  // the clock, and the arm moves on.
  await holdLease();
  r = await post(`${ARM}/calibrate`, {kind: 'robot'});
  assert.equal(r.status, 202, r.text);
  assertErrorShape(await post(`${ARM}/calibrate`, {kind: 'robot'}), 409, 'conflict');
  assert.ok(await pollUntil(async () => (await state(ARM)).calibration.running !== null ? {done: true} : null,
      {polls: 100, intervalMs: 50}), JSON.stringify((await state(ARM)).calibration));
  await new Promise((res) => setTimeout(res, 2000));  // the arm is on its way to the first poses
  await stallServer(300);
  await assertEnabled(await state(ARM), 'right after a 300 ms stall of the server while the arm moved');
  let polls = 0;
  const done = await pollUntil(async () => {
    // The lease lapses 30 s after the last command: the operator keeps it while the routine runs.
    if (++polls % 50 === 0) await holdLease();
    const s = await state(ARM);
    await assertEnabled(s, `calibrating (${JSON.stringify(s.calibration)})`);
    return s.calibration.running === null ? {done: true, c: s.calibration} : null;
  }, {polls: 900, intervalMs: 200});
  assert.ok(done && done.done, `the calibration did not end within 180 s: ${JSON.stringify(await state(ARM))}`);
  assert.equal(done.c.last.ok, true, JSON.stringify(done.c));
  assert.equal(done.c.robot.version, 1, JSON.stringify(done.c));
  assert.ok(done.c.robot.residual_mm < 1.3, JSON.stringify(done.c));
  assert.deepEqual(done.c.missing, ['us']);
  // The image-to-probe calibration (the SIMULATED N-wire phantom, a few seconds, no arm motion), which
  // the sweep requires too.
  r = await post(`${ARM}/calibrate`, {kind: 'us'});
  assert.equal(r.status, 202, r.text);
  const image = await pollUntil(async () => {
    const c = (await state(ARM)).calibration;
    return c.running === null ? {done: true, c} : null;
  }, {polls: 600, intervalMs: 200});
  assert.ok(image && image.done, JSON.stringify((await state(ARM)).calibration));
  assert.equal(image.c.last.ok, true, JSON.stringify(image.c));
  assert.equal(image.c.us.version, 1, JSON.stringify(image.c));
  assert.ok(image.c.us.residual_mm < 0.5, JSON.stringify(image.c));
  assert.deepEqual(image.c.missing, []);
  await switchMode(ARM, 'sweep');
  const plan = await sweep('plan');
  assert.equal(plan.status, 200, plan.text);
  assert.equal(plan.json.via_points.length, 16);
  assert.ok(plan.json.registration.error_mm < 0.3, JSON.stringify(plan.json.registration));
  assert.ok(await pollUntil(async () => (await state(ARM)).sweep.phase === 'planned'));
  r = await sweep('start');
  assertErrorShape(r, 409, 'conflict');
  assert.match(r.json.error.message, /pre_position first/);
});

test('a sweep begun while the catheter moves: pre_position, start, acquiring on /us_arm/sweep, abort', async () => {
  const {lease_token: leaseToken} = await holdLease();
  await enable(CATHETER);
  const ws = new WebSocket(`${WS_URL}?token=${encodeURIComponent(TOKEN)}&lease=${leaseToken}`,
      [FoxgloveClient.SUPPORTED_SUBPROTOCOL], {headers: {'X-Tendril-Client': 'api-test'}});
  const client = new FoxgloveClient({ws});
  open.push(client);
  const channels = new Map();
  const phases = new Set();
  const subscriptions = new Map();  // subscription id -> topic
  const forceMessages = [], sweepMessages = [];  // {at: arrival (ms), m}
  client.on('advertise', (list) => list.forEach((c) => channels.set(c.topic, c)));
  client.on('message', ({subscriptionId, data}) => {
    const m = JSON.parse(new TextDecoder().decode(data));
    if (subscriptions.get(subscriptionId) === '/us_arm/force') {
      forceMessages.push({at: performance.now(), m});
      return;
    }
    if (m.sweep) {
      phases.add(m.sweep.phase);
      sweepMessages.push({at: performance.now(), m: m.sweep});
    }
  });
  await new Promise((resolve, reject) => {
    client.on('serverInfo', resolve);
    client.on('error', reject);
  });
  assert.ok(await pollUntil(() => channels.has('/us_arm/sweep'), {polls: 100, intervalMs: 50}),
      `topics: ${[...channels.keys()].join(', ')}`);
  assert.equal(channels.get('/us_arm/sweep').schemaName, 'tendril.UltrasoundSweepState');
  subscriptions.set(client.subscribe(channels.get('/us_arm/sweep').id), '/us_arm/sweep');
  assert.ok(channels.has('/us_arm/force'), `topics: ${[...channels.keys()].join(', ')}`);
  assert.equal(channels.get('/us_arm/force').schemaName, 'tendril.ArmForce');
  subscriptions.set(client.subscribe(channels.get('/us_arm/force').id), '/us_arm/force');

  assert.equal((await sweep('pre_position')).status, 202);
  const moveCatheter = await post(`${CATHETER}/move_jp`, {goal: [15, 0, 0, 0]});
  assert.equal(moveCatheter.status, 202, moveCatheter.text);
  const ready = await pollUntil(async () => (await state(ARM)).sweep.phase === 'ready', {polls: 600, intervalMs: 100});
  assert.ok(ready, JSON.stringify(await state(ARM)));
  // The topic carries the phase too (at 20 Hz: wait for its message, the sweep stays ready until start).
  assert.ok(await pollUntil(() => phases.has('ready'), {polls: 100, intervalMs: 20}), [...phases].join(', '));
  // The lease lapses 30 s (wall time) after the last command; a loaded machine slows simulated time, so
  // the pre-positioning may outlast it: the operator renews it before starting.
  await holdLease();
  const started = await sweep('start');
  assert.equal(started.status, 202, `${started.text}; ${JSON.stringify((await state(ARM)).sweep)}`);
  const acquiring = await pollUntil(async () => (await state(ARM)).sweep.phase === 'acquiring',
      {polls: 600, intervalMs: 50});
  assert.ok(acquiring, JSON.stringify(await state(ARM)));
  const s = (await state(ARM)).sweep;
  assert.ok(Math.abs(s.force_n - 0.8) <= 0.15, JSON.stringify(s));
  assert.equal(s.force_target_n, 0.8);
  assert.ok(phases.has('ready') && phases.has('approaching'), [...phases].join(', '));
  // /us_arm/force over 2 s of control time in contact (the messages' own t: in simulated time a busy
  // machine slows the server's clock, and the rate is the server's, not the machine's): ≥ 80 messages a
  // second of it (the control loop's ticks, polled at 100 Hz), every message well formed, and its F_n
  // what /us_arm/sweep says over the same window (at least 2 s of wall time: control time never runs ahead).
  const from = performance.now();
  const since = (list) => list.filter(({at}) => at >= from).map(({m}) => m);
  const spanned = await pollUntil(() => {
    const f = since(forceMessages);
    return f.length > 1 && f[f.length - 1].t - f[0].t >= 2.0 ? {done: true} : null;
  }, {polls: 600, intervalMs: 50});
  const wallS = (performance.now() - from) / 1000;
  assert.ok(spanned, `/us_arm/force did not span 2 s of control time in ${wallS.toFixed(1)} s: ` +
      `${since(forceMessages).length} messages`);
  const windowed = since(forceMessages);
  const forces = windowed.filter((m) => m.t < windowed[0].t + 2.0), sweeps = since(sweepMessages);
  const mean = (values) => values.reduce((a, b) => a + b, 0) / values.length;
  const forceMean = mean(forces.map((m) => m.normal_n)), sweepMean = mean(sweeps.map((m) => m.force_n));
  console.log(`# /us_arm/force: ${forces.length / 2} Hz over 2 s of control time (${wallS.toFixed(1)} s of wall ` +
      `time), mean F_n ${forceMean.toFixed(3)} N; /us_arm/sweep: ${(sweeps.length / wallS).toFixed(1)} Hz, ` +
      `mean F_n ${sweepMean.toFixed(3)} N; ` +
      `phases ${[...new Set(forces.map((m) => m.phase))].join(', ')}`);
  assert.ok(forces.length >= 160, `${forces.length} force messages in 2 s of control time`);
  assert.ok(sweeps.length >= 10, `${sweeps.length} sweep messages in ${wallS.toFixed(1)} s`);
  for (const m of forces) {
    assert.equal(m.frame_id, 'us_arm_probe');
    assert.equal(m.target_n, 0.8);
    assert.equal(m.force_n.length, 3);
    assert.ok(Math.abs(m.normal_n + m.force_n[2]) < 1e-9, JSON.stringify(m));
    assert.ok(['approaching', 'acquiring', 'moving'].includes(m.phase), JSON.stringify(m));
  }
  assert.ok(Math.abs(forceMean - sweepMean) < 0.05, `force topic ${forceMean} N, sweep ${sweepMean} N`);
  assert.ok(Math.abs(forceMean - 0.8) < 0.15, `mean F_n ${forceMean} N in contact`);
  // Strictly later control times, one message per tick at most.
  for (let i = 1; i < forces.length; ++i) assert.ok(forces[i].t > forces[i - 1].t, `t ${forces[i - 1].t} then ${forces[i].t}`);
  const catheter = (await get(`${CATHETER}/measured_js`)).json.position[0];
  assert.ok(Math.abs(catheter - 15) < 0.1, `the catheter reached ${catheter} mm`);
  assert.equal((await sweep('abort')).status, 202);
  const aborted = await pollUntil(async () => {
    const w = (await state(ARM)).sweep;
    return w.phase === 'aborted' && !w.retracting;
  }, {polls: 200, intervalMs: 50});
  assert.ok(aborted, JSON.stringify((await state(ARM)).sweep));
  assert.equal((await state(ARM)).state, 'ENABLED');
  assert.equal((await state(CATHETER)).state, 'ENABLED');
  assertErrorShape(await sweep('abort'), 409, 'conflict');
  client.close();
});
