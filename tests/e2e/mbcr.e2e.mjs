// Browser test of the variable-diameter robot's panel (web/mbcr.js) against a tendrild serving the
// catheter and the SIMULATED mbcr_vd robot (config/robots/mbcr_vd.json): select the robot, take its
// lease, enable it, run the reference circle from the page with a variable diameter; the plots get data and
// the diameter grows (Abah 2022, §2.7.2: a rises from a_min to ~17 mm in the circle's first 2 s).
// Env: TENDRIL_URL, TENDRIL_TOKEN (tests/e2e/run.sh starts the server with config/robots/mbcr_vd.json).
import {test, before, after} from 'node:test';
import assert from 'node:assert/strict';
import path from 'node:path';
import {ARTIFACTS, WAIT, openBrowser, serverUnderTest, tid} from './browser.mjs';

const {BASE_URL, TOKEN} = serverUnderTest();

let context;
let page;
let closeBrowser;
const pageErrors = [];

before(async () => {
  ({context, page, close: closeBrowser} = await openBrowser('mbcr'));
  page.on('pageerror', (err) => pageErrors.push(err.message));
});

after(async () => {
  await closeBrowser?.();
});

const innerRadius = async () => parseFloat(await page.locator(tid('mbcr-radius')).textContent());

test('the reference circle runs from the Diameter tab; the plots fill and the diameter grows', async () => {
  await page.goto(`${BASE_URL}/?token=${encodeURIComponent(TOKEN)}`);
  await page.waitForFunction(() => document.querySelectorAll('[data-testid="robot-select"] option').length === 2,
    null, WAIT);
  // The catheter first: no Diameter tab.
  assert.equal(await page.locator(tid('tab-mbcr')).isHidden(), true);
  await page.locator(tid('robot-select')).selectOption('mbcr');
  await page.waitForSelector(tid('joint-row-diameter'), WAIT);
  assert.match(await page.locator(tid('robot-kind')).textContent(), /mbcr vd/);
  await page.locator(tid('tab-mbcr')).click();
  await page.waitForFunction(() => /mm/.test(document.querySelector('[data-testid="mbcr-diameter"]').textContent), null, WAIT);
  // At rest: a at its start value, the robot straight.
  assert.ok(Math.abs(await innerRadius() - 2.663) < 0.05, `a at rest ${await innerRadius()}`);
  assert.equal(await page.locator(tid('mbcr-margin')).textContent(), 'straight');

  await page.locator('#lease-button').click();
  await page.waitForFunction(() => /lease: yours \(mbcr\)/.test(document.querySelector('[data-testid="lease-status"]').textContent),
    null, WAIT);
  await page.waitForFunction(() => !document.querySelector('[data-testid="enable-button"]').disabled, null, WAIT);
  await page.click(tid('enable-button'));
  await page.waitForFunction(() => document.querySelector('[data-testid="enable-button"]').disabled, null, WAIT);

  await page.locator(tid('mbcr-diameter-variable')).check();
  await page.locator(tid('mbcr-start')).click();
  await page.waitForFunction(() => /circle \(variable\)/.test(document.querySelector('[data-testid="mbcr-motion"]').textContent),
    null, {timeout: 60000});
  // In the circle the diameter grows (to ~17 mm by 1.6 s in the library's run).
  await page.waitForFunction(() => parseFloat(document.querySelector('[data-testid="mbcr-radius"]').textContent) > 10,
    null, WAIT);
  for (const plot of ['mbcr-diameter-plot', 'mbcr-force-plot']) {
    assert.equal(await page.locator(tid(plot)).getAttribute('data-available'), 'true', plot);
  }
  assert.match(await page.locator(tid('mbcr-rms')).textContent(), /N$/);
  // The values come over the WebSocket topic /mbcr/actuation (REST only while it is silent).
  await page.waitForFunction(() => document.querySelector('[data-testid="mbcr-panel"]').dataset.source === 'stream',
    null, WAIT);
  await page.waitForTimeout(2000);
  await page.screenshot({path: path.join(ARTIFACTS, 'mbcr.png')});

  await page.locator(tid('mbcr-stop')).click();
  await page.waitForFunction(() => /^none/.test(document.querySelector('[data-testid="mbcr-motion"]').textContent), null, WAIT);
  assert.deepEqual(pageErrors, []);
});
