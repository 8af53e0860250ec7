// Load classes that once delayed the e-stop (issue 30), and the e-stop probe that times it under each.
// Shared by the CI suite (estop_under_load.test.mjs, a few e-stops per class against the sanitized
// tendrild) and the bench (tests/bench/estop_latency.mjs, hundreds per class, for a person to read).
//
// Every load is bounded in time (the class's deadline) and in count (requests, connections), and
// talks to 127.0.0.1 only. A load reports what it did (requests, answers by status, connection
// errors); nothing is swallowed: an unexpected status or a failed request is counted and shown.
//
// One e-stop sample = the request sent → its answer: REST `POST /api/v1/estop` on a new TCP
// connection each time (connect + request + 200), or the Foxglove `estop` service on a WebSocket
// opened while the load runs (service call → its response with status 200). After each sample the
// latched e-stop is checked (GET operating_state: estop true) and reset with the lease, untimed, so
// every sample is a real latch.
import http from 'node:http';
import net from 'node:net';
import {performance} from 'node:perf_hooks';
import wsProtocol from '@foxglove/ws-protocol';
import WebSocket from 'ws';

const {FoxgloveClient} = wsProtocol;  // CommonJS package: no named ESM exports
const ROBOT = 'srmc';

// The server under test, from its URL (TENDRIL_URL) and token; refuses anything but loopback.
export function target(url, token) {
  const u = new URL(url);
  if (u.protocol !== 'http:' || !['127.0.0.1', 'localhost'].includes(u.hostname)) {
    throw new Error(`the e-stop load runs against http://127.0.0.1 only, not ${url}`);
  }
  if (!token) throw new Error('a token is needed (TENDRIL_TOKEN)');
  return {host: '127.0.0.1', port: Number(u.port), token};
}

// One HTTP request. agent: false = a new TCP connection closed after the answer. Resolves with
// {status, text, ms} or, when the connection failed or `timeoutMs` passed first, {status: 0, error}.
export function request(t, {method = 'GET', path, headers = {}, body, agent = false, timeoutMs = 10000}) {
  return new Promise((resolve) => {
    const started = performance.now();
    const h = {Authorization: `Bearer ${t.token}`, ...headers};
    if (body !== undefined) h['Content-Length'] = Buffer.byteLength(body);
    let settled = false;
    const done = (r) => {
      if (settled) return;
      settled = true;
      clearTimeout(timer);
      resolve({...r, ms: performance.now() - started});
    };
    const req = http.request({host: t.host, port: t.port, method, path, headers: h, agent});
    const timer = setTimeout(() => {
      done({status: 0, error: `no answer within ${timeoutMs} ms`});
      req.destroy();
    }, timeoutMs);
    req.on('response', (res) => {
      const chunks = [];
      res.on('data', (c) => chunks.push(c));
      res.on('end', () => done({status: res.statusCode, text: Buffer.concat(chunks).toString('utf8')}));
      res.on('error', (e) => done({status: 0, error: `answer cut off: ${e.message}`}));
    });
    req.on('error', (e) => done({status: 0, error: `${e.code || ''} ${e.message}`.trim()}));
    if (body !== undefined) req.write(body);
    req.end();
  });
}

// Requests that manage the robot between samples (lease, reset, state, health) on one kept connection.
export function controlClient(t) {
  const agent = new http.Agent({keepAlive: true, maxSockets: 1});
  const json = {'Content-Type': 'application/json', 'X-Tendril-Client': 'estop-load-control'};
  return {
    agent,
    post: (path, body = {}, timeoutMs = 10000) =>
      request(t, {method: 'POST', path: `/api/v1${path}`, headers: json, body: JSON.stringify(body), agent, timeoutMs}),
    get: (path, timeoutMs = 10000) => request(t, {path: `/api/v1${path}`, headers: json, agent, timeoutMs}),
    close: () => agent.destroy(),
  };
}

// ---- e-stop probes --------------------------------------------------------------------------------

