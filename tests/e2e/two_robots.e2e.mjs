// Browser test of the console against a tendrild serving two robots (the set-up of Heunis et al. 2021: the SIMULATED
// catheter and the SIMULATED UR5 arm). The robot selector lists both; choosing one rebuilds the joint
// panel and the mode bar from that robot's description, and the lease badge shows that robot's own
// lease: the console holds the catheter's while a lab engineer's script holds the arm's.
// Env: TENDRIL_URL, TENDRIL_TOKEN (tests/e2e/run.sh starts the server with config/robots/ur5_arm.json).
import {test, before, after} from 'node:test';
import assert from 'node:assert/strict';
import path from 'node:path';
import {ARTIFACTS, WAIT, openBrowser, serverUnderTest, tid} from './browser.mjs';

const {BASE_URL, TOKEN} = serverUnderTest();

let context;
let page;
let closeBrowser;
const pageErrors = [];

// The lab engineer's script: REST with a lease token of its own.
const engineer = {leaseToken: 'new'};
async function engineerCall(method, urlPath, body) {
  const res = await fetch(`${BASE_URL}/api/v1${urlPath}`, {
    method,
    headers: {'Authorization': `Bearer ${TOKEN}`, 'Content-Type': 'application/json',
              'X-Tendril-Client': 'lab-engineer', 'X-Tendril-Lease': engineer.leaseToken},
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  const json = await res.json().catch(() => null);
  return {status: res.status, json};
}

before(async () => {
  ({context, page, close: closeBrowser} = await openBrowser('two'));
  page.on('pageerror', (err) => pageErrors.push(err.message));
});

after(async () => {
  await engineerCall('DELETE', '/lease').catch(() => {});
  await closeBrowser?.();
});

const leaseBadge = () => page.locator(tid('lease-status'));

test('the robot selector shows the catheter and the arm; each has its own joints, modes and lease', async () => {
  const granted = await engineerCall('POST', '/robots/ur5/lease', {});
  assert.equal(granted.status, 200, JSON.stringify(granted.json));
  engineer.leaseToken = granted.json.lease_token;

  await page.goto(`${BASE_URL}/?token=${encodeURIComponent(TOKEN)}`);
  await page.waitForFunction(() => document.querySelectorAll('[data-testid="robot-select"] option').length === 2,
    null, WAIT);
  const options = await page.locator(`${tid('robot-select')} option`).allTextContents();
  assert.deepEqual(options, ['srmc', 'ur5']);
  // The catheter first: four joints, its own modes, and its lease free.
  await page.waitForSelector(tid('joint-row-insertion'), WAIT);
  assert.equal(await page.locator('[data-testid^="joint-row-"]').count(), 4);
  assert.equal(await page.locator(tid('scene-title')).textContent(), 'Steerable catheter shape');
  await page.waitForFunction(() => /lease: free \(srmc\)/.test(document.querySelector('[data-testid="lease-status"]').textContent),
    null, WAIT);
  await page.locator('#lease-button').click();
  await page.waitForFunction(() => /lease: yours \(srmc\)/.test(document.querySelector('[data-testid="lease-status"]').textContent),
    null, WAIT);

  // The arm: six joints in rad, its modes, and the engineer's lease shown as someone else's.
  await page.locator(tid('robot-select')).selectOption('ur5');
  await page.waitForSelector(tid('joint-row-shoulder_pan'), WAIT);
  assert.equal(await page.locator('[data-testid^="joint-row-"]').count(), 6);
  assert.equal(await page.locator(tid('joint-row-insertion')).count(), 0, 'the catheter\'s joints are gone');
  assert.match(await page.locator(tid('robot-kind')).textContent(), /serial arm/);
  assert.equal(await page.locator(tid('scene-title')).textContent(), 'Serial arm shape');
  const modes = await page.locator('#mode-buttons button[data-mode]').evaluateAll((bs) => bs.map((b) => b.dataset.mode));
  assert.deepEqual(modes, ['joint', 'cartesian']);
  await page.waitForFunction(() => {
    const badge = document.querySelector('[data-testid="lease-status"]');
    return badge.classList.contains('other') && /lease: other operator \(ur5\)/.test(badge.textContent);
  }, null, WAIT);
  assert.match(await leaseBadge().getAttribute('title'), /the operator lease is held by client:lab-engineer/);
  await page.waitForFunction(() => document.querySelector('[data-testid="joint-measured-shoulder_pan"]').textContent !== '—',
    null, WAIT);
  await page.screenshot({path: path.join(ARTIFACTS, 'two-robots-arm-1280x800.png')});

  // Taking the lease here asks for the arm's lease only: the console is offered a takeover, and cancels.
  await page.locator('#lease-button').click();
  await page.locator(`${tid('takeover-dialog')}[open]`).waitFor(WAIT);
  assert.match(await page.locator(tid('takeover-text')).textContent(), /operator lease of ur5 is held by client:lab-engineer/);
  await page.locator(tid('takeover-cancel-button')).click();
  const arm = await engineerCall('GET', '/robots/ur5/lease');
  assert.equal(arm.json.mine, true, 'the engineer still holds the arm');

  // Back to the catheter: the console still holds its lease, which the engineer's script cannot use.
  await page.locator(tid('robot-select')).selectOption('srmc');
  await page.waitForFunction(() => /lease: yours \(srmc\)/.test(document.querySelector('[data-testid="lease-status"]').textContent),
    null, WAIT);
  const refused = await engineerCall('POST', '/robots/srmc/state_command', {command: 'enable'});
  assert.equal(refused.status, 409);
  assert.equal(refused.json.error.code, 'lease_held');
  assert.deepEqual(pageErrors, []);
});
