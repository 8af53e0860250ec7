// Browser test of the Tip tab (web/tip_control.js, issue 31 item 7) against a tendrild serving the
// catheter, the SIMULATED UR5 arm, the variable-diameter robot and the continuum robot: in each robot's
// Cartesian mode the tip's position is shown, a held jog button moves it along its axis and it stops on
// release (and on E-STOP), a typed goal is previewed and Go brings the tip there within the robot's
// tolerance; the arm's measured force is shown and changes when the tool presses the SIMULATED tissue.
// A disabled control says why. Screenshots at 1280 and 2560 px: tests/e2e/artifacts/tip-*.png.
// Env: TENDRIL_URL, TENDRIL_TOKEN (tests/e2e/run.sh starts the server with the three robot files).
import {test, before, after} from 'node:test';
import assert from 'node:assert/strict';
import path from 'node:path';
import {ARTIFACTS, WAIT, openBrowser, serverUnderTest, tid, clickWhenEnabled} from './browser.mjs';

const {BASE_URL, TOKEN} = serverUnderTest();
// A bound on a hung server only: the robot's own clock times the moves (simulated time runs slower than
// this machine's clock when it is loaded).
const HANG_MS = 180000;

let page;
let closeBrowser;
const pageErrors = [];

before(async () => {
  ({page, close: closeBrowser} = await openBrowser('tip', {width: 1280, height: 900}));
  page.on('pageerror', (err) => pageErrors.push(err.message));
  await page.goto(`${BASE_URL}/?token=${encodeURIComponent(TOKEN)}`);
  await page.waitForFunction(() => document.querySelectorAll('[data-testid="robot-select"] option').length === 4, null, WAIT);
});

after(async () => {
  await closeBrowser?.();
});

async function rest(urlPath) {
  const res = await fetch(`${BASE_URL}/api/v1${urlPath}`, {headers: {Authorization: `Bearer ${TOKEN}`}});
  return res.json();
}
const tipOf = async (robot) => (await rest(`/robots/${robot}/measured_cp`)).position;
const text = async (id) => (await page.locator(tid(id)).textContent()).trim();

// Select the robot, open its Tip tab, take its lease, enable it and switch to its Cartesian mode; the
// jog and Go say why they are disabled on the way.
async function ready(robot, mode, tabLabel) {
  await page.locator(tid('robot-select')).selectOption(robot);
  await page.locator(`${tid('tab-cartesian')}:not([hidden])`).waitFor(WAIT);
  assert.equal(await text('tab-cartesian'), tabLabel);
  await page.click(tid('tab-cartesian'));
  await page.waitForFunction(() => document.querySelector('[data-testid="cart-position"]').dataset.z, null, WAIT);
  assert.match(await text('cart-jog-why'), /Take the lease/);
  assert.equal(await page.locator(tid('cart-jog-z-plus')).isDisabled(), true);
  await page.locator('#lease-button').click();
  await page.waitForFunction((r) => new RegExp(`lease: yours \\(${r}\\)`).test(
    document.querySelector('[data-testid="lease-status"]').textContent), robot, WAIT);
  // The mode first (it may be chosen while disabled), then Enable.
  const Mode = `${mode[0].toUpperCase()}${mode.slice(1)}`;
  await page.waitForFunction((m) => document.querySelector('[data-testid="cart-jog-why"]').textContent
    .includes(`Press the ${m} mode button, then Enable`), Mode, WAIT);
  await clickWhenEnabled(page, tid(`mode-${mode}`));
  await page.waitForFunction((m) => document.querySelector(`[data-testid="mode-${m}"]`).getAttribute('aria-pressed') === 'true', mode, WAIT);
  await page.waitForFunction(() => /Enable the robot first/.test(document.querySelector('[data-testid="cart-jog-why"]').textContent), null, WAIT);
  await clickWhenEnabled(page, tid('enable-button'));
  await page.waitForFunction(() => document.querySelector('[data-testid="state-badge"]').dataset.state === 'ENABLED', null, WAIT);
  // The drives switch on in the robot's time, which runs slower than the wall clock on a loaded machine
  // (simulated time): bounded like a move, by HANG_MS.
  await page.waitForFunction(() => !document.querySelector('[data-testid="cart-jog-x-plus"]').disabled, null, {timeout: HANG_MS}).catch(async (err) => {
    err.message += `; ${await text('cart-jog-why')}; status: ${await text('command-status')}`;
    throw err;
  });
  assert.equal(await text('cart-jog-why'), '');
}

