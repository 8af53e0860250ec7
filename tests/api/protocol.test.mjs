// Protocol tests with an independent client (@foxglove/ws-protocol's FoxgloveClient over `ws`):
// the lease takeover rules (confirmation, never while servoing, the old holder is told), Foxglove
// parameters (read by all, set by the lease holder only, within the configured limits, enforced on
// commands, pushed to subscribers) and status messages for refusals.
import {test, after} from 'node:test';
import assert from 'node:assert/strict';
import wsProtocol from '@foxglove/ws-protocol';
import WebSocket from 'ws';
import {BASE_URL, TOKEN, ROBOT, robotConfig, get, post, call, script, assertErrorShape, pollUntil, sleep} from './helpers.mjs';

const {FoxgloveClient} = wsProtocol;
const WS_URL = BASE_URL.replace(/^http/, 'ws') + '/ws';
const R = `/robots/${ROBOT}`;
// Two scripts, each with a lease of its own (a lease token), and labels proto-a / proto-b.
const A = script('proto-a');
const B = script('proto-b');
const open = [];

// lease: a lease token the socket presents (?lease=), so it acts under that lease.
function connect({client, role, lease} = {}) {
  const query = `?token=${encodeURIComponent(TOKEN)}${role ? `&role=${role}` : ''}${lease ? `&lease=${lease}` : ''}`;
  const headers = client ? {'X-Tendril-Client': client} : {};
  const ws = new WebSocket(WS_URL + query, [FoxgloveClient.SUPPORTED_SUBPROTOCOL], {headers, rejectUnauthorized: false});
  const foxglove = new FoxgloveClient({ws});
  const received = [];  // every status and parameterValues, in order
  foxglove.on('status', (s) => received.push({op: 'status', ...s}));
  foxglove.on('parameterValues', (p) => received.push({op: 'parameterValues', ...p}));
  const ready = new Promise((resolve, reject) => {
    foxglove.on('serverInfo', resolve);
    foxglove.on('error', reject);
  });
  const services = new Promise((resolve) => foxglove.on('advertiseServices', resolve));
  open.push(foxglove);
  return {foxglove, received, ready, services};
}

// Waits for a received message that `pick` accepts (bounded: a hung server fails the test).
async function waitForMessage(received, pick, what) {
  const found = await pollUntil(() => {
    const m = received.find(pick);
    return m ? {done: true, m} : null;
  }, {polls: 200, intervalMs: 25});
  assert.ok(found && found.m, `no ${what} arrived; got ${JSON.stringify(received).slice(0, 400)}`);
  return found.m;
}

async function enable(client) {
  const res = await client.post(`${R}/state_command`, {command: 'enable'});
  assert.equal(res.status, 200, res.text);
  const ready = await pollUntil(async () => {
    const s = (await get(`${R}/operating_state`)).json;
    return s.state === 'ENABLED' && s.drives_ready && !s.is_busy ? {done: true} : null;
  }, {polls: 200, intervalMs: 25});
  assert.ok(ready && ready.done, 'robot did not become ENABLED with ready drives');
}

after(async () => {
  for (const c of open) c.close();
  // Leave the server as we found it: configured limits, robot disabled, lease free.
  for (const client of [A, B]) {
    await client.takeLeaseOver();
    await client.call('DELETE', '/lease');
  }
});

