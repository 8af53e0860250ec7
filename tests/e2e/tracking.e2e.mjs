// Browser test of the console's Tracking tab (web/tracking.js) against a running tendrild with the
// SIMULATED bi-plane fluoroscope: the tab's controls have accessible names, the switch subscribes
// /imaging/tracking (off by default), both planes report "found", the imaged 3D tip lies within the
// disagreement bound of the model's and is drawn in the 3D scene, a threshold edited in the form is
// applied by the server (its GET says so), a new roadmap is taken, and the switch turns the tracking
// off again. Then the image-guided mode from the console: with the shipped synthetic ICA planned and
// loaded, the catheter tab shows the loop's status and the deadman's insertion inserts while the
// replanner steers. Screenshots: tests/e2e/artifacts/tracking.png, image-guided.png (git-ignored).
// Env: TENDRIL_URL, TENDRIL_TOKEN (tests/e2e/run.sh sets them); CHROMIUM (default /usr/bin/chromium).
import {test, before, after} from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import {fileURLToPath} from 'node:url';
import {ARTIFACTS, openBrowser, serverUnderTest, tid} from './browser.mjs';

const {BASE_URL, TOKEN} = serverUnderTest();
const WAIT = {timeout: 30000};  // bound on a hung page or server, not a speed assertion

let context;
let page;
let closeBrowser;
const pageErrors = [];

