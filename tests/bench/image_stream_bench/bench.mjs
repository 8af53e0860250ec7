// Image streaming benchmark: tendrild (simulated bi-plane fluoroscope + joint states over the Foxglove
// WebSocket protocol) against the simplest alternative a lab would build (a Node `ws` broadcast relay
// fed with the same messages). Reports frames/s per client, capture-to-client latency p50/p95 and
// server CPU per client. Never a test: it reports numbers and asserts nothing about speed.
//   node bench.mjs --tendrild build/server/tendrild [--clients 4] [--width 1024] [--fps 30]
//                  [--state-hz 100] [--quality 80] [--duration 15] [--warmup 3] [--encoding json|protobuf]
// --encoding protobuf: tendrild's clients read the images from /imaging/{view}/compressed (protobuf,
// no base64) instead of the JSON /imaging/{view}; the relay is fed the JSON form either way.
import {spawn} from 'node:child_process';
import fs from 'node:fs';
import net from 'node:net';
import os from 'node:os';
import path from 'node:path';
import {fileURLToPath} from 'node:url';
import wsProtocol from '@foxglove/ws-protocol';
import WebSocket from 'ws';

const {FoxgloveClient} = wsProtocol;
const here = path.dirname(fileURLToPath(import.meta.url));
const repo = path.resolve(here, '../../..');
const args = Object.fromEntries(
    process.argv.slice(2).reduce((pairs, a, i, all) => (a.startsWith('--') ? [...pairs, [a.slice(2), all[i + 1]]] : pairs), []));
const opt = {
  tendrild: path.resolve(args.tendrild ?? path.join(repo, 'build/server/tendrild')),
  clients: Number(args.clients ?? 4),
  width: Number(args.width ?? 1024),
  fps: Number(args.fps ?? 30),
  stateHz: Number(args['state-hz'] ?? 100),
  quality: Number(args.quality ?? 80),
  duration: Number(args.duration ?? 15),
  warmup: Number(args.warmup ?? 3),
  encoding: args.encoding ?? 'json',
};
if (!['json', 'protobuf'].includes(opt.encoding)) throw new Error(`--encoding json|protobuf, not ${opt.encoding}`);
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const TICKS = 100;  // USER_HZ on Linux: /proc/<pid>/stat times are in 1/100 s

function cpuSeconds(pid) {
  const stat = fs.readFileSync(`/proc/${pid}/stat`, 'utf8');
  const fields = stat.slice(stat.lastIndexOf(')') + 2).split(' ');
  return (Number(fields[11]) + Number(fields[12])) / TICKS;  // utime + stime
}

// CPU seconds of the threads of `pid` whose name starts with `prefix`.
function threadCpuSeconds(pid, prefix) {
  let total = 0;
  for (const tid of fs.readdirSync(`/proc/${pid}/task`)) {
    try {
      if (!fs.readFileSync(`/proc/${pid}/task/${tid}/comm`, 'utf8').startsWith(prefix)) continue;
      const stat = fs.readFileSync(`/proc/${pid}/task/${tid}/stat`, 'utf8');
      const fields = stat.slice(stat.lastIndexOf(')') + 2).split(' ');
      total += (Number(fields[11]) + Number(fields[12])) / TICKS;
    } catch {}
  }
  return total;
}

// tendrild's CPU over `ms`, split into the imaging threads (rendering + JPEG) and everything else.
async function tendrilCpuOver(pid, ms) {
  const all0 = cpuSeconds(pid), img0 = threadCpuSeconds(pid, 'imaging-');
  const t0 = performance.now();
  await sleep(ms);
  const all1 = cpuSeconds(pid), img1 = threadCpuSeconds(pid, 'imaging-');
  const wall = (performance.now() - t0) / 1000;
  return {total: (all1 - all0) / wall, imaging: (img1 - img0) / wall, rest: (all1 - all0 - (img1 - img0)) / wall,
          imagingSeconds: img1 - img0};
}

// CPU of `pids` (summed) as a fraction of one core over `ms`.
async function cpuOver(pids, ms) {
  const before = pids.map(cpuSeconds);
  const t0 = performance.now();
  await sleep(ms);
  const after = pids.map(cpuSeconds);
  const wall = (performance.now() - t0) / 1000;
  return pids.map((_, i) => (after[i] - before[i]) / wall);
}

