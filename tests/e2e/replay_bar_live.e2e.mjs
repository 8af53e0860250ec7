// Browser test of the replay bar's other side (web/replay.js) against a live server (tests/e2e/run.sh):
// the console learns from GET /api/v1/health (mode "live") that there is no replay, so it never asks for
// GET /api/v1/replay (a live server answers it 404, which the browser showed as a failed request on
// every page load) and shows no replay bar. replay.e2e.mjs covers the replaying server.
// Screenshots: tests/e2e/artifacts/replay-bar-live-{1280,1920}.png (git-ignored).
// Env: TENDRIL_URL, TENDRIL_TOKEN (tests/e2e/run.sh sets them); CHROMIUM (default /usr/bin/chromium).
import {test} from 'node:test';
import assert from 'node:assert/strict';
import path from 'node:path';
import {ARTIFACTS, openBrowser, serverUnderTest, tid} from './browser.mjs';

const {BASE_URL, TOKEN} = serverUnderTest();
const WAIT = {timeout: 30000};  // bound on a hung page or server, not a speed assertion

for (const width of [1280, 1920]) {
  test(`a live server: the console asks no replay and shows no replay bar (${width} px)`, async () => {
    const {page, close} = await openBrowser(`replay-bar-live-${width}`, {width, height: width === 1280 ? 800 : 1080});
    try {
      const asked = [];
      const failed = [];
      page.on('response', (response) => {
        const {pathname} = new URL(response.url());
        if (!pathname.startsWith('/api/')) return;
        asked.push(pathname);
        if (response.status() >= 400) failed.push(`${pathname} ${response.status()}`);
      });
      await page.goto(`${BASE_URL}/?token=${encodeURIComponent(TOKEN)}`);
      await page.waitForFunction(() => document.querySelector('[data-testid="connection-indicator"]')?.dataset.kind === 'live',
                                 null, WAIT);
      // The replay bar decides from the health answer; wait for that answer before judging.
      await page.waitForFunction(() => performance.getEntriesByType('resource')
        .some((entry) => new URL(entry.name).pathname === '/api/v1/health'), null, WAIT);
      await page.screenshot({path: path.join(ARTIFACTS, `replay-bar-live-${width}.png`)});
      assert.ok(asked.includes('/api/v1/health'), `the console read GET /health: ${asked.join(', ')}`);
      assert.ok(!asked.includes('/api/v1/replay'), `a live server is not asked for the replay: ${asked.join(', ')}`);
      assert.deepEqual(failed, [], 'no API request of the page load failed');
      assert.equal(await page.locator(tid('replay-bar')).isHidden(), true, 'no replay bar on a live server');
      assert.equal(await page.evaluate(() => document.body.classList.contains('replaying')), false);
    } finally {
      await close();
    }
  });
}