export async function restEstop(t, timeoutMs) {
  const r = await request(t, {method: 'POST', path: '/api/v1/estop', body: '{}', timeoutMs,
    headers: {'Content-Type': 'application/json', 'X-Tendril-Client': 'estop-probe'}});
  return {kind: 'rest', ms: r.ms, ok: r.status === 200, detail: r.status === 200 ? '' : r.error || `HTTP ${r.status}: ${r.text}`};
}

// A Foxglove client (operator token) opened now; resolves once the estop service is advertised,
// or with {error} after timeoutMs. call() times one estop service call → its response.
export function openEstopSocket(t, timeoutMs) {
  const started = performance.now();
  return new Promise((resolve) => {
    const url = `ws://${t.host}:${t.port}/ws?token=${encodeURIComponent(t.token)}`;
    const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL], {headers: {'X-Tendril-Client': 'estop-probe-ws'}});
    const client = new FoxgloveClient({ws});
    const waiting = new Map();  // callId -> resolve
    let closed = '';
    let nextCall = 1;
    let advertised = false;
    const fail = (why) => {
      if (!closed) closed = why;
      for (const w of waiting.values()) w({error: why});
      waiting.clear();
      if (!advertised) {  // refused or closed during the handshake: said at once
        clearTimeout(timer);
        resolve({error: `the WebSocket failed before it advertised its services: ${why} (after ${(performance.now() - started).toFixed(1)} ms)`,
          close: () => ws.terminate()});
      }
    };
    const timer = setTimeout(() => {
      resolve({error: `the WebSocket did not advertise its services within ${timeoutMs} ms`, close: () => ws.terminate()});
    }, timeoutMs);
    client.on('error', (e) => fail(`WebSocket error: ${e?.message ?? e}`));
    client.on('close', (e) => fail(`WebSocket closed (code ${e?.code ?? '?'})`));
    client.on('serviceCallResponse', (m) => {
      const w = waiting.get(m.callId);
      if (!w) return;
      waiting.delete(m.callId);
      w({data: new TextDecoder().decode(new Uint8Array(m.data.buffer, m.data.byteOffset, m.data.byteLength))});
    });
    client.on('advertiseServices', (services) => {
      const estop = services.find((s) => s.name === 'estop');
      if (!estop || advertised || closed) return;
      advertised = true;
      clearTimeout(timer);
      resolve({
        openMs: performance.now() - started,
        close: () => client.close(),
        async call(callTimeoutMs) {
          if (closed) return {kind: 'ws', ms: 0, ok: false, detail: closed};
          const callId = nextCall++;
          const t0 = performance.now();
          const answer = await new Promise((res) => {
            const timeout = setTimeout(() => {
              waiting.delete(callId);
              res({error: `no service response within ${callTimeoutMs} ms`});
            }, callTimeoutMs);
            waiting.set(callId, (a) => {
              clearTimeout(timeout);
              res(a);
            });
            client.sendServiceCallRequest({serviceId: estop.id, callId, encoding: 'json', data: new TextEncoder().encode('{}')});
          });
          const ms = performance.now() - t0;
          if (answer.error) return {kind: 'ws', ms, ok: false, detail: answer.error};
          let status = 0;
          try {
            status = JSON.parse(answer.data).status;
          } catch (e) {
            return {kind: 'ws', ms, ok: false, detail: `service response is not JSON (${e.message}): ${answer.data}`};
          }
          return {kind: 'ws', ms, ok: status === 200, detail: status === 200 ? '' : answer.data};
        },
      });
    });
  });
}

// ---- loads ----------------------------------------------------------------------------------------

