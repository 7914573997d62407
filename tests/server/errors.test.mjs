// errors.test.mjs - bad input gets the status PROTOCOL.md gives, an RFC 9457 problem naming the
// offending parameter, and changes nothing: the state hash of the paused daemon is the same after.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import net from 'node:net';
import { start, stop, call, ok, pause, hash, PROBLEM } from './harness.mjs';

let d, h0, rockId;
before(async () => {
  d = await start(['--nx', '10', '--ny', '10', '--max-body', '65536', '--max-substeps', '200', '--paused']);
  await pause(d);
  rockId = (await ok(d, 'POST', '/v1/rocks', { position: [0, 0, 2], radius: 0.1 })).id;
  await ok(d, 'POST', '/v1/sim/step', { frames: 3 });
  h0 = await hash(d);
});
after(async () => {
  assert.equal((await stop(d)).code, 0);
});

// Sends a request, checks the problem it earns, and that the state did not change.
async function refused(method, path, body, status, param, headers) {
  const r = await call(d, method, path, body, headers);
  const what = `${method} ${path} ${body instanceof Uint8Array ? `<${body.length} bytes>` : JSON.stringify(body)?.slice(0, 200)}`;
  assert.equal(r.status, status, `${what} -> ${r.status} ${r.text}`);
  assert.equal(r.type, PROBLEM, r.text);
  assert.equal(r.json.status, status);
  assert.match(r.json.type, /^urn:clothd:problem:/);
  assert.ok(r.json.title.length > 0 && r.json.detail.length > 0);
  if (param !== undefined) assert.equal(r.json.param, param, r.text);
  assert.equal(await hash(d), h0, `${what} changed the state`);
  return r.json;
}

test('malformed JSON is 400', async () => {
  await refused('PATCH', '/v1/params', '{', 400);
  await refused('PATCH', '/v1/params', 'not json', 400);
  await refused('PATCH', '/v1/params', '', 400);
  await refused('PATCH', '/v1/params', '[1, 2]', 400);
  await refused('PATCH', '/v1/params', '"k_bend"', 400);
  await refused('PATCH', '/v1/params', '{"k_bend": nan}', 400);
  await refused('PATCH', '/v1/params', '{"k_bend": NaN', 400);
  await refused('PATCH', '/v1/params', '[NaN]', 400);
  await refused('PATCH', '/v1/params', '{"k_bend": 1, NaN: 2}', 400);
  // A body that is not JSON is 400 whatever its Content-Type says.
  await refused('PUT', '/v1/scene', 'nx=5', 400, undefined, { 'Content-Type': 'application/x-www-form-urlencoded' });
});

test('bare NaN, Infinity and numbers past a double (not JSON, but values a client meant) are 422, naming their field', async () => {
  for (const [method, path, body, param, token] of [
    ['PATCH', '/v1/params', '{"k_bend": NaN}', 'k_bend', 'NaN'], // what Python's json.dumps writes
    ['PATCH', '/v1/params', '{"solver_tolerance":Infinity}', 'solver_tolerance', 'Infinity'],
    ['PATCH', '/v1/params', '{"self_thickness": -Infinity}', 'self_thickness', '-Infinity'],
    ['PATCH', '/v1/params', '{"wind": "x\\\\\\", NaN", "k_bend": 1e999}', 'k_bend', '1e999'], // (a string holding \\, \" and NaN first)
    ['PATCH', '/v1/params', '{"gravity": [0, 0,\nNaN]}', 'gravity', 'NaN'],
    ['POST', '/v1/rocks', '{"position": [0, 0, 1], "radius": 1e999}', 'radius', '1e999'],
    ['POST', '/v1/scenes', '{"id": "nan", "params": {"k_bend": NaN}}', 'k_bend', 'NaN'],
    ['POST', '/v1/sim/step', '{"frames": NaN}', 'frames', 'NaN'],
  ]) {
    const p = await refused(method, path, body, 422, param);
    assert.equal(p.detail, `${param} must be a finite number (got ${token})`);
  }
  assert.equal((await call(d, 'GET', '/v1/scenes')).json.scenes.length, 1);
});

