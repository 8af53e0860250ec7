// WebSocket contract tests: an independent Foxglove client (@foxglove/ws-protocol's FoxgloveClient
// over the `ws` package) connects to /ws with subprotocol foxglove.websocket.v1 and ?token=.
import {test} from 'node:test';
import assert from 'node:assert/strict';
import wsProtocol from '@foxglove/ws-protocol';
import WebSocket from 'ws';
import protobuf from 'protobufjs';
import descriptor from 'protobufjs/ext/descriptor/index.js';

const {FoxgloveClient} = wsProtocol;  // CommonJS package: no named ESM exports
import {BASE_URL, TOKEN, ROBOT, robotConfig, get} from './helpers.mjs';

const WS_URL = BASE_URL.replace(/^http/, 'ws') + '/ws';

// Resolves with the first value `pick` returns for an event, or rejects after `ms` (a bound on a
// hung server, not a speed assertion).
function waitFor(client, event, pick, ms = 10000) {
  return new Promise((resolve, reject) => {
    const timer = setTimeout(() => reject(new Error(`no suitable '${event}' within ${ms} ms`)), ms);
    const listener = (arg) => {
      const v = pick(arg);
      if (v !== undefined) {
        clearTimeout(timer);
        client.off(event, listener);
        resolve(v);
      }
    };
    client.on(event, listener);
  });
}

function connect(url) {
  const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
  return {ws, client: new FoxgloveClient({ws})};
}