// `loops` clients, each sending `make(i)` one after the other on a kept connection until stop() or
// the deadline, at most maxRequests each. `expected` lists the answers that count as clean.
function requestLoops(t, {name, loops, maxRequests = 100000, timeoutMs = 60000, expected, make, after}) {
  const stats = {name, requests: 0, statuses: {}, unexpected: [], inFlight: 0, perLoop: Array(loops).fill(0)};
  let stopping = false;
  let deadline = Infinity;
  const agents = [];
  const runs = [];
  const run = async (i, agent) => {
    for (let n = 0; n < maxRequests && !stopping && performance.now() < deadline; n++) {
      stats.inFlight++;
      const r = await request(t, {...make(i), agent, timeoutMs});
      stats.inFlight--;
      stats.requests++;
      stats.perLoop[i]++;
      const key = r.status === 0 ? 'no answer' : String(r.status);
      stats.statuses[key] = (stats.statuses[key] || 0) + 1;
      if (!expected.includes(r.status)) {
        if (stats.unexpected.length < 5) stats.unexpected.push(`${key}: ${(r.error || r.text || '').slice(0, 200)}`);
      } else if (after) {
        await after(r, agent, stats);
      }
    }
  };
  return {
    stats,
    start(maxMs) {
      deadline = performance.now() + maxMs;
      for (let i = 0; i < loops; i++) {
        const agent = new http.Agent({keepAlive: true, maxSockets: 1});
        agents.push(agent);
        runs.push(run(i, agent));
      }
    },
    ready: () => runs.length === loops,  // each loop sent its first request at start()
    async stop() {
      stopping = true;
      await Promise.all(runs);
      for (const a of agents) a.destroy();
      return stats;
    },
    describe: () => `${loops} loop(s), ${stats.requests} requests, answers ${JSON.stringify(stats.statuses)}`,
    problems: () => [
      ...stats.unexpected.map((u) => `unexpected answer ${u}`),
      ...stats.perLoop.flatMap((n, i) => (n > 0 ? [] : [`loop ${i} got no answer at all`])),
    ],
  };
}

// A JSON array of `count` small objects, [{"a":1},{"a":1},...], filling about `bytes`.
function objectArray(bytes) {
  return `[${Array(Math.max(1, Math.floor(bytes / 8))).fill('{"a":1}').join(',')}]`;
}

// A centerline CSV (x,y,z,r mm, gently curved) of about `bytes`, built once. The points are at most
// 0.2 mm apart and closer for a large file: the server refuses a centerline longer than 10 m.
export function vesselCsv(bytes) {
  const spacing = Math.min(0.2, 8000 / (bytes / 31));
  const lines = ['x,y,z,r'];
  let size = 8;
  for (let i = 0; size < bytes; i++) {
    const z = spacing * i;
    const line = `${(5 * Math.sin(z * 0.01)).toFixed(4)},${(3 * Math.cos(z * 0.0065)).toFixed(4)},${z.toFixed(4)},2.5000`;
    lines.push(line);
    size += line.length + 1;
  }
  return Buffer.from(lines.join('\n') + '\n');
}

const viewer = {'X-Tendril-Role': 'viewer'};

