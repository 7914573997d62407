// crosssite.test.mjs - a page of another origin cannot change anything (docs/security.md "Access",
// the cross-site rule of PROTOCOL.md), tried with the headers a browser sends: Origin (another site, another
// port of this machine, `null`) and Sec-Fetch-Site. The viewer's own origin, clients that send
// neither header (curl) and origins of allowed_origins may; reads stay open, without
// Access-Control-Allow-Origin unless the origin is allowed. Refused requests spend a budget of
// their own, not the one of the control client behind the same address. The same from a real
// page in Chromium: tests/web/crosssite.test.mjs.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { chmodSync, writeFileSync } from 'node:fs';
import { join } from 'node:path';
import { start, stop, call, hash, tempDir, PROBLEM } from './harness.mjs';

const CONTROL = 'c0ntrol-t0ken-0123456789abcdef';
const ROCK = JSON.stringify({ position: [0, 0, 2], radius: 0.1 });

// A control token file for a daemon that needs one.
function tokenFile() {
  const f = join(tempDir(), 'control');
  writeFileSync(f, `${CONTROL}\n`);
  chmodSync(f, 0o600);
  return f;
}

// Every changing route, with a body it would accept.
const changes = [
  ['POST', '/v1/rocks', ROCK], ['POST', '/v1/sim/reset', '{}'], ['POST', '/v1/sim/resume', '{}'],
  ['PATCH', '/v1/params', '{"k_bend": 31}'], ['PUT', '/v1/scene', '{"nx": 20}'], ['DELETE', '/v1/rocks', undefined],
  ['PUT', '/v1/pins', '{"preset": "corners"}'], ['PUT', '/v1/grab', '{"vertex": 3, "target": [0, 0, 1]}'],
];

test('a changing request from a page of another origin is 403 and changes nothing', async () => {
  const d = await start(['--paused', '--auto-drop-interval', '0', '--allowed-origins', 'https://viewer.example']);
  const port = Number(new URL(d.url).port);
  const h0 = await hash(d);
  // What browsers send for a fetch or a form from another page (text/plain: no preflight).
  const hostile = [
    { Origin: 'http://attacker.example', 'Sec-Fetch-Site': 'cross-site' },
    { Origin: 'null' }, // a sandboxed frame, a file: page, a redirect
    { 'Sec-Fetch-Site': 'cross-site' }, // no Origin, but the browser says so
    { Origin: `http://127.0.0.1:${port + 1}`, 'Sec-Fetch-Site': 'same-site' }, // another port of this machine
    { Origin: `http://localhost:${port}`, 'Sec-Fetch-Site': 'same-site' }, // another name than the one it was reached by
    { Origin: 'https://viewer.example.attacker' },
  ];
  for (const [method, path, body] of changes) {
    for (const headers of hostile) {
      const r = await call(d, method, path, body, { 'Content-Type': 'text/plain', ...headers });
      const what = `${method} ${path} ${JSON.stringify(headers)}`;
      assert.equal(r.status, 403, what);
      assert.equal(r.type, PROBLEM, what);
      assert.equal(r.json.type, 'urn:clothd:problem:cross-site', what);
      assert.equal(r.headers.get('access-control-allow-origin'), null, what);
    }
  }
  assert.equal(await hash(d), h0, 'a cross-site request changed the state');
  const sim = (await call(d, 'GET', '/v1/sim')).json;
  assert.equal(sim.state, 'paused');
  assert.equal(sim.n_rocks, 0);
  assert.equal((await call(d, 'GET', '/v1/params')).json.k_bend, 20);
  // Reads stay readable, with no Access-Control-Allow-Origin for the page.
  const read = await call(d, 'GET', '/v1/sim', undefined, { Origin: 'http://attacker.example', 'Sec-Fetch-Site': 'cross-site' });
  assert.equal(read.status, 200);
  assert.equal(read.headers.get('access-control-allow-origin'), null);

  // The viewer's own page (the Host it was reached on, the HTTP port), a typed URL, curl, and an
  // allowed origin may.
  const own = await call(d, 'POST', '/v1/rocks', ROCK, { Origin: `http://127.0.0.1:${port}`, 'Sec-Fetch-Site': 'same-origin' });
  assert.equal(own.status, 201);
  assert.equal(own.headers.get('access-control-allow-origin'), null, 'same origin needs no CORS header');
  assert.equal((await call(d, 'POST', '/v1/rocks', ROCK.replace('[0,0,2]', '[0.5,0,2]'), { 'Sec-Fetch-Site': 'none' })).status, 201);
  assert.equal((await call(d, 'POST', '/v1/rocks', ROCK.replace('[0,0,2]', '[-0.5,0,2]'))).status, 201);
  const allowed = await call(d, 'PATCH', '/v1/params', { k_bend: 25 },
    { Origin: 'https://viewer.example', 'Sec-Fetch-Site': 'cross-site' });
  assert.equal(allowed.status, 200);
  assert.equal(allowed.headers.get('access-control-allow-origin'), 'https://viewer.example');
  assert.equal(allowed.headers.get('vary'), 'Origin');
  assert.equal((await call(d, 'GET', '/v1/sim')).json.n_rocks, 3);
  await stop(d);
});

