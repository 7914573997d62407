// access.test.mjs - who may use clothd (docs/security.md "Access"): loopback without a token by
// default, no other address without a token unless --insecure; the control and view tokens on
// every API route and on the stream (query parameter or subprotocol); the Host header (DNS
// rebinding) and the Origin of stream connections.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { chmodSync, writeFileSync } from 'node:fs';
import { join } from 'node:path';
import { CLOTHD, start, stop, call, tempDir, until, execChecked, metric } from './harness.mjs';
import { connect, next } from './wsclient.mjs';

const run = execChecked; // execFile, and a sanitizer report fails the test
const CONTROL = 'c0ntrol-t0ken-0123456789abcdef';
const VIEW = 'view-t0ken-0123456789abcdef';

function tokenFile(dir, name, text) {
  const f = join(dir, name);
  writeFileSync(f, `${text}\n`);
  chmodSync(f, 0o600);
  return f;
}

// The reason a start is refused (clothd exits non-zero and says why on stderr).
async function refusal(args) {
  const err = await run(CLOTHD, ['--port', '0', '--stream-port', '0', '--backend', 'cpu', ...args]).then(
    () => null, (e) => {
      if (e.sanitizerReport) throw e; // a refusal, but not that one
      return e;
    });
  assert.ok(err, `clothd ${args.join(' ')} started`);
  assert.notEqual(err.code, 0);
  return err.stderr;
}

const bearer = (t) => ({ Authorization: `Bearer ${t}` });

async function guarded(flags = []) {
  const dir = tempDir();
  const d = await start(['--token-file', tokenFile(dir, 'control', CONTROL), '--view-token-file',
    tokenFile(dir, 'view', VIEW), '--paused', ...flags]);
  d.streamPort = (await call(d, 'GET', '/v1/health')).json.stream.port;
  return d;
}

test('beyond loopback only with a token, or --insecure; tokens must be sound', async () => {
  const why = await refusal(['--listen', '0.0.0.0']);
  assert.match(why, /refusing to listen on 0\.0\.0\.0 without a token/);
  assert.match(why, /--token-file/);
  assert.match(why, /--insecure/);
  assert.match(await refusal(['--listen', 'example.com']), /not a numeric IPv4 or IPv6 address/);
  const dir = tempDir();
  assert.match(await refusal(['--token-file', tokenFile(dir, 'short', 'abc')]), /16 to 512 characters/);
  assert.match(await refusal(['--token-file', tokenFile(dir, 'spaces', 'a token with spaces in it')]), /only letters, digits/);
  assert.match(await refusal(['--view-token-file', tokenFile(dir, 'v', VIEW)]), /view_token_file needs token_file/);
  assert.match(await refusal(['--token-file', tokenFile(dir, 'a', CONTROL), '--view-token-file', tokenFile(dir, 'b', CONTROL)]),
    /the same/);
  assert.match(await refusal(['--token-file', join(dir, 'missing')]), /missing: No such file/);
  // With a token, or told --insecure, it starts on every address.
  const withToken = await start(['--listen', '0.0.0.0', '--token-file', tokenFile(dir, 'ok', CONTROL)]);
  assert.equal((await fetch(`${withToken.url.replace('0.0.0.0', '127.0.0.1')}/v1/sim`)).status, 401);
  await stop(withToken);
  const insecure = await start(['--listen', '0.0.0.0', '--insecure']);
  assert.equal((await fetch(`${insecure.url.replace('0.0.0.0', '127.0.0.1')}/v1/sim`)).status, 200);
  await stop(insecure);
});

test('the control token opens every route, the view token reads only', async () => {
  const d = await guarded();
  // No token: 401 asking for one; a token that is not the server's: 401.
  const none = await call(d, 'GET', '/v1/sim');
  assert.equal(none.status, 401);
  assert.equal(none.headers.get('www-authenticate'), 'Bearer realm="clothd"');
  assert.equal(none.json.type, 'urn:clothd:problem:unauthorized');
  assert.match(none.json.detail, /Authorization: Bearer/);
  assert.equal((await call(d, 'GET', '/v1/sim', undefined, bearer(`${CONTROL}x`))).status, 401);
  assert.equal((await call(d, 'GET', '/v1/sim', undefined, bearer(CONTROL.slice(0, -1)))).status, 401);
  assert.equal((await call(d, 'GET', '/v1/sim', undefined, { Authorization: CONTROL })).status, 401);
  assert.equal((await call(d, 'POST', '/v1/rocks', { position: [0, 0, 2], radius: 0.1 })).status, 401);
  // The view token reads; changes are 403 and change nothing.
  const before = (await call(d, 'GET', '/v1/sim', undefined, bearer(VIEW))).json;
  assert.equal(before.state, 'paused');
  for (const [method, path, body] of [['POST', '/v1/rocks', { position: [0, 0, 2], radius: 0.1 }],
    ['PATCH', '/v1/params', { k_bend: 30 }], ['POST', '/v1/sim/resume'], ['PUT', '/v1/scene', { nx: 20 }],
    ['DELETE', '/v1/rocks']]) {
    const r = await call(d, method, path, body, bearer(VIEW));
    assert.equal(r.status, 403, `${method} ${path}`);
    assert.match(r.json.detail, /view token reads only/);
  }
  for (const path of ['/v1/params', '/v1/rocks', '/v1/journal', '/metrics', '/v1/params/schema'])
    assert.equal((await call(d, 'GET', path, undefined, bearer(VIEW))).status, 200, path);
  const after = (await call(d, 'GET', '/v1/sim', undefined, bearer(VIEW))).json;
  assert.equal(after.state_hash, before.state_hash);
  assert.equal(after.n_rocks, 0);
  // The control token does everything.
  assert.equal((await call(d, 'POST', '/v1/rocks', { position: [0, 0, 2], radius: 0.1 }, bearer(CONTROL))).status, 201);
  assert.equal((await call(d, 'PATCH', '/v1/params', { k_bend: 30 }, bearer(CONTROL))).status, 200);
  // Open to all: liveness, and the viewer's static files (public code, no data).
  assert.equal((await call(d, 'GET', '/v1/health')).status, 200);
  assert.equal((await call(d, 'GET', '/')).status, 200);
  await stop(d);
});