// The classes, in the order they run (the idle connections last: a server that ran out of descriptors
// may not recover). `start(t)` returns a load, or null (idle): start(maxMs), ready(), stop() → its
// stats, describe(), problems() (empty when it ended cleanly: only expected answers, every loop answered).
export function loadClasses({vesselBytes = 16 << 20, idleConnections = 2000, reopen = false} = {}) {
  let csv = null;  // built on first use, shared by both upload loops
  return [
    {name: 'idle', what: 'no load', start: () => null},
    {
      name: 'json_viewers',
      what: 'two viewers posting 64 KiB array-of-objects bodies to move_jp in a loop',
      start: (t) => {
        // 64,000 bytes: under the 64 KiB body limit of command routes.
        const head = '{"position":[0,0,0,0],"pad":';
        const body = head + objectArray(64000 - head.length - 2) + '}';
        return requestLoops(t, {
          name: 'json_viewers', loops: 2, expected: [400, 403, 429, 503],
          make: (i) => ({method: 'POST', path: `/api/v1/robots/${ROBOT}/move_jp`, body,
            headers: {...viewer, 'Content-Type': 'application/json', 'X-Tendril-Client': `load-viewer-${i}`}}),
        });
      },
    },
    {
      name: 'calibration_json',
      what: 'two operators (no lease) posting 147 KiB calibrations bodies (outlines: an array of objects) in a loop',
      start: (t) => {
        const head = '{"segment":"distal","outlines":';
        const body = head + objectArray(147 * 1024 - head.length - 2) + '}';
        return requestLoops(t, {
          name: 'calibration_json', loops: 2, expected: [400, 422, 429, 503],
          make: (i) => ({method: 'POST', path: `/api/v1/robots/${ROBOT}/calibrations`, body,
            headers: {'Content-Type': 'application/json', 'X-Tendril-Client': `load-calibration-${i}`}}),
        });
      },
    },
    {
      name: 'side_view',
      what: 'four viewers fetching calibration/side_view pictures in a loop',
      start: (t) => requestLoops(t, {
        name: 'side_view', loops: 4, expected: [200, 429, 503],
        make: (i) => ({path: `/api/v1/robots/${ROBOT}/calibration/side_view?segment=distal&actuation_mm=1`,
          headers: {...viewer, 'X-Tendril-Client': `load-side-view-${i}`}}),
      }),
    },
    {
      name: 'vessel_uploads',
      what: `two operators uploading ${(vesselBytes / 1048576).toFixed(0)} MiB vessel CSVs in a loop (each deleted after)`,
      start: (t) => {
        csv ??= vesselCsv(vesselBytes);
        return requestLoops(t, {
          name: 'vessel_uploads', loops: 2, maxRequests: 50, expected: [201, 429, 503],
          make: (i) => ({method: 'POST', path: '/api/v1/vessels?name=estop-load', body: csv,
            headers: {'Content-Type': 'text/csv', 'X-Tendril-Client': `load-vessel-${i}`}}),
          // Keeps the server's memory bounded: each stored vessel is forgotten again at once.
          after: async (r, agent, stats) => {
            const id = JSON.parse(r.text).id;
            const d = await request(t, {method: 'DELETE', path: `/api/v1/vessels/${id}`, agent, timeoutMs: 60000});
            if (d.status !== 200 && stats.unexpected.length < 5) stats.unexpected.push(`DELETE /vessels/${id}: ${d.status} ${d.error || d.text}`);
          },
        });
      },
    },
    {
      name: 'idle_connections',
      what: `${idleConnections} idle unauthenticated TCP connections held open${reopen ? ' (reopened when closed)' : ''}`,
      readyMs: 15000,  // the server's accept() works through the burst first
      start: (t) => idleConnectionLoad(t, idleConnections, {reopen}),
    },
  ];
}