test('duplicate keys and unknown fields are 400, naming the field', async () => {
  await refused('PATCH', '/v1/params', '{"k_bend": 1, "k_bend": 2}', 400);
  await refused('PATCH', '/v1/params', { nope: 1 }, 400, 'nope');
  await refused('PATCH', '/v1/params', { k_bend: 10, nx: 12 }, 400, 'nx'); // a scene parameter
  await refused('PUT', '/v1/scene', { k_bend: 10 }, 400, 'k_bend'); // a live one
  await refused('POST', '/v1/rocks', { position: [0, 0, 1], radius: 0.1, colour: 'red' }, 400, 'colour');
  await refused('PUT', '/v1/pins', { preset: 'edges', extra: true }, 400, 'extra');
  await refused('POST', '/v1/sim/step', { frames: 1, speed: 2 }, 400, 'speed');
  await refused('POST', '/v1/sim/pause', { now: true }, 400, 'now');
});

test('a long field name cut inside a character still makes a problem body', async () => {
  // detail (300 bytes) and param (64) are cut to size; a cut inside a character drops its bytes,
  // else the problem is not UTF-8 and there is no body at all.
  let p = await refused('PATCH', '/v1/params', { ['é'.repeat(200)]: 1 }, 400);
  assert.equal(p.param, 'é'.repeat(31));
  p = await refused('PATCH', '/v1/params', { [`a${'é'.repeat(200)}`]: 1 }, 400);
  assert.equal(p.detail, `unknown parameter 'a${'é'.repeat(139)}`);
});

test("a parameter's value of a wrong type is 422, any other field's 400", async () => {
  await refused('PATCH', '/v1/params', { k_bend: '10' }, 422, 'k_bend');
  await refused('PATCH', '/v1/params', { solver_iterations: '5' }, 422, 'solver_iterations');
  await refused('PATCH', '/v1/params', { solver_tolerance: null }, 422, 'solver_tolerance'); // JSON.stringify(NaN)
  await refused('PATCH', '/v1/params', { self_thickness: [0.005] }, 422, 'self_thickness');
  await refused('PATCH', '/v1/params', { ground: 1 }, 422, 'ground');
  await refused('PATCH', '/v1/params', { gravity: [0, 0] }, 422, 'gravity');
  await refused('PATCH', '/v1/params', { gravity: [0, 0, 'down'] }, 422, 'gravity');
  await refused('PATCH', '/v1/params', { integrator: 1 }, 422, 'integrator');
  await refused('PUT', '/v1/scene', { nx: '64' }, 422, 'nx');
  await refused('POST', '/v1/rocks', { position: 'here', radius: 0.1 }, 400, 'position');
  await refused('POST', '/v1/rocks', { position: [0, 0, 1], radius: 0.1, kinematic: 'yes' }, 400, 'kinematic');
  await refused('PUT', '/v1/pins', { vertices: 'all', pinned: true }, 400, 'vertices');
  await refused('PUT', '/v1/grab', { vertex: 3, target: [0, 0] }, 400, 'target');
  await refused('POST', '/v1/sim/step', { frames: 'two' }, 400, 'frames');
});

test("self-collision's and the solver's parameters: 0, negative, NaN, a string or past the range is 422 naming it, the parameters as they were", async () => {
  const before = await call(d, 'GET', '/v1/params');
  // (NaN as a client's JSON.stringify writes it: null)
  for (const [name, value] of [['self_thickness', 0], ['self_thickness', -0.005], ['self_thickness', NaN],
    ['self_thickness', 'thin'], ['self_thickness', 1], ['self_collision', 'yes'], ['self_collision', 1],
    ['solver_iterations', 0], ['solver_iterations', -1], ['solver_iterations', NaN], ['solver_iterations', '4'],
    ['solver_iterations', 1e6], ['solver_tolerance', 0], ['solver_tolerance', NaN]])
    await refused('PATCH', '/v1/params', { [name]: value }, 422, name);
  assert.deepEqual((await call(d, 'GET', '/v1/params')).json, before.json);
});

