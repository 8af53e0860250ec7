// Shared helpers of the API tests: the server under test comes from the environment
// (TENDRIL_URL = http://127.0.0.1:PORT, TENDRIL_TOKEN), as tests/api/run.sh sets it.
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import {fileURLToPath} from 'node:url';

export const BASE_URL = (process.env.TENDRIL_URL || '').replace(/\/$/, '');
export const TOKEN = process.env.TENDRIL_TOKEN || '';
if (!BASE_URL || !TOKEN) {
  throw new Error('Set TENDRIL_URL (e.g. http://127.0.0.1:8080) and TENDRIL_TOKEN, or run tests/api/run.sh <tendrild>');
}
export const API = `${BASE_URL}/api/v1`;
export const REPO_ROOT = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '../..');
export const ROBOT = 'srmc';
export const robotConfig = JSON.parse(fs.readFileSync(path.join(REPO_ROOT, 'config/robots/srmc.json'), 'utf8'));

// X-Tendril-Client is a label (the lease holder's name in messages), never an identity. Without a
// lease token the tests' calls are the bearer-token identity, as plain curl is (README).
export const CLIENT_ID = 'api-test';

// lease: a lease token to send as X-Tendril-Lease (a script with a lease of its own, see script()).
export async function call(method, urlPath, {body, raw, token = TOKEN, client = CLIENT_ID, lease, headers = {}} = {}) {
  const h = {Accept: 'application/json', ...headers};
  if (token) h.Authorization = `Bearer ${token}`;
  if (client) h['X-Tendril-Client'] = client;
  if (lease) h['X-Tendril-Lease'] = lease;
  let payload;
  if (raw !== undefined) {
    payload = raw;
    h['Content-Type'] = 'application/json';
  } else if (body !== undefined) {
    payload = JSON.stringify(body);
    h['Content-Type'] = 'application/json';
  }
  const response = await fetch(urlPath.startsWith('http') ? urlPath : API + urlPath, {method, headers: h, body: payload});
  const text = await response.text();
  let json = null;
  try {
    json = text ? JSON.parse(text) : null;
  } catch {
    json = null;
  }
  return {status: response.status, json, text, headers: response.headers};
}

export const get = (p, o) => call('GET', p, o);
export const post = (p, body = {}, o = {}) => call('POST', p, {body, ...o});

// The lease lapses after 30 s without a command; a test file that commands takes (or renews) it
// before each test, so a slow test before it cannot leave it lapsed. Bearer-token identity.
export async function holdLease() {
  const res = await post('/lease', {});
  assert.equal(res.status, 200, `POST /lease: ${res.text}`);
  return res.json;
}

// A script with a lease of its own (README): it sends its name as a label and X-Tendril-Lease with
// the token of its last granted POST /lease ("new" before, which asks for a token-only lease), so
// neither the bearer identity nor another script can use its lease.
export function script(name) {
  const s = {
    name,
    leaseToken: 'new',
    call: (method, urlPath, o = {}) => call(method, urlPath, {client: name, lease: s.leaseToken, ...o}),
    get: (urlPath, o = {}) => s.call('GET', urlPath, o),
    post: (urlPath, body = {}, o = {}) => s.call('POST', urlPath, {body, ...o}),
    // POST /lease (optionally confirming a takeover); keeps the granted token.
    async takeLease(body = {}) {
      const res = await s.post('/lease', body);
      if (res.status === 200) s.leaseToken = res.json.lease_token;
      return res;
    },
    // Takes the lease, confirming a takeover if another holds it; asserts success.
    async takeLeaseOver() {
      let res = await s.takeLease();
      if (res.status === 409 && res.json.error.takeover_token) res = await s.takeLease({takeover_token: res.json.error.takeover_token});
      assert.equal(res.status, 200, `lease for ${name}: ${res.text}`);
      return res.json;
    },
  };
  return s;
}

// The API's error shape: {"error":{"code":"snake_case","message":"for a person"}}.
export function assertErrorShape(res, status, code) {
  assert.equal(res.status, status, `expected HTTP ${status}, got ${res.status}: ${res.text}`);
  assert.ok(res.json && typeof res.json.error === 'object', `error body missing: ${res.text}`);
  assert.match(res.json.error.code, /^[a-z][a-z0-9_]*$/, `error.code not snake_case: ${res.text}`);
  assert.equal(typeof res.json.error.message, 'string');
  assert.ok(res.json.error.message.length > 0, 'error.message is empty');
  if (code) assert.equal(res.json.error.code, code, `expected code ${code}: ${res.text}`);
}

export const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

// Polls `probe` until it is done: an object with a `done` key is done when that key is truthy, any
// other value when it is truthy (`true`, a found message). Bounded by a count of polls, not by
// wall-clock assertions. Returns the last value (done or not) so the caller can assert with a message.
export function isDone(value) {
  if (value !== null && typeof value === 'object' && 'done' in value) return Boolean(value.done);
  return Boolean(value);
}

export async function pollUntil(probe, {polls = 100, intervalMs = 50} = {}) {
  let last;
  for (let i = 0; i < polls; i++) {
    last = await probe();
    if (isDone(last)) return last;
    await sleep(intervalMs);
  }
  return last;
}

export function tolerance(unit) {
  return unit === 'rad' ? 0.005 : unit === 'deg' ? 0.3 : 0.05;
}