test('the cross-site rule runs before the token check', async () => {
  const f = tokenFile();
  const d = await start(['--paused', '--token-file', f]);
  const auth = { Authorization: `Bearer ${CONTROL}` };
  const h0 = (await call(d, 'GET', '/v1/sim', undefined, auth)).json.state_hash;
  // Without a token: 403 cross-site, not 401 (nothing about the token is told to the page).
  const r = await call(d, 'POST', '/v1/sim/reset', '{}', { Origin: 'http://attacker.example' });
  assert.equal(r.status, 403);
  assert.equal(r.json.type, 'urn:clothd:problem:cross-site');
  assert.equal(r.headers.get('www-authenticate'), null);
  // With the token too (a page cannot have it, but the rule does not depend on that).
  assert.equal((await call(d, 'POST', '/v1/sim/reset', '{}', { ...auth, Origin: 'null' })).status, 403);
  assert.equal((await call(d, 'GET', '/v1/sim', undefined, auth)).json.state_hash, h0);
  await stop(d);
});

test('refused requests have a budget of their own: 401s do not use up the control client\'s', async () => {
  const f = tokenFile();
  const RATE = 1, BURST = 5;
  const d = await start(['--paused', '--token-file', f, '--rate-limit', String(RATE), '--rate-burst', String(BURST)]);
  const auth = { Authorization: `Bearer ${CONTROL}` };
  // Tokens the bucket regains over an elapsed time: none within a second at RATE 1, which is
  // the normal case; a machine slow enough (ASan on a loaded CI host) to take longer gets that
  // many refusals more, and no more.
  const regained = (t0) => Math.floor(((performance.now() - t0) / 1000) * RATE);
  // 50 requests without a token, from the same address as the control client: the first
  // rate_burst are 401, then 429 (a guesser is slowed), whatever they are; then a read.
  const t0 = performance.now();
  const statuses = [];
  for (let k = 0; k < 50; k++) statuses.push((await call(d, 'POST', '/v1/sim/pause', '{}')).status);
  const limited = await call(d, 'GET', '/v1/sim');
  statuses.push(limited.status);
  const extra = regained(t0);
  assert.deepEqual(statuses.slice(0, BURST), [401, 401, 401, 401, 401]);
  const rest = statuses.slice(BURST);
  assert.ok(rest.every((s) => s === 429 || s === 401), JSON.stringify(statuses));
  assert.ok(rest.filter((s) => s === 401).length <= extra, `${JSON.stringify(statuses)}, ${extra} regained`);
  if (extra === 0) assert.equal(limited.status, 429, 'reads without a token are refusals too');
  if (limited.status === 429) assert.ok(Number(limited.headers.get('retry-after')) >= 1);
  // The control client's budget is untouched: rate_burst changes in a row, then its own limit.
  const t1 = performance.now();
  for (let k = 0; k < BURST; k++) assert.equal((await call(d, 'POST', '/v1/sim/pause', '{}', auth)).status, 200, `change ${k + 1}`);
  const sixth = (await call(d, 'POST', '/v1/sim/pause', '{}', auth)).status;
  if (regained(t1) === 0) assert.equal(sixth, 429, 'and its own limit still holds');
  await stop(d);
});
