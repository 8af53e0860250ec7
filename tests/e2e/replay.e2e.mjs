// Browser test of the console's replay bar (web/replay.js) against tendrild --replay on a few seconds
// that a live server recorded (tests/e2e/run.sh): the bar appears only in replay mode, Pause/Play, the
// rate selector and the position slider change the server's replay (its GET /replay says so), the time
// reads elapsed / total, and no robot command is offered (the server refuses them: 409 replay_mode).
// Screenshot: tests/e2e/artifacts/replay.png (git-ignored).
// Env: TENDRIL_URL, TENDRIL_TOKEN (tests/e2e/run.sh sets them); CHROMIUM (default /usr/bin/chromium).
import {test, before, after} from 'node:test';
import assert from 'node:assert/strict';
import path from 'node:path';
import {ARTIFACTS, openBrowser, serverUnderTest, tid} from './browser.mjs';

const {BASE_URL, TOKEN} = serverUnderTest();
const WAIT = {timeout: 30000};  // bound on a hung page or server, not a speed assertion

let context;
let page;
let closeBrowser;
const pageErrors = [];

async function replay(method = 'GET', body) {
  const response = await fetch(`${BASE_URL}/api/v1/replay`, {
    method,
    headers: {Authorization: `Bearer ${TOKEN}`, 'Content-Type': 'application/json'},
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  const json = await response.json();
  assert.equal(response.status, 200, JSON.stringify(json));
  return json;
}

// Polls the server's replay state until `check` holds (bounded).
async function until(check, what) {
  const deadline = Date.now() + WAIT.timeout;
  let last;
  while (Date.now() < deadline) {
    last = await replay();
    if (check(last)) return last;
    await new Promise((r) => setTimeout(r, 100));
  }
  throw new Error(`the replay never got ${what}: ${JSON.stringify(last)}`);
}

before(async () => {
  ({context, page, close: closeBrowser} = await openBrowser('replay'));
  page.on('pageerror', (err) => pageErrors.push(err.message));
});

after(async () => {
  await closeBrowser?.();
});

test('the replay bar controls the server\'s replay: pause, play, rate, position; no commands offered', async () => {
  await page.goto(`${BASE_URL}/?token=${encodeURIComponent(TOKEN)}`);
  await page.waitForSelector(`${tid('replay-bar')}:not([hidden])`, WAIT);
  // Slow and from the start once the page is there, so the recording of a few seconds lasts the test.
  const first = await replay();
  await replay('PUT', {position_ns: first.start_ns, rate: 0.25, playing: true});
  await page.waitForFunction(() => document.querySelector('[data-testid="replay-play"]').textContent === 'Pause',
                             null, WAIT);

  await page.click(tid('replay-play'));
  await until((r) => r.playing === false, 'paused');
  await page.waitForFunction(() => document.querySelector('[data-testid="replay-play"]').textContent === 'Play',
                             null, WAIT);
  // Paused, nothing arrives by request: the page says "replay paused" and keeps the ages the data had
  // when it stopped, instead of turning STALE and offline (the age bound is 250 ms; wait well past it).
  await page.waitForTimeout(1500);
  const paused = await page.evaluate(() => ({
    connection: document.querySelector('[data-testid="connection-indicator"]').dataset.kind,
    stale: [...document.querySelectorAll('[data-testid^="age-"]')].filter((el) => el.dataset.stale === 'true')
        .map((el) => `${el.dataset.testid}: ${el.textContent}`),
  }));
  assert.equal(paused.connection, 'replay-paused');
  assert.deepEqual(paused.stale, [], 'no age badge turns STALE while the replay is paused');

  await page.selectOption(tid('replay-rate'), '2');
  await until((r) => r.rate === 2, 'rate 2');

  // The middle of the slider's 0–10000, as a drag ends: input events, then change.
  await page.evaluate(() => {
    const slider = document.querySelector('[data-testid="replay-position"]');
    slider.value = '5000';
    slider.dispatchEvent(new Event('input', {bubbles: true}));
    slider.dispatchEvent(new Event('change', {bubbles: true}));
  });
  const middle = await until((r) => Math.abs(r.position_ns - (r.start_ns + r.end_ns) / 2) < (r.end_ns - r.start_ns) * 0.01,
                             'the middle position');
  assert.equal(middle.playing, false, 'seeking does not start the replay');
  const total = (middle.end_ns - middle.start_ns) / 1e9;
  await page.waitForFunction((t) => {
    const text = document.querySelector('[data-testid="replay-time"]').textContent;
    const [elapsed, all] = text.split(' / ').map((s) => s.split(':').reduce((a, v) => a * 60 + Number(v), 0));
    return Math.abs(all - t) < 0.11 && Math.abs(elapsed - t / 2) < Math.max(0.11, t * 0.02);
  }, total, WAIT);
  assert.match(await page.locator(tid('replay-clock')).textContent(), /^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d\.\d UTC$/);

  await page.click(tid('replay-play'));
  await until((r) => r.playing === true || r.ended === true, 'playing');

  // The robot is not driven: the command buttons (E-STOP included: nothing moves) are not offered.
  assert.equal(await page.locator('.topbar .commands').isVisible(), false, 'no robot commands in a replay');
  await page.screenshot({path: path.join(ARTIFACTS, 'replay.png')});
  assert.deepEqual(pageErrors, []);
});
