// Browser test of issue 31 item 13 against a tendrild with the SIMULATED ultrasound arm (us_arm): the
// robot–world calibration moves the arm through 12 poses in Cartesian control, so the server refuses it
// unless the arm is ENABLED in cartesian mode. The console offered Calibrate in joint mode (then the
// refusal named POST /api/...); now the button is disabled there and says why, in operator words,
// beside it and in its title, and is offered once the arm is ENABLED in cartesian mode.
// Env: TENDRIL_URL, TENDRIL_TOKEN (tests/e2e/run.sh starts the server with config/robots/us_arm.json).
import {test, before, after} from 'node:test';
import assert from 'node:assert/strict';
import path from 'node:path';
import {ARTIFACTS, WAIT, clickWhenEnabled, openBrowser, serverUnderTest, tid} from './browser.mjs';

const {BASE_URL, TOKEN} = serverUnderTest();
const ROBOT = 'us_arm';

let page;
let closeBrowser;
const pageErrors = [];

before(async () => {
  ({page, close: closeBrowser} = await openBrowser('arm-calibrate'));
  page.on('pageerror', (err) => pageErrors.push(err.message));
});

after(async () => {
  await closeBrowser?.();
});

const calibrate = () => page.locator(tid('us-cal-robot-calibrate')).evaluate((b) => ({
  disabled: b.disabled, title: b.title,
  message: document.querySelector('[data-testid="us-cal-robot-message"]').textContent,
}));

test('Calibrate robot says why it is not offered outside an ENABLED arm in cartesian mode', async () => {
  await page.goto(`${BASE_URL}/?token=${encodeURIComponent(TOKEN)}`);
  await page.waitForFunction((r) => [...document.querySelectorAll('[data-testid="robot-select"] option')].some((o) => o.value === r),
                             ROBOT, WAIT);
  await page.selectOption(tid('robot-select'), ROBOT);
  await page.locator(`${tid('tab-robot')}:not([hidden])`).waitFor(WAIT);
  await page.click(tid('tab-robot'));
  await page.locator(tid('us-cal-robot-calibrate')).waitFor(WAIT);
  await page.click(tid('lease-button'));
  await page.waitForFunction(() => document.querySelector('[data-testid="lease-status"]').classList.contains('held'), null, WAIT);
  // DISABLED, joint mode: not offered; the reason says what to do.
  await page.waitForFunction(() => /Not now: .*Enable/.test(document.querySelector('[data-testid="us-cal-robot-message"]').textContent),
                             null, WAIT);
  let c = await calibrate();
  assert.ok(c.disabled, JSON.stringify(c));
  assert.match(c.title, /Not now: the arm moves through 12 poses: Enable it first/, c.title);
  // ENABLED in joint mode: the reason names the mode button to press.
  await page.waitForFunction(() => !document.querySelector('[data-testid="enable-button"]').disabled, null, WAIT);
  await page.click(tid('enable-button'));
  await page.waitForFunction(() => document.querySelector('[data-testid="state-badge"]').dataset.state === 'ENABLED', null, WAIT);
  await page.waitForFunction(() => /press the Cartesian mode button/.test(document.querySelector('[data-testid="us-cal-robot-message"]').textContent),
                             null, WAIT);
  c = await calibrate();
  assert.ok(c.disabled, JSON.stringify(c));
  assert.match(c.message, /Not now: the arm moves through 12 poses in cartesian control: press the Cartesian mode button first \(it is in joint mode\)/, c.message);
  assert.doesNotMatch(c.message + c.title, /POST \/api|REQ-/);
  await page.screenshot({path: path.join(ARTIFACTS, '31-arm-calibrate-joint-mode.png')});
  // The sweep's sentence too: what to press ("no plan yet: press Plan"), not the request.
  await page.waitForFunction(() => document.querySelector('[data-testid="us-message"]').textContent.length > 0, null, WAIT);
  assert.doesNotMatch(await page.locator(tid('us-message')).textContent(), /POST |\{"action"/);
  // Cartesian mode: offered, no reason left.
  // Modes change only while the robot holds: a freshly enabled arm settles first (the badge says busy).
  await page.waitForFunction(() => document.querySelector('[data-testid="state-badge"]').title.includes('busy false'), null, WAIT);
  await clickWhenEnabled(page, tid('mode-cartesian'));
  await page.waitForFunction(() => document.querySelector('[data-testid="mode-cartesian"]').getAttribute('aria-pressed') === 'true',
                             null, WAIT).catch(async (err) => {
    err.message += `; status: ${await page.locator(tid('command-status')).textContent()}`;
    throw err;
  });
  await page.waitForFunction(() => !document.querySelector('[data-testid="us-cal-robot-calibrate"]').disabled, null, WAIT);
  c = await calibrate();
  assert.equal(c.message, '', JSON.stringify(c));
  assert.match(c.title, /run the robot calibration routine/);
  // Leave the arm as it was found.
  await page.click(tid('disable-button'));
  await page.click(tid('lease-button'));
  assert.deepEqual(pageErrors, []);
});
