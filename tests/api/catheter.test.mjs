// The steerable catheter's modes over REST and the Foxglove WebSocket (Abah 2022, §4.7): every mode
// switch, refused switches with their reason, configuration goals, and the console joystick as a
// REST call and as a Foxglove client channel, with its deadman. Free space (tests/api/server.sh
// drops the simulated vessel).
import {test, after, beforeEach} from 'node:test';
import assert from 'node:assert/strict';
import wsProtocol from '@foxglove/ws-protocol';
import WebSocket from 'ws';
import {BASE_URL, TOKEN, ROBOT, get, post, call, holdLease, assertErrorShape, pollUntil, sleep} from './helpers.mjs';

const {FoxgloveClient} = wsProtocol;
const R = `/robots/${ROBOT}`;
const deg = Math.PI / 180;

const operatingState = async () => {
  const res = await get(`${R}/operating_state`);
  assert.equal(res.status, 200, res.text);
  return res.json;
};
const setpoint = async () => (await get(`${R}/setpoint_js`)).json.position;
// Holding: not busy on two polls 50 ms apart. A 202 can come back before the control loop has taken the
// command (it goes through the lock-free mailbox at the next tick), so one "not busy" read right after
// a move can be the state from before it — seen with the Release build in the container, whose answers
// are fast enough to beat the tick.
const holding = () => {
  let quiet = 0;
  return pollUntil(async () => {
    quiet = (await operatingState()).is_busy ? 0 : quiet + 1;
    return quiet >= 2;
  }, {polls: 400, intervalMs: 50});
};

// The first /{robot}/operating_state message on the Foxglove WebSocket that satisfies `accept`.
async function streamedOperatingState(accept) {
  const ws = new WebSocket(`${BASE_URL.replace(/^http/, 'ws')}/ws?token=${encodeURIComponent(TOKEN)}`,
      [FoxgloveClient.SUPPORTED_SUBPROTOCOL], {rejectUnauthorized: false});
  const client = new FoxgloveClient({ws});
  const topic = `/${ROBOT}/operating_state`;
  try {
    return await new Promise((resolve, reject) => {
      const timer = setTimeout(() => reject(new Error(`no ${topic} message within 10 s`)), 10000);
      let subscription;
      client.on('error', reject);
      client.on('advertise', (channels) => {
        const channel = channels.find((c) => c.topic === topic);
        if (channel && subscription === undefined) subscription = client.subscribe(channel.id);
      });
      client.on('message', (m) => {
        if (m.subscriptionId !== subscription) return;
        const os = JSON.parse(new TextDecoder().decode(new Uint8Array(m.data.buffer, m.data.byteOffset, m.data.byteLength)));
        if (accept(os)) {
          clearTimeout(timer);
          resolve(os);
        }
      });
    });
  } finally {
    client.close();
  }
}

async function switchTo(mode) {
  const res = await post(`${R}/mode`, {mode});
  assert.equal(res.status, 200, res.text);
  const ok = await pollUntil(async () => (await operatingState()).mode === mode);
  assert.ok(ok, `mode did not become ${mode}`);
}

// Commands here are the bearer-token identity's (README: plain curl); it (re)takes the lease before
// each test, so a slow test cannot leave it lapsed for the next.
beforeEach(holdLease);

after(async () => {
  await post('/lease', {});
  await post(`${R}/joystick`, {axes: [0, 0, 0, 0], deadman: false});
  await holding();
  await post(`${R}/mode`, {mode: 'joint'});
  await post(`${R}/state_command`, {command: 'disable'});
  await call('DELETE', '/lease');
});

test('the catheter lists its modes, configuration space and joystick sources', async () => {
  const res = await get('/robots');
  const srmc = res.json.find((r) => r.name === ROBOT);
  for (const m of ['joint', 'configuration', 'active_compliance', 'telemanipulation', 'image_guided', 'path_following'])
    assert.ok(srmc.modes.includes(m), `modes include ${m}: ${JSON.stringify(srmc.modes)}`);
  assert.deepEqual(srmc.configuration.names, ['insertion', 'roll', 'theta_proximal', 'theta_distal']);
  assert.ok(srmc.joystick_sources.includes('console'));
  const s = await operatingState();
  assert.equal(s.spring_deflection_mm.length, 2);
  assert.equal(typeof s.spring_deflection_limit_mm, 'number');
  assert.equal(s.configuration.length, 4);
});

test('every mode switch from a holding robot, and back to joint, without moving it', async () => {
  assert.equal((await post('/lease', {})).status, 200);
  assert.equal((await post(`${R}/state_command`, {command: 'enable'})).status, 200);
  assert.ok(await pollUntil(async () => (await operatingState()).drives_ready), 'drives ready');
  await holding();
  const before = await setpoint();
  for (const m of ['configuration', 'active_compliance', 'telemanipulation', 'joint']) {
    await switchTo(m);
    const now = await setpoint();
    now.forEach((v, i) => assert.ok(Math.abs(v - before[i]) < 0.05, `${m}: joint ${i} moved ${v - before[i]}`));
  }
});

