// Browser test of the ultrasound arm's panel (web/ultrasound.js) against a tendrild serving the
// SIMULATED catheter (srmc) and the SIMULATED ultrasound arm (us_arm, config/robots/us_arm.json) in one
// server (issue 17): a sweep from the console end to end — plan, preview, pre-position, start, every
// via-point acquired with B-mode images and the fitted ellipse arriving, done — WHILE this test drives
// the catheter over REST with a lease of its own (a second operator's script). The 3D view is fixed to
// the tissue frame through /tf. Screenshot: tests/e2e/artifacts/ultrasound.png. A hold of the arm is
// resumed from the console as an operator would (Resume, Pre-position, Start: the sweep continues),
// counted and printed, up to MAX_HOLDS; a FAULT fails the test.
// Env: TENDRIL_URL, TENDRIL_TOKEN (tests/e2e/run.sh starts the server with config/robots/us_arm.json).
import {test, before, after} from 'node:test';
import assert from 'node:assert/strict';
import path from 'node:path';
import {ARTIFACTS, WAIT, tid, openBrowser, serverUnderTest} from './browser.mjs';

const {BASE_URL, TOKEN} = serverUnderTest();
const SWEEP_WAIT = {timeout: 240000};  // a sanitized server and a software renderer on two shared cores
const ARM = process.env.TENDRIL_US_ARM || 'us_arm';
const CATHETER = 'srmc';
// Faults from control-loop stalls the test acknowledges before it gives up (seen: 4 in a 65 s run at
// load 7 on two cores): more means the robot cannot sweep here, and the test fails.
const MAX_HOLDS = 4;

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