// `count` TCP connections that send nothing, held open. The kernel completes every handshake at once
// and queues the connections for the server's accept(); the load is ready when the server has worked
// through that burst: a GET /health on a new connection, queued behind them, answered (absorbMs). A
// server out of descriptors never answers it; runClass then measures anyway after readyMs. With
// `reopen`, a connection the server closes is opened again 100 ms later (an attacker's reconnect
// flood: a different load, kept out of CI), at most 4 × count opens in all (more would run the
// loopback out of ephemeral ports while the closed ones sit in TIME_WAIT). Client-side errors (EMFILE,
// EADDRNOTAVAIL) mean the test machine, not the server, ran out: they make the load unclean.
function idleConnectionLoad(t, count, {reopen = false} = {}) {
  const stats = {name: 'idle_connections', opens: 0, connected: 0, open: 0, peakOpen: 0, closedByServer: 0, settled: 0,
    absorbMs: NaN, absorbError: '', clientErrors: {}, serverErrors: {}};
  const sockets = new Set();
  let stopping = false;
  let deadline = Infinity;
  let started = 0;
  let probe = null;
  const maxOpens = reopen ? 4 * count : count;
  const clientSide = new Set(['EMFILE', 'ENFILE', 'EADDRNOTAVAIL', 'ENOBUFS', 'ENOMEM']);
  const open = () => {
    if (stopping || stats.opens >= maxOpens || performance.now() > deadline) return;
    stats.opens++;
    const s = net.connect({host: t.host, port: t.port});
    sockets.add(s);
    let connected = false;
    let settled = false;
    const settle = () => {
      if (!settled) stats.settled++;
      settled = true;
    };
    s.on('connect', () => {
      settle();
      connected = true;
      stats.connected++;
      stats.open++;
      stats.peakOpen = Math.max(stats.peakOpen, stats.open);
    });
    s.on('data', () => {});  // an answer (e.g. 408 or 503) is read and dropped
    s.on('error', (e) => {
      const table = clientSide.has(e.code) ? stats.clientErrors : stats.serverErrors;
      table[e.code || e.message] = (table[e.code || e.message] || 0) + 1;
    });
    s.on('close', () => {
      settle();
      sockets.delete(s);
      if (connected) stats.open--;
      if (stopping) return;
      if (connected) stats.closedByServer++;
      if (reopen) setTimeout(open, 100);
    });
  };
  return {
    stats,
    start(maxMs) {
      deadline = performance.now() + maxMs;
      started = performance.now();
      for (let i = 0; i < count; i++) open();
    },
    ready: () => {
      if (stats.settled < count) return false;
      probe ??= request(t, {path: '/api/v1/health', timeoutMs: Math.max(1000, deadline - performance.now())}).then((r) => {
        if (r.status === 200) stats.absorbMs = performance.now() - started;
        else stats.absorbError = r.error || `HTTP ${r.status}`;
      });
      return Number.isFinite(stats.absorbMs);
    },
    async stop() {
      stopping = true;
      for (const s of sockets) s.destroy();
      sockets.clear();
      if (probe) await probe;
      return stats;
    },
    describe: () => `${stats.opens} opens, ${stats.connected} connected, at most ${stats.peakOpen} open at once, ` +
      `${stats.closedByServer} closed by the server, errors ${JSON.stringify({...stats.serverErrors, ...stats.clientErrors})}; ` +
      `burst absorbed (a new connection's GET /health answered) ${Number.isFinite(stats.absorbMs) ? `after ${fmt(stats.absorbMs)} ms` : `never: ${stats.absorbError || 'not within the class'}`}`,
    problems: () => [
      ...Object.entries(stats.clientErrors).map(([k, n]) => `client-side ${k} ×${n} (raise ulimit -n for the test)`),
      ...(stats.connected > 0 ? [] : ['no connection was accepted at all']),
    ],
  };
}

// ---- one class --------------------------------------------------------------------------------------

export function percentile(values, p) {
  if (values.length === 0) return NaN;
  const sorted = [...values].sort((a, b) => a - b);
  return sorted[Math.min(sorted.length - 1, Math.max(0, Math.ceil((p / 100) * sorted.length) - 1))];
}

export function summary(values) {
  return {n: values.length, p50: percentile(values, 50), p99: percentile(values, 99), max: values.length ? Math.max(...values) : NaN};
}

export const fmt = (ms) => (Number.isFinite(ms) ? ms.toFixed(1) : '-');