test('lease takeover: 409 names the holder and offers a token; confirmed takeover works, never while servoing', async () => {
  await A.takeLeaseOver();
  const a = connect({client: A.name, lease: A.leaseToken});
  await a.ready;
  await enable(A);

  const refused = await B.takeLease();
  assertErrorShape(refused, 409, 'lease_held');
  assert.equal(refused.json.error.holder, `client:${A.name}`);
  const token = refused.json.error.takeover_token;
  assert.equal(typeof token, 'string');
  assert.ok(token.length >= 16);
  assertErrorShape(await B.takeLease({takeover_token: 'made-up'}), 409, 'bad_takeover_token');

  // A streams servo commands (zero velocity) every 40 ms: the takeover must be refused meanwhile.
  let streaming = true;
  const stream = (async () => {
    while (streaming) {
      const res = await A.post(`${R}/servo_jv`, {velocity: [0, 0, 0, 0]});
      assert.equal(res.status, 200, res.text);
      await sleep(40);
    }
  })();
  await sleep(120);
  const duringServo = await B.takeLease({takeover_token: token});
  streaming = false;
  await stream;
  assertErrorShape(duringServo, 409, 'servo_active');
  assert.equal((await A.get('/lease')).json.mine, true, 'A still holds the lease');

  // Once the stream has ended (command timeout 150 ms), the confirmed takeover succeeds.
  await sleep(robotConfig.command_timeout_ms + 150);
  const taken = await B.takeLease({takeover_token: token});
  assert.equal(taken.status, 200, taken.text);
  assert.deepEqual([taken.json.held, taken.json.mine, taken.json.holder], [true, true, `client:${B.name}`]);
  assert.equal(typeof taken.json.expires_s, 'number');
  assert.notEqual(taken.json.lease_token, A.leaseToken, 'a takeover issues a new lease token');

  const lease = (await A.get('/lease')).json;
  assert.deepEqual([lease.held, lease.mine, lease.holder], [true, false, `client:${B.name}`]);
  const warning = await waitForMessage(a.received, (m) => m.op === 'status' && m.level === 1 && /taken over/.test(m.message),
    'status warning to the old holder');
  assert.match(warning.message, new RegExp(`client:${B.name}`));
  assertErrorShape(await A.post(`${R}/servo_jv`, {velocity: [0, 0, 0, 0]}), 409, 'lease_held');
  assert.equal((await B.post(`${R}/state_command`, {command: 'disable'})).status, 200);
  await B.call('DELETE', '/lease');
});

