// Run by scripts/test-container.sh against the image as a lab runs it: the image's own configuration
// on a new named volume, nothing chmod-ed or chown-ed by the test. A catheter calibration saved through
// the API must land beside the robot files on that volume (it failed with "Permission denied" while
// the volume belonged to root). TENDRIL_CALIBRATION_FILE names the file to save.
import {test} from 'node:test';
import assert from 'node:assert/strict';
import {get, post, pollUntil} from '../api/helpers.mjs';

const R = '/robots/srmc';
const name = process.env.TENDRIL_CALIBRATION_FILE;

test('a calibration is saved on the image\'s configuration volume', {timeout: 120000}, async () => {
  assert.ok(name, 'set TENDRIL_CALIBRATION_FILE');
  const images = [];
  let view;
  for (let k = 1; k <= 10; k++) {
    const res = await get(`${R}/calibration/side_view?segment=proximal&actuation_mm=${(0.1 * k).toFixed(1)}`);
    assert.equal(res.status, 200, res.text);
    view = res.json;
    images.push({actuation_mm: view.actuation_mm, data: view.data});
  }
  const submitted = await post(`${R}/calibrations`, {
    segment: 'proximal', images, mm_per_pixel: view.mm_per_pixel, straight_mm: view.straight_mm, save_as: name,
  });
  assert.equal(submitted.status, 202, submitted.text);
  const job = await pollUntil(async () => {
    const res = await get(`/jobs/${submitted.json.id}`);
    assert.equal(res.status, 200, res.text);
    return ['succeeded', 'failed', 'cancelled'].includes(res.json.state) ? res.json : null;
  }, {polls: 600, intervalMs: 100});
  assert.ok(job, 'the calibration job did not finish');
  assert.equal(job.state, 'succeeded', job.message);
  assert.equal(job.result.written.file, `/opt/tendril/config/robots/${name}`);
});
