// Browser test of the console (web/) against a running tendrild with simulated drives: open with
// ?token=, see a lease held elsewhere refused with the holder named, take the lease, enable, set goals
// and move, see the measured values and the 3D view (canvas pixels) change, press E-STOP (button and
// Escape key) and see the badge show it, and keep working over REST when the WebSocket is refused.
// Screenshots go to tests/e2e/artifacts/ (git-ignored).
// Env: TENDRIL_URL, TENDRIL_TOKEN (tests/e2e/run.sh sets them); CHROMIUM (default /usr/bin/chromium).
import {test, before, after} from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import {fileURLToPath} from 'node:url';
import {chromium} from 'playwright-core';

const BASE_URL = (process.env.TENDRIL_URL || '').replace(/\/$/, '');
const TOKEN = process.env.TENDRIL_TOKEN || '';
if (!BASE_URL || !TOKEN) throw new Error('Set TENDRIL_URL and TENDRIL_TOKEN, or run tests/e2e/run.sh <tendrild>');
const ARTIFACTS = path.join(path.dirname(fileURLToPath(import.meta.url)), 'artifacts');
const WAIT = {timeout: 20000};  // bound on a hung page, not a speed assertion

let context;
let page;
let userDataDir;
const pageErrors = [];

const tid = (id) => `[data-testid="${id}"]`;

before(async () => {
  fs.mkdirSync(ARTIFACTS, {recursive: true});
  userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), 'tendril-e2e-'));
  context = await chromium.launchPersistentContext(userDataDir, {
    executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
    headless: true,
    viewport: {width: 1280, height: 800},
    args: ['--headless=new', '--no-sandbox', '--disable-gpu', '--disable-background-networking',
           '--disable-component-update', '--no-first-run', '--disable-sync', '--disable-quic',
           // WebGL without a GPU: SwiftShader (software) is what renders here.
           '--use-angle=swiftshader', '--enable-unsafe-swiftshader'],
  });
  page = context.pages()[0] ?? await context.newPage();
  page.on('pageerror', (err) => pageErrors.push(err.message));
});

after(async () => {
  // Leave the server without a latched e-stop for whoever runs next.
  try {
    await page?.request.post(`${BASE_URL}/api/v1/estop/reset`, {headers: {Authorization: `Bearer ${TOKEN}`}, data: {}});
  } catch {
    // the server may already be gone
  }
  await context?.close();
  if (userDataDir) fs.rmSync(userDataDir, {recursive: true, force: true});
});

// Pixels of the 3D canvas, downscaled, read back through a 2D canvas.
async function canvasPixels() {
  return page.evaluate(() => {
    const source = document.querySelector('[data-testid="scene-canvas"]');
    const w = 192;
    const h = Math.max(1, Math.round(w * source.height / source.width));
    const c = document.createElement('canvas');
    c.width = w;
    c.height = h;
    const ctx = c.getContext('2d');
    ctx.drawImage(source, 0, 0, w, h);
    return Array.from(ctx.getImageData(0, 0, w, h).data);
  });
}

function differingFraction(a, b) {
  assert.equal(a.length, b.length, 'canvas size unchanged');
  let differing = 0;
  for (let i = 0; i < a.length; i += 4) {
    if (Math.abs(a[i] - b[i]) + Math.abs(a[i + 1] - b[i + 1]) + Math.abs(a[i + 2] - b[i + 2]) > 48) differing++;
  }
  return differing / (a.length / 4);
}

async function measuredValue(joint) {
  return Number(await page.locator(`${tid(`joint-measured-${joint}`)}`).textContent());
}

// Waits for a condition on the page; on timeout saves a screenshot and says what the page showed.
async function waitForBadge(predicate, arg, options = WAIT) {
  try {
    await page.waitForFunction(predicate, arg, options);
  } catch (err) {
    const shot = path.join(ARTIFACTS, `failure-${Date.now()}.png`);
    await page.screenshot({path: shot}).catch(() => {});
    const shown = await page.evaluate(() => ({
      badge: document.querySelector('[data-testid="state-badge"]').textContent.trim(),
      status: document.querySelector('[data-testid="command-status"]').textContent,
      lease: document.querySelector('[data-testid="lease-status"]').textContent,
      banner: document.querySelector('[data-testid="banner"]').textContent.trim(),
      measured: [...document.querySelectorAll('[data-testid^="joint-measured-"]')].map((e) => e.textContent),
      setpoint: [...document.querySelectorAll('[data-testid^="joint-setpoint-"]')].map((e) => e.textContent),
    })).catch(() => ({}));
    err.message += `\npage showed ${JSON.stringify(shown)}; screenshot ${shot}`;
    throw err;
  }
}

