// The soak's client side (tests/soak/run.sh starts the server): the console open in headless
// Chromium, a Foxglove WebSocket client subscribed to every channel, the robot enabled with a small
// move every SOAK_MOVE_EVERY seconds; every 10 s the robot's state, the server's CPU (per thread) and
// resident memory are sampled. At the end: the safety events, the control loop's statistics from
// /metrics, a summary on stdout and in SOAK_REPORT, and the exit status (0 = no fault or hold that the
// soak did not ask for, no lost WebSocket, no page error).
// Env: TENDRIL_URL, TENDRIL_TOKEN, TENDRIL_PID, SOAK_MINUTES, SOAK_MOVE_EVERY, SOAK_REPORT, CHROMIUM.
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import wsProtocol from '@foxglove/ws-protocol';
import WebSocket from 'ws';
import {chromium} from 'playwright-core';

const {FoxgloveClient} = wsProtocol;
const URL_BASE = process.env.TENDRIL_URL.replace(/\/$/, '');
const TOKEN = process.env.TENDRIL_TOKEN;
const PID = Number(process.env.TENDRIL_PID);
const MINUTES = Number(process.env.SOAK_MINUTES || 60);
const MOVE_EVERY_S = Number(process.env.SOAK_MOVE_EVERY || 60);
const REPORT = process.env.SOAK_REPORT;
const ROBOT = 'srmc';
const CLK_TCK = 100;  // Linux USER_HZ
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const log = (...a) => console.log(new Date().toISOString().slice(11, 19), ...a);

async function call(method, p, body) {
  const headers = {Authorization: `Bearer ${TOKEN}`, 'X-Tendril-Client': 'soak', Accept: 'application/json'};
  if (body !== undefined) headers['Content-Type'] = 'application/json';
  const res = await fetch(`${URL_BASE}/api/v1${p}`, {method, headers, body: body === undefined ? undefined : JSON.stringify(body)});
  const text = await res.text();
  let json = null;
  try {
    json = text ? JSON.parse(text) : null;
  } catch {
    json = null;
  }
  return {status: res.status, json, text};
}

async function metrics() {
  const res = await fetch(`${URL_BASE}/metrics`, {headers: {Authorization: `Bearer ${TOKEN}`}});
  const text = await res.text();
  const value = (name, labels = '') => {
    const line = text.split('\n').find((l) => l.startsWith(name + labels + ' '));
    return line ? Number(line.split(' ').at(-1)) : null;
  };
  return {
    cycles: value('tendril_control_cycles_total'),
    overruns: value('tendril_control_overruns_total'),
    late_cycles: value('tendril_control_late_cycles_total'),
    lost_time_max_us: value('tendril_control_lost_time_max_us'),
    period_error_us: {
      p50: value('tendril_control_period_error_us', '{quantile="0.5"}'),
      p99: value('tendril_control_period_error_us', '{quantile="0.99"}'),
      max: value('tendril_control_period_error_us', '{quantile="1"}'),
    },
    work_us: {
      p50: value('tendril_control_work_us', '{quantile="0.5"}'),
      p99: value('tendril_control_work_us', '{quantile="0.99"}'),
      max: value('tendril_control_work_us', '{quantile="1"}'),
    },
    sched_fifo: value('tendril_control_realtime', '{kind="sched_fifo"}'),
    mlockall: value('tendril_control_realtime', '{kind="mlockall"}'),
  };
}

// CPU seconds of the process and of each thread (summed by thread name).
function cpu() {
  const parse = (stat) => {
    const close = stat.lastIndexOf(')');
    const name = stat.slice(stat.indexOf('(') + 1, close);
    const fields = stat.slice(close + 2).split(' ');
    return {name, seconds: (Number(fields[11]) + Number(fields[12])) / CLK_TCK};
  };
  const total = parse(fs.readFileSync(`/proc/${PID}/stat`, 'utf8')).seconds;
  const threads = {};
  for (const tid of fs.readdirSync(`/proc/${PID}/task`)) {
    try {
      const t = parse(fs.readFileSync(`/proc/${PID}/task/${tid}/stat`, 'utf8'));
      threads[t.name] = (threads[t.name] || 0) + t.seconds;
    } catch {
      // the thread ended meanwhile
    }
  }
  return {total, threads};
}