test('refused switches say why: unknown mode 422, while moving 409 not_holding (kept in operating_state)', async () => {
  assertErrorShape(await post(`${R}/mode`, {mode: 'cartesian'}), 422, 'unknown_mode');
  assertErrorShape(await post(`${R}/mode`, {}), 400);
  const q = await setpoint();
  assert.equal((await post(`${R}/move_jp`, {goal: [q[0] + 8, q[1], q[2], q[3]]})).status, 202);
  const res = await post(`${R}/mode`, {mode: 'configuration'});
  assertErrorShape(res, 409, 'not_holding');
  const s = await operatingState();
  assert.equal(s.mode, 'joint');
  assert.equal(s.mode_refusal.mode, 'configuration');
  assert.match(s.mode_refusal.reason, /moving/);
  await holding();
  await post(`${R}/move_jp`, {goal: q});
  await holding();
});

test('configuration mode: move_configuration in radians reaches the bend angles', async () => {
  assertErrorShape(await post(`${R}/move_configuration`, {goal: {theta_proximal: 0.1}}), 409, 'wrong_mode');
  await switchTo('configuration');
  assertErrorShape(await post(`${R}/move_jp`, {goal: await setpoint()}), 409, 'wrong_mode');
  assertErrorShape(await post(`${R}/move_configuration`, {goal: {theta_distal: 170 * deg}}), 422, 'out_of_limits');
  assertErrorShape(await post(`${R}/move_configuration`, {goal: {theta_distal: 'a lot'}}), 400);
  assertErrorShape(await call('POST', `${R}/move_configuration`, {raw: '{"goal":{"theta_distal":NaN}}'}), 400);
  const res = await post(`${R}/move_configuration`, {goal: {theta_proximal: 20 * deg, theta_distal: -25 * deg}});
  assert.equal(res.status, 202, res.text);
  assert.equal(res.json.joints.length, 4);
  assert.ok(await holding(), 'move ends');
  const s = await operatingState();
  assert.ok(Math.abs(s.configuration[2] - 20 * deg) < 1 * deg, `theta_proximal ${s.configuration[2] / deg} deg`);
  assert.ok(Math.abs(s.configuration[3] + 25 * deg) < 1 * deg, `theta_distal ${s.configuration[3] / deg} deg`);
  const back = await post(`${R}/move_configuration`, {goal: {theta_proximal: 0, theta_distal: 0}});
  assert.equal(back.status, 202, back.text);
  await holding();
  await switchTo('joint');
});

test('a partial configuration goal moves only what it names: the insertion stays where it is', async () => {
  await holding();
  const q = await setpoint();
  assert.equal((await post(`${R}/move_jp`, {goal: [30, q[1], q[2], q[3]]})).status, 202);
  assert.ok(await holding(), 'joint move ends');
  await switchTo('configuration');
  const res = await post(`${R}/move_configuration`, {goal: {theta_proximal: 5 * deg}});
  assert.equal(res.status, 202, res.text);
  assert.ok(Math.abs(res.json.goal[0] - 30) < 0.01, `the goal keeps the insertion: ${JSON.stringify(res.json.goal)}`);
  assert.ok(await holding(), 'configuration move ends');
  const s = await operatingState();
  assert.ok(Math.abs((await setpoint())[0] - 30) < 0.01, `insertion stayed at 30 mm: ${(await setpoint())[0]}`);
  assert.ok(Math.abs(s.configuration[2] - 5 * deg) < 0.5 * deg, `theta_proximal ${s.configuration[2] / deg} deg`);
  assert.equal((await post(`${R}/move_configuration`, {goal: {theta_proximal: 0}})).status, 202);
  await holding();
  await switchTo('joint');
});

