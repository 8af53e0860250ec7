// Browser test of the ultrasound arm's panel (web/ultrasound.js) against a tendrild serving the
// SIMULATED catheter (srmc) and the SIMULATED ultrasound arm (us_arm, config/robots/us_arm.json) in one
// server (issue 17): a sweep from the console end to end — plan, preview, pre-position, start, every
// via-point acquired with B-mode images and the fitted ellipse arriving, done — WHILE this test drives
// the catheter over REST with a lease of its own (a second operator's script). The 3D view is fixed to
// the tissue frame through /tf. Screenshot: tests/e2e/artifacts/ultrasound.png. The server runs in
// simulated time (tests/e2e/run.sh: tendrild --simulated-time), where a stall of this shared machine
// slips simulated time and can neither fault nor hold the arm: a hold, a FAULT or a time-out fails the
// test with what the page and the server showed. Nothing is retried past one.
// Env: TENDRIL_URL, TENDRIL_TOKEN (tests/e2e/run.sh starts the server with config/robots/us_arm.json).
import {test, before, after} from 'node:test';
import assert from 'node:assert/strict';
import path from 'node:path';
import {ARTIFACTS, WAIT, tid, openBrowser, serverUnderTest} from './browser.mjs';

const {BASE_URL, TOKEN} = serverUnderTest();
const SWEEP_WAIT = {timeout: 240000};  // a sanitized server and a software renderer on two shared cores
const ARM = process.env.TENDRIL_US_ARM || 'us_arm';
const CATHETER = 'srmc';

let browser;
let page;
const pageErrors = [];

