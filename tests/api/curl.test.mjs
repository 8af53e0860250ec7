// The README's curl examples, run with curl itself: one process and one TCP connection per call,
// the bearer token and nothing else. Issue 14: such a script took the lease and its next command was
// refused 409 lease_held by "connection:1", a connection that had already closed. Also the README's
// script with a lease of its own (X-Tendril-Lease), which the bearer token alone cannot use.
import {test, after} from 'node:test';
import assert from 'node:assert/strict';
import {execFile} from 'node:child_process';
import {promisify} from 'node:util';
import {API, TOKEN, ROBOT, get, post, call, pollUntil} from './helpers.mjs';

const execFileAsync = promisify(execFile);
const R = `/robots/${ROBOT}`;

// Runs a bash script with T (the token) and API (http://127.0.0.1:PORT/api/v1) set, as a user would
// after `T=…`; returns its standard output.
async function shell(script) {
  const {stdout} = await execFileAsync('bash', ['-c', `set -euo pipefail\n${script}`],
    {env: {...process.env, T: TOKEN, API}});
  return stdout;
}

// Each curl call below prints its body and, on a line of its own, the HTTP status (-w).
function answers(stdout) {
  const lines = stdout.trim().split('\n');
  const out = [];
  for (let i = 0; i + 1 < lines.length; i += 2) out.push({json: JSON.parse(lines[i]), status: Number(lines[i + 1])});
  return out;
}

async function waitUntil(pick, what) {
  const found = await pollUntil(async () => {
    const s = (await get(`${R}/operating_state`)).json;
    return pick(s) ? {done: true, s} : {done: false, s};
  }, {polls: 400, intervalMs: 50});
  assert.ok(found.done, `${what}: ${JSON.stringify(found.s)}`);
}

after(async () => {
  await post('/lease', {});
  await post(`${R}/state_command`, {command: 'disable'});
  await call('DELETE', '/lease');
});

test('plain curl (bearer token only): take the lease, enable, move, read, give it back', async () => {
  const W = `-w '\\n%{http_code}\\n'`;
  const [lease, enable] = answers(await shell(`
H=(-H "Authorization: Bearer $T")
curl -s "\${H[@]}" ${W} -X POST $API/lease
curl -s "\${H[@]}" ${W} -X POST -d '{"command":"enable"}' $API${R}/state_command
`));
  assert.equal(lease.status, 200, JSON.stringify(lease.json));
  assert.deepEqual([lease.json.held, lease.json.mine, lease.json.holder], [true, true, 'api-client']);
  assert.equal(enable.status, 200, `the next curl call holds the lease: ${JSON.stringify(enable.json)}`);
  await waitUntil((s) => s.state === 'ENABLED' && s.drives_ready && !s.is_busy, 'enabled');

  const q = (await get(`${R}/setpoint_js`)).json.position;
  const goal = [q[0] + 2, q[1], q[2], q[3]];
  const [move, measured] = answers(await shell(`
H=(-H "Authorization: Bearer $T")
curl -s "\${H[@]}" ${W} -X POST -d '{"goal":${JSON.stringify(goal)}}' $API${R}/move_jp
curl -s "\${H[@]}" ${W} $API${R}/measured_js
`));
  assert.equal(move.status, 202, JSON.stringify(move.json));
  assert.equal(measured.status, 200);
  assert.equal(measured.json.position.length, 4);
  await waitUntil((s) => !s.is_busy, 'move finished');
  const reached = (await get(`${R}/setpoint_js`)).json.position;
  assert.ok(Math.abs(reached[0] - goal[0]) < 1e-6, `moved to ${reached[0]}, goal ${goal[0]}`);

  const [disable, release, status] = answers(await shell(`
H=(-H "Authorization: Bearer $T")
curl -s "\${H[@]}" ${W} -X POST -d '{"command":"disable"}' $API${R}/state_command
curl -s "\${H[@]}" ${W} -X DELETE $API/lease
curl -s "\${H[@]}" ${W} $API/lease
`));
  assert.equal(disable.status, 200, JSON.stringify(disable.json));
  assert.equal(release.status, 200, JSON.stringify(release.json));
  assert.equal(status.json.held, false);
});

test('a curl script with a lease of its own: the bearer token alone cannot use it', async () => {
  const W = `-w '\\n%{http_code}\\n'`;
  const [mine, other, status, release] = answers(await shell(`
H=(-H "Authorization: Bearer $T")
L=$(curl -s "\${H[@]}" -H "X-Tendril-Lease: new" -H "X-Tendril-Client: my-script" -X POST $API/lease | jq -r .lease_token)
S=("\${H[@]}" -H "X-Tendril-Lease: $L")
curl -s "\${S[@]}" ${W} -X POST -d '{"command":"disable"}' $API${R}/state_command
curl -s "\${H[@]}" ${W} -X POST -d '{"command":"enable"}' $API${R}/state_command
curl -s "\${H[@]}" ${W} $API/lease
curl -s "\${S[@]}" ${W} -X DELETE $API/lease
`));
  assert.equal(mine.status, 200, `the lease token holds: ${JSON.stringify(mine.json)}`);
  assert.equal(other.status, 409, JSON.stringify(other.json));
  assert.equal(other.json.error.code, 'lease_held');
  assert.match(other.json.error.message, /client:my-script/);
  assert.deepEqual([status.json.held, status.json.mine, status.json.holder], [true, false, 'client:my-script']);
  assert.equal(status.json.lease_token, undefined, 'the token is shown to nobody else');
  assert.equal(release.status, 200, JSON.stringify(release.json));
  assert.notEqual((await get(`${R}/operating_state`)).json.state, 'ENABLED', 'the refused command changed nothing');
});
