// The OpenAPI document (GET /api/v1/openapi.json, public) against the routes the server serves:
// every documented method answers (not 404 "no endpoint", not 405), and on every documented path the
// methods it does not document answer 405. (That every route the server dispatches is documented is
// checked from the C++ route table in tests/unit/server/test_http_server.cpp.)
// Documented methods are probed as a viewer, so no command changes anything (403 forbidden_role).
import {test} from 'node:test';
import assert from 'node:assert/strict';
import {ROBOT, call} from './helpers.mjs';

const METHODS = ['get', 'post', 'put', 'delete', 'patch'];
const VIEWER = {headers: {'X-Tendril-Role': 'viewer'}};
let doc;
let command;  // one of the robot type's own commands (GET /robots), for /robots/{robot}/{command}

function concrete(path) {
  return path.replace('{robot}', ROBOT).replace('{id}', 'no-such-id').replace('{command}', command);
}
function url(path, entry) {
  const server = (entry.servers || doc.servers)[0].url.replace(/\/$/, '');
  return new URL(server + concrete(path), process.env.TENDRIL_URL).toString();
}

test('GET /api/v1/openapi.json is public and is OpenAPI 3.1', async () => {
  const res = await call('GET', '/openapi.json', {token: null, client: null});
  assert.equal(res.status, 200, res.text);
  doc = res.json;
  assert.match(doc.openapi, /^3\.1\./);
  assert.equal(doc.servers[0].url, '/api/v1');
  assert.ok(Object.keys(doc.paths).length >= 20);
  const robots = await call('GET', '/robots');
  command = robots.json.find((r) => r.name === ROBOT)?.commands?.[0];
  assert.ok(command, `the robot lists its type's commands: ${robots.text.slice(0, 200)}`);
});

test('every documented path and method is served', async () => {
  assert.ok(doc, 'document loaded');
  for (const [path, entry] of Object.entries(doc.paths)) {
    for (const method of METHODS.filter((m) => entry[m])) {
      if (path === '/estop' && method === 'post') continue;  // would latch the e-stop; checked by 405 below
      const res = await call(method.toUpperCase(), url(path, entry), {...VIEWER, body: method === 'get' ? undefined : {}});
      const noEndpoint = res.status === 404 && /^no endpoint/.test(res.json?.error?.message ?? '');
      assert.ok(!noEndpoint && res.status !== 405, `${method.toUpperCase()} ${path}: ${res.status} ${res.text.slice(0, 200)}`);
      if (res.status >= 400) assert.ok(res.json?.error?.code, `${method} ${path}: error shape: ${res.text.slice(0, 200)}`);
    }
  }
});

test('methods a documented path does not list answer 405 with Allow', async () => {
  for (const [path, entry] of Object.entries(doc.paths)) {
    const documented = METHODS.filter((m) => entry[m]);
    for (const method of METHODS.filter((m) => !entry[m] && m !== 'patch')) {
      // As an operator without the lease: a route's role check must not hide that the method is not served.
      const res = await call(method.toUpperCase(), url(path, entry), {body: method === 'get' ? undefined : {}});
      assert.equal(res.status, 405, `${method.toUpperCase()} ${path} is not documented but answered ${res.status} ${res.text.slice(0, 160)}`);
      const allow = (res.headers.get('allow') || '').toLowerCase().split(/,\s*/).sort();
      assert.deepEqual(allow, [...documented].sort(), `Allow header of ${path}`);
    }
  }
});