test('values out of range are 422', async () => {
  await refused('PATCH', '/v1/params', { k_bend: -1 }, 422, 'k_bend');
  await refused('PATCH', '/v1/params', { mu: 1e30 }, 422, 'mu');
  await refused('PATCH', '/v1/params', { gravity: [0, 0, 1e30] }, 422, 'gravity');
  await refused('PATCH', '/v1/params', { substeps: 2.5 }, 422, 'substeps');
  await refused('PATCH', '/v1/params', { substeps: 300 }, 422, 'substeps'); // above max_substeps
  await refused('PATCH', '/v1/params', { integrator: 'rk4' }, 422, 'integrator');
  await refused('PUT', '/v1/scene', { nx: 1 }, 422, 'nx');
  await refused('PUT', '/v1/scene', { nx: 5000 }, 422, 'nx');
  await refused('PUT', '/v1/scene', { size_x: 0 }, 422, 'size_x');
  await refused('PUT', '/v1/scene', { pins: 'diagonal' }, 422, 'pins');
  await refused('POST', '/v1/rocks', { radius: 0.1 }, 422, 'position');
  await refused('POST', '/v1/rocks', { position: [0, 0, 1] }, 422, 'radius');
  await refused('POST', '/v1/rocks', { position: [0, 0, 1], radius: -0.1 }, 422, 'radius');
  await refused('POST', '/v1/rocks', { position: [0, 0, 1], radius: 0 }, 422, 'radius');
  await refused('POST', '/v1/rocks', { position: [0, 0, 1], radius: 0.1, density: 0 }, 422, 'density');
  await refused('POST', '/v1/rocks', { position: [1e30, 0, 1], radius: 0.1 }, 422, 'position');
  await refused('POST', '/v1/rocks', { position: [0, 0, 1], radius: 0.1, orientation: [0, 0, 0, 0] }, 422, 'orientation');
  await refused('PATCH', `/v1/rocks/${rockId}`, { radius: -2 }, 422, 'radius');
  await refused('PUT', '/v1/pins', { preset: 'diagonal' }, 422, 'preset');
  await refused('PUT', '/v1/pins', { vertices: [3, 100], pinned: true }, 422, 'vertices');
  await refused('PUT', '/v1/pins', { vertices: [-1], pinned: true }, 422, 'vertices');
  await refused('PUT', '/v1/grab', { vertex: 100, target: [0, 0, 1] }, 422, 'vertex');
  await refused('PUT', '/v1/grab', { vertex: 5, target: [0, 0, 1e7] }, 422, 'target');
  await refused('POST', '/v1/sim/step', { frames: 0 }, 422, 'frames');
  await refused('POST', '/v1/sim/step', { substeps: 100001 }, 422, 'substeps');
  await refused('POST', '/v1/sim/step', {}, 400);
  await refused('POST', '/v1/sim/step', { frames: 1, substeps: 1 }, 400);
});

test('an unstable change is 422 and names a parameter', async () => {
  // the explicit integrators' guard (implicit_euler, the default, takes any stiffness in range)
  const p = await refused('PATCH', '/v1/params', { integrator: 'velocity_verlet', k_structural: 1e8 }, 422, 'k_structural');
  assert.match(p.type, /unstable/);
  assert.match(p.detail, /max_substeps/);
  const q = await refused('PATCH', '/v1/params', { integrator: 'velocity_verlet', k_structural: 1e8, auto_substeps: false }, 422);
  assert.match(q.detail, /auto_substeps/);
});