function rssMb() {
  const m = fs.readFileSync(`/proc/${PID}/status`, 'utf8').match(/VmRSS:\s+(\d+) kB/);
  return m ? Number(m[1]) / 1024 : null;
}

function streamingClient(stats) {
  const ws = new WebSocket(`${URL_BASE.replace(/^http/, 'ws')}/ws?token=${encodeURIComponent(TOKEN)}`,
                           [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
  const client = new FoxgloveClient({ws});
  const topics = new Map();
  client.on('advertise', (channels) => {
    for (const c of channels) {
      const id = client.subscribe(c.id);
      topics.set(id, c.topic);
      stats.messages[c.topic] ??= 0;
    }
  });
  client.on('message', ({subscriptionId}) => {
    const topic = topics.get(subscriptionId);
    if (topic) stats.messages[topic]++;
  });
  client.on('close', () => {
    stats.closed = true;
  });
  client.on('error', (e) => stats.errors.push(String(e?.message ?? e)));
  return {close: () => client.close()};
}

async function waitState(probe, polls = 200) {
  for (let i = 0; i < polls; i++) {
    const s = (await call('GET', `/robots/${ROBOT}/operating_state`)).json;
    if (s && probe(s)) return s;
    await sleep(100);
  }
  return (await call('GET', `/robots/${ROBOT}/operating_state`)).json;
}

async function main() {
  const problems = [];
  const ws = {messages: {}, closed: false, errors: []};
  const samples = [];
  const metricsStart = await metrics();
  const cpuStart = cpu();
  const started = Date.now();

  const userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), 'tendril-soak-'));
  const context = await chromium.launchPersistentContext(userDataDir, {
    executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
    headless: true,
    viewport: {width: 1280, height: 800},
    args: ['--headless=new', '--no-sandbox', '--disable-gpu', '--disable-background-networking',
           '--disable-component-update', '--no-first-run', '--disable-sync', '--disable-quic',
           '--use-angle=swiftshader', '--enable-unsafe-swiftshader'],
  });
  const page = context.pages()[0] ?? await context.newPage();
  const pageErrors = [];
  page.on('pageerror', (err) => pageErrors.push(err.message));
  await page.goto(`${URL_BASE}/?token=${encodeURIComponent(TOKEN)}`);
  const stream = streamingClient(ws);

  // Enable and settle.
  if ((await call('POST', '/lease', {})).status !== 200) problems.push('could not take the lease');
  const enabled = await call('POST', `/robots/${ROBOT}/state_command`, {command: 'enable'});
  if (enabled.status !== 200) problems.push(`enable answered ${enabled.status}: ${enabled.text}`);
  await waitState((s) => s.drives_ready && !s.is_busy);
  log(`soak: ${MINUTES} min, console open, streaming ${Object.keys(ws.messages).length} channels,` +
      ` robot enabled, ${MOVE_EVERY_S > 0 ? `a 2 mm move every ${MOVE_EVERY_S} s` : 'at rest'}`);

  let nextMove = Date.now() + MOVE_EVERY_S * 1000;
  let moves = 0;
  let worstState = null;
  const end = started + MINUTES * 60_000;
  while (Date.now() < end) {
    await sleep(Math.min(10_000, Math.max(0, end - Date.now())));
    const state = (await call('GET', `/robots/${ROBOT}/operating_state`)).json;
    const c = cpu();
    samples.push({t_s: (Date.now() - started) / 1000, state: state?.state, hold: state?.hold_reason ?? null,
                  rss_mb: rssMb(), cpu_s: c.total});
    if (state && state.state !== 'ENABLED') {
      worstState = worstState ?? state;
      problems.push(`at ${Math.round((Date.now() - started) / 1000)} s the robot was ${state.state}` +
                    `${state.fault ? ` (${state.fault.message})` : ''}${state.hold_reason ? ` (${state.hold_reason})` : ''}`);
      break;
    }
    if (MOVE_EVERY_S > 0 && Date.now() >= nextMove) {
      nextMove += MOVE_EVERY_S * 1000;
      const q = (await call('GET', `/robots/${ROBOT}/setpoint_js`)).json.position;
      for (const goal of [[q[0] + 2, q[1], q[2], q[3]], q]) {
        await call('POST', '/lease', {});
        const r = await call('POST', `/robots/${ROBOT}/move_jp`, {goal});
        if (r.status !== 202) problems.push(`move_jp answered ${r.status}: ${r.text}`);
        await waitState((s) => s.is_busy || s.state !== 'ENABLED', 10);  // the move has started
        await waitState((s) => !s.is_busy || s.state !== 'ENABLED');
      }
      moves++;
    }
    if (samples.length % 30 === 0) log(`${Math.round((Date.now() - started) / 60000)} min: ${state?.state}, rss ${rssMb()?.toFixed(0)} MB`);
  }

  const wallS = (Date.now() - started) / 1000;
  const cpuEnd = cpu();
  const metricsEnd = await metrics();
  const finalState = (await call('GET', `/robots/${ROBOT}/operating_state`)).json;
  const events = (await call('GET', '/faults')).json ?? [];
  const faultsAndHolds = (Array.isArray(events) ? events : events.events ?? [])
    .filter((e) => e.kind === 'fault' || e.kind === 'hold' || e.kind === 'estop');
  for (const e of faultsAndHolds) problems.push(`safety event: ${e.kind} ${e.code}: ${e.message}`);
  if (ws.closed) problems.push('the streaming WebSocket closed');
  if (pageErrors.length) problems.push(`console page errors: ${pageErrors.slice(0, 3).join('; ')}`);
  await page.screenshot({path: REPORT.replace(/\.json$/, '.png')}).catch(() => {});
  stream.close();
  await context.close();
  fs.rmSync(userDataDir, {recursive: true, force: true});
  await call('POST', `/robots/${ROBOT}/state_command`, {command: 'disable'});

  const threadShare = {};
  for (const [name, s] of Object.entries(cpuEnd.threads))
    threadShare[name] = Number((((s - (cpuStart.threads[name] || 0)) / wallS) * 100).toFixed(2));
  const report = {
    minutes: wallS / 60,
    moves,
    passed: problems.length === 0,
    problems,
    loop: {
      period_error_us: metricsEnd.period_error_us,
      work_us: metricsEnd.work_us,
      overruns: metricsEnd.overruns - (metricsStart.overruns ?? 0),
      late_cycles: metricsEnd.late_cycles - (metricsStart.late_cycles ?? 0),
      lost_time_max_ms: metricsEnd.lost_time_max_us / 1000,
      cycles: metricsEnd.cycles - metricsStart.cycles,
      sched_fifo: metricsEnd.sched_fifo,
      mlockall: metricsEnd.mlockall,
      timing_record: finalState?.loop_timing,
    },
    cpu_percent_of_a_core: Number((((cpuEnd.total - cpuStart.total) / wallS) * 100).toFixed(2)),
    cpu_percent_by_thread: Object.fromEntries(Object.entries(threadShare).sort((a, b) => b[1] - a[1])),
    rss_mb: {max: Math.max(...samples.map((s) => s.rss_mb ?? 0)), last: rssMb()},
    websocket_messages: ws.messages,
    samples,
  };
  fs.writeFileSync(REPORT, JSON.stringify(report, null, 2));
  const l = report.loop;
  console.log(`soak: ${report.minutes.toFixed(1)} min, ${moves} moves, period error p50/p99/max ` +
              `${l.period_error_us.p50}/${l.period_error_us.p99}/${l.period_error_us.max} us, ` +
              `${l.overruns} overruns, ${l.late_cycles} late cycles, lost time max ${l.lost_time_max_ms.toFixed(1)} ms, ` +
              `CPU ${report.cpu_percent_of_a_core} % of a core, RSS max ${report.rss_mb.max.toFixed(0)} MB`);
  console.log(`soak: report ${REPORT}`);
  for (const p of problems) console.log(`soak: PROBLEM ${p}`);
  console.log(`soak: ${problems.length === 0 ? 1 : 0} passed, ${problems.length === 0 ? 0 : 1} failed`);
  process.exit(problems.length === 0 ? 0 : 1);
}

main().catch((e) => {
  console.error('soak: error', e);
  process.exit(2);
});