// Waits for the page's condition; on time-out fails with what the page shows (phase, message, status
// line, banner) and keeps a screenshot.
async function waitOrExplain(what, fn, arg, options) {
  const ok = await page.waitForFunction(fn, arg, options).then(() => true, () => false);
  if (ok) return;
  const s = await sweepState();
  const banner = await page.locator(tid('banner')).textContent().catch(() => '');
  await page.screenshot({path: path.join(ARTIFACTS, 'ultrasound-failed.png')}).catch(() => {});
  assert.fail(`${what}: ${JSON.stringify(s)} banner: ${banner}`);
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
    // The robot calibration first (REQ-TF-7: no sweep without it), from the Calibration sub-panel: in
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
    assert.ok(inCartesian, `cartesian mode: ${await page.locator(tid('command-status')).textContent()}`);
    // A hold of the arm ends the routine with its reason (on a loaded machine the SIMULATED force
    // sensor's thread can fall silent > 20 ms): Resume and Calibrate again, as an operator would, up to 3.
    let calibrated = false;
    // The one fault a stall of this shared machine can cause while the arm moves (the control loop lost
    // more than its bound) is acknowledged the same way: Disable, Enable, cartesian, Calibrate again.
    for (let attempt = 1; attempt <= 3 && !calibrated; attempt++) {
      if (/FAULT/.test(await page.locator(tid('state-badge')).textContent())) {
        const fault = (await driverCall('GET', `/robots/${ARM}/operating_state`)).json?.fault;
        assert.match(JSON.stringify(fault), /control time lost/, `the arm faulted: ${JSON.stringify(fault)}`);
        console.log(`# calibration attempt ${attempt}: acknowledging ${JSON.stringify(fault)}`);
        await page.click(tid('disable-button'));
        await page.waitForFunction(() => document.querySelector('[data-testid="state-badge"]').textContent.includes('DISABLED'), null, WAIT);
        await page.click(tid('enable-button'));
        await page.waitForFunction(() => document.querySelector('[data-testid="state-badge"]').textContent.includes('ENABLED'), null, WAIT);
        await page.waitForFunction(() => {
          const b = document.querySelector('[data-testid="mode-cartesian"]');
          if (b.getAttribute('aria-pressed') === 'true') return true;
          if (!b.disabled) b.click();
          return false;
        }, null, {timeout: 30000, polling: 1000});
      }
      // Resume is refused while the hold's cause persists (a CI run saw the SIMULATED force sensor still
      // silent, before it sampled in the control thread): clicked again, each refusal printed, for up to
      // 10 tries a second apart.
      for (let click = 1; click <= 10 && /PAUSED/.test(await page.locator(tid('state-badge')).textContent()); click++) {
        const resume = await page.locator(tid('resume-button')).isVisible().catch(() => false) ? 'resume-button' : 'banner-resume-button';
        await page.click(tid(resume));
        const enabled = await page.waitForFunction(() => document.querySelector('[data-testid="state-badge"]').textContent.includes('ENABLED'),
                                                   null, {timeout: 1000}).then(() => true, () => false);
        if (!enabled) console.log(`# resume refused: ${await page.locator(tid('command-status')).textContent()}`);
      }
      assert.doesNotMatch(await page.locator(tid('state-badge')).textContent(), /PAUSED/, 'the hold cleared and the arm resumed');
      // Calibrate; a refusal (the arm still settling after Enable) is shown under the button and the
      // click tried again, printed, as the mode switches are.
      let started = false;
      for (let click = 1; click <= 10 && !started; click++) {
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
      await page.waitForFunction(() => document.querySelector('[data-testid="us-cal-running"]').dataset.kind === 'robot' ||
          document.querySelector('[data-testid="us-cal-last"]').dataset.ok !== '', null, WAIT);
      await page.waitForFunction(() => document.querySelector('[data-testid="us-cal-running"]').dataset.kind !== 'robot',
          null, {timeout: 300000, polling: 500}).catch(() => {});
      calibrated = (await page.locator(tid('us-cal-robot')).getAttribute('data-version')) !== '';
      if (!calibrated) console.log(`# calibration attempt ${attempt}: ${await page.locator(tid('us-cal-last')).textContent()}`);
    }
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
    // 60 s on a quiet machine). A hold (the arm's force bound, a stream the page lost) pauses the sweep
    // as it must; the test then does what the operator would from the console — Resume, Pre-position,
    // Start — and says so. A FAULT (a control-loop stall beyond its bound, a drive's EMCY) fails the test:
    // it is not part of a sweep.
    const recoveries = [];
    const deadline = Date.now() + SWEEP_WAIT.timeout;
    let last = null;
    for (;;) {
      const s = await sweepState();
      const robot = await page.evaluate(() => ({
        state: document.querySelector('[data-testid="state-badge"]').textContent.trim(),
        sweepMode: document.querySelector('[data-testid="mode-sweep"]').getAttribute('aria-pressed') === 'true',
      }));
      if (s.phase === 'done' && s.frames >= 3) break;
      if (/FAULT|E-STOP/.test(robot.state)) {
        await page.screenshot({path: path.join(ARTIFACTS, 'ultrasound-failed.png')});
        assert.fail(`the arm faulted during the sweep: ${JSON.stringify(s)} robot ${JSON.stringify(robot)} ` +
                    `banner: ${await page.locator(tid('banner')).textContent()}`);
      }
      if (Date.now() > deadline || recoveries.length > MAX_HOLDS) {
        await page.screenshot({path: path.join(ARTIFACTS, 'ultrasound-failed.png')});
        assert.fail(`sweep did not get far: ${JSON.stringify(s)} robot ${JSON.stringify(robot)} recoveries ${recoveries.join('; ')}`);
      }
      const enabled = (id) => page.evaluate((t) => {
        const b = document.querySelector(`[data-testid="${t}"]`);
        return !!b && !b.disabled && !b.hidden && b.offsetParent !== null;
      }, id);
      let action = null;
      if (/DISABLED/.test(robot.state)) action = 'enable-button';
      else if (/PAUSED/.test(robot.state)) action = await enabled('resume-button') ? 'resume-button' : 'banner-resume-button';
      else if (!robot.sweepMode) action = 'mode-sweep';
      else if (['planned', 'aborted'].includes(s.phase) || (s.phase === 'paused' && !/continues/.test(s.message || ''))) action = 'us-sweep-pre-position';
      else if (s.phase === 'ready' || s.phase === 'paused') action = 'us-sweep-start';
      if (action && await enabled(action) && action !== last) {
        if (!['us-sweep-pre-position', 'us-sweep-start'].includes(action) || s.phase === 'paused') {
          recoveries.push(`${action} (robot ${robot.state}, phase ${s.phase}, ${s.slices} slices: ${s.status})`);
        }
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
    if (recoveries.length) console.log(`# recovered from ${recoveries.length} holds/faults: ${recoveries.join(' | ')}`);
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
