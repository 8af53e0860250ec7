// Browser test of the sdu_continuum panel (web/continuum.js) against a tendrild serving the SIMULATED
// continuum robot with sensing disk units (config/robots/sdu_continuum.json) beside the catheter
// (issue 16's scenario from the console): take the lease, enable, command motion toward the SIMULATED
// human arm, press Approach: the speed-scale factor falls as the arm comes near, then the robot stops on
// contact and the panel names the disk and the angular slot. Screenshot: tests/e2e/artifacts/continuum.png.
// Env: TENDRIL_URL, TENDRIL_TOKEN (tests/e2e/run.sh starts the server with config/robots/sdu_continuum.json).
import {test, before, after} from 'node:test';
import assert from 'node:assert/strict';
import path from 'node:path';
import {ARTIFACTS, WAIT, openBrowser, serverUnderTest, tid} from './browser.mjs';

const {BASE_URL, TOKEN} = serverUnderTest();
const SCENARIO_WAIT = {timeout: 180000};  // the SIMULATED arm's approach on a sanitized server, two shared cores
const ROBOT = process.env.TENDRIL_SDU_ROBOT || 'sdu';

let context;
let page;
let closeBrowser;
const pageErrors = [];

before(async () => {
  ({context, page, close: closeBrowser} = await openBrowser('sdu', {width: 1280, height: 900}));
  page.on('pageerror', (err) => pageErrors.push(err.message));
});

after(async () => {
  await closeBrowser?.();
});

const panel = () => page.evaluate(() => {
  const q = (id) => document.querySelector(`[data-testid="${id}"]`);
  return {
    supervisor: q('continuum-supervisor')?.dataset.state, reason: q('continuum-reason')?.textContent,
    scale: Number(q('continuum-speed-scale')?.dataset.value), contact: q('continuum-contact')?.dataset.contact,
    disk: q('continuum-contact')?.dataset.disk, slot: q('continuum-contact')?.dataset.slot,
    text: q('continuum-contact')?.textContent, status: q('command-status')?.textContent,
  };
});

