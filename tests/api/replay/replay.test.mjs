// tendrild --replay, against the session the API tests just recorded (tests/api/run.sh starts it on
// TENDRIL_REPLAYED_DIR after the recording was read back): the same topics with the same schemas and
// encodings as recorded (read with @mcap/core, an independent reader), the joint states replayed in
// recorded order, play/pause/seek/rate over REST with bad input refused (400), and no robot commanded:
// every command, with or without the lease, answers 409 replay_mode.
import {test} from 'node:test';
import assert from 'node:assert/strict';
import {readFileSync, readdirSync} from 'node:fs';
import {join} from 'node:path';
import wsProtocol from '@foxglove/ws-protocol';
import WebSocket from 'ws';
import {McapIndexedReader} from '@mcap/core';
import zstd from '@foxglove/wasm-zstd';
import lz4 from '@foxglove/wasm-lz4';
import {BASE_URL, TOKEN, ROBOT, call, get, post, assertErrorShape} from '../helpers.mjs';

const {FoxgloveClient} = wsProtocol;
const dir = process.env.TENDRIL_REPLAYED_DIR;
if (!dir) throw new Error('set TENDRIL_REPLAYED_DIR to the folder tendrild replays');
const put = (body, options = {}) => call('PUT', '/replay', {body, ...options});

// The recorded channels, by topic, as @mcap/core reads them.
async function recordedChannels() {
  await zstd.isLoaded;
  const decompressHandlers = {
    zstd: (data, size) => zstd.decompress(data, Number(size)),
    lz4: (data, size) => lz4(data, Number(size)),
  };
  const channels = new Map();
  for (const file of readdirSync(dir).filter((f) => f.endsWith('.mcap')).sort()) {
    const bytes = new Uint8Array(readFileSync(join(dir, file)));
    const readable = {size: async () => BigInt(bytes.byteLength), read: async (o, s) => bytes.subarray(Number(o), Number(o + s))};
    const reader = await McapIndexedReader.Initialize({readable, decompressHandlers});
    for (const [, channel] of reader.channelsById) {
      if (channels.has(channel.topic)) continue;
      channels.set(channel.topic, {channel, schema: reader.schemasById.get(channel.schemaId)});
    }
  }
  return channels;
}

test('GET /health says the server replays (the console asks GET /replay only then) and runs no control loop', async () => {
  const res = await call('GET', '/health', {token: null, client: null});
  assert.equal(res.status, 200, res.text);
  assert.equal(res.json.mode, 'replay');
  assert.equal(res.json.control_realtime.requested, false);
  assert.equal(res.json.control_realtime.granted, false);
});

test('GET /replay describes the recording; PUT refuses bad input with 400 and a message', async () => {
  const res = await get('/replay');
  assert.equal(res.status, 200, res.text);
  const r = res.json;
  assert.ok(r.files.length >= 1);
  assert.ok(r.files.every((f) => f.finalised), 'the API session was finalised at SIGTERM');
  assert.ok(r.end_ns > r.start_ns);
  assert.ok(r.position_ns >= r.start_ns && r.position_ns <= r.end_ns);
  // Every recorded topic (as @mcap/core reads the files), and the replay's own status.
  for (const topic of [...(await recordedChannels()).keys(), `/${ROBOT}/joint_states`, '/replay/status']) {
    assert.ok(r.topics.includes(topic), `${topic} in ${r.topics}`);
  }
  for (const body of [{rate: 0}, {rate: 11}, {rate: -1}, {rate: 'fast'}, {playing: 'yes'}, {position_ns: -1},
    {position_ns: r.end_ns + 1e9}, {position_ns: r.start_ns - 1e9}, {speed: 2}, {}]) {
    assertErrorShape(await put(body), 400, 'bad_replay_control');
  }
  assertErrorShape(await call('PUT', '/replay', {raw: '{"rate": NaN}'}), 400);
  assertErrorShape(await put({playing: false}, {headers: {'X-Tendril-Role': 'viewer'}}), 403, 'forbidden_role');
  assertErrorShape(await call('DELETE', '/replay'), 405);
  const paused = await put({playing: false, position_ns: r.start_ns, rate: 2});
  assert.equal(paused.status, 200, paused.text);
  assert.equal(paused.json.playing, false);
  assert.ok(Math.abs(paused.json.position_ns - r.start_ns) < 1e6, 'paused where asked');
  assert.equal(paused.json.rate, 2);
});

