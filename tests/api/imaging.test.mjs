// The segmentation editor and roadmaps over REST (/api/v1/imaging/…): per plane its parameters, a
// partial PUT validated by the parameters' own parser (404 unknown plane, 400 malformed JSON, 422 a bad
// value naming the field), the imaged robot's lease for a change (403 viewer, 409 someone else's
// lease), and a change applied by the plane's imaging thread at its next frame: while /imaging/tracking
// is watched (over the WebSocket) the GET shows it applied and /imaging/segmentation publishes it.
import {test} from 'node:test';
import assert from 'node:assert/strict';
import wsProtocol from '@foxglove/ws-protocol';
import WebSocket from 'ws';
import {BASE_URL, TOKEN, ROBOT, call, get, post, holdLease, script, assertErrorShape, pollUntil} from './helpers.mjs';

const {FoxgloveClient} = wsProtocol;
const WS_URL = BASE_URL.replace(/^http/, 'ws') + '/ws';
const put = (p, body, o = {}) => call('PUT', p, {body, ...o});

test('GET /imaging/segmentation: both planes, their parameters, roadmap and the imaged robot', async () => {
  const res = await get('/imaging/segmentation');
  assert.equal(res.status, 200, res.text);
  assert.equal(res.json.robot, ROBOT);
  for (const plane of ['ap', 'lateral']) {
    const p = res.json.planes[plane];
    assert.ok(p, `${plane}: ${res.text}`);
    assert.equal(typeof p.parameters.threshold, 'number');
    assert.equal(typeof p.parameters.roi.width, 'number');
    assert.equal(p.tracked, true, 'simulated planes are tracked');
    assert.ok(p.roadmap.count >= 1, 'the start-up roadmap counts');
  }
});

test('a change needs the imaged robot lease: viewer 403, another client 409', async () => {
  await holdLease();
  const viewer = await put('/imaging/segmentation/ap', {threshold: 41}, {headers: {'X-Tendril-Role': 'viewer'}});
  assertErrorShape(viewer, 403, 'forbidden_role');
  const other = script('imaging-other');
  const refused = await other.call('PUT', '/imaging/segmentation/ap', {body: {threshold: 41}});
  assertErrorShape(refused, 409, 'lease_held');
  const roadmap = await other.call('POST', '/imaging/roadmap/lateral', {body: {}});
  assertErrorShape(roadmap, 409, 'lease_held');
  const after = await get('/imaging/segmentation');
  assert.notEqual(after.json.planes.ap.parameters.threshold, 41, 'a refused change changes nothing');
});

test('bad requests: unknown plane 404, malformed JSON 400, a bad value 422 naming the field', async () => {
  await holdLease();
  assertErrorShape(await put('/imaging/segmentation/oblique', {threshold: 40}), 404, 'unknown_plane');
  assertErrorShape(await post('/imaging/roadmap/oblique', {}), 404, 'unknown_plane');
  const malformed = await call('PUT', '/imaging/segmentation/ap', {raw: '{"threshold": '});
  assert.equal(malformed.status, 400, malformed.text);
  assertErrorShape(await put('/imaging/segmentation/ap', [1, 2]), 400);  // not an object
  const before = (await get('/imaging/segmentation')).json.planes.ap.parameters;
  for (const [body, field] of [
    [{threshold: 999}, 'threshold'],
    [{threshold: 'high'}, 'threshold'],
    [{roi: {width: -4}}, 'roi.width'],
    [{roi: {x: 100000}}, 'roi.x'],
    [{canny_low: 300, canny_high: 100}, 'canny_low'],
    [{no_such_key: 1}, 'no_such_key'],
  ]) {
    const res = await put('/imaging/segmentation/ap', body);
    assertErrorShape(res, 422, 'invalid_parameter');
    assert.equal(res.json.error.field, field, `${JSON.stringify(body)}: ${res.text}`);
    assert.match(res.json.error.message, new RegExp(field.split('.').pop()), 'the message names the field');
  }
  const after = (await get('/imaging/segmentation')).json.planes.ap.parameters;
  assert.deepEqual(after, before, 'refused changes leave the parameters as they were');
  assertErrorShape(await call('DELETE', '/imaging/segmentation/ap'), 405);
  assertErrorShape(await call('PUT', '/imaging/segmentation', {body: {}}), 405);
});

test('a change and a roadmap are applied at the next tracked frame and published on /imaging/segmentation', async () => {
  await holdLease();
  const ws = new WebSocket(`${WS_URL}?token=${encodeURIComponent(TOKEN)}`, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
  const client = new FoxgloveClient({ws});
  const channels = new Map();
  const published = [];
  const decoder = new TextDecoder();
  client.on('advertise', (list) => list.forEach((c) => channels.set(c.topic, c)));
  try {
    assert.ok(await pollUntil(() => channels.has('/imaging/tracking') && channels.has('/imaging/segmentation'), {polls: 200}),
      `advertised: ${[...channels.keys()].join(', ')}`);
    assert.equal(channels.get('/imaging/segmentation').schemaName, 'tendril.SegmentationParameters');
    const segSub = client.subscribe(channels.get('/imaging/segmentation').id);
    client.on('message', (m) => {
      if (m.subscriptionId === segSub)
        published.push(JSON.parse(decoder.decode(new Uint8Array(m.data.buffer, m.data.byteOffset, m.data.byteLength))));
    });
    client.subscribe(channels.get('/imaging/tracking').id);  // the planes render and segment

    const current = (await get('/imaging/segmentation')).json.planes.lateral;
    const threshold = current.parameters.threshold === 33 ? 34 : 33;
    const res = await put('/imaging/segmentation/lateral', {threshold, canny_high: 110});
    assert.equal(res.status, 200, res.text);
    assert.equal(res.json.parameters.threshold, threshold);
    assert.equal(res.json.parameters.canny_high, 110);
    assert.equal(res.json.parameters.morphology_px, current.parameters.morphology_px, 'keys not sent are kept');
    const applied = await pollUntil(async () => {
      const g = await get('/imaging/segmentation');
      return g.json.planes.lateral.applied && g.json.planes.lateral.parameters.threshold === threshold ? g : undefined;
    }, {polls: 200});
    assert.ok(applied, 'the lateral plane applied the change');
    assert.ok(await pollUntil(() => published.some((m) => m.planes.lateral.parameters.threshold === threshold), {polls: 200}),
      'the applied change was published on /imaging/segmentation');

    const taken = await post('/imaging/roadmap/ap', {});
    assert.equal(taken.status, 202, taken.text);
    const ap = await pollUntil(async () => {
      const g = (await get('/imaging/segmentation')).json.planes.ap;
      return g.roadmap.count > applied.json.planes.ap.roadmap.count && !g.roadmap.pending ? g : undefined;
    }, {polls: 200});
    assert.ok(ap, 'the AP plane took the roadmap');
    assert.ok(await pollUntil(() => published.some((m) => m.planes.ap.roadmap.count === ap.roadmap.count), {polls: 200}),
      'the new roadmap was published on /imaging/segmentation');
  } finally {
    client.close();
  }
});