async function rest(method, urlPath, body) {
  const response = await fetch(`${BASE_URL}/api/v1${urlPath}`, {
    method,
    headers: {Authorization: `Bearer ${TOKEN}`, 'X-Tendril-Client': 'tracking-e2e', 'Content-Type': 'application/json'},
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  const text = await response.text();
  return {status: response.status, json: text ? JSON.parse(text) : null, text};
}

// Waits for a condition on the page; on timeout saves a screenshot and says what the tab showed.
async function waitOn(predicate, arg, options = WAIT) {
  try {
    await page.waitForFunction(predicate, arg, options);
  } catch (err) {
    const shot = path.join(ARTIFACTS, `tracking-failure-${Date.now()}.png`);
    await page.screenshot({path: shot}).catch(() => {});
    const shown = await page.evaluate(() => Object.fromEntries(
      ['tracking-ap-status', 'tracking-lateral-status', 'tracking-tip', 'tracking-disagreement', 'seg-status',
       'roadmap-info', 'command-status', 'lease-status']
        .map((id) => [id, document.querySelector(`[data-testid="${id}"]`)?.textContent]))).catch(() => ({}));
    err.message += `\nthe page showed ${JSON.stringify(shown)}; screenshot ${shot}`;
    throw err;
  }
}

before(async () => {
  ({context, page, close: closeBrowser} = await openBrowser('tracking'));
  page.on('pageerror', (err) => pageErrors.push(err.message));
});

after(async () => {
  await closeBrowser?.();
});

test('the console loads; the lease is taken; the Tracking tab shows the server\'s parameters', async () => {
  await page.goto(`${BASE_URL}/?token=${encodeURIComponent(TOKEN)}`);
  await page.waitForFunction(() => document.querySelector('[data-testid="connection-indicator"]').dataset.kind === 'live',
                             null, {timeout: 60000});
  await page.click(tid('lease-button'));
  await waitOn(() => document.querySelector('[data-testid="lease-status"]').classList.contains('held'));
  await page.click(tid('tab-tracking'));
  const server = await rest('GET', '/imaging/segmentation');
  assert.equal(server.status, 200, server.text);
  await waitOn((t) => document.querySelector('[data-testid="seg-threshold"]').value === String(t),
               server.json.planes.ap.parameters.threshold);
  assert.equal(await page.locator(tid('tracking-switch')).getAttribute('aria-checked'), 'false', 'tracking is off by default');
  const subscribed = await page.evaluate(() => window.tendrilConnection.subscribedTopics());
  assert.ok(!subscribed.includes('/imaging/tracking'), `not subscribed while off: ${subscribed}`);
});

test('every control of the Tracking tab has an accessible name and a data-testid', async () => {
  const cdp = await context.newCDPSession(page);
  await cdp.send('Accessibility.enable');
  const interactive = new Set(['button', 'textbox', 'spinbutton', 'slider', 'combobox', 'checkbox', 'switch', 'tab']);
  const offenders = [];
  let checked = 0;
  const {nodes} = await cdp.send('Accessibility.getFullAXTree');
  for (const node of nodes) {
    if (node.ignored || !interactive.has(node.role?.value)) continue;
    checked++;
    if (!String(node.name?.value ?? '').trim()) {
      const {node: dom} = await cdp.send('DOM.describeNode', {backendNodeId: node.backendDOMNodeId});
      offenders.push(`${node.role.value} without a name: <${dom.localName} ${(dom.attributes || []).join(' ')}>`);
    }
  }
  await cdp.detach();
  assert.ok(checked >= 20, `found the controls (${checked})`);
  assert.deepEqual(offenders, []);
  const noTestId = await page.evaluate(() => [...document.querySelectorAll('#panel-tracking button, #panel-tracking input, #panel-tracking select')]
    .filter((el) => !el.dataset.testid).map((el) => el.outerHTML.slice(0, 80)));
  assert.deepEqual(noTestId, []);
});

test('the switch subscribes the tracking: both planes found, the imaged tip within the bound of the model\'s, drawn in 3D', async () => {
  await page.click(tid('tracking-switch'));
  assert.equal(await page.locator(tid('tracking-switch')).getAttribute('aria-checked'), 'true');
  await waitOn(() => ['ap', 'lateral'].every((p) => document.querySelector(`[data-testid="tracking-${p}-status"]`).dataset.found === 'true'));
  // Read where the page shows it (a message whose planes' frames were not in step has no 3D tip: "—").
  await waitOn(() => document.querySelector('[data-testid="tracking-disagreement"]').dataset.level === 'ok');
  const text = await (await page.waitForFunction(() => {
    const el = document.querySelector('[data-testid="tracking-disagreement"]');
    return el.dataset.level === 'ok' ? el.textContent : false;
  }, null, WAIT)).jsonValue();
  const mm = Number(text.split(' ')[0]);
  assert.ok(mm >= 0 && mm <= 3, `imaged tip to model tip ${text}`);
  // The tracked (EKF) tip drawn in the scene lies within the bound of the model's tip of the same message.
  const tips = await (await page.waitForFunction(() => {
    const tip = window.tendrilLive.view()?.trackedTip;
    const last = window.tendrilLive.tracking()?.last;
    if (!tip?.visible || !Array.isArray(last?.tip_mm) || !Array.isArray(last?.model_tip_mm)) return false;
    return {at: [tip.position.x, tip.position.y, tip.position.z], sent: last.tip_mm, model: last.model_tip_mm,
            bound: last.disagreement_bound_mm};
  }, null, WAIT)).jsonValue();
  assert.ok(tips.at.every((v, i) => Math.abs(v - tips.sent[i]) < 1e-6), `drawn where the message says: ${JSON.stringify(tips)}`);
  const d = Math.hypot(...tips.at.map((v, i) => v - tips.model[i]));
  assert.ok(d <= tips.bound, `the drawn tip is ${d.toFixed(2)} mm from the model's tip (bound ${tips.bound} mm): ${JSON.stringify(tips)}`);
  // The plot has both the segmented tip and the EKF estimate.
  await waitOn(() => document.querySelector('[data-testid="tip-tracking-plot"]').dataset.available === 'true');
});

test('a threshold edited in the form is applied by the server', async () => {
  await page.selectOption(tid('seg-plane'), 'ap');
  const before = (await rest('GET', '/imaging/segmentation')).json.planes.ap.parameters;
  const threshold = before.threshold + 3;
  await page.fill(tid('seg-threshold'), String(threshold));
  await page.click(tid('seg-apply-button'));
  // The click handler replaces the previous "parameters applied" before its request goes out.
  await waitOn(() => /parameters applied/.test(document.querySelector('[data-testid="seg-status"]').textContent) &&
                     document.querySelector('[data-testid="seg-status"]').dataset.kind === 'ok');
  const after = (await rest('GET', '/imaging/segmentation')).json.planes.ap;
  assert.equal(after.parameters.threshold, threshold);
  assert.equal(after.applied, true);
  assert.equal(after.parameters.canny_low, before.canny_low, 'only the edited field changed');
  // A value the parameters refuse: the field is named on the page and nothing changes.
  await page.fill(tid('seg-threshold'), '999');
  await page.click(tid('seg-apply-button'));
  await waitOn(() => document.querySelector('[data-testid="seg-status"]').dataset.kind === 'error');
  assert.match(await page.locator(tid('seg-status')).textContent(), /threshold/);
  assert.equal((await rest('GET', '/imaging/segmentation')).json.planes.ap.parameters.threshold, threshold);
  // Still tracked with the new threshold.
  await waitOn(() => document.querySelector('[data-testid="tracking-ap-status"]').dataset.found === 'true');
});

test('Take roadmap takes a new roadmap; tracking goes on; screenshot', async () => {
  await page.selectOption(tid('seg-plane'), 'lateral');
  const before = (await rest('GET', '/imaging/segmentation')).json.planes.lateral.roadmap.count;
  await page.click(tid('roadmap-button'));
  await waitOn(() => /new roadmap taken/.test(document.querySelector('[data-testid="seg-status"]').textContent));
  const after = (await rest('GET', '/imaging/segmentation')).json.planes.lateral.roadmap;
  assert.ok(after.count > before && !after.pending, JSON.stringify(after));
  await waitOn(() => document.querySelector('[data-testid="tracking-lateral-status"]').dataset.found === 'true');
  await page.waitForTimeout(1500);  // a few seconds of plot
  await page.locator('#panel-tracking').evaluate((el) => { el.scrollTop = 0; });
  await page.waitForTimeout(300);
  await page.screenshot({path: path.join(ARTIFACTS, 'tracking.png')});
  await page.locator(tid('roadmap-button')).scrollIntoViewIfNeeded();
  await page.screenshot({path: path.join(ARTIFACTS, 'tracking-editor.png')});
});

test('switching the tracking off unsubscribes it and hides the imaged tip', async () => {
  await page.click(tid('tracking-switch'));
  assert.equal(await page.locator(tid('tracking-switch')).getAttribute('aria-checked'), 'false');
  const subscribed = await page.evaluate(() => window.tendrilConnection.subscribedTopics());
  assert.ok(!subscribed.includes('/imaging/tracking'), `unsubscribed: ${subscribed}`);
  assert.equal(await page.evaluate(() => !!window.tendrilLive.view()?.trackedTip?.visible), false);
  assert.equal(await page.locator(tid('tracking-ap-status')).textContent(), '—');
  assert.deepEqual(pageErrors, [], 'no errors on the page');
});

// From the page itself (its cookie session holds the lease): plan along the shipped synthetic ICA and
// load the plan for the robot, as the Plan tab would.
async function planAndLoad() {
  const csv = fs.readFileSync(path.join(path.dirname(fileURLToPath(import.meta.url)), '../../config/vessels/synthetic_ica.csv'), 'utf8');
  return page.evaluate(async (text) => {
    const call = async (method, url, body, type = 'application/json') => {
      const r = await fetch(`/api/v1${url}`, {method, body, credentials: 'same-origin', headers: {'Content-Type': type}});
      const answer = await r.json().catch(() => null);
      if (!r.ok) throw new Error(`${method} ${url}: ${r.status} ${JSON.stringify(answer)}`);
      return answer;
    };
    const job = await call('POST', '/plans?robot=srmc&branch=0&ds=0.5&dq1=3', text, 'text/csv');
    for (let i = 0; i < 600; ++i) {
      const j = await call('GET', `/jobs/${job.id}`);
      if (j.state === 'succeeded') break;
      if (j.state === 'failed' || j.state === 'cancelled') throw new Error(`plan ${j.state}: ${JSON.stringify(j)}`);
      await new Promise((r) => setTimeout(r, 100));
    }
    return call('POST', '/robots/srmc/path_following', JSON.stringify({plan: job.id}));
  }, csv);
}

const operating = async () => (await rest('GET', '/robots/srmc/operating_state')).json;
async function untilServer(predicate, what, timeoutMs = 30000) {
  const until = Date.now() + timeoutMs;
  for (;;) {
    const os = await operating();
    if (predicate(os)) return os;
    if (Date.now() > until) {
      assert.fail(`${what}: last ${JSON.stringify({state: os.state, mode: os.mode, hold: os.hold, joystick: os.joystick,
                                                    image_guidance: os.image_guidance, refusal: os.mode_refusal})}`);
    }
    await new Promise((r) => setTimeout(r, 100));
  }
}

test('image-guided mode from the console: the loop\'s status on the catheter tab; the deadman inserts, the replanner steers', async () => {
  await planAndLoad();
  await page.waitForFunction(() => !document.querySelector('[data-testid="enable-button"]').disabled, null, WAIT);
  await page.click(tid('enable-button'));
  await untilServer((os) => os.state === 'ENABLED' && !os.is_busy, 'enabled and holding');
  await page.click(tid('mode-image_guided'));
  await untilServer((os) => os.mode === 'image_guided', 'image_guided entered');
  await page.click(tid('tab-catheter'));
  await waitOn(() => !document.querySelector('[data-testid="image-guidance"]').hidden);
  // The loop runs before anyone inserts: the mode demands the tracking itself.
  await untilServer((os) => os.image_guidance?.replans > 0, 'replanned targets');
  await waitOn(() => document.querySelector('[data-testid="guidance-status"]').dataset.status === 'tracking' &&
                     Number(document.querySelector('[data-testid="guidance-replans"]').textContent) > 0);
  const before = await operating();
  // Space holds the deadman; the arrow keys set the insertion speed on the focused slider.
  await page.locator(tid('stick-insertion')).scrollIntoViewIfNeeded();
  await page.focus(tid('stick-insertion'));
  await page.keyboard.down('Space');
  await waitOn(() => document.querySelector('[data-testid="deadman-button"]').getAttribute('aria-pressed') === 'true');
  for (let i = 0; i < 10; ++i) await page.keyboard.press('ArrowRight');
  let moving;
  try {
    moving = await untilServer((os) => os.joystick?.source === 'console' &&
        os.image_guidance.drive_insertion_mm - before.image_guidance.drive_insertion_mm > 1.0, 'insertion from the console');
  } catch (err) {
    const shown = await page.evaluate(() => ({
      joystick: document.querySelector('[data-testid="joystick-status"]').textContent,
      insertion: document.querySelector('[data-testid="stick-insertion"]').value,
      focused: document.activeElement?.dataset?.testid,
      badge: document.querySelector('[data-testid="state-badge"]').dataset.state,
      status: document.querySelector('[data-testid="command-status"]').textContent}));
    err.message += `\nthe page showed ${JSON.stringify(shown)}`;
    throw err;
  }
  // The console sends insertion only; the bends are the replanner's.
  assert.deepEqual(moving.joystick.axes.slice(1), [0, 0, 0], JSON.stringify(moving.joystick));
  assert.match(await page.locator(tid('joystick-status')).textContent(), /the replanner steers/);
  await page.screenshot({path: path.join(ARTIFACTS, 'image-guided.png')});
  await page.keyboard.up('Space');
  await page.locator(tid('stick-insertion')).blur();
  const after = await untilServer((os) => os.image_guidance.replans > moving.image_guidance.replans, 'replanning goes on');
  assert.ok(Number.isFinite(after.image_guidance.measured_insertion_mm), JSON.stringify(after.image_guidance));
  assert.match(await page.locator(tid('guidance-drive')).textContent(), /^\d+\.\d mm$/);
  // Insertion stopped: the mode can be left while the tracking still runs; the panel goes with it.
  await untilServer((os) => !os.is_busy, 'holding after the insertion');
  await page.click(tid('mode-joint'));
  await untilServer((os) => os.mode === 'joint', 'back in joint mode');
  await waitOn(() => document.querySelector('[data-testid="image-guidance"]').hidden);
  assert.deepEqual(pageErrors, [], 'no errors on the page');
});