test('the console loads, drops the token from the address bar and builds the joint panel', async () => {
  await page.goto(`${BASE_URL}/?token=${encodeURIComponent(TOKEN)}`);
  await page.waitForFunction(() => !location.search.includes('token='), null, WAIT);
  assert.ok(!page.url().includes(TOKEN), `token left in the address bar: ${page.url()}`);
  // Joint rows come from GET /robots: the SRMC has four.
  await page.waitForSelector(tid('joint-row-insertion'), WAIT);
  assert.equal(await page.locator('fieldset.joint').count(), 4);
  for (const j of ['insertion', 'roll', 'proximal_bend', 'distal_bend']) {
    await page.waitForSelector(tid(`joint-row-${j}`), WAIT);
  }
  await page.waitForFunction(() => document.querySelector('[data-testid="state-badge"]').dataset.state, null, WAIT);
  await page.waitForFunction(
      () => !Number.isNaN(Number(document.querySelector('[data-testid="joint-measured-insertion"]').textContent)), null, WAIT);
  await page.waitForSelector(tid('scene-canvas'), WAIT);
  // The live stream (WebSocket) should take over from REST polling.
  await page.waitForFunction(() => document.querySelector('[data-testid="connection-indicator"]').dataset.kind === 'live',
                             null, WAIT);
  await page.screenshot({path: path.join(ARTIFACTS, '01-loaded.png')});
});

test('every control has an accessible name and a data-testid', async () => {
  const offenders = await page.evaluate(() => {
    const bad = [];
    for (const el of document.querySelectorAll('button, input, select, textarea')) {
      const labelled = el.getAttribute('aria-label') || (el.id && document.querySelector(`label[for="${el.id}"]`)) ||
                       el.closest('label');
      if (!labelled) bad.push(`no accessible name: ${el.outerHTML.slice(0, 80)}`);
      if (!el.dataset.testid) bad.push(`no data-testid: ${el.outerHTML.slice(0, 80)}`);
    }
    return bad;
  });
  assert.deepEqual(offenders, []);
  // The E-STOP is inside the 1280x800 viewport without scrolling.
  const box = await page.locator(tid('estop-button')).boundingBox();
  assert.ok(box && box.x >= 0 && box.y >= 0 && box.x + box.width <= 1280 && box.y + box.height <= 800, 'E-STOP visible');
  assert.ok(box.width >= 100 && box.height >= 48, `E-STOP is big: ${JSON.stringify(box)}`);
});

// Another operator (a plain REST client with its own identity).
function otherOperator(method, urlPath) {
  return fetch(`${BASE_URL}/api/v1${urlPath}`, {
    method,
    headers: {Authorization: `Bearer ${TOKEN}`, 'X-Tendril-Client': 'e2e-other-operator', 'Content-Type': 'application/json'},
    body: method === 'POST' ? '{}' : undefined,
  });
}

test('a lease held by someone else is refused and the console says by whom', async () => {
  const taken = await otherOperator('POST', '/lease');
  assert.equal(taken.status, 200, await taken.text());
  try {
    await page.click(tid('lease-button'));
    await page.waitForFunction(() => document.querySelector('[data-testid="lease-status"]').classList.contains('other'),
                               null, WAIT);
    const status = await page.locator(tid('command-status')).textContent();
    assert.match(status, /lease/i);
    assert.match(status, /e2e-other-operator/, `the message names the holder: ${status}`);
    await page.screenshot({path: path.join(ARTIFACTS, '02-lease-held-elsewhere.png')});
  } finally {
    await otherOperator('DELETE', '/lease');
  }
});

const badgeState = () => page.locator(tid('state-badge')).getAttribute('data-state');

// Enable through the console's button. The simulated drives must not fault by themselves: a FAULT
// here fails the test with the cause the console shows.
async function enableFromConsole() {
  assert.notEqual(await badgeState(), 'FAULT',
                  `robot in FAULT before enabling: ${(await page.locator(tid('banner')).textContent()).trim()}`);
  await page.waitForFunction(() => !document.querySelector('[data-testid="enable-button"]').disabled, null, WAIT);
  await page.click(tid('enable-button'));
  await page.waitForFunction(() => ['ENABLED', 'FAULT'].includes(
      document.querySelector('[data-testid="state-badge"]').dataset.state), null, WAIT);
  assert.equal(await badgeState(), 'ENABLED',
               `enable ended in ${await badgeState()}: ${(await page.locator(tid('banner')).textContent()).trim()}`);
  await page.waitForFunction(() => !document.querySelector('[data-testid="move-button"]').disabled, null, WAIT);
}