test('parameters: everyone reads, only the lease holder tightens, commands obey, subscribers are told', async () => {
  const joint = robotConfig.joints[0];  // insertion
  const maxVelocity = `/${ROBOT}/${joint.name}/max_velocity`;
  const upper = `/${ROBOT}/${joint.name}/upper`;
  const viewer = connect({role: 'viewer'});
  const info = await viewer.ready;
  assert.ok(info.capabilities.includes('parameters'), JSON.stringify(info.capabilities));
  assert.ok(info.capabilities.includes('parametersSubscribe'));

  viewer.foxglove.getParameters([], 'all');
  const all = await waitForMessage(viewer.received, (m) => m.op === 'parameterValues' && m.id === 'all', 'all parameters');
  const byName = new Map(all.parameters.map((p) => [p.name, p.value]));
  assert.equal(byName.get(maxVelocity), joint.max_velocity);
  assert.equal(byName.get(upper), joint.upper);
  assert.equal(byName.get(`/${ROBOT}/servo_timeout_s`), robotConfig.command_timeout_ms / 1000);
  for (const j of robotConfig.joints) assert.ok(byName.has(`/${ROBOT}/${j.name}/lower`), j.name);
  viewer.foxglove.subscribeParameterUpdates([maxVelocity]);

  // A viewer is refused with a status; the answer shows the value unchanged.
  viewer.foxglove.setParameters([{name: maxVelocity, value: 1}], 'viewer-set');
  const viewerRefusal = await waitForMessage(viewer.received, (m) => m.op === 'status' && /forbidden_role/.test(m.message), 'refusal');
  assert.equal(viewerRefusal.level, 2);
  const unchanged = await waitForMessage(viewer.received, (m) => m.op === 'parameterValues' && m.id === 'viewer-set', 'answer');
  assert.equal(unchanged.parameters[0].value, joint.max_velocity);

  const op = connect({client: A.name});
  await op.ready;
  op.foxglove.setParameters([{name: maxVelocity, value: 1}], 'no-lease');
  await waitForMessage(op.received, (m) => m.op === 'status' && /lease_held/.test(m.message), 'lease refusal');

  // The socket takes the lease itself (a lease bound to this connection); A's REST calls use the
  // lease token the service answered.
  const services = await op.services;
  const leaseService = services.find((s) => s.name === 'lease');
  const response = new Promise((resolve) => op.foxglove.on('serviceCallResponse', resolve));
  op.foxglove.sendServiceCallRequest({serviceId: leaseService.id, callId: 1, encoding: 'json',
    data: new TextEncoder().encode(JSON.stringify({action: 'acquire'}))});
  const granted = JSON.parse(new TextDecoder().decode((await response).data));
  assert.equal(granted.status, 200, JSON.stringify(granted));
  assert.match(granted.body.holder, /^client:proto-a$/);
  A.leaseToken = granted.body.lease_token;
  assert.equal((await A.get('/lease')).json.mine, true, 'the token from the socket holds over REST');
  // Never wider than the configured limit.
  op.foxglove.setParameters([{name: maxVelocity, value: joint.max_velocity * 2}], 'too-wide');
  const wide = await waitForMessage(op.received, (m) => m.op === 'status' && /out_of_range/.test(m.message), 'out_of_range');
  assert.equal(wide.level, 2);
  op.foxglove.setParameters([{name: `/${ROBOT}/${joint.name}/configured_upper`, value: 1}], 'read-only');
  await waitForMessage(op.received, (m) => m.op === 'status' && /read_only_parameter/.test(m.message), 'read-only refusal');

  // Tighten velocity and the upper limit together.
  const tightUpper = joint.upper / 2;
  op.foxglove.setParameters([{name: maxVelocity, value: joint.max_velocity / 2}, {name: upper, value: tightUpper}], 'tighten');
  const set = await waitForMessage(op.received, (m) => m.op === 'parameterValues' && m.id === 'tighten', 'set answer');
  assert.deepEqual(Object.fromEntries(set.parameters.map((p) => [p.name, p.value])),
    {[maxVelocity]: joint.max_velocity / 2, [upper]: tightUpper});
  const update = await waitForMessage(viewer.received, (m) => m.op === 'parameterValues' && m.id === undefined, 'update');
  assert.deepEqual(update.parameters.map((p) => [p.name, p.value]), [[maxVelocity, joint.max_velocity / 2]],
    'subscribers get only what they subscribed to');

  // Commands obey the tightened limits.
  await enable(A);
  const fast = await A.post(`${R}/servo_jv`, {velocity: [joint.max_velocity * 0.75, 0, 0, 0]});
  assertErrorShape(fast, 422, 'out_of_limits');
  assert.match(fast.json.error.message, /max_velocity/);
  const position = (await get(`${R}/measured_js`)).json.position;
  const far = [...position];
  far[0] = tightUpper + 1;
  const beyond = await A.post(`${R}/move_jp`, {goal: far});
  assertErrorShape(beyond, 422, 'out_of_limits');
  assert.match(beyond.json.error.message, /operating range/);

  // Back to the configured values (unset = configured), with the robot disabled.
  assert.equal((await A.post(`${R}/state_command`, {command: 'disable'})).status, 200);
  op.foxglove.setParameters([{name: maxVelocity, value: undefined}, {name: upper, value: undefined}], 'reset');
  const reset = await waitForMessage(op.received, (m) => m.op === 'parameterValues' && m.id === 'reset', 'reset answer');
  assert.deepEqual(reset.parameters.map((p) => p.value).sort(), [joint.max_velocity, joint.upper].sort());
  // The lease is bound to the socket: when it closes, the lease is free at once (not after 30 s).
  op.foxglove.close();
  const freed = await pollUntil(async () => ({done: !(await get('/lease')).json.held}), {polls: 100, intervalMs: 20});
  assert.ok(freed && freed.done, 'the lease of a closed socket is released');
});

test('refused service calls and client publishing produce status messages', async () => {
  const c = connect({client: B.name});
  await c.ready;
  const services = await c.services;
  const stateCommand = services.find((s) => s.name === 'state_command');
  assert.ok(stateCommand);
  c.foxglove.sendServiceCallRequest({serviceId: stateCommand.id, callId: 1, encoding: 'json',
    data: new TextEncoder().encode(JSON.stringify({robot: ROBOT, command: 'enable'}))});
  const status = await waitForMessage(c.received, (m) => m.op === 'status' && /state_command: lease_held/.test(m.message), 'refusal status');
  assert.equal(status.level, 1);
});