function freePort() {
  return new Promise((resolve) => {
    const s = net.createServer();
    s.listen(0, '127.0.0.1', () => {
      const {port} = s.address();
      s.close(() => resolve(port));
    });
  });
}

function runClients(mode, url) {
  return Promise.all(Array.from({length: opt.clients}, () => new Promise((resolve, reject) => {
    const child = spawn(process.execPath, [path.join(here, 'client.mjs'), mode, url, String(opt.warmup), String(opt.duration)],
                        {stdio: ['ignore', 'pipe', 'inherit']});
    let out = '';
    child.stdout.on('data', (d) => (out += d));
    child.on('exit', (code) => {
      try {
        resolve(JSON.parse(out.trim().split('\n').at(-1)));
      } catch {
        reject(new Error(`${mode} client exited ${code} without a result: ${out}`));
      }
    });
  })));
}

// Subscribes to the three topics and keeps the first messages (payload text) of each.
async function record(url, perTopic) {
  const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
  const client = new FoxgloveClient({ws});
  const topics = new Map();
  const kept = {'/srmc/joint_states': [], '/imaging/ap': [], '/imaging/lateral': []};
  const decoder = new TextDecoder();
  await new Promise((resolve) => {
    client.on('advertise', (channels) => {
      for (const c of channels) if (c.topic in kept) topics.set(client.subscribe(c.id), c.topic);
    });
    client.on('message', ({subscriptionId, data}) => {
      const list = kept[topics.get(subscriptionId)];
      if (list && list.length < perTopic) list.push(decoder.decode(data));
      if (Object.values(kept).every((l) => l.length >= perTopic)) resolve();
    });
  });
  client.close();
  return kept;
}

function summarise(results) {
  const mean = (f) => results.reduce((s, r) => s + f(r), 0) / results.length;
  const worst = (f) => Math.max(...results.map(f));
  return {
    ap: mean((r) => r.ap_fps), lateral: mean((r) => r.lateral_fps), state: mean((r) => r.state_hz),
    p50: mean((r) => r.latency_ms.p50 ?? NaN), p95: mean((r) => r.latency_ms.p95 ?? NaN),
    p95worst: worst((r) => r.latency_ms.p95 ?? NaN), mbit: mean((r) => r.mbit_s),
    pub50: mean((r) => r.publish_latency_ms.p50 ?? NaN), pub95: mean((r) => r.publish_latency_ms.p95 ?? NaN),
  };
}

function metricValue(text, name, labels) {
  const line = text.split('\n').find((l) => l.startsWith(name + labels + ' '));
  return line ? Number(line.split(' ').at(-1)) : NaN;
}