// The tip's measured position and the robot's time stamp (s): in simulated time the robot's clock, not
// this machine's, says how long a jog ran (a loaded machine slows simulated time down).
const sampleOf = async (robot) => {
  const cp = await rest(`/robots/${robot}/measured_cp`);
  return {p: cp.position, t: cp.timestamp};
};
async function sampleAfter(robot, from, seconds) {
  const deadline = Date.now() + HANG_MS;
  let s = await sampleOf(robot);
  while (s.t < from.t + seconds && Date.now() < deadline) {
    await page.waitForTimeout(100);
    s = await sampleOf(robot);
  }
  assert.ok(s.t >= from.t + seconds, `the robot's clock ran ${seconds} s in ${HANG_MS / 1000} s`);
  return s;
}

// Presses a jog button in the page task that sees it enabled (as clickWhenEnabled does for a click: a
// page that turns STALE between a check and a press disables the button under the pointer), and lets
// it go.
const press = (selector) => page.waitForFunction((sel) => {
  const b = document.querySelector(sel);
  if (!b || b.disabled) return false;
  b.dispatchEvent(new PointerEvent('pointerdown', {bubbles: true}));
  return true;
}, selector, WAIT);
const release = (selector) => page.evaluate((sel) => {
  document.querySelector(sel).dispatchEvent(new PointerEvent('pointerup', {bubbles: true}));
}, selector);

// Holds a jog button until the tip has moved 2 mm along its axis, then releases it: the tip moved that
// way, no faster than the chosen speed, little off the axis, and is still once released.
async function jog(robot, axis, sign, speedMmS) {
  const index = {x: 0, y: 1, z: 2}[axis];
  await page.selectOption(tid('cart-jog-speed'), String(speedMmS));
  const s0 = await sampleOf(robot);
  const button = tid(`cart-jog-${axis}-${sign > 0 ? 'plus' : 'minus'}`);
  await press(button);
  await page.waitForFunction(() => document.querySelector('[data-testid="cart-panel"]').dataset.jogging === 'true', null, WAIT);
  let s = s0;
  let stale = false;
  const deadline = Date.now() + HANG_MS;
  let held = {};
  while (sign * (s.p[index] - s0.p[index]) < 2.0 && Date.now() < deadline) {
    await page.waitForTimeout(100);
    s = await sampleOf(robot);
    held = await page.evaluate(() => ({stale: document.body.dataset.stale, ...document.querySelector('[data-testid="cart-panel"]').dataset}));
    stale ||= held.stale === 'true';
    if (held.jogging !== 'true') break;  // the page ended the jog while held: the assertion below says why
  }
  await release(button);
  const jogging = await page.locator(tid('cart-panel')).getAttribute('data-jogging');
  const why = await text('cart-jog-why');
  const status = await text('command-status');
  assert.equal(jogging, 'false');
  assert.equal(await page.locator(tid('cart-panel')).getAttribute('data-jog-ended'), 'released');
  const released = await sampleOf(robot);
  const s1 = await sampleAfter(robot, released, 0.6);  // the zero twist and the deceleration
  const s2 = await sampleAfter(robot, s1, 0.5);
  const moved = s1.p.map((v, i) => v - s0.p[i]);
  const info = JSON.stringify({s0, released, s1, s2, stale, why, status, whileHeld: held});
  assert.ok(sign * moved[index] >= 2.0, `held, the tip moved 2 mm along ${axis} ${sign > 0 ? '+' : '−'}: ${info}`);
  assert.ok(Math.abs(moved[index]) <= speedMmS * (s1.t - s0.t) + 0.5, `no faster than ${speedMmS} mm/s: ${info}`);
  for (let i = 0; i < 3; ++i) {
    if (i !== index) assert.ok(Math.abs(moved[i]) < Math.max(1.0, 0.25 * Math.abs(moved[index])), `little off ${axis}: ${info}`);
  }
  // Jogging on, it would cover 2.5 mm in 0.5 s.
  assert.ok(Math.hypot(...s2.p.map((v, i) => v - s1.p[i])) < 0.3, `released, the tip stopped: ${info}`);
  return moved;
}