test('unknown ids are 404', async () => {
  await refused('GET', '/v1/rocks/999', undefined, 404, 'id');
  await refused('PATCH', '/v1/rocks/999', { radius: 0.2 }, 404, 'id');
  await refused('DELETE', '/v1/rocks/999', undefined, 404, 'id');
  await refused('GET', '/v1/rocks/abc', undefined, 404);
  await refused('GET', '/v1/rocks/0', undefined, 404);
  await refused('GET', '/v1/rocks/99999999999', undefined, 404);
  await refused('GET', '/v1/nothing-here', undefined, 404);
});

test('wrong methods are 405', async () => {
  await refused('PUT', '/v1/sim', {}, 405);
  await refused('GET', '/v1/sim/step', undefined, 405);
  await refused('POST', '/v1/snapshot', 'x', 405);
  await refused('PATCH', '/v1/scene', { nx: 5 }, 405);
});

test('stepping while running is 409', async () => {
  await ok(d, 'POST', '/v1/sim/resume');
  const r = await call(d, 'POST', '/v1/sim/step', { frames: 1 });
  assert.equal(r.status, 409);
  assert.equal(r.type, PROBLEM);
  await pause(d);
  // The daemon ran meanwhile: that is the one thing allowed to change the hash here.
  const snap = await call(d, 'GET', '/v1/snapshot');
  h0 = await hash(d);
  assert.equal(snap.status, 200);
});

test('bodies over max_body are 413', async () => {
  await refused('PATCH', '/v1/params', JSON.stringify({ k_bend: 10, pad: 'x'.repeat(70000) }), 413);
  await refused('PUT', '/v1/snapshot', Buffer.alloc(100000, 1), 413);
});

test('a body sent without Content-Length (chunked) is counted as it arrives', async () => {
  const url = new URL(d.url);
  const reply = await new Promise((resolve, reject) => {
    const sock = net.connect(Number(url.port), url.hostname, () => {
      sock.write('PATCH /v1/params HTTP/1.1\r\nHost: 127.0.0.1\r\nTransfer-Encoding: chunked\r\nConnection: close\r\n\r\n');
      for (let k = 0; k < 70; k++) sock.write(`3e8\r\n${' '.repeat(1000)}\r\n`);
      sock.write('0\r\n\r\n');
    });
    let text = '';
    sock.on('data', (c) => (text += c));
    sock.on('end', () => resolve(text));
    sock.on('error', reject);
  });
  assert.match(reply, /^HTTP\/1\.1 413 /);
  assert.equal(await hash(d), h0);
});

test('bad snapshots are refused', async () => {
  const good = (await call(d, 'GET', '/v1/snapshot')).buf;
  await refused('PUT', '/v1/snapshot', Buffer.from('not a snapshot'), 400);
  await refused('PUT', '/v1/snapshot', good.subarray(0, good.length - 1), 400);
  const corrupt = Buffer.from(good);
  corrupt[good.length - 5] ^= 0x40;
  await refused('PUT', '/v1/snapshot', corrupt, 400);
  const version = Buffer.from(good);
  version[4] = 99;
  await refused('PUT', '/v1/snapshot', version, 400);
  await refused('PUT', '/v1/snapshot', '', 400);
});

test('static paths cannot leave web_root', async () => {
  const url = new URL(d.url);
  for (const p of ['/../../../etc/passwd', '/..%2f..%2fetc%2fpasswd', '/%2e%2e/%2e%2e/etc/passwd', '/sub/../../etc/passwd',
    '/.%2e/etc/passwd', '/..\\..\\etc\\passwd']) {
    const text = await new Promise((resolve, reject) => {
      // Raw request line: fetch would normalise the path first.
      const sock = net.connect(Number(url.port), url.hostname, () => {
        sock.write(`GET ${p} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n`);
      });
      let t = '';
      sock.on('data', (c) => (t += c));
      sock.on('end', () => resolve(t));
      sock.on('error', reject);
    });
    assert.match(text, /^HTTP\/1\.1 (404|400) /, `${p}: ${text.slice(0, 80)}`);
    assert.doesNotMatch(text, /root:/);
  }
});