test('take the lease, enable, move: measured values and the 3D view change', async (t) => {
  await page.click(tid('lease-button'));
  await page.waitForFunction(() => document.querySelector('[data-testid="lease-status"]').classList.contains('held'), null, WAIT);
  await enableFromConsole();

  await page.click(tid('fit-view-button'));
  await page.waitForTimeout(300);  // let the view render after the camera moved
  const before = await canvasPixels();
  const background = before.filter((_, i) => i % 4 === 0).filter((r) => r > 60).length;
  assert.ok(background > 50, 'the 3D view draws something (backbone, grid) rather than an empty canvas');
  await page.locator(tid('scene-canvas')).screenshot({path: path.join(ARTIFACTS, '03-scene-before.png')});

  const insertion0 = await measuredValue('insertion');
  const insertionGoal = insertion0 < 60 ? insertion0 + 25 : insertion0 - 25;
  await page.fill(tid('joint-goal-insertion'), insertionGoal.toFixed(2));
  await page.fill(tid('joint-goal-proximal_bend'), '6.00');
  await page.fill(tid('joint-goal-distal_bend'), '-3.00');
  await page.waitForFunction(() => !document.querySelector('[data-testid="move-button"]').disabled, null, WAIT);
  await page.click(tid('move-button'));
  await page.waitForFunction(() => /Moving|Move: done/.test(document.querySelector('[data-testid="command-status"]').textContent),
                             null, WAIT);
  // Reach the goal; a FAULT on the way fails the test with the console's explanation.
  await waitForBadge(
      (goal) => document.querySelector('[data-testid="state-badge"]').dataset.state === 'FAULT' ||
                (Math.abs(Number(document.querySelector('[data-testid="joint-measured-insertion"]').textContent) - goal) < 0.1 &&
                 Math.abs(Number(document.querySelector('[data-testid="joint-measured-proximal_bend"]').textContent) - 6) < 0.1),
      insertionGoal, {timeout: 30000});
  assert.equal(await badgeState(), 'ENABLED',
               `robot faulted during the move: ${(await page.locator(tid('banner')).textContent()).trim()}`);
  const insertion1 = await measuredValue('insertion');
  assert.ok(Math.abs(insertion1 - insertionGoal) < 0.1, `insertion reached the goal: ${insertion0} -> ${insertion1}`);
  await page.waitForTimeout(500);  // the next stream messages reach the view
  const afterMove = await canvasPixels();
  const changed = differingFraction(before, afterMove);
  assert.ok(changed > 0.002, `3D view changed after the move (${(changed * 100).toFixed(2)}% of pixels)`);
  await page.locator(tid('scene-canvas')).screenshot({path: path.join(ARTIFACTS, '04-scene-after.png')});
  await page.screenshot({path: path.join(ARTIFACTS, '05-after-move.png')});
});

test('E-STOP button latches the e-stop, the badge and banner show it', async () => {
  await page.click(tid('estop-button'));
  await waitForBadge(() => {
    const badge = document.querySelector('[data-testid="state-badge"]');
    return badge.dataset.estop === 'true' && /E-STOP/.test(badge.textContent);
  });
  assert.equal(await page.locator(tid('banner')).getAttribute('data-level'), 'estop', 'the banner shows the e-stop');
  assert.match(await page.locator(tid('banner')).textContent(), /emergency stop/i);
  assert.ok(await page.locator(tid('move-button')).isDisabled(), 'Move is disabled during e-stop');
  await page.screenshot({path: path.join(ARTIFACTS, '06-estop.png')});

  await page.click(tid('estop-reset-button'));
  await waitForBadge(() => {
    const badge = document.querySelector('[data-testid="state-badge"]');
    return badge.dataset.estop === 'false' && badge.dataset.state === 'DISABLED';
  });
  assert.notEqual(await page.locator(tid('banner')).getAttribute('data-level'), 'estop', 'the e-stop banner is gone after reset');
});

test('the Escape key is an e-stop too, even while typing in a goal', async () => {
  await page.focus(tid('joint-goal-roll'));
  await page.keyboard.press('Escape');
  await waitForBadge(() => document.querySelector('[data-testid="state-badge"]').dataset.estop === 'true');
  await page.click(tid('estop-reset-button'));
  await waitForBadge(() => document.querySelector('[data-testid="state-badge"]').dataset.estop === 'false');
  assert.deepEqual(pageErrors, [], 'no uncaught errors in the page');
});

test('without the WebSocket the console falls back to REST polling (and the cookie session still works)', async () => {
  const second = await context.newPage();
  try {
    // Refuse the stream: the page must keep showing live values by polling REST.
    await second.routeWebSocket(/\/ws$/, (ws) => ws.close({code: 1011, reason: 'blocked by test'}));
    await second.goto(`${BASE_URL}/`);  // no ?token=: the session cookie from the first page carries access
    await second.waitForFunction(
        () => document.querySelector('[data-testid="connection-indicator"]').dataset.kind === 'polling', null, WAIT);
    await second.waitForFunction(
        () => !Number.isNaN(Number(document.querySelector('[data-testid="joint-measured-insertion"]').textContent)) &&
              document.querySelector('[data-testid="state-badge"]').dataset.state, null, WAIT);
    // The shape and the tip pose come by REST too.
    await second.waitForFunction(() => /tip x/.test(document.querySelector('[data-testid="tip-position"]').textContent),
                                 null, WAIT);
    await second.waitForTimeout(500);  // the view draws the polled backbone
    await second.screenshot({path: path.join(ARTIFACTS, '07-rest-fallback.png')});
  } finally {
    await second.close();
  }
});
