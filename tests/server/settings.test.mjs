// settings.test.mjs - one table, four sources: defaults, the config file, CLOTHD_* variables and
// flags, in that order of precedence, for startup settings and engine parameters alike.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { writeFileSync } from 'node:fs';
import { join } from 'node:path';
import { start, stop, ok, tempDir, execChecked, CLOTHD } from './harness.mjs';

const run = execChecked; // execFile, and a sanitizer report fails the test

test('config file < environment < flags', async () => {
  const dir = tempDir();
  const conf = join(dir, 'clothd.conf');
  writeFileSync(conf, [
    '# a comment',
    'k_bend = 11',
    'k_shear = 44       # trailing comment',
    'gravity = 0, 0, -3',
    'integrator = symplectic_euler',
    'nx = 10',
    'ny = 9',
    'auto_drop_interval = 0',
    'max_rocks = 3',
  ].join('\n'));
  const d = await start(['--config', conf, '--k-shear', '55', '--paused'], { env: { CLOTHD_K_BEND: '22', CLOTHD_NY: '7' } });
  const p = await ok(d, 'GET', '/v1/params');
  assert.equal(p.k_bend, 22); // environment over the file
  assert.equal(p.k_shear, 55); // flag over the file
  assert.deepEqual(p.gravity, [0, 0, -3]);
  assert.equal(p.integrator, 'symplectic_euler');
  const s = await ok(d, 'GET', '/v1/scene');
  assert.equal(s.nx, 10);
  assert.equal(s.ny, 7);
  // A startup setting from the file: max_rocks = 3.
  for (let k = 0; k < 3; k++) await ok(d, 'POST', '/v1/rocks', { position: [k, 0, 3], radius: 0.1 });
  const r = await fetch(`${d.url}/v1/rocks`, { method: 'POST', body: JSON.stringify({ position: [0, 0, 4], radius: 0.1 }) });
  assert.equal(r.status, 422);
  assert.equal((await r.json()).param, 'max_rocks');
  await stop(d);
});

test('bad settings stop the start with a clear reason', async () => {
  const dir = tempDir();
  const conf = join(dir, 'bad.conf');
  writeFileSync(conf, 'k_bend = 10\nwarp_speed = 9\n');
  await assert.rejects(run(CLOTHD, ['--config', conf]), /bad\.conf:2: unknown setting 'warp_speed'/);
  await assert.rejects(run(CLOTHD, ['--port', '70000']), /port must be a whole number from 0 to 65535/);
  await assert.rejects(run(CLOTHD, ['--k-bend', 'soft']), /k_bend must be a number/);
  await assert.rejects(run(CLOTHD, ['--gravity', '1,2']), /gravity must be three numbers/);
  // Too long a vector is refused whole, not cut (to "1,2,3   ...", which reads as three numbers).
  await assert.rejects(run(CLOTHD, ['replay', join(dir, 'none'), '--gravity', `1,2,3${' '.repeat(300)},4`]),
    /gravity must be three numbers/);
  await assert.rejects(run(CLOTHD, ['--backend', 'tpu']), /backend must be one of auto\|cuda\|cpu/);
  await assert.rejects(run(CLOTHD, ['--listen', 'not-an-address', '--port', '0']), /listen address 'not-an-address'/);
  await assert.rejects(run(CLOTHD, ['--nope']), /unknown setting 'nope'/);
  await assert.rejects(run(CLOTHD, ['--config', join(dir, 'missing.conf')]), /missing\.conf: No such file/);
});

test('a config file line may be of any length; CRLF works; a bad line is named', async () => {
  const dir = tempDir();
  const conf = join(dir, 'long.conf');
  // Once read 1023 bytes at a time: the rest of a long comment became a line of its own.
  writeFileSync(conf, `# ${'x'.repeat(2000)}\r\nnx = 9\r\nny = 8   # ${'y'.repeat(1500)}\r\n\r\nauto_drop_interval = 0`);
  const d = await start(['--config', conf, '--paused']);
  const s = await ok(d, 'GET', '/v1/scene');
  assert.equal(s.nx, 9);
  assert.equal(s.ny, 8);
  await stop(d);
  const bad = join(dir, 'bad.conf');
  writeFileSync(bad, `nx = 9\n# ${'z'.repeat(3000)}\n\nno equals sign here\n`);
  await assert.rejects(run(CLOTHD, ['--config', bad]), /bad\.conf:4: expected 'name = value'/);
  writeFileSync(bad, 'nx = 9\nny = 9\0 junk\n');
  await assert.rejects(run(CLOTHD, ['--config', bad]), /bad\.conf:2: holds a NUL byte/);
});

test('--help lists every setting and parameter; routes and version', async () => {
  const { stdout } = await run(CLOTHD, ['--help']);
  for (const flag of ['--port', '--state-file', '--web-root', '--k-structural', '--auto-drop-interval', '--integrator'])
    assert.ok(stdout.includes(flag), flag);
  assert.match((await run(CLOTHD, ['--version'])).stdout, /^clothd \d+\.\d+\.\d+/);
  assert.match((await run(CLOTHD, ['routes'])).stdout, /^GET \/v1\/health$/m);
});

test('an unknown CLOTHD_ variable is ignored with a warning', async () => {
  const d = await start(['--paused'], { env: { CLOTHD_NOT_A_SETTING: '1' } });
  assert.match(d.log, /ignoring environment variable CLOTHD_NOT_A_SETTING/);
  await stop(d);
});