// Types a goal, checks the preview, presses Go and waits until the tip is there within tolerance.
async function goTo(robot, goal, toleranceMm) {
  for (const [i, axis] of ['x', 'y', 'z'].entries()) await page.fill(tid(`cart-goal-${axis}`), goal[i].toFixed(1));
  const preview = await text('cart-preview');
  assert.match(preview, /^will move: x [+−][\d.]+, y [+−][\d.]+, z [+−][\d.]+ mm \([\d.]+ mm in a straight line\), orientation kept$/);
  await clickWhenEnabled(page, tid('cart-go'));
  await page.waitForFunction(() => /moving to|refused/.test(document.querySelector('[data-testid="command-status"]').textContent), null, WAIT);
  assert.match(await text('command-status'), /moving to/);
  // Until the tip is there, or 10 s of the robot's time (the longest of these moves takes about 4 s).
  const start = await sampleOf(robot);
  let s = start;
  const deadline = Date.now() + HANG_MS;
  while (Math.hypot(...s.p.map((v, i) => v - goal[i])) > toleranceMm && s.t < start.t + 10 && Date.now() < deadline) {
    await page.waitForTimeout(250);
    s = await sampleOf(robot);
  }
  assert.ok(Math.hypot(...s.p.map((v, i) => v - goal[i])) <= toleranceMm,
            `Go reached ${JSON.stringify(goal)} in ${(s.t - start.t).toFixed(1)} s of the robot's time: ${JSON.stringify(s.p)}`);
  return preview;
}