test('the continuum scenario from the console: approach slows the robot, touch stops it, disk and slot shown', async () => {
  await page.goto(`${BASE_URL}/?token=${encodeURIComponent(TOKEN)}`);
  await page.waitForFunction((r) => [...document.querySelectorAll('[data-testid="robot-select"] option')].some((o) => o.value === r),
    ROBOT, WAIT);
  await page.locator(tid('robot-select')).selectOption(ROBOT);
  await page.locator(`${tid('tab-robot')}:not([hidden])`).waitFor(WAIT);
  assert.equal((await page.locator(tid('tab-robot')).textContent()).trim(), 'Continuum');
  await page.click(tid('tab-robot'));
  // The live state arrives: the supervisor's state and the speed scale with nothing near.
  await page.waitForFunction(() => document.querySelector('[data-testid="continuum-supervisor"]').dataset.state, null, WAIT);
  await page.waitForFunction(() => document.querySelectorAll('[data-testid^="continuum-disk-"]').length >= 5, null, WAIT);

  await page.locator('#lease-button').click();
  await page.waitForFunction((r) => new RegExp(`lease: yours \\(${r}\\)`).test(
    document.querySelector('[data-testid="lease-status"]').textContent), ROBOT, WAIT);
  // The SIMULATED arm starts from its configured place.
  await page.waitForFunction(() => !document.querySelector('[data-testid="continuum-arm-reset"]').disabled, null, WAIT);
  await page.click(tid('continuum-arm-reset'));
  await page.waitForFunction(() => !document.querySelector('[data-testid="enable-button"]').disabled, null, WAIT);
  await page.click(tid('enable-button'));
  await page.waitForFunction(() => document.querySelector('[data-testid="state-badge"]').textContent.includes('ENABLED'), null, WAIT);
  const before = await panel();
  assert.equal(before.contact, 'false', JSON.stringify(before));

  // Command motion toward the arm: bend the segment (the joint panel's goal in rad, and Move).
  await page.click(tid('tab-joints'));
  // The Joints tab shows and takes a revolute joint in degrees (web/joints.js); the goal is given in rad.
  const bendDeg = Number(process.env.TENDRIL_SDU_BEND_RAD || 0.4) * 180 / Math.PI;
  await page.fill(tid('joint-goal-bending'), bendDeg.toFixed(1));
  await page.click(tid('move-button'));
  await page.click(tid('tab-robot'));

  // The arm approaches: the speed scale falls below 1 (slowed by proximity) …
  await page.fill(tid('continuum-arm-speed'), '20');
  await page.click(tid('continuum-arm-approach'));
  await page.waitForFunction(() => Number(document.querySelector('[data-testid="continuum-speed-scale"]').dataset.value) < 0.9,
    null, SCENARIO_WAIT);
  const slowed = await panel();
  assert.ok(slowed.scale < 0.9, JSON.stringify(slowed));
  // … and on touch the robot stops: contact on a disk and a slot, the supervisor says why.
  await page.waitForFunction(() => document.querySelector('[data-testid="continuum-contact"]').dataset.contact === 'true',
    null, SCENARIO_WAIT);
  await page.waitForFunction(() => /stop/.test(document.querySelector('[data-testid="continuum-supervisor"]').dataset.state),
    null, WAIT);
  const stopped = await panel();
  assert.match(stopped.disk, /^\d+$/, JSON.stringify(stopped));
  assert.match(stopped.slot, /^\d+$/, JSON.stringify(stopped));
  assert.match(stopped.text, /CONTACT on disk \d+, slot \d+/);
  assert.ok(stopped.reason.length > 0, 'the supervisor gives a reason');
  // The panel's angle of the contact slot is the server's (the Hall windows sit between the ToF ones).
  const server = /Hall (\d+) \(([\d.]+) deg\)/.exec(stopped.reason);
  const shown = /slot (\d+) \(([\d.]+)°\)/.exec(stopped.text);
  assert.ok(server && shown, JSON.stringify(stopped));
  if (server[1] === shown[1]) assert.equal(Number(shown[2]), Number(server[2]), JSON.stringify(stopped));
  assert.ok(stopped.scale <= slowed.scale, JSON.stringify({slowed, stopped}));
  const row = page.locator(tid(`continuum-disk-${stopped.disk}`));
  assert.equal(await row.getAttribute('data-contact'), 'true');
  // The 3D view shows the contact slot's marker: a large red sphere on the contact disk's ring.
  const marker = await page.evaluate(() => {
    const view = window.tendrilLive.view();
    const disks = view.entities.get('continuum-panel/disks');
    const big = disks.children.filter((c) => c.type === 'Mesh' && c.scale.x > 20);
    return big.map((m) => ({r: m.material.color.r, g: m.material.color.g}));
  });
  assert.equal(marker.length, 1, `one contact marker: ${JSON.stringify(marker)}`);
  assert.ok(marker[0].r > 0.9 && marker[0].g < 0.3, JSON.stringify(marker));
  await page.locator(tid('continuum-supervisor')).scrollIntoViewIfNeeded();
  await page.evaluate(() => window.tendrilLive.view().fit());
  await page.waitForTimeout(1500);  // a frame of the software renderer
  // The page keeps up with the stream while the robot is held on the contact (no STALE).
  await page.waitForFunction(() => document.querySelector('[data-testid="age-joints"]').dataset.stale === 'false', null, WAIT);
  await page.screenshot({path: path.join(ARTIFACTS, 'continuum.png')});

  // The way out from the console: holding Roll ▶ rolls the segment along the contact (the robot stays
  // held; the no-slip roll is the one motion allowed besides backing away), releasing it stops the roll.
  const measured = async () => (await (await fetch(`${BASE_URL}/api/v1/robots/${ROBOT}/measured_js`, {
    headers: {Authorization: `Bearer ${TOKEN}`}})).json()).position;
  // A page that goes STALE while the button is held ends the roll (and disables the button) until
  // the button is pressed again: a loaded two-core machine does that (a cold CI run saw no motion at
  // all). The test presses again then, as an operator would, at most 5 times, and prints each; a roll
  // that does not move while the page stayed fresh fails at once. Only the page's own staleness (the
  // console's load on the browser, issue 31) is pressed through: the robot must be in its contact hold
  // (PAUSED), never in FAULT, before each press, else the test fails with the fault.
  const roll = page.locator(tid('continuum-roll-plus'));
  const robotState = async () => (await (await fetch(`${BASE_URL}/api/v1/robots/${ROBOT}/operating_state`, {
    headers: {Authorization: `Bearer ${TOKEN}`}})).json());
  let q0, q1, moved = 0;
  for (let attempt = 1; attempt <= 5 && !(moved > 0.005); attempt++) {
    const st = await robotState();
    assert.notEqual(st.state, 'FAULT', `before roll attempt ${attempt} the robot faulted: ${JSON.stringify(st.fault)}, ` +
                    `loop timing ${JSON.stringify(st.loop_timing)}`);
    await page.waitForFunction(() => !document.querySelector('[data-testid="continuum-roll-plus"]').disabled, null, WAIT);
    q0 = await measured();
    await roll.hover();
    await page.mouse.down();
    // Every change of the page's freshness and of the roll button while held, for 1.5 s.
    const held = await page.evaluate(async () => {
      const age = document.querySelector('[data-testid="age-joints"]');
      const button = document.querySelector('[data-testid="continuum-roll-plus"]');
      const seen = {stale: age.dataset.stale !== 'false', disabled: button.disabled};
      const observer = new MutationObserver(() => {
        seen.stale ||= age.dataset.stale !== 'false';
        seen.disabled ||= button.disabled;
      });
      observer.observe(age, {attributes: true, attributeFilter: ['data-stale']});
      observer.observe(button, {attributes: true, attributeFilter: ['disabled']});
      await new Promise((done) => setTimeout(done, 1500));
      observer.disconnect();
      return seen;
    });
    await page.mouse.up();
    await page.waitForTimeout(500);  // the stream's end reaches the robot
    q1 = await measured();
    moved = Math.max(...q1.map((v, i) => Math.abs(v - q0[i])));
    if (moved > 0.005) break;
    const status = await page.locator(tid('command-status')).textContent();
    assert.ok(held.stale || held.disabled,
        `the roll moved the joints while the page stayed fresh: ${JSON.stringify({q0, q1, status})}`);
    console.log(`# roll attempt ${attempt}: no motion; while held the page was ${held.stale ? 'STALE' : 'fresh'}, ` +
                `the button ${held.disabled ? 'disabled' : 'enabled'}; status "${status}"`);
  }
  assert.ok(moved > 0.005, `the roll moved the joints: ${JSON.stringify({q0, q1})}`);
  assert.notEqual((await robotState()).state, 'FAULT', JSON.stringify((await robotState()).fault));
  await page.waitForTimeout(500);
  const q2 = await measured();
  const after = Math.max(...q2.map((v, i) => Math.abs(v - q1[i])));
  assert.ok(after < 0.002, `released, the roll stopped: ${JSON.stringify({q1, q2})}`);

  // Retreat: the arm leaves (the robot stays stopped until the operator acts; the panel keeps the cause).
  // Retreat: pressed as soon as the page has fresh data (the button is disabled while the page is
  // STALE, which a loaded two-core machine makes happen for seconds at a time).
  const pressed = await page.waitForFunction(() => {
    const b = document.querySelector('[data-testid="continuum-arm-retreat"]');
    if (b.disabled) return false;
    b.click();
    return true;
  }, null, {timeout: 60000, polling: 100}).then(() => true, () => false);
  assert.ok(pressed, `Retreat stayed disabled for 60 s: ${await page.locator(tid('continuum-hint')).textContent()}`);
  await page.waitForFunction(() => /retreat/.test(document.querySelector('[data-testid="continuum-arm"]').textContent), null, WAIT);
  assert.deepEqual(pageErrors, []);
});