// The catheter's operator: REST with its own lease token.
const driver = {leaseToken: 'new'};
async function driverCall(method, urlPath, body) {
  const res = await fetch(`${BASE_URL}/api/v1${urlPath}`, {
    method,
    headers: {'Authorization': `Bearer ${TOKEN}`, 'Content-Type': 'application/json',
              'X-Tendril-Client': 'catheter-driver', 'X-Tendril-Lease': driver.leaseToken},
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  const json = await res.json().catch(() => null);
  return {status: res.status, json};
}

before(async () => {
  browser = await openBrowser('us', {width: 1280, height: 900});
  page = browser.page;
  page.on('pageerror', (err) => pageErrors.push(err.message));
});

after(async () => {
  await driverCall('DELETE', '/lease').catch(() => {});
  await browser?.close();
});

const sweepState = () => page.evaluate(() => {
  const q = (id) => document.querySelector(`[data-testid="${id}"]`);
  return {
    phase: q('us-phase')?.dataset.phase, progress: Number(q('us-progress')?.dataset.value),
    slices: Number(q('us-via-point')?.dataset.slices), viaPoint: q('us-via-point')?.dataset.viaPoint,
    frames: Number(q('us-image')?.dataset.frames), ellipse: Number(q('us-ellipse')?.dataset.shapes || 0),
    message: q('us-message')?.textContent, status: q('command-status')?.textContent,
  };
});

// The arm as the server sees it: state, hold and fault with their causes, loop timing.
async function armState() {
  const s = (await driverCall('GET', `/robots/${ARM}/operating_state`)).json ?? {};
  // The event log's newest holds and faults carry the full text (which device, how long; or how late).
  const events = ((await driverCall('GET', '/faults')).json ?? []).filter((e) => ['hold', 'fault'].includes(e.kind));
  return {state: s.state, mode: s.mode, hold: s.hold ?? null, fault: s.fault ?? null, loop_timing: s.loop_timing,
          calibration: s.calibration, sweep: s.sweep && {phase: s.sweep.phase, message: s.sweep.message},
          events: events.slice(0, 3)};
}

// Fails, with what the page and the server show and a screenshot, when the arm is held or faulted: in
// simulated time no stall of the machine can cause either, so it is a failure of the logic.
async function failOnHoldOrFault(when) {
  const badge = await page.locator(tid('state-badge')).textContent();
  if (!/PAUSED|FAULT|E-STOP/.test(badge)) return;
  await page.screenshot({path: path.join(ARTIFACTS, 'ultrasound-failed.png')}).catch(() => {});
  assert.fail(`${when}: the arm is ${badge.trim()}; server: ${JSON.stringify(await armState())}; ` +
              `page: ${JSON.stringify(await sweepState())} banner: ${await page.locator(tid('banner')).textContent()}`);
}

// Waits for the page's condition; on time-out fails with what the page shows (phase, message, status
// line, banner), what the server says of the arm, and keeps a screenshot.
async function waitOrExplain(what, fn, arg, options) {
  const ok = await page.waitForFunction(fn, arg, options).then(() => true, () => false);
  if (ok) return;
  const s = await sweepState();
  const banner = await page.locator(tid('banner')).textContent().catch(() => '');
  await page.screenshot({path: path.join(ARTIFACTS, 'ultrasound-failed.png')}).catch(() => {});
  assert.fail(`${what}: ${JSON.stringify(s)} banner: ${banner}; server: ${JSON.stringify(await armState())}`);
}

test('a sweep runs from the console while the catheter is driven in the same server', async () => {
  // The catheter's operator takes its lease, enables it and keeps moving it for the whole sweep.
  const granted = await driverCall('POST', `/robots/${CATHETER}/lease`, {});
  assert.equal(granted.status, 200, JSON.stringify(granted.json));
  driver.leaseToken = granted.json.lease_token;
  const enabled = await driverCall('POST', `/robots/${CATHETER}/state_command`, {command: 'enable'});
  assert.ok(enabled.status < 300, JSON.stringify(enabled.json));
  let driving = true;
  let catheterMoves = 0;
  let catheterRefusals = [];
  const drive = (async () => {
    for (let k = 0; driving; k++) {
      // Insertion (joint 0, mm) back and forth between 10 and 30 mm, a move_jp every 3 s, the
      // other joints where they are.
      const sp = await driverCall('GET', `/robots/${CATHETER}/setpoint_js`);
      const goal = Array.isArray(sp.json?.position) ? [...sp.json.position] : null;
      if (goal) {
        goal[0] = k % 2 ? 30 : 10;
        const r = await driverCall('POST', `/robots/${CATHETER}/move_jp`, {goal});
        if (r.status < 300) catheterMoves++;
        else catheterRefusals.push(`${r.status} ${JSON.stringify(r.json)}`);
      }
      await new Promise((res) => setTimeout(res, 3000));
    }
  })();

  try {
    await page.goto(`${BASE_URL}/?token=${encodeURIComponent(TOKEN)}`);
    await page.waitForFunction((arm) => [...document.querySelectorAll('[data-testid="robot-select"] option')]
      .some((o) => o.value === arm), ARM, WAIT);
    await page.locator(tid('robot-select')).selectOption(ARM);
    await page.locator(`${tid('tab-robot')}:not([hidden])`).waitFor(WAIT);
    assert.equal((await page.locator(tid('tab-robot')).textContent()).trim(), 'Ultrasound');
    await page.click(tid('tab-robot'));
    // The catheter's fluoroscopy panels on Hold: this test is about the arm, and two 512² JPEG streams
    // decoded by a software-rendering page cost the server's control loop CPU on two shared cores.
    for (const view of ['ap', 'lateral']) await page.click(tid(`image-${view}-hold-button`)).catch(() => {});
    await page.locator('#lease-button').click();
    await page.waitForFunction((arm) => new RegExp(`lease: yours \\(${arm}\\)`).test(
      document.querySelector('[data-testid="lease-status"]').textContent), ARM, WAIT);
    await page.waitForFunction(() => !document.querySelector('[data-testid="enable-button"]').disabled, null, WAIT);
    await page.click(tid('enable-button'));
    await page.waitForFunction(() => document.querySelector('[data-testid="state-badge"]').textContent.includes('ENABLED'),
      null, WAIT);
    // The robot calibration first (the sweep refuses without it), from the Calibration sub-panel: in
    // cartesian mode, the Calibrate button, then about 65 s of motion through 12 poses.
    assert.match(await page.locator(tid('us-cal-missing')).textContent(), /robot/);
    const inCartesian = await page.waitForFunction(() => {
      const b = document.querySelector('[data-testid="mode-cartesian"]');
      if (b.getAttribute('aria-pressed') === 'true') return true;
      if (!window.__cartesianClickAt || Date.now() - window.__cartesianClickAt > 3000) {
        window.__cartesianClickAt = Date.now();
        if (!b.disabled) b.click();
      }
      return false;
    }, null, {timeout: 30000, polling: 250}).then(() => true, () => false);
    await failOnHoldOrFault('switching to cartesian mode');
    assert.ok(inCartesian, `cartesian mode: ${await page.locator(tid('command-status')).textContent()}`);
    // Calibrate, once; a refusal (the arm still settling after Enable) is shown under the button and the
    // click tried again, printed, as the mode switches are. A hold or a fault fails the test.
    let started = false;
    for (let click = 1; click <= 10 && !started; click++) {
      await failOnHoldOrFault('before the robot calibration');
      await page.waitForFunction(() => !document.querySelector('[data-testid="us-cal-robot-calibrate"]').disabled, null, WAIT);
      await page.click(tid('us-cal-robot-calibrate'));
      await page.waitForFunction(() => document.querySelector('[data-testid="us-cal-robot-message"]').dataset.refused !== undefined &&
          document.querySelector('[data-testid="us-cal-robot-message"]').textContent !== 'sending…', null, WAIT);
      const refused = await page.locator(tid('us-cal-robot-message')).getAttribute('data-refused') === 'true';
      if (refused) {
        console.log(`# calibrate refused: ${await page.locator(tid('us-cal-robot-message')).textContent()}`);
        await page.waitForTimeout(1000);
      }
      started = !refused;
    }
    assert.ok(started, `calibrate: ${await page.locator(tid('us-cal-robot-message')).textContent()}`);
    await page.waitForTimeout(1000);  // the routine's state arrives on /us_arm/sweep (20 Hz)
    await waitOrExplain('the robot calibration starts', () =>
      document.querySelector('[data-testid="us-cal-running"]').dataset.kind === 'robot' ||
      document.querySelector('[data-testid="us-cal-last"]').dataset.ok !== '', null, WAIT);
    // About 65 s of motion through 12 poses (simulated time; longer in wall time on a slow machine). The
    // routine ends (ok or not) or the arm is held/faulted: whichever comes first; a time-out fails.
    await waitOrExplain('the robot calibration ends', () =>
      document.querySelector('[data-testid="us-cal-running"]').dataset.kind !== 'robot' ||
      /PAUSED|FAULT|E-STOP/.test(document.querySelector('[data-testid="state-badge"]').textContent),
    null, {timeout: 300000, polling: 500});
    await failOnHoldOrFault('during the robot calibration');
    const calibrated = (await page.locator(tid('us-cal-robot')).getAttribute('data-version')) !== '';
    const calibration = await page.locator(tid('us-cal-robot')).textContent();
    const lastCalibration = await page.locator(tid('us-cal-last')).textContent();
    console.log(`robot calibration from the console: ${calibration} (${lastCalibration})`);
    assert.ok(calibrated, `calibration: ${lastCalibration} / ${await page.locator(tid('us-cal-running')).textContent()}`);
    assert.equal(await page.locator(tid('us-cal-robot')).getAttribute('data-version'), '1', lastCalibration);
    // The image-to-probe calibration, which the sweep requires too: the SIMULATED N-wire phantom, a few
    // seconds and no arm motion, from the same sub-panel.
    await page.waitForFunction(() => !document.querySelector('[data-testid="us-cal-us-calibrate"]').disabled, null, WAIT);
    await page.click(tid('us-cal-us-calibrate'));
    await page.waitForFunction(() => document.querySelector('[data-testid="us-cal-us"]').dataset.version !== '',
        null, {timeout: 120000, polling: 500});
    console.log(`image calibration from the console: ${await page.locator(tid('us-cal-us')).textContent()}`);
    assert.equal(await page.locator(tid('us-cal-us')).getAttribute('data-version'), '1',
        await page.locator(tid('us-cal-last')).textContent());
    assert.equal(await page.locator(tid('us-cal-missing')).textContent(), '');

    // Sweep mode (the mode bar); a switch refused while the arm settles after Enable is tried again.
    const inSweep = await page.waitForFunction(() => {
      const b = document.querySelector('[data-testid="mode-sweep"]');
      if (b.getAttribute('aria-pressed') === 'true') return true;
      if (!b.disabled && !window.__sweepClickAt || Date.now() - window.__sweepClickAt > 3000) {
        window.__sweepClickAt = Date.now();
        if (!b.disabled) b.click();
      }
      return false;
    }, null, {timeout: 30000, polling: 250}).then(() => true, () => false);
    await failOnHoldOrFault('switching to sweep mode');
    assert.ok(inSweep, `sweep mode: ${await page.locator(tid('command-status')).textContent()} / ${await page.locator(tid('banner')).textContent()}`);

    // Plan: the CT centreline fit, via-points and registration.
    await page.waitForFunction(() => !document.querySelector('[data-testid="us-sweep-plan"]').disabled, null, WAIT);
    await page.click(tid('us-sweep-plan'));
    await waitOrExplain('plan', () => ['planned', 'ready'].includes(document.querySelector('[data-testid="us-phase"]').dataset.phase),
      null, SWEEP_WAIT);
    // Preview shows the planned via-points in the 3D view without moving.
    await page.click(tid('us-sweep-preview'));
    await waitOrExplain('preview', () => Number(document.querySelector('[data-testid="us-recon-info"]').dataset.viaPoints) >= 1,
      null, SWEEP_WAIT);
    // Pre-position above the first via-point, start, and run the sweep to its end (16 via-points, about
    // 60 s of simulated time). A hold, a FAULT or a paused sweep fails the test with its cause. Simulated
    // time runs as fast as this machine lets it (a loaded two-core machine halves it), so the wall-clock
    // guard is on progress: the sweep fails when its phase, via-point and progress stand still for
    // SWEEP_WAIT (a hang), or after 10 minutes in all.
    const deadline = Date.now() + 600000;
    let last = null;
    let progressAt = Date.now(), progressSeen = '';
    for (;;) {
      const s = await sweepState();
      const progress = `${s.phase} ${s.viaPoint} ${s.slices} ${s.progress}`;
      if (progress !== progressSeen) [progressSeen, progressAt] = [progress, Date.now()];
      const robot = await page.evaluate(() => ({
        state: document.querySelector('[data-testid="state-badge"]').textContent.trim(),
        sweepMode: document.querySelector('[data-testid="mode-sweep"]').getAttribute('aria-pressed') === 'true',
      }));
      if (s.phase === 'done' && s.frames >= 3) break;
      await failOnHoldOrFault(`during the sweep (phase ${s.phase})`);
      const stuck = Date.now() - progressAt > SWEEP_WAIT.timeout;
      if (s.phase === 'paused' || stuck || Date.now() > deadline) {
        await page.screenshot({path: path.join(ARTIFACTS, 'ultrasound-failed.png')});
        const why = s.phase === 'paused' ? 'paused' : stuck ? `made no progress for ${SWEEP_WAIT.timeout / 1000} s`
          : 'did not end within 10 min';
        assert.fail(`the sweep ${why}: ${JSON.stringify(s)} ` +
                    `robot ${JSON.stringify(robot)}; server: ${JSON.stringify(await armState())}`);
      }
      const enabled = (id) => page.evaluate((t) => {
        const b = document.querySelector(`[data-testid="${t}"]`);
        return !!b && !b.disabled && !b.hidden && b.offsetParent !== null;
      }, id);
      let action = null;
      if (!robot.sweepMode) action = 'mode-sweep';
      else if (s.phase === 'planned') action = 'us-sweep-pre-position';
      else if (s.phase === 'ready') action = 'us-sweep-start';
      if (action && await enabled(action) && action !== last) {
        await page.evaluate((t) => document.querySelector(`[data-testid="${t}"]`).click(), action);
        last = action;
      } else if (!action) {
        last = null;
      }
      await page.waitForTimeout(1000);
      if (action === last && ['us-sweep-start', 'us-sweep-pre-position'].includes(action)) {
        // the phase changes once the server takes it; a repeat click only when it did not
        const after = await sweepState();
        if (after.phase === s.phase) last = null;
      }
    }
    const s = await sweepState();
    console.log(`# sweep reached: phase ${s.phase}, ${s.slices} slices, progress ${s.progress}, ${s.frames} images; ${s.message}`);
    assert.equal(s.phase, 'done', JSON.stringify(s));
    assert.equal(s.slices, 16, `every via-point of the plan acquired: ${JSON.stringify(s)}`);
    assert.ok(s.progress > 0, JSON.stringify(s));
    assert.ok(s.frames >= 3, `images arrived: ${JSON.stringify(s)}`);
    await page.waitForFunction(() => Number(document.querySelector('[data-testid="us-ellipse"]').dataset.shapes || 0) >= 1,
      null, WAIT);
    // The force plot has samples and the force is near the target while acquiring.
    await page.waitForFunction(() => document.querySelector('[data-testid="us-force-plot"]').dataset.available === 'true',
      null, WAIT);
    // ... from /us_arm/force (100 Hz), not the 20 Hz fallback of /us_arm/sweep.
    const force = await page.evaluate(() => ({...document.querySelector('[data-testid="us-force"]').dataset}));
    console.log(`# force plot: ${force.samples} samples, source ${force.source}, last ${force.value} N`);
    assert.equal(force.source, 'force', JSON.stringify(force));
    assert.ok(Number(force.samples) > 100, JSON.stringify(force));
    assert.ok(Number.isFinite(Number(force.value)), JSON.stringify(force));
    // The 3D view is fixed to the tissue frame, which /tf gives.
    const tf = await page.evaluate(() => ({...document.querySelector('[data-testid="us-tf-info"]').dataset}));
    assert.equal(tf.fixedFrame, 'tissue');
    assert.equal(tf.tissueKnown, 'true');
    // Screenshots: the panel scrolled to the image with its ellipse and the force plot; then the 3D
    // view enlarged on the tissue-fixed reconstruction.
    await page.evaluate(() => document.querySelector('[data-testid="us-image"]').scrollIntoView({block: 'start'}));
    await page.waitForTimeout(500);
    await page.screenshot({path: path.join(ARTIFACTS, 'ultrasound.png')});
    await page.click(tid('enlarge-view'));
    await page.evaluate(() => {
      const view = window.tendrilLive.view();
      const surface = [...view.entities.entries()].find(([id]) => /(^|\/)surface$/.test(id));
      if (surface) view.fitTo(surface[1]);
    });
    await page.waitForTimeout(2500);  // a resize and a frame of the software renderer
    await page.screenshot({path: path.join(ARTIFACTS, 'ultrasound-3d.png')});
    await page.click(tid('enlarge-view'));
  } finally {
    driving = false;
    await drive;
  }
  assert.ok(catheterMoves >= 3, `the catheter was driven during the sweep (${catheterMoves} moves; refused: ${catheterRefusals.slice(0, 3).join('; ')})`);
  const cath = await driverCall('GET', `/robots/${CATHETER}/operating_state`);
  console.log(`# catheter: ${catheterMoves} moves accepted during the sweep, now ${cath.json?.state}`);
  assert.deepEqual(pageErrors, []);
});