async function benchTendril(work) {
  const port = await freePort();
  const token = 'bench-' + Math.random().toString(16).slice(2);
  const config = {
    listen: `127.0.0.1:${port}`, token, web_root: path.join(repo, 'web'), vendor_root: path.join(repo, 'node_modules'),
    control_rate_hz: 1000, publish_rate_hz: opt.stateHz, realtime_priority: true,
    robots: [path.join(repo, 'config/robots/srmc.json')],
    imaging: {enabled: true, width: opt.width, height: opt.width, fps: opt.fps, jpeg_quality: opt.quality},
  };
  fs.writeFileSync(path.join(work, 'server.json'), JSON.stringify(config, null, 2));
  const log = fs.openSync(path.join(work, 'tendrild.log'), 'w');
  const server = spawn(opt.tendrild, ['--config', path.join(work, 'server.json')], {stdio: ['ignore', log, log], cwd: repo});
  const base = `http://127.0.0.1:${port}`;
  for (let i = 0; ; ++i) {
    try {
      if ((await fetch(`${base}/api/v1/health`)).ok) break;
    } catch {}
    if (i > 100 || server.exitCode !== null) throw new Error(`tendrild did not start; see ${work}/tendrild.log`);
    await sleep(200);
  }
  try {
    const wsUrl = `ws://127.0.0.1:${port}/ws?token=${token}`;
    await sleep(2000);
    const idle = await tendrilCpuOver(server.pid, 5000);
    const recorded = await record(wsUrl, 30);
    fs.writeFileSync(path.join(work, 'recorded.json'), JSON.stringify(recorded));
    const clientsDone = runClients(opt.encoding === 'protobuf' ? 'foxglove-protobuf' : 'foxglove', wsUrl);
    await sleep(opt.warmup * 1000);
    const metricsBefore = await (await fetch(`${base}/metrics`, {headers: {Authorization: `Bearer ${token}`}})).text();
    const busy = await tendrilCpuOver(server.pid, opt.duration * 1000);
    const results = await clientsDone;
    const metrics = await (await fetch(`${base}/metrics`, {headers: {Authorization: `Bearer ${token}`}})).text();
    const timing = {};
    for (const view of ['ap', 'lateral']) {
      timing[view] = {
        render_p50_ms: 1000 * metricValue(metrics, 'tendril_imaging_render_seconds', `{view="${view}",quantile="0.5"}`),
        encode_p50_ms: 1000 * metricValue(metrics, 'tendril_imaging_encode_seconds', `{view="${view}",quantile="0.5"}`),
        render_p95_ms: 1000 * metricValue(metrics, 'tendril_imaging_render_seconds', `{view="${view}",quantile="0.95"}`),
        encode_p95_ms: 1000 * metricValue(metrics, 'tendril_imaging_encode_seconds', `{view="${view}",quantile="0.95"}`),
        jpeg_kb: metricValue(metrics, 'tendril_imaging_jpeg_bytes', `{view="${view}"}`) / 1000,
        skipped: metricValue(metrics, 'tendril_imaging_skipped_frames_total', `{view="${view}"}`),
        frames: metricValue(metrics, 'tendril_imaging_frames_total', `{view="${view}"}`),
      };
    }
    const dropped = metricValue(metrics, 'tendril_ws_messages_dropped_total', '');
    const framesInWindow = ['ap', 'lateral'].reduce(
        (n, v) => n + metricValue(metrics, 'tendril_imaging_frames_total', `{view="${v}"}`) -
            metricValue(metricsBefore, 'tendril_imaging_frames_total', `{view="${v}"}`), 0);
    timing.cpu_ms_per_frame = (1000 * busy.imagingSeconds) / framesInWindow;
    return {idle, busy, results, timing, dropped};
  } finally {
    server.kill('SIGTERM');
    await new Promise((r) => server.exitCode !== null ? r() : server.on('exit', r));
  }
}

async function benchRelay(work) {
  const port = await freePort();
  const relay = spawn(process.execPath, [path.join(here, 'relay.mjs'), String(port)], {stdio: ['ignore', 'pipe', 'inherit']});
  await new Promise((r) => relay.stdout.once('data', r));
  const feeder = spawn(process.execPath, [path.join(here, 'feeder.mjs'), `ws://127.0.0.1:${port}`,
                                          path.join(work, 'recorded.json'), String(opt.stateHz), String(opt.fps)],
                       {stdio: ['ignore', 'pipe', 'inherit']});
  await new Promise((r) => feeder.stdout.once('data', r));
  try {
    await sleep(2000);
    const [idle, feederIdle] = await cpuOver([relay.pid, feeder.pid], 5000);
    const clientsDone = runClients('relay', `ws://127.0.0.1:${port}`);
    await sleep(opt.warmup * 1000);
    const [busy, feederBusy] = await cpuOver([relay.pid, feeder.pid], opt.duration * 1000);
    const results = await clientsDone;
    return {idle, busy, feederIdle, feederBusy, results};
  } finally {
    feeder.kill();
    relay.kill();
  }
}

const fmt = (v, d = 1) => (Number.isFinite(v) ? v.toFixed(d) : 'n/a');
const work = fs.mkdtempSync(path.join(os.tmpdir(), 'tendril-image-bench-'));
console.log(`image_stream_bench: ${opt.clients} clients, state ${opt.stateHz} Hz, 2 × ${opt.width}×${opt.width} JPEG ` +
            `(quality ${opt.quality}) at ${opt.fps} fps, tendrild images as ${opt.encoding}, ${opt.duration} s measured after ${opt.warmup} s warm-up; ` +
            `${os.cpus().length} CPUs, load ${os.loadavg().map((l) => l.toFixed(1)).join(' ')}`);
const t = await benchTendril(work);
const r = await benchRelay(work);
const ts = summarise(t.results), rs = summarise(r.results);