test('no robot is commanded: every command answers 409 replay_mode, lease or not', async () => {
  const robots = await get('/robots');
  assert.equal(robots.status, 200);
  assert.ok(robots.json.some((robot) => robot.name === ROBOT), 'the robots are described as configured');
  assertErrorShape(await post(`/robots/${ROBOT}/move_jp`, {goal: [1, 0, 0, 0]}), 409, 'replay_mode');
  assertErrorShape(await post(`/robots/${ROBOT}/state_command`, {command: 'enable'}), 409, 'replay_mode');
  assertErrorShape(await post('/estop', {}), 409, 'replay_mode');
  const lease = await post('/lease', {});
  assert.equal(lease.status, 200, lease.text);
  assertErrorShape(await post(`/robots/${ROBOT}/servo_jv`, {velocity: [1, 0, 0, 0]}), 409, 'replay_mode');
  assertErrorShape(await get(`/robots/${ROBOT}/measured_js`), 409, 'replay_mode');
  await call('DELETE', '/lease');
});

test('the recorded topics come back through the WebSocket with their schemas, in recorded order', async () => {
  const recorded = await recordedChannels();
  const ws = new WebSocket(`${BASE_URL.replace(/^http/, 'ws')}/ws?token=${encodeURIComponent(TOKEN)}`,
    [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
  const client = new FoxgloveClient({ws});
  try {
    const channels = new Map();
    const advertised = new Promise((resolve) => client.on('advertise', (list) => {
      list.forEach((c) => channels.set(c.topic, c));
      if (channels.has(`/${ROBOT}/joint_states`) && channels.has('/replay/status')) resolve();
    }));
    await advertised;
    for (const [topic, {channel, schema}] of recorded) {
      const live = channels.get(topic);
      assert.ok(live, `${topic} advertised`);
      assert.equal(live.encoding, channel.messageEncoding, topic);
      assert.equal(live.schemaName, schema?.name ?? '', topic);
      if (channel.messageEncoding === 'json' && schema) assert.equal(live.schema, new TextDecoder().decode(schema.data), topic);
    }
    const start = (await get('/replay')).json.start_ns;
    assert.equal((await put({playing: false, position_ns: start})).status, 200);
    const joints = client.subscribe(channels.get(`/${ROBOT}/joint_states`).id);
    const status = client.subscribe(channels.get('/replay/status').id);
    const decoder = new TextDecoder();
    const stamps = [];
    const positions = [];
    const enough = new Promise((resolve) => client.on('message', (m) => {
      const json = JSON.parse(decoder.decode(new Uint8Array(m.data.buffer, m.data.byteOffset, m.data.byteLength)));
      if (m.subscriptionId === joints) stamps.push(json.timestamp);
      if (m.subscriptionId === status) positions.push(json.position_ns);
      if (stamps.length >= 40 && positions.length >= 3) resolve();
    }));
    const play = await put({position_ns: start, rate: 4, playing: true});
    assert.equal(play.status, 200, play.text);
    await Promise.race([enough, new Promise((_, reject) => setTimeout(() => reject(new Error(
      `only ${stamps.length} joint states and ${positions.length} statuses within 20 s`)), 20000))]);
    const paused = await put({playing: false});
    assert.equal(paused.json.playing, false);
    // Newest-only delivery may skip a message for a slow reader, never reorder: the recorded time
    // stamps in the payloads only grow.
    // A new subscriber first gets the topic's newest message, here one from before the seek: at most one.
    if (stamps[0] > stamps[1]) stamps.shift();
    for (let i = 1; i < stamps.length; ++i) assert.ok(stamps[i] >= stamps[i - 1], `joint state ${i} out of order: ${JSON.stringify(stamps.slice(0, i + 2).map((s) => s - start / 1e9))}`);
    for (let i = 1; i < positions.length; ++i) assert.ok(positions[i] >= positions[i - 1], 'the position only grows');
  } finally {
    client.close();
  }
});