// Runs one class: starts its load, waits until the server has the work (at most readyMs), opens a
// WebSocket, then `rounds` rounds of a REST and a WebSocket e-stop (each followed by the state check
// and the reset), spread over at least spreadMs, until classMs is over or an e-stop went unanswered; stops the load and waits for its
// requests to end; resets the e-stop and asks GET /health. Returns every figure; asserts nothing.
export async function runClass(t, cls, {rounds, spreadMs = 0, sampleTimeoutMs = 5000, classMs = 20000, log = () => {}}) {
  const readyMs = cls.readyMs ?? 5000;
  const control = controlClient(t);
  const result = {name: cls.name, what: cls.what, rest: [], ws: [], failures: [], load: null, wsOpenMs: NaN, health: null};
  // The lease first, on the control connection kept through the class (the reset needs the lease).
  const lease = async () => {
    const l = await control.post('/lease');
    if (l.status !== 200) result.failures.push(`POST /lease: ${l.status} ${l.error || l.text}`);
  };
  await lease();
  let leaseAt = performance.now();
  const load = cls.start(t);
  const classStart = performance.now();
  try {
    if (load) {
      load.start(classMs + readyMs);
      const readyBy = performance.now() + readyMs;
      while (!load.ready() && performance.now() < readyBy) await new Promise((r) => setTimeout(r, 20));
      await new Promise((r) => setTimeout(r, 300));  // the server is inside the work
    }
    const socket = await openEstopSocket(t, sampleTimeoutMs);
    if (socket.error) result.failures.push(socket.error);
    else result.wsOpenMs = socket.openMs;
    const sampleStart = performance.now();
    const sampleEnd = sampleStart + classMs;
    const afterSample = async (s) => {
      (s.kind === 'rest' ? result.rest : result.ws).push(s.ms);
      if (!s.ok) {
        result.failures.push(`${s.kind} e-stop ${s.kind === 'rest' ? result.rest.length : result.ws.length}: ${s.detail} (after ${fmt(s.ms)} ms)`);
        return false;
      }
      // An answered e-stop is latched: operating_state says so at once. When it does not, it is read
      // again for up to a second to tell a late latch from a lost e-stop (both fail).
      const latched = async () => {
        const st = await control.get(`/robots/${ROBOT}/operating_state`);
        return {st, yes: st.status === 200 && JSON.parse(st.text).estop === true};
      };
      const first = await latched();
      if (!first.yes) {
        const t0 = performance.now();
        let later = first;
        while (!later.yes && performance.now() - t0 < 1000) {
          await new Promise((r) => setTimeout(r, 10));
          later = await latched();
        }
        const when = later.yes ? `it said estop true ${fmt(performance.now() - t0)} ms later` : 'and still not 1 s later (the e-stop was lost)';
        result.failures.push(`after a ${s.kind} e-stop answered 200, operating_state did not say estop true (${when}); ` +
          `first read: ${first.st.status} ${first.st.error || first.st.text.slice(0, 300)}`);
      }
      if (performance.now() - leaseAt > 15000) {
        await lease();
        leaseAt = performance.now();
      }
      const reset = await control.post('/estop/reset');
      if (reset.status !== 200) result.failures.push(`POST /estop/reset: ${reset.status} ${reset.error || reset.text}`);
      return true;
    };
    for (let round = 0; round < rounds && performance.now() < sampleEnd; round++) {
      if (!(await afterSample(await restEstop(t, sampleTimeoutMs)))) break;
      if (!socket.error && !(await afterSample(await socket.call(sampleTimeoutMs)))) break;
      // The rounds spread over spreadMs (a load's slow phase, e.g. parsing an upload after receiving
      // it, lasts a second or more), at moments that do not keep step with the load's own rhythm.
      const next = sampleStart + ((round + 1) * spreadMs) / rounds + ((round * 37) % 80);
      await new Promise((r) => setTimeout(r, Math.max(20, next - performance.now())));
    }
    socket.close();
  } finally {
    if (load) {
      result.load = await load.stop();
      result.loadText = load.describe();
      result.loadProblems = load.problems();
    }
    result.seconds = (performance.now() - classStart) / 1000;
    // Leave no e-stop latched for the next class (a lease first: the reset needs it).
    const l = await control.post('/lease');
    const reset = await control.post('/estop/reset');
    if (l.status !== 200 || reset.status !== 200) {
      result.failures.push(`final reset: lease ${l.status} ${l.error || ''}, reset ${reset.status} ${reset.error || reset.text}`);
    }
    const health = await request(t, {path: '/api/v1/health', timeoutMs: sampleTimeoutMs});
    result.health = {status: health.status, ms: health.ms, detail: health.error || ''};
    control.close();
  }
  log(report(result));
  return result;
}

export function report(r) {
  const rest = summary(r.rest);
  const ws = summary(r.ws);
  return [
    `class ${r.name}: ${r.what}`,
    `  REST e-stop n=${rest.n} p50=${fmt(rest.p50)} p99=${fmt(rest.p99)} max=${fmt(rest.max)} ms; ` +
      `WS e-stop n=${ws.n} p50=${fmt(ws.p50)} p99=${fmt(ws.p99)} max=${fmt(ws.max)} ms (WS opened in ${fmt(r.wsOpenMs)} ms)`,
    `  load: ${r.loadText ?? 'none'}; ${r.seconds.toFixed(1)} s; GET /health after: ${r.health.status || r.health.detail} in ${fmt(r.health.ms)} ms`,
    ...r.failures.map((f) => `  failure: ${f}`),
    ...(r.loadProblems ?? []).map((f) => `  load problem: ${f}`),
  ].join('\n');
}
