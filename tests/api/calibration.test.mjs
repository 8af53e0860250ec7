// The shape calibration of Abah 2022, §4.5.2 over REST: pictures from the SIMULATED side-view camera
// at dq = 0.1 mm steps, a calibration job that fits the shape matrix from them, the new robot file
// it writes (never over an existing one), and the refusals.
import {test} from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import {ROBOT, get, post, assertErrorShape, pollUntil} from './helpers.mjs';

const R = `/robots/${ROBOT}`;

async function finished(id) {
  const job = await pollUntil(async () => {
    const res = await get(`/jobs/${id}`);
    assert.equal(res.status, 200, res.text);
    return ['succeeded', 'failed', 'cancelled'].includes(res.json.state) ? {done: true, ...res.json} : null;
  }, {polls: 600, intervalMs: 100});
  assert.ok(job && job.done, `job ${id} did not finish`);
  return job;
}

test('pictures of the simulated calibration camera fit a shape matrix and a new robot file', async () => {
  const images = [];
  let view;
  for (let k = 1; k <= 10; k++) {
    const res = await get(`${R}/calibration/side_view?segment=proximal&actuation_mm=${(0.1 * k).toFixed(1)}`);
    assert.equal(res.status, 200, res.text);
    view = res.json;
    assert.equal(view.simulated, true);
    assert.equal(view.format, 'png');
    assert.equal(Buffer.from(view.data, 'base64').subarray(1, 4).toString(), 'PNG');
    images.push({actuation_mm: view.actuation_mm, data: view.data});
  }
  const name = `srmc-calibrated-${process.pid}.json`;
  const submitted = await post(`${R}/calibrations`, {
    segment: 'proximal', images, mm_per_pixel: view.mm_per_pixel, straight_mm: view.straight_mm, save_as: name,
  });
  assert.equal(submitted.status, 202, submitted.text);
  assert.match(submitted.headers.get('location'), /^\/api\/v1\/jobs\//);
  const job = await finished(submitted.json.id);
  assert.equal(job.state, 'succeeded', job.message);
  assert.equal(job.kind, 'calibration');
  const r = job.result;
  assert.equal(r.shape_matrix.length, 4);
  assert.equal(r.shape_matrix[0].length, 2);
  assert.equal(r.pictures.length, 10);
  // The simulated bare tip is the robot file's constant curvature, k = 1.4 rad/mm over 22 mm: the
  // largest picture (q = 1 mm) bends ≈ 80°, and the fitted tip angle agrees.
  const tipBend = (q) => Math.PI / 2 - r.shape_matrix.reduce((sum, row, i) => sum + (row[0] + row[1] * q) * 22 ** i, 0);
  assert.ok(Math.abs(tipBend(1.0) - 1.4) < 0.01, `fitted tip bend at 1 mm: ${tipBend(1.0)} rad`);
  assert.ok(r.mean_abs_error_deg < 0.1, `mean fit error ${r.mean_abs_error_deg}°`);
  assert.ok(r.pictures.every((p) => Math.abs(p.tube_width_mm - 0.6) < 0.1), JSON.stringify(r.pictures[0]));
  // The new file holds the matrix; asking for the same name again is refused before any work.
  const written = JSON.parse(fs.readFileSync(r.written.file, 'utf8'));
  assert.deepEqual(written.catheter.model.proximal_shape_matrix, r.shape_matrix);
  const again = await post(`${R}/calibrations`, {segment: 'proximal', images: images.slice(0, 2), mm_per_pixel: 0.025, save_as: name});
  assertErrorShape(again, 409, 'file_exists');
});

test('calibration requests that cannot be fitted are refused with the key at fault', async () => {
  assertErrorShape(await post(`${R}/calibrations`, {samples: [[1, 0.1, 1.5]]}), 400, 'bad_request');
  assertErrorShape(await post(`${R}/calibrations`, {segment: 'proximal', images: [{actuation_mm: 0.1, data: '%%'}], mm_per_pixel: 0.02}), 400);
  assertErrorShape(await post(`${R}/calibrations`, {segment: 'distal', samples: [[1, 0.1, 1.5]], modal_order: 40}), 400);
  assertErrorShape(await post(`/robots/nope/calibrations`, {segment: 'distal', samples: [[1, 0.1, 1.5]]}), 404, 'unknown_robot');
  assertErrorShape(await get(`${R}/calibration/side_view?actuation_mm=7`), 422, 'out_of_range');
  assertErrorShape(await get(`${R}/calibration/side_view?segment=middle`), 400);
  const viewer = await post(`${R}/calibrations`, {segment: 'distal', samples: [[1, 0.1, 1.5]]}, {headers: {'X-Tendril-Role': 'viewer'}});
  assertErrorShape(viewer, 403, 'forbidden_role');
  // Too few samples for n·m = 8 unknowns: the job runs and fails, saying why.
  const few = await post(`${R}/calibrations`, {segment: 'distal', samples: [[1, 0.1, 1.5], [2, 0.2, 1.4]]});
  assert.equal(few.status, 202, few.text);
  const job = await finished(few.json.id);
  assert.equal(job.state, 'failed');
  assert.match(job.message, /sample/i);
});
