// Browser tests of issue 31, "the console as a surgeon drives it", against a tendrild serving the
// SIMULATED catheter (srmc), continuum robot (sdu) and UR5 arm (ur5): a refused mode switch (this
// console's and a script's) at every screen width from 1280 to 2560 px with a hold and an E-STOP
// banner, goals typed before an E-STOP, revolute joints in degrees, switching robots (the stream stays
// live), per-robot tabs and 3D view, the robot kept across a reload, operator words and status lines
// that follow the robot.
// Env: TENDRIL_URL, TENDRIL_TOKEN (tests/e2e/run.sh starts the server with the extra robots).
import {test, before, after} from 'node:test';
import assert from 'node:assert/strict';
import path from 'node:path';
import {ARTIFACTS, WAIT, clickWhenEnabled, openBrowser, serverUnderTest, tid} from './browser.mjs';

const {BASE_URL, TOKEN} = serverUnderTest();

let context;
let page;
let closeBrowser;
const pageErrors = [];

// Another client: a lab engineer's curl-like script with a lease token of its own.
const script = {leaseToken: 'new'};
async function scriptCall(method, urlPath, body) {
  const res = await fetch(`${BASE_URL}/api/v1${urlPath}`, {
    method,
    headers: {'Authorization': `Bearer ${TOKEN}`, 'Content-Type': 'application/json',
              'X-Tendril-Client': 'curl-script', 'X-Tendril-Lease': script.leaseToken},
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  const json = await res.json().catch(() => null);
  return {status: res.status, json};
}

// A refused switch made by the script: it takes the robot's lease, asks for a mode the robot refuses
// (image_guided without a plan: the longest refusal this server gives), and gives the lease back.
async function scriptRefusedSwitch(robot, mode) {
  const granted = await scriptCall('POST', `/robots/${robot}/lease`, {});
  assert.equal(granted.status, 200, JSON.stringify(granted.json));
  script.leaseToken = granted.json.lease_token;
  const refused = await scriptCall('POST', `/robots/${robot}/mode`, {mode});
  assert.equal(refused.status >= 400, true, JSON.stringify(refused.json));
  const released = await scriptCall('DELETE', `/robots/${robot}/lease`);
  assert.equal(released.status, 200, JSON.stringify(released.json));
  return refused.json.error.message;
}

before(async () => {
  ({context, page, close: closeBrowser} = await openBrowser('surgeon', {width: 1600, height: 1000}));
  page.on('pageerror', (err) => pageErrors.push(err.message));
});

after(async () => {
  await closeBrowser?.();
});

async function waitFor(predicate, arg, options = WAIT) {
  try {
    await page.waitForFunction(predicate, arg, options);
  } catch (err) {
    const shot = path.join(ARTIFACTS, `failure-surgeon-${Date.now()}.png`);
    await page.screenshot({path: shot}).catch(() => {});
    err.message += `\nstatus ${await page.locator(tid('command-status')).textContent().catch(() => '?')}; screenshot ${shot}`;
    throw err;
  }
}

const badge = () => page.evaluate(() => document.querySelector('[data-testid="state-badge"]').dataset);

// Clicks a command (once, when it is enabled) and waits for its answer in the status line.
async function command(id, answer) {
  await clickWhenEnabled(page, tid(id));
  await waitFor((source) => new RegExp(source).test(document.querySelector('[data-testid="command-status"]').textContent),
                answer.source);
}

async function openConsole(robot = 'srmc') {
  await page.goto(`${BASE_URL}/?token=${encodeURIComponent(TOKEN)}`);
  await waitFor(() => document.querySelectorAll('[data-testid="robot-select"] option').length === 3);
  if (await page.locator(tid('robot-select')).inputValue() !== robot) await page.selectOption(tid('robot-select'), robot);
  await waitFor(() => document.querySelector('[data-testid="connection-indicator"]').dataset.kind === 'live');
}

async function takeLease(robot = 'srmc') {
  await waitFor(() => !document.querySelector('#lease-button').disabled);
  if (!(await page.locator(tid('lease-status')).evaluate((e) => e.classList.contains('held')))) await page.click(tid('lease-button'));
  await waitFor(() => document.querySelector('[data-testid="lease-status"]').classList.contains('held'));
}

async function releaseLease() {
  if (await page.locator(tid('lease-status')).evaluate((e) => e.classList.contains('held'))) await page.click(tid('lease-button'));
  await waitFor(() => !document.querySelector('[data-testid="lease-status"]').classList.contains('held'));
}

// What the layout gives the strip's parts at this size: every figure the assertions below use.
function measure() {
  return page.evaluate(() => {
    const rect = (el) => {
      const r = el.getBoundingClientRect();
      return {left: r.left, top: r.top, right: r.right, bottom: r.bottom, width: r.width, height: r.height};
    };
    const q = (s) => document.querySelector(s);
    const refusal = q('[data-testid="mode-refusal"]');
    const banner = q('[data-testid="banner"]');
    const text = banner.querySelector('.banner-text');
    const buttons = [...banner.querySelectorAll('button')].filter((b) => !b.hidden).map((b) => {
      const r = rect(b);
      const hit = document.elementFromPoint(r.left + r.width / 2, r.top + r.height / 2);
      return {id: b.dataset.testid, ...r, reachable: !!hit && (hit === b || b.contains(hit))};
    });
    return {
      vw: window.innerWidth, vh: window.innerHeight,
      refusal: refusal.hidden ? null : {...rect(refusal), scrollWidth: refusal.scrollWidth, clientWidth: refusal.clientWidth,
                                        text: refusal.textContent, owner: refusal.dataset.owner},
      banner: {...rect(banner), level: banner.dataset.level, text: banner.textContent.replace(/\s+/g, ' ').trim()},
      bannerText: {...rect(text), scrollWidth: text.scrollWidth, clientWidth: text.clientWidth,
                   scrollHeight: text.scrollHeight, clientHeight: text.clientHeight},
      buttons,
      main: rect(q('main.layout')),
      estop: rect(q('[data-testid="estop-button"]')),
    };
  });
}

function assertLayout(m, what) {
  const say = `${what} at ${m.vw}x${m.vh}: ${JSON.stringify(m)}`;
  if (m.refusal) {
    assert.ok(m.refusal.scrollWidth <= m.refusal.clientWidth + 1, `the refusal wraps within its box: ${say}`);
    assert.ok(m.refusal.right <= m.vw, `the refusal is on screen: ${say}`);
  }
  // The banner gets at least its content: 34rem or the whole row, its words whole, its buttons on screen.
  assert.ok(m.banner.width >= Math.min(m.vw - 4, 500), `the banner keeps its width: ${say}`);
  assert.ok(m.bannerText.scrollWidth <= m.bannerText.clientWidth + 1 && m.bannerText.scrollHeight <= m.bannerText.clientHeight + 1,
            `the banner's words are whole: ${say}`);
  for (const b of m.buttons) {
    assert.ok(b.left >= 0 && b.right <= m.vw && b.top >= 0 && b.bottom <= m.vh, `${b.id} is on screen: ${say}`);
    assert.ok(b.reachable, `${b.id} can be clicked (nothing covers it): ${say}`);
  }
  assert.ok(m.main.height >= 300, `the main area keeps its height: ${say}`);
  assert.ok(m.estop.top >= 0 && m.estop.bottom <= m.vh && m.estop.right <= m.vw, `E-STOP is in view: ${say}`);
}

const WIDTHS = [[1280, 800], [1366, 768], [1600, 1000], [1920, 1080], [2560, 1440]];

async function sweep(label) {
  for (const [width, height] of WIDTHS) {
    await page.setViewportSize({width, height});
    await page.waitForTimeout(300);
    await page.evaluate(() => document.body.scrollTo(0, 0));
    assertLayout(await measure(), label);
    await page.screenshot({path: path.join(ARTIFACTS, `31-${label}-${width}.png`)});
    // Scrolled to the side panel's tabs: E-STOP stays in view.
    await page.evaluate(() => document.querySelector('[data-testid="tab-events"]').scrollIntoView({block: 'end'}));
    const m = await measure();
    assert.ok(m.estop.top >= 0 && m.estop.bottom <= m.vh, `E-STOP in view with the tabs scrolled to (${label}, ${width}): ${JSON.stringify(m.estop)}`);
    await page.evaluate(() => document.body.scrollTo(0, 0));
  }
}

// The robot as a fresh server has it: no e-stop, DISABLED, joint mode, no lease (a run against a
// server that an earlier run left otherwise starts from the same place).
async function fromRest() {
  const os = (await scriptCall('GET', '/robots/srmc/operating_state')).json;
  const granted = await scriptCall('POST', '/lease', {});
  assert.equal(granted.status, 200, JSON.stringify(granted.json));
  script.leaseToken = granted.json.lease_token;
  if (os.estop) assert.equal((await scriptCall('POST', '/estop/reset', {})).status, 200);
  const disabled = await scriptCall('POST', '/robots/srmc/state_command', {command: 'disable'});
  assert.equal(disabled.status, 200, JSON.stringify(disabled.json));
  await scriptCall('POST', '/robots/srmc/mode', {mode: 'joint'});
  await scriptCall('DELETE', '/lease');
}

test('a refused mode switch never collapses the page: own and another client\'s, with a hold and an E-STOP, 1280-2560 px', async () => {
  await fromRest();
  await openConsole('srmc');
  // Another client's refusal first (the console holds no lease): noted compactly and attributed.
  const scriptReason = await scriptRefusedSwitch('srmc', 'image_guided');
  await waitFor(() => !document.querySelector('[data-testid="mode-refusal"]').hidden);
  await sweep('other-refusal');
  await page.setViewportSize({width: 1600, height: 1000});
  let m = await measure();
  assert.equal(m.refusal.owner, 'other', JSON.stringify(m.refusal));
  assert.match(m.refusal.text, /Another client/, m.refusal.text);
  assert.ok(!m.refusal.text.includes(scriptReason), `another client's reason is not this console's error: ${m.refusal.text}`);
  assert.doesNotMatch(await page.locator(tid('command-status')).textContent(), /refused/);

  // This console's own refusal, said whole, while the robot holds (operator pause: Resume offered).
  await page.setViewportSize({width: 1600, height: 1000});
  await takeLease();
  await command('enable-button', /Enable: done/);
  await waitFor(() => document.querySelector('[data-testid="state-badge"]').dataset.state === 'ENABLED');
  await command('mode-image_guided', /Mode Image guided refused/);
  await waitFor(() => document.querySelector('[data-testid="mode-refusal"]').dataset.owner === 'this');
  m = await measure();
  assert.match(m.refusal.text, /Image guided refused: .*plan/i, m.refusal.text);
  // In operator words: what to press, not the request to send (the server's sentence is in the title).
  assert.doesNotMatch(m.refusal.text, /POST \/api|REQ-/, m.refusal.text);
  assert.match(m.refusal.text, /press Load plan in the Plan tab/, m.refusal.text);
  assert.doesNotMatch(await page.locator(tid('command-status')).textContent(), /POST \/api|REQ-/);
  await command('pause-button', /Pause: done/);
  await waitFor(() => document.querySelector('[data-testid="banner"]').dataset.level === 'paused');
  await sweep('own-refusal-paused');

  // An E-STOP with the refusal still kept by the server: the banner says it whole.
  await page.setViewportSize({width: 1600, height: 1000});
  await page.click(tid('estop-button'));
  await waitFor(() => document.querySelector('[data-testid="banner"]').dataset.level === 'estop');
  await sweep('own-refusal-estop');
  await page.setViewportSize({width: 1600, height: 1000});
  await command('estop-reset-button', /Reset e-stop: done/);
  await waitFor(() => document.querySelector('[data-testid="state-badge"]').dataset.estop === 'false');
  assert.deepEqual(pageErrors, []);
});

async function serverJs(robot, what = 'setpoint_js') {
  const r = await scriptCall('GET', `/robots/${robot}/${what}`);
  assert.equal(r.status, 200, JSON.stringify(r.json));
  return r.json.position;
}

async function enable() {
  if ((await badge()).state === 'ENABLED') return;
  await command('enable-button', /Enable: done/);
  await waitFor(() => document.querySelector('[data-testid="state-badge"]').dataset.state === 'ENABLED');
}

test('goals typed before an E-STOP are cleared, and the page says so; Reset and Enable move nothing', async () => {
  await page.setViewportSize({width: 1280, height: 800});
  await takeLease();
  await enable();
  await command('mode-joint', /Mode Joint: done/);
  await page.click(tid('tab-joints'));
  const before = await serverJs('srmc');
  await page.fill(tid('joint-goal-insertion'), String((before[0] + 20).toFixed(2)));
  await page.fill(tid('joint-goal-roll'), '20.0');
  await waitFor(() => /will move: insertion/.test(document.querySelector('[data-testid="move-preview"]').textContent));
  await page.click(tid('estop-button'));
  await waitFor(() => document.querySelector('[data-testid="state-badge"]').dataset.estop === 'true');
  await waitFor(() => !document.querySelector('[data-testid="goals-cleared"]').hidden);
  const cleared = await page.locator(tid('goals-cleared')).textContent();
  assert.match(cleared, /E-STOP cleared the goals you had typed \(insertion .*roll .*20\.0°\)/, cleared);
  assert.equal(await page.locator(tid('move-preview')).textContent(), '', 'no "will move" preview is left');
  for (const j of ['insertion', 'roll']) {
    assert.ok(!(await page.locator(tid(`joint-goal-${j}`)).evaluate((e) => e.classList.contains('edited'))), `${j} goal cleared`);
  }
  await page.screenshot({path: path.join(ARTIFACTS, '31-estop-goals-cleared.png')});
  await command('estop-reset-button', /Reset e-stop: done/);
  await waitFor(() => document.querySelector('[data-testid="state-badge"]').dataset.estop === 'false');
  await enable();
  assert.ok(await page.locator(tid('move-button')).isDisabled(), 'nothing waits to be moved after Reset and Enable');
  await page.waitForTimeout(1000);
  const after = await serverJs('srmc');
  assert.ok(Math.abs(after[0] - before[0]) < 0.01 && Math.abs(after[1] - before[1]) < 0.001, `${before} -> ${after}`);
});

test('a revolute joint is typed, shown and moved in degrees in the Joints tab', async () => {
  await page.click(tid('tab-joints'));
  const limits = await page.locator(tid('joint-limits-roll')).textContent();
  assert.match(limits, /-180\.0 … 180\.0°/, limits);
  assert.equal((await page.locator(`${tid('joint-row-roll')} .goal-unit`).textContent()).trim(), '°');
  await page.fill(tid('joint-goal-roll'), '30');
  await waitFor(() => /roll .* → 30\.0°/.test(document.querySelector('[data-testid="move-preview"]').textContent));
  await command('move-button', /Moving to goal/);
  const until = Date.now() + 15000;
  let roll = NaN;
  while (Date.now() < until) {
    roll = (await serverJs('srmc'))[1];
    if (Math.abs(roll - 30 * Math.PI / 180) < 0.002) break;
    await page.waitForTimeout(200);
  }
  assert.ok(Math.abs(roll - 30 * Math.PI / 180) < 0.002, `30° typed, the server's roll is ${roll} rad`);
  await waitFor(() => Math.abs(Number(document.querySelector('[data-testid="joint-measured-roll"]').textContent) - 30) < 0.5);
  // A stop this console did not make ends a move: the "Moving to …" line says the move stopped (it
  // stayed after a hold). Here an E-STOP pressed elsewhere (needs no lease).
  await page.fill(tid('joint-goal-roll'), '-150');
  await command('move-button', /Moving to goal.*-150\.0°/);
  assert.equal((await scriptCall('POST', '/estop', {})).status, 200);
  await waitFor(() => /Stopped before the goal: E-STOP/.test(document.querySelector('[data-testid="command-status"]').textContent));
  await page.screenshot({path: path.join(ARTIFACTS, '31-stopped-before-goal.png')});
  await command('estop-reset-button', /Reset e-stop: done/);
  await waitFor(() => document.querySelector('[data-testid="state-badge"]').dataset.estop === 'false');
  await enable();
});

test('Enable is neither offered nor green while another operator holds the lease', async () => {
  await command('disable-button', /Disable: done/);
  await releaseLease();
  const granted = await scriptCall('POST', '/robots/srmc/lease', {});
  assert.equal(granted.status, 200, JSON.stringify(granted.json));
  script.leaseToken = granted.json.lease_token;
  try {
    await waitFor(() => document.querySelector('[data-testid="lease-status"]').classList.contains('other'), null, {timeout: 8000});
    await waitFor(() => document.querySelector('[data-testid="state-badge"]').dataset.state === 'DISABLED');
    const enable = await page.locator(tid('enable-button')).evaluate((b) => ({disabled: b.disabled, go: b.classList.contains('btn-go'), title: b.title}));
    assert.ok(enable.disabled && !enable.go, JSON.stringify(enable));
    assert.match(enable.title, /Another operator holds the lease/, enable.title);
  } finally {
    await scriptCall('DELETE', '/robots/srmc/lease');
  }
  await waitFor(() => !document.querySelector('[data-testid="lease-status"]').classList.contains('other'), null, {timeout: 8000});
  await waitFor(() => document.querySelector('[data-testid="enable-button"]').classList.contains('btn-go'));
});

test('switching robots keeps the stream live and the images coming', async () => {
  await page.setViewportSize({width: 1280, height: 800});
  for (const robot of ['ur5', 'sdu', 'srmc', 'ur5', 'srmc', 'sdu', 'ur5', 'srmc']) {
    await page.selectOption(tid('robot-select'), robot);
    const t0 = Date.now();
    // Live again (not "polling (REST)") and the images shown, within a few seconds …
    await waitFor(() => document.querySelector('[data-testid="connection-indicator"]').dataset.kind === 'live' &&
                        document.querySelector('[data-testid="image-ap"]').dataset.state === 'live', null, {timeout: 5000});
    const live = Date.now() - t0;
    // … and it stays on the stream (the old socket's close turned it back to REST polling, for minutes):
    // live, or STALE for a moment on two loaded cores, never polling.
    await page.waitForTimeout(1500);
    const kind = await page.locator(tid('connection-indicator')).getAttribute('data-kind');
    console.log(`# ${robot}: live in ${live} ms, then ${kind}`);
    assert.ok(kind === 'live' || kind === 'stale', `${robot} stays on the stream: ${kind} ` +
              `(${await page.locator(tid('connection-indicator')).textContent()})`);
    assert.equal(await page.evaluate(() => window.tendrilLive.state.wsLive), true, `${robot}: the stream is open`);
    assert.equal(await page.locator(tid('image-ap')).getAttribute('data-state'), 'live', `${robot}: the images keep coming`);
  }
});

test('each robot shows only its own tabs and scene, asks nothing of another\'s, and is kept across a reload', async () => {
  await page.setViewportSize({width: 1280, height: 800});
  const pathRequests = [];
  const count = (response) => {
    if (/\/path_following$/.test(new URL(response.url()).pathname)) pathRequests.push(`${response.status()} ${response.url()}`);
  };
  page.on('response', count);
  try {
    for (const robot of ['ur5', 'sdu', 'srmc', 'ur5', 'srmc', 'sdu']) {
      await page.selectOption(tid('robot-select'), robot);
      await waitFor((r) => document.querySelector('[data-testid="connection-indicator"]').dataset.kind === 'live' &&
                           document.title.startsWith(r.toUpperCase()), robot, {timeout: 5000});
      await page.waitForTimeout(1000);  // the new robot's scene has come
      const s = await page.evaluate(() => ({
        tabs: [...document.querySelectorAll('[role="tab"]')].filter((t) => !t.hidden).map((t) => t.dataset.testid),
        entities: [...window.tendrilLive.view().entities.keys()],
        url: location.search,
      }));
      console.log(`# ${robot}: tabs ${s.tabs.join(' ')}; entities ${s.entities.join(' ')}`);
      const catheter = robot === 'srmc';
      assert.equal(s.tabs.includes('tab-plan'), catheter, `Plan tab for ${robot}: ${s.tabs}`);
      assert.equal(s.tabs.includes('tab-tracking'), catheter, `Tracking tab for ${robot}: ${s.tabs}`);
      const foreign = s.entities.filter((id) => /^[a-z0-9_]+\//.test(id) && !id.startsWith(`${robot}/`) && !id.includes('panel'));
      assert.deepEqual(foreign, [], `the 3D view of ${robot} shows no other robot's objects`);
      assert.match(s.url, new RegExp(`robot=${robot}`));
    }
    // On the arm and the continuum robot no console asks for path following (the arm got a 422 every 5 s).
    await page.selectOption(tid('robot-select'), 'ur5');
    pathRequests.length = 0;
    await page.waitForTimeout(6000);
    assert.deepEqual(pathRequests, [], 'no path-following requests for the arm');
  } finally {
    page.off('response', count);
  }
  await page.screenshot({path: path.join(ARTIFACTS, '31-ur5-tabs.png')});
  // A reload keeps the robot shown (it jumped to the first robot).
  await page.selectOption(tid('robot-select'), 'sdu');
  await page.goto(`${BASE_URL}/?token=${encodeURIComponent(TOKEN)}`);
  await waitFor(() => document.querySelectorAll('[data-testid="robot-select"] option').length === 3);
  await waitFor(() => document.querySelector('[data-testid="joint-row-bending"]') !== null);
  assert.equal(await page.locator(tid('robot-select')).inputValue(), 'sdu');
  assert.deepEqual(pageErrors, []);
});

// The STALE fraction of the page sampled every 100 ms for `seconds`.
function staleFraction(seconds) {
  return page.evaluate(async (s) => {
    let n = 0;
    let stale = 0;
    const t0 = performance.now();
    while (performance.now() - t0 < s * 1000) {
      n++;
      if (document.body.dataset.stale !== 'false') stale++;
      await new Promise((r) => setTimeout(r, 100));
    }
    return stale / n;
  }, seconds);
}

test('a page whose 3D renders take 300 ms sheds its own work and keeps its data current', async () => {
  await page.setViewportSize({width: 1280, height: 800});
  if (!page.url().startsWith(BASE_URL)) await openConsole('srmc');
  await page.selectOption(tid('robot-select'), 'srmc');
  await waitFor(() => document.querySelector('[data-testid="connection-indicator"]').dataset.kind === 'live');
  await page.waitForTimeout(2000);
  // Every render of the 3D view costs 300 ms more (as software rendering on two loaded cores did, and
  // more with a bigger scene), and the view has something new to draw all the time.
  await page.evaluate(() => {
    window.slowFrames = true;
    const renderer = window.tendrilLive.view().renderer;
    const render = renderer.render.bind(renderer);
    renderer.render = (...args) => {
      const t = performance.now();
      if (window.slowFrames) while (performance.now() - t < 300) { /* the frame's cost */ }
      return render(...args);
    };
    // The view changes all the time (as while the robot moves, or the operator turns it).
    const view = window.tendrilLive.view();
    window.keepDirty = setInterval(() => view.requestRender(), 20);
  });
  try {
    await page.waitForTimeout(3000);
    const fraction = await staleFraction(10);
    console.log(`# STALE ${(fraction * 100).toFixed(0)} % of 10 s with 300 ms renders; ${JSON.stringify(await page.evaluate(() => window.tendrilLive.load?.()))}`);
    assert.equal(await page.evaluate(() => document.body.dataset.shedding), 'true', 'the page sheds its own work');
    // The figure is reported, not held to a tight bound on a shared 2-core machine: 2c319b7's console was
    // STALE 17-19 % (and never shed, which the assertion above catches); this one measured 0 % alone and
    // 11 % after the other tests of this file (a 300 ms block of the main thread ages the data whatever
    // the page does; shedding makes the blocks rarer). Half the time STALE would mean the data is lost.
    assert.ok(fraction < 0.5, `STALE ${(fraction * 100).toFixed(0)} % of the time with 300 ms renders`);
  } finally {
    await page.evaluate(() => {
      window.slowFrames = false;
      clearInterval(window.keepDirty);
    });
  }
  // Frames on time again: the page stops shedding.
  await waitFor(() => document.body.dataset.shedding === 'false', null, {timeout: 15000});
});

test('the continuum robot: Roll says why it is not available, in words beside it and in its title', async () => {
  await page.selectOption(tid('robot-select'), 'sdu');
  await waitFor(() => document.querySelector('[data-testid="connection-indicator"]').dataset.kind === 'live');
  await page.click(tid('tab-robot'));
  await waitFor(() => document.querySelector('[data-testid="continuum-roll-why"]')?.textContent.length > 0);
  // Without the lease: the panel's reason.
  await waitFor(() => /Roll: Take the lease/i.test(document.querySelector('[data-testid="continuum-roll-why"]').textContent));
  await takeLease('sdu');
  await waitFor(() => /only while the robot holds on a contact/.test(document.querySelector('[data-testid="continuum-roll-why"]').textContent));
  // (A STALE moment on two loaded cores says that instead, for that moment.)
  await waitFor(() => ['continuum-roll-minus', 'continuum-roll-plus'].every((id) => {
    const b = document.querySelector(`[data-testid="${id}"]`);
    return b.disabled && /only while the robot holds on a contact/.test(b.title);
  }));
  await releaseLease();
});

test('the continuum robot\'s contact hold says what works while held, in operator words, and Roll works from the keyboard', async () => {
  await page.setViewportSize({width: 1280, height: 800});
  await page.selectOption(tid('robot-select'), 'sdu');
  await waitFor(() => document.querySelector('[data-testid="connection-indicator"]').dataset.kind === 'live');
  await takeLease('sdu');
  await page.click(tid('tab-robot'));
  await waitFor(() => !document.querySelector('[data-testid="continuum-arm-reset"]').disabled);
  await page.click(tid('continuum-arm-reset'));
  await enable();
  // Bend toward the SIMULATED arm (23° in the Joints tab, 0.40 rad at the API) and bring the arm in.
  await page.click(tid('tab-joints'));
  await page.fill(tid('joint-goal-bending'), '23');
  await command('move-button', /Moving to goal/);
  await page.click(tid('tab-robot'));
  await page.fill(tid('continuum-arm-speed'), '20');
  await page.click(tid('continuum-arm-approach'));
  await waitFor(() => document.querySelector('[data-testid="continuum-contact"]').dataset.contact === 'true' &&
                      document.querySelector('[data-testid="state-badge"]').dataset.state === 'PAUSED', null, {timeout: 180000});
  await waitFor(() => document.querySelector('[data-testid="banner-next"]').textContent.length > 0);
  const next = await page.locator(tid('banner-next')).textContent();
  // What works while held, in operator words: no request to send, no contact guidance (refused while
  // held), the Roll buttons named as they are on screen.
  assert.doesNotMatch(next, /POST \/api|\/roll|guidance/i, next);
  assert.match(next, /roll along it: press the ◀ Roll \/ Roll ▶ buttons in the Robot tab/, next);
  assert.match(await page.locator(tid('banner-next')).evaluate((e) => e.closest('[data-testid="banner"]').title), /./);
  await page.screenshot({path: path.join(ARTIFACTS, '31-continuum-contact-hold.png')});
  // Roll from the keyboard: Enter held on the focused Roll ▶ rolls, its release stops. (A page that goes
  // STALE while it is held ends the roll by design; then it is pressed again, at most 5 times.)
  const measured = async () => (await scriptCall('GET', '/robots/sdu/measured_js')).json.position;
  let moved = 0;
  let q0;
  let q1;
  for (let attempt = 1; attempt <= 5 && !(moved > 0.005); attempt++) {
    // Available, and then no reason is shown beside it.
    await waitFor(() => !document.querySelector('[data-testid="continuum-roll-plus"]').disabled &&
                        document.querySelector('[data-testid="continuum-roll-why"]').textContent === '');
    q0 = await measured();
    await page.focus(tid('continuum-roll-plus'));
    await page.keyboard.down('Enter');
    await page.waitForTimeout(1500);
    await page.keyboard.up('Enter');
    await page.waitForTimeout(500);
    q1 = await measured();
    moved = Math.max(...q1.map((v, i) => Math.abs(v - q0[i])));
    if (!(moved > 0.005)) console.log(`# keyboard roll attempt ${attempt}: no motion; ${await page.locator(tid('continuum-roll-why')).textContent()}`);
  }
  assert.ok(moved > 0.005, `Enter on Roll ▶ rolled the segment: ${JSON.stringify({q0, q1})}`);
  await page.waitForTimeout(500);
  const q2 = await measured();
  assert.ok(Math.max(...q2.map((v, i) => Math.abs(v - q1[i]))) < 0.002, `released, the roll stopped: ${JSON.stringify({q1, q2})}`);
  await page.click(tid('continuum-arm-retreat'));
  assert.deepEqual(pageErrors, []);
});