console.log('\nper client                      AP fps  LAT fps  state Hz  capture→client p50/p95/max ms  send→client p50/p95 ms  Mbit/s');
const row = (name, c) => console.log(
    `${name.padEnd(30)} ${fmt(c.ap_fps).padStart(6)} ${fmt(c.lateral_fps).padStart(8)} ${fmt(c.state_hz).padStart(9)} ` +
    `${(fmt(c.latency_ms.p50) + ' / ' + fmt(c.latency_ms.p95) + ' / ' + fmt(c.latency_ms.max)).padStart(29)} ` +
    `${(fmt(c.publish_latency_ms.p50) + ' / ' + fmt(c.publish_latency_ms.p95)).padStart(23)} ${fmt(c.mbit_s).padStart(7)}`);
t.results.forEach((c, i) => row(`tendril client ${i + 1}`, c));
r.results.forEach((c, i) => row(`node ws relay client ${i + 1}`, c));

// Serving cost per client: tendrild without its imaging threads (rendering does not depend on clients).
const tPer = (t.busy.rest - t.idle.rest) / opt.clients, rPer = (r.busy - r.idle) / opt.clients;
console.log('\nserver CPU (% of one core)     0 clients  ' + `${opt.clients} clients  per client`);
console.log(`tendrild without imaging       ${fmt(100 * t.idle.rest).padStart(9)}  ${fmt(100 * t.busy.rest).padStart(9)}  ${fmt(100 * tPer).padStart(10)}`);
console.log(`tendrild imaging threads       ${fmt(100 * t.idle.imaging).padStart(9)}  ${fmt(100 * t.busy.imaging).padStart(9)}` +
            `   (${fmt(t.timing.cpu_ms_per_frame, 2)} ms CPU per frame; full rate needs ${fmt(0.2 * opt.fps * t.timing.cpu_ms_per_frame)} % of a core)`);
console.log(`node ws relay                  ${fmt(100 * r.idle).padStart(9)}  ${fmt(100 * r.busy).padStart(9)}  ${fmt(100 * rPer).padStart(10)}`);
console.log(`  (its feeder process          ${fmt(100 * r.feederIdle).padStart(9)}  ${fmt(100 * r.feederBusy).padStart(9)})`);
for (const view of ['ap', 'lateral']) {
  const v = t.timing[view];
  console.log(`tendril ${view.padEnd(8)} render p50/p95 ${fmt(v.render_p50_ms)}/${fmt(v.render_p95_ms)} ms, ` +
              `JPEG+base64 p50/p95 ${fmt(v.encode_p50_ms)}/${fmt(v.encode_p95_ms)} ms, JPEG ${fmt(v.jpeg_kb)} kB, ` +
              `${v.frames} frames, ${v.skipped} exposures skipped`);
}
console.log(`tendril newest-only drops (all clients): ${t.dropped}`);
console.log('\nsummary (mean over clients)    AP fps  LAT fps  state Hz  capture p50/p95 ms  send→client p50/p95 ms  CPU/client %');
const sumRow = (name, s, per) => console.log(
    `${name.padEnd(30)} ${fmt(s.ap).padStart(6)} ${fmt(s.lateral).padStart(8)} ${fmt(s.state).padStart(9)} ` +
    `${(fmt(s.p50) + ' / ' + fmt(s.p95)).padStart(19)} ${(fmt(s.pub50) + ' / ' + fmt(s.pub95)).padStart(23)} ${fmt(100 * per, 2).padStart(13)}`);
sumRow('tendril', ts, tPer);
sumRow('node ws relay', rs, rPer);
console.log(`ratio tendril / relay: send→client latency p50 ${fmt(ts.pub50 / rs.pub50, 2)}, p95 ${fmt(ts.pub95 / rs.pub95, 2)}; ` +
            `capture→client p50 ${fmt(ts.p50 / rs.p50, 2)}, p95 ${fmt(ts.p95 / rs.p95, 2)}; ` +
            `CPU per client ${fmt(tPer / rPer, 2)}; image fps ${fmt((ts.ap + ts.lateral) / (rs.ap + rs.lateral), 2)}`);
console.log('note: tendril\'s capture→client includes rendering + JPEG; its send→client starts when the encoded frame ' +
            'is ready (message header log time). The relay\'s feeder sends already-encoded frames, so for it both are the same.');
console.log(`machine load average at the end: ${os.loadavg().map((l) => l.toFixed(1)).join(' ')}`);
console.log(`work files: ${work}`);