test('the stream takes the token in the URL or the subprotocol list, before the upgrade', async () => {
  const d = await guarded();
  await assert.rejects(connect(d), 'no token');
  await assert.rejects(connect(d, { path: `/stream?token=${CONTROL}x` }), 'a wrong token');
  await assert.rejects(connect(d, { protocol: ['clothd.v1', 'bearer.nope-nope-nope-nope'] }), 'a wrong token');
  const viaQuery = await connect(d, { path: `/stream?token=${VIEW}` });
  await next(viaQuery, 'text', (m) => m.type === 'hello');
  // A browser cannot set Authorization on a WebSocket: the subprotocol list carries the token, and
  // the server picks clothd.v1 from it.
  const viaProtocol = await connect(d, { protocol: ['clothd.v1', `bearer.${CONTROL}`] });
  assert.equal(viaProtocol.ws.protocol, 'clothd.v1');
  await next(viaProtocol, 'text', (m) => m.type === 'hello');
  // A view connection sees frames but may not grab; a control connection may.
  viaQuery.ws.send(JSON.stringify({ type: 'grab', vertex: 5, target: [0, 0, 2] }));
  const refused = await next(viaQuery, 'text', (m) => m.type === 'error');
  assert.equal(refused.status, 403);
  assert.match(refused.detail, /control token/);
  viaProtocol.ws.send(JSON.stringify({ type: 'grab', vertex: 5, target: [0, 0, 2] }));
  const grabbed = await next(viaProtocol, 'text', (m) => m.type === 'event' && m.event === 'grab');
  assert.equal(grabbed.command.vertex, 5);
  assert.equal((await call(d, 'GET', '/v1/journal', undefined, bearer(VIEW))).json.entries.filter((e) => e.command.op === 'grab').length, 1);
  viaQuery.ws.close();
  viaProtocol.ws.close();
  await stop(d);
});

test('the Host header must name this server (DNS rebinding)', async () => {
  const d = await start(['--paused', '--allowed-hosts', 'cloth.example, other.example']);
  const port = new URL(d.url).port;
  // fetch cannot set Host: a raw request does.
  const { request } = await import('node:http');
  const withHost = (host) => new Promise((resolve, reject) => {
    const r = request({ host: '127.0.0.1', port, path: '/v1/sim', headers: { Host: host } }, (res) => {
      let body = '';
      res.on('data', (c) => (body += c));
      res.on('end', () => resolve({ status: res.statusCode, body }));
    });
    r.on('error', reject);
    r.end();
  });
  for (const host of [`127.0.0.1:${port}`, `localhost:${port}`, `[::1]:${port}`, '127.0.0.1', `cloth.example:${port}`,
    `OTHER.example:${port}`, `10.1.2.3:${port}`])
    assert.equal((await withHost(host)).status, 200, host);
  for (const host of [`attacker.example:${port}`, 'cloth.example.attacker.example', `localhost.attacker:${port}`]) {
    const r = await withHost(host);
    assert.equal(r.status, 403, host);
    assert.match(JSON.parse(r.body).detail, /allowed_hosts/);
  }
  await stop(d);
});

test('a page of another origin cannot open the stream', async () => {
  const d = await start(['--paused', '--allowed-origins', 'https://viewer.example']);
  d.streamPort = (await call(d, 'GET', '/v1/health')).json.stream.port;
  const httpPort = Number(new URL(d.url).port);
  const host = `127.0.0.1:${d.streamPort}`;
  const tryOrigin = (origin, h = host) => connect(d, { headers: { Origin: origin, Host: h } });
  // The viewer's own page: the stream's host, on the HTTP port.
  const own = await tryOrigin(`http://127.0.0.1:${httpPort}`);
  await next(own, 'text', (m) => m.type === 'hello');
  own.ws.close();
  const listed = await tryOrigin('https://viewer.example');
  await next(listed, 'text', (m) => m.type === 'hello');
  listed.ws.close();
  // Not a client without Origin (curl, node) either: no browser, no cross-site request.
  const plain = await connect(d);
  await next(plain, 'text', (m) => m.type === 'hello');
  plain.ws.close();
  for (const [origin, h] of [
    [`http://attacker.example:${httpPort}`, host], // another site
    [`http://127.0.0.1:${httpPort + 1}`, host], // another port of this machine
    ['null', host], // a sandboxed or file: page
    [`http://attacker.example:${httpPort}`, `attacker.example:${d.streamPort}`], // DNS rebinding
    ['https://viewer.example.attacker', host]]) {
    await assert.rejects(tryOrigin(origin, h), `${origin} with Host ${h}`);
  }
  await until('the refusals counted', async () => metric((await call(d, 'GET', '/metrics')).text, 'clothd_stream_refused_total',
    'reason="origin"') === 4 && metric((await call(d, 'GET', '/metrics')).text, 'clothd_stream_refused_total', 'reason="host"') === 1);
  await stop(d);
});