// Issue 12: every hold names its cause and its way out; the catheter's relax and withdraw are for a
// held robot only. (The spring-deflection hold itself needs the vessel: tests/integration and the
// browser test tests/e2e/holds.e2e.mjs.)
test('an operator pause: operating_state.hold names the cause and the way out; resume ends it', async () => {
  await holding();
  assert.equal((await operatingState()).hold, null, 'no hold while ENABLED');
  assertErrorShape(await post(`${R}/state_command`, {command: 'relax'}), 409, 'invalid_state');
  assertErrorShape(await post(`${R}/state_command`, {command: 'withdraw', distance_mm: 1}), 409, 'invalid_state');
  assert.equal((await post(`${R}/state_command`, {command: 'pause'})).status, 200);
  const paused = await pollUntil(async () => ({done: (await operatingState()).state === 'PAUSED', os: await operatingState()}));
  const {hold} = paused.os;
  assert.equal(hold.cause, 'operator_pause', JSON.stringify(hold));
  assert.equal(hold.message, 'paused by the operator');
  assert.equal(hold.cleared, true);
  assert.deepEqual(hold.allowed, ['resume']);
  assert.match(hold.next, /Resume/);
  // The stream's operating_state says the same (it leaves out only the robot's live wording), so a
  // page that has only that topic still names the pause (ci4 of 9c6349f showed "operator pause").
  const streamed = await streamedOperatingState((os) => os.state === 'PAUSED');
  assert.equal(streamed.hold?.message, 'paused by the operator', JSON.stringify(streamed.hold));
  assert.match(streamed.hold?.next ?? '', /Resume/);
  // Nothing to relax in free space, and no withdrawal after an operator's pause (not a limit hold).
  assertErrorShape(await post(`${R}/state_command`, {command: 'relax'}), 409, 'already_relaxed');
  assertErrorShape(await post(`${R}/state_command`, {command: 'withdraw', distance_mm: 1}), 409, 'invalid_state');
  assertErrorShape(await post(`${R}/state_command`, {command: 'withdraw', distance_mm: 50}), 422, 'out_of_range');
  assert.equal((await post(`${R}/state_command`, {command: 'resume'})).status, 200);
  const resumed = await pollUntil(async () => ({done: (await operatingState()).state === 'ENABLED'}));
  assert.ok(resumed.done, 'resumed');
  assert.equal((await operatingState()).hold, null);
});

test('telemanipulation over REST: nothing moves without the deadman, the bend moves with it', async () => {
  assertErrorShape(await post(`${R}/joystick`, {axes: [0, 0, 0.5, 0], deadman: true}), 409, 'wrong_mode');
  await switchTo('telemanipulation');
  assertErrorShape(await post(`${R}/joystick`, {axes: [0, 0, 2, 0], deadman: true}), 422, 'out_of_range');
  assertErrorShape(await post(`${R}/joystick`, {axes: [0, 0, 0], deadman: true}), 422, 'wrong_size');
  assertErrorShape(await post(`${R}/joystick`, {axes: [0, 0, 0, 0]}), 400);
  const q0 = await setpoint();
  for (let i = 0; i < 10; ++i) {
    assert.equal((await post(`${R}/joystick`, {axes: [0, 0, 1, 0], deadman: false})).status, 200);
    await sleep(30);
  }
  assert.ok(Math.abs((await setpoint())[2] - q0[2]) < 1e-6, 'moved without the deadman');
  for (let i = 0; i < 15; ++i) {
    await post(`${R}/joystick`, {axes: [0, 0, 1, 0], deadman: true});
    await sleep(30);
  }
  const s = await operatingState();
  assert.ok((await setpoint())[2] - q0[2] > 0.05, 'proximal bend moved with the deadman held');
  await post(`${R}/joystick`, {axes: [0, 0, 0, 0], deadman: false});
  assert.ok(await holding(), 'holds after the deadman is released');
  assert.ok(['console', null].includes(s.joystick.source));
});

test('telemanipulation over a Foxglove client channel /srmc/joystick', async () => {
  // The socket is its own identity unless it presents the lease token (?lease=, or X-Tendril-Lease).
  const {lease_token: leaseToken} = await holdLease();
  const ws = new WebSocket(`${BASE_URL.replace(/^http/, 'ws')}/ws?token=${encodeURIComponent(TOKEN)}&lease=${leaseToken}`,
      [FoxgloveClient.SUPPORTED_SUBPROTOCOL], {headers: {'X-Tendril-Client': 'api-test'}, rejectUnauthorized: false});
  const client = new FoxgloveClient({ws});
  const statuses = [];
  client.on('status', (s) => statuses.push(s));
  await new Promise((resolve, reject) => {
    client.on('serverInfo', resolve);
    client.on('error', reject);
  });
  try {
    const channel = client.advertise({topic: `/${ROBOT}/joystick`, encoding: 'json', schemaName: 'tendril.Joystick'});
    const q0 = await setpoint();
    for (let i = 0; i < 20; ++i) {
      client.sendMessage(channel, new TextEncoder().encode(JSON.stringify({axes: [0, 0, 0, -1], deadman: true})));
      await sleep(25);
    }
    client.sendMessage(channel, new TextEncoder().encode(JSON.stringify({axes: [0, 0, 0, 0], deadman: false})));
    const moved = (await setpoint())[3] - q0[3];
    assert.ok(moved < -0.1, `distal bend moved ${moved} mm; statuses ${JSON.stringify(statuses)}`);
    // A bad message gets a status, not motion.
    client.sendMessage(channel, new TextEncoder().encode(JSON.stringify({axes: [0, 0, 0, 9], deadman: true})));
    const warned = await pollUntil(() => statuses.find((s) => /joystick: out_of_range/.test(s.message)));
    assert.ok(warned, `no status for a bad joystick message: ${JSON.stringify(statuses)}`);
  } finally {
    client.close();
  }
  assert.ok(await holding());
  await switchTo('joint');
});