test('a WebSocket without the token is refused', async () => {
  const ws = new WebSocket(WS_URL, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
  const outcome = await new Promise((resolve) => {
    ws.on('unexpected-response', (_req, res) => resolve(`http ${res.statusCode}`));
    ws.on('open', () => resolve('open'));
    ws.on('error', (err) => resolve(`error ${err.message}`));
  });
  ws.terminate();
  assert.notEqual(outcome, 'open', 'handshake without token must not succeed');
  assert.match(outcome, /401|403|error/);
});

test('serverInfo, advertised channels, and joint_states messages with 4 positions', async () => {
  const {ws, client} = connect(`${WS_URL}?token=${encodeURIComponent(TOKEN)}`);
  try {
    const channels = new Map();
    client.on('advertise', (list) => list.forEach((c) => channels.set(c.topic, c)));
    const info = await waitFor(client, 'serverInfo', (i) => i);
    assert.equal(ws.protocol, 'foxglove.websocket.v1');
    assert.equal(typeof info.name, 'string');
    assert.ok(Array.isArray(info.capabilities), 'serverInfo.capabilities is a list');

    const jointTopic = `/${ROBOT}/joint_states`;
    const channel = channels.get(jointTopic) ??
      await waitFor(client, 'advertise', (list) => list.find((c) => c.topic === jointTopic));
    for (const topic of [`/${ROBOT}/operating_state`, `/${ROBOT}/scene`, '/safety/events']) {
      if (!channels.has(topic)) await waitFor(client, 'advertise', (list) => list.find((c) => c.topic === topic));
    }
    assert.equal(channel.encoding, 'json');
    assert.equal(channel.schemaName, 'tendril.JointState');
    assert.equal(channels.get(`/${ROBOT}/scene`).schemaName, 'foxglove.SceneUpdate');

    const subscriptionId = client.subscribe(channel.id);
    const decoder = new TextDecoder();
    const messages = [];
    await waitFor(client, 'message', (m) => {
      if (m.subscriptionId !== subscriptionId) return undefined;
      const bytes = new Uint8Array(m.data.buffer, m.data.byteOffset, m.data.byteLength);
      messages.push({timestamp: m.timestamp, json: JSON.parse(decoder.decode(bytes))});
      return messages.length >= 3 ? true : undefined;
    });
    for (const {timestamp, json} of messages) {
      assert.ok(timestamp > 0n, 'message timestamp in ns');
      assert.deepEqual(json.name, robotConfig.joints.map((j) => j.name));
      assert.equal(json.position.length, 4);
      json.position.forEach((v) => assert.ok(Number.isFinite(v)));
      assert.equal(json.setpoint.length, 4, 'joint_states carries the setpoint too');
    }

    // The scene stream is a foxglove.SceneUpdate with the backbone polyline.
    const sceneChannel = channels.get(`/${ROBOT}/scene`);
    const sceneSub = client.subscribe(sceneChannel.id);
    const scene = await waitFor(client, 'message', (m) => {
      if (m.subscriptionId !== sceneSub) return undefined;
      return JSON.parse(decoder.decode(new Uint8Array(m.data.buffer, m.data.byteOffset, m.data.byteLength)));
    });
    const backbone = scene.entities.find((e) => /(^|\/)backbone$/.test(e.id));
    assert.ok(backbone, `scene has a backbone entity: ${JSON.stringify(scene).slice(0, 200)}`);
    assert.ok(backbone.lines[0].points.length >= 2);
    for (const p of backbone.lines[0].points) for (const k of ['x', 'y', 'z']) assert.ok(Number.isFinite(p[k]));
  } finally {
    client.close();
  }
});

// Issue 12: at rest the sensors' noise moved the shape by thousandths of a millimetre and the scene went
// out with every tick, so a software-rendered console redrew the 3D view all the time and showed it
// STALE. A scene is sent when it changes visibly (more than 0.05 mm or about 0.6°).
test('a robot at rest: the scene is not resent with every joint_states tick', async () => {
  const operating = async () => (await get(`/robots/${ROBOT}/operating_state`)).json;
  assert.equal((await operating()).is_busy, false, 'the robot is at rest');
  const {client} = connect(`${WS_URL}?token=${encodeURIComponent(TOKEN)}`);
  try {
    const counts = {joints: 0, scene: 0};
    const subscriptions = new Map();
    client.on('advertise', (list) => {
      for (const c of list) {
        if (c.topic === `/${ROBOT}/joint_states`) subscriptions.set(client.subscribe(c.id), 'joints');
        if (c.topic === `/${ROBOT}/scene`) subscriptions.set(client.subscribe(c.id), 'scene');
      }
    });
    client.on('message', (m) => {
      const which = subscriptions.get(m.subscriptionId);
      if (which) counts[which] += 1;
    });
    await waitFor(client, 'message', (m) => (subscriptions.get(m.subscriptionId) === 'scene' ? true : undefined));
    counts.joints = 0;
    counts.scene = 0;
    await new Promise((r) => setTimeout(r, 3000));
    assert.equal((await operating()).is_busy, false, 'the robot stayed at rest');
    assert.ok(counts.joints >= 30, `joint_states streamed: ${JSON.stringify(counts)}`);
    assert.ok(counts.scene * 5 <= counts.joints, `the scene went out with the joint states: ${JSON.stringify(counts)}`);
  } finally {
    client.close();
  }
});

test('the simulated fluoroscope streams JPEG foxglove.CompressedImage and the vessel wall as a PointCloud', async () => {
  const {client} = connect(`${WS_URL}?token=${encodeURIComponent(TOKEN)}`);
  try {
    const channels = new Map();
    client.on('advertise', (list) => list.forEach((c) => channels.set(c.topic, c)));
    await waitFor(client, 'serverInfo', (i) => i);
    for (const topic of ['/imaging/ap', '/imaging/lateral', '/maps/vessel']) {
      if (!channels.has(topic)) await waitFor(client, 'advertise', (list) => list.find((c) => c.topic === topic));
    }
    assert.equal(channels.get('/imaging/ap').schemaName, 'foxglove.CompressedImage');
    assert.equal(channels.get('/maps/vessel').schemaName, 'foxglove.PointCloud');
    const decoder = new TextDecoder();
    const parse = (m) => JSON.parse(decoder.decode(new Uint8Array(m.data.buffer, m.data.byteOffset, m.data.byteLength)));

    const imageSub = client.subscribe(channels.get('/imaging/ap').id);
    const image = await waitFor(client, 'message', (m) => (m.subscriptionId === imageSub ? parse(m) : undefined));
    assert.equal(image.format, 'jpeg');
    const jpeg = Buffer.from(image.data, 'base64');
    assert.deepEqual([...jpeg.subarray(0, 3)], [0xff, 0xd8, 0xff], 'data is a JPEG (SOI marker)');
    assert.deepEqual([...jpeg.subarray(-2)], [0xff, 0xd9], 'the JPEG is complete (EOI marker)');
    assert.ok(image.timestamp.sec > 0, 'capture timestamp');

    const cloudSub = client.subscribe(channels.get('/maps/vessel').id);
    const cloud = await waitFor(client, 'message', (m) => (m.subscriptionId === cloudSub ? parse(m) : undefined));
    const points = Buffer.from(cloud.data, 'base64');
    assert.ok(cloud.point_stride >= 12, 'x, y, z floats at least');
    assert.ok(points.length >= 100 * cloud.point_stride, 'the vessel wall has points');
    assert.equal(points.length % cloud.point_stride, 0);
    assert.deepEqual(cloud.fields.slice(0, 3).map((f) => f.name), ['x', 'y', 'z']);
  } finally {
    client.close();
  }
});

// Issue 15: images in a binary message encoding. /imaging/{view}/compressed is protobuf
// foxglove.CompressedImage, decoded here by protobufjs from nothing but the descriptor set the server
// advertises; it carries the very JPEG bytes of the JSON stream's frame of the same time stamp, and
// /imaging/{view}/overlay that frame's overlay.
test('the images also stream as protobuf foxglove.CompressedImage, described by the advertised FileDescriptorSet', async () => {
  const {client} = connect(`${WS_URL}?token=${encodeURIComponent(TOKEN)}`);
  try {
    const channels = new Map();
    client.on('advertise', (list) => list.forEach((c) => channels.set(c.topic, c)));
    await waitFor(client, 'serverInfo', (i) => i);
    for (const topic of ['/imaging/ap', '/imaging/ap/compressed', '/imaging/ap/overlay']) {
      if (!channels.has(topic)) await waitFor(client, 'advertise', (list) => list.find((c) => c.topic === topic));
    }
    const binary = channels.get('/imaging/ap/compressed');
    assert.equal(binary.encoding, 'protobuf');
    assert.equal(binary.schemaEncoding, 'protobuf');
    assert.equal(binary.schemaName, 'foxglove.CompressedImage');
    const set = descriptor.FileDescriptorSet.decode(Buffer.from(binary.schema, 'base64'));
    const CompressedImage = protobuf.Root.fromDescriptor(set).lookupType('foxglove.CompressedImage');
    assert.deepEqual(CompressedImage.fieldsArray.map((f) => [f.name, f.id]).sort((a, b) => a[1] - b[1]),
                     [['timestamp', 1], ['data', 2], ['format', 3], ['frame_id', 4]]);

    const stamp = (t) => `${t.sec ?? t.seconds}.${t.nsec ?? t.nanos}`;
    const json = new Map();
    const binaryFrames = new Map();
    const overlays = new Map();
    const subs = {
      [client.subscribe(channels.get('/imaging/ap').id)]: 'json',
      [client.subscribe(binary.id)]: 'binary',
      [client.subscribe(channels.get('/imaging/ap/overlay').id)]: 'overlay',
    };
    const bytesOf = (m) => new Uint8Array(m.data.buffer, m.data.byteOffset, m.data.byteLength);
    const both = await waitFor(client, 'message', (m) => {
      const kind = subs[m.subscriptionId];
      if (kind === 'json') {
        const msg = JSON.parse(new TextDecoder().decode(bytesOf(m)));
        json.set(stamp(msg.timestamp), msg);
      } else if (kind === 'binary') {
        const msg = CompressedImage.toObject(CompressedImage.decode(bytesOf(m)), {longs: Number, bytes: Buffer});
        binaryFrames.set(stamp({sec: msg.timestamp?.seconds ?? 0, nsec: msg.timestamp?.nanos ?? 0}), msg);
      } else if (kind === 'overlay') {
        const msg = JSON.parse(new TextDecoder().decode(bytesOf(m)));
        overlays.set(stamp(msg.timestamp), msg);
      }
      for (const [key, frame] of binaryFrames) {
        if (json.has(key) && overlays.has(key)) return {json: json.get(key), frame, overlay: overlays.get(key)};
      }
      return undefined;
    }, 20000);
    assert.equal(both.frame.format, 'jpeg');
    assert.equal(both.frame.frame_id, 'imaging_ap');
    assert.deepEqual([...both.frame.data.subarray(0, 3)], [0xff, 0xd8, 0xff], 'a JPEG (SOI marker)');
    assert.ok(Buffer.from(both.json.data, 'base64').equals(both.frame.data),
              'the same JPEG bytes as the JSON stream\'s frame of that time stamp');
    assert.ok(both.frame.data.length < both.json.data.length * 0.8, 'no base64: about 3/4 of the JSON data string');
    assert.deepEqual(both.overlay.robot, both.json.overlay.robot, 'the overlay stream carries that frame\'s overlay');
    assert.ok(both.overlay.robot.length > 10, 'the projected model backbone');
  } finally {
    client.close();
  }
});

// Issue 15: foxglove.ImageAnnotations for the overlay, so Foxglove's Image panel draws the model
// backbone, the plan and (while tracked) the segmented instrument and its tip over the image. Decoded
// with the advertised descriptor set only; the line strips are the JSON overlay's of the same stamp.
test('the overlay also streams as protobuf foxglove.ImageAnnotations, the same pixels as the JSON overlay', async () => {
  const {client} = connect(`${WS_URL}?token=${encodeURIComponent(TOKEN)}`);
  try {
    const channels = new Map();
    client.on('advertise', (list) => list.forEach((c) => channels.set(c.topic, c)));
    await waitFor(client, 'serverInfo', (i) => i);
    for (const topic of ['/imaging/lateral/overlay', '/imaging/lateral/annotations']) {
      if (!channels.has(topic)) await waitFor(client, 'advertise', (list) => list.find((c) => c.topic === topic));
    }
    const channel = channels.get('/imaging/lateral/annotations');
    assert.equal(channel.encoding, 'protobuf');
    assert.equal(channel.schemaName, 'foxglove.ImageAnnotations');
    const root = protobuf.Root.fromDescriptor(descriptor.FileDescriptorSet.decode(Buffer.from(channel.schema, 'base64')));
    const ImageAnnotations = root.lookupType('foxglove.ImageAnnotations');
    const stamp = (t) => `${t.sec ?? t.seconds ?? 0}.${t.nsec ?? t.nanos ?? 0}`;
    const overlays = new Map();
    const annotations = new Map();
    const subs = {
      [client.subscribe(channels.get('/imaging/lateral/overlay').id)]: 'overlay',
      [client.subscribe(channel.id)]: 'annotations',
    };
    const bytesOf = (m) => new Uint8Array(m.data.buffer, m.data.byteOffset, m.data.byteLength);
    const pair = await waitFor(client, 'message', (m) => {
      if (subs[m.subscriptionId] === 'overlay') {
        const msg = JSON.parse(new TextDecoder().decode(bytesOf(m)));
        overlays.set(stamp(msg.timestamp), msg);
      } else if (subs[m.subscriptionId] === 'annotations') {
        const msg = ImageAnnotations.toObject(ImageAnnotations.decode(bytesOf(m)), {longs: Number, enums: String, defaults: true});
        annotations.set(stamp(msg.points[0].timestamp), msg);
      }
      for (const [key, a] of annotations) if (overlays.has(key)) return {annotations: a, overlay: overlays.get(key)};
      return undefined;
    }, 20000);
    const robot = pair.annotations.points[0];
    assert.equal(robot.type, 'LINE_STRIP');
    assert.ok(robot.thickness > 0 && robot.outline_color.a > 0, JSON.stringify(robot.outline_color));
    assert.equal(robot.points.length, pair.overlay.robot.length);
    assert.ok(robot.points.length > 10, 'the projected model backbone');
    robot.points.forEach((p, i) => {
      assert.ok(Math.abs(p.x - pair.overlay.robot[i][0]) <= 0.051 && Math.abs(p.y - pair.overlay.robot[i][1]) <= 0.051,
                `point ${i}: ${JSON.stringify(p)} vs ${JSON.stringify(pair.overlay.robot[i])}`);
    });
  } finally {
    client.close();
  }
});