test('the arm in Cartesian mode: the tool position, Go, a jog that stops on release and on E-STOP, the force', async () => {
  await ready('ur5', 'cartesian', 'Tool');
  assert.match(await text('cart-go-why'), /Type a goal position/);
  const p0 = await tipOf('ur5');
  // The shown position is the measured one (to 0.1 mm, the arm at rest).
  const shown = await page.evaluate(() => ['x', 'y', 'z'].map((a) => Number(document.querySelector('[data-testid="cart-position"]').dataset[a])));
  assert.ok(Math.hypot(...shown.map((v, i) => v - p0[i])) < 0.5, JSON.stringify({shown, p0}));

  // Down onto the SIMULATED tissue (surface at z 150 mm, 0.5 N/mm): the preview says what will move
  // before anything does; Go takes the tool there within the arm's 1 mm goal tolerance. In free space
  // the contact force is the sensor's noise; 2 mm into the tissue it reads about 1 N, under the 3 N limit.
  await page.waitForFunction(() => document.querySelector('[data-testid="cart-force"]').dataset.value !== undefined, null, WAIT);
  const forceFree = Number(await page.locator(tid('cart-force')).getAttribute('data-value'));
  assert.ok(forceFree < 0.3, `free space ${forceFree} N`);
  assert.match(await page.locator('.rp-group', {has: page.locator(tid('cart-force'))}).locator('h3').textContent(), /limit 3\.0 N/);
  const preview = await goTo('ur5', [p0[0], p0[1], 148], 1.0);
  assert.match(preview, new RegExp(`z −${(p0[2] - 148).toFixed(1)} mm`));
  await page.waitForFunction(() => Number(document.querySelector('[data-testid="cart-force"]').dataset.value) > 0.6, null, WAIT);
  const forcePressed = Number(await page.locator(tid('cart-force')).getAttribute('data-value'));
  assert.ok(forcePressed < 3.0, `pressed ${forcePressed} N`);
  await page.waitForTimeout(1200);  // a few samples in the plot
  assert.equal(await page.locator(tid('cart-force-plot')).getAttribute('data-available'), 'true');
  await page.screenshot({path: path.join(ARTIFACTS, 'tip-arm-1280.png')});
  await page.setViewportSize({width: 2560, height: 1300});
  await page.waitForTimeout(800);
  await page.screenshot({path: path.join(ARTIFACTS, 'tip-arm-2560.png')});
  await page.setViewportSize({width: 1280, height: 900});

  // Jogged up off the tissue, the force falls back to noise.
  const moved = await jog('ur5', 'z', 1, 5);
  console.log(`# arm jog z+ at 5 mm/s: ${moved.map((v) => v.toFixed(2)).join(', ')} mm`);
  await page.waitForFunction(() => Number(document.querySelector('[data-testid="cart-force"]').dataset.value) < 0.3, null, WAIT);

  // E-STOP while a jog button is held: the stream ends at once and the button says why.
  await press(tid('cart-jog-x-plus'));
  await page.waitForFunction(() => document.querySelector('[data-testid="cart-panel"]').dataset.jogging === 'true', null, WAIT);
  await page.evaluate(() => document.querySelector('#estop-button').click());
  await page.waitForFunction(() => document.querySelector('[data-testid="cart-panel"]').dataset.jogging === 'false', null, WAIT);
  assert.match(await text('cart-jog-why'), /E-STOP latched/);
  await release(tid('cart-jog-x-plus'));
  const e1 = await sampleAfter('ur5', await sampleOf('ur5'), 0.3);
  const e2 = await sampleAfter('ur5', e1, 0.5);
  assert.ok(Math.hypot(...e2.p.map((v, i) => v - e1.p[i])) < 0.3, `after the E-STOP the tool is still: ${JSON.stringify({e1, e2})}`);
  await clickWhenEnabled(page, tid('estop-reset-button'));
  await page.waitForFunction(() => document.querySelector('[data-testid="state-badge"]').dataset.estop === 'false', null, WAIT);
  assert.deepEqual(pageErrors, []);
});

test('the variable-diameter robot in task mode: Go to a typed tip position, and a jog', async () => {
  await ready('mbcr', 'task', 'Tip');
  const p0 = await tipOf('mbcr');
  // 20 mm sideways and 10 mm down from the straight robot (at full length it cannot go sideways only);
  // the robot's goal tolerance is 1 mm.
  await goTo('mbcr', [p0[0] + 20, p0[1], p0[2] - 10], 1.0);
  const moved = await jog('mbcr', 'y', 1, 5);
  console.log(`# mbcr jog y+ at 5 mm/s: ${moved.map((v) => v.toFixed(2)).join(', ')} mm`);
  assert.deepEqual(pageErrors, []);
});

test('the continuum robot in tip mode: Go says why it is not offered, a jog moves the tip', async () => {
  await ready('sdu', 'tip', 'Tip');
  assert.equal(await page.locator(tid('cart-go')).isDisabled(), true);
  assert.match(await text('cart-go-why'), /takes no goal position.*Jog it instead/);
  const moved = await jog('sdu', 'y', -1, 5);
  console.log(`# sdu jog y− at 5 mm/s: ${moved.map((v) => v.toFixed(2)).join(', ')} mm`);
  await page.screenshot({path: path.join(ARTIFACTS, 'tip-continuum-1280.png')});
  assert.deepEqual(pageErrors, []);
});
