// spec.test.mjs - proto/openapi.yaml and the daemon agree: the same routes and methods as
// `clothd routes`, and the same parameter and scene fields as the live API; the spec lints clean
// under @redocly/cli; and every answer the API tests get is validated against it (harness.mjs).
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { execFile } from 'node:child_process';
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { promisify } from 'node:util';
import { start, stop, ok, execChecked, checkAnswer, specPathItem, SPEC, CLOTHD, PROBLEM } from './harness.mjs';

const execFileP = promisify(execFile);

const spec = readFileSync(join(process.env.CLOTHD_SOURCE, 'proto', 'openapi.yaml'), 'utf8').split('\n');

// The routes under `paths:` and their methods (a path item may be a $ref to components/pathItems).
function specRoutes() {
  const out = [];
  for (const entry of Object.entries(SPEC.paths)) {
    const [, item] = specPathItem(entry);
    for (const m of ['get', 'put', 'post', 'patch', 'delete']) if (item[m]) out.push(`${m.toUpperCase()} ${entry[0]}`);
  }
  return out.sort();
}

// The property names of a component schema (six-space keys under `    Name:` ... `properties:`).
function schemaProperties(name) {
  const start = spec.findIndex((l) => l === `    ${name}:`);
  assert.ok(start > 0, `schema ${name} in openapi.yaml`);
  const props = [];
  let inProps = false;
  for (const line of spec.slice(start + 1)) {
    if (/^ {4}\S/.test(line)) break;
    if (/^ {6}properties:/.test(line)) inProps = true;
    else if (/^ {6}\S/.test(line)) inProps = false;
    const m = /^ {8}([a-z_]+):/.exec(line);
    if (inProps && m) props.push(m[1]);
  }
  return props.sort();
}

test('openapi.yaml lists exactly the routes and methods of the route table', async () => {
  const { stdout } = await execChecked(CLOTHD, ['routes']);
  const table = stdout.trim().split('\n').sort();
  assert.ok(table.length >= 25);
  assert.deepEqual(specRoutes(), table);
});

test('openapi.yaml names every parameter and scene field the API has', async () => {
  const d = await start(['--paused']);
  assert.deepEqual(schemaProperties('Params'), Object.keys(await ok(d, 'GET', '/v1/params')).sort());
  assert.deepEqual(schemaProperties('Scene'), Object.keys(await ok(d, 'GET', '/v1/scene')).sort());
  const rock = (await ok(d, 'POST', '/v1/rocks', { position: [0, 0, 3], radius: 0.1 })).rock;
  assert.deepEqual(schemaProperties('Rock'), Object.keys(rock).sort());
  assert.deepEqual(schemaProperties('Sim'), Object.keys(await ok(d, 'GET', '/v1/sim')).sort());
  await stop(d);
});

test('openapi.yaml\'s Params holds every live row of the settings table: type, range, default, unit, help', async () => {
  // The engine's rows are generated (clothsim-params --openapi, docs.params_openapi); the daemon
  // loop's are written by hand. Both are held here to the table the daemon serves.
  const d = await start(['--paused']);
  const rows = (await ok(d, 'GET', '/v1/params/schema')).params.filter((r) => r.kind === 'live');
  await stop(d);
  const props = SPEC.components.schemas.Params.properties;
  assert.deepEqual(Object.keys(props).sort(), rows.map((r) => r.name).sort());
  // The API prints numbers to 9 significant digits (JSON_REAL_PRECISION(9): seed's maximum,
  // 2147483647, reads 2147483650), so numbers are compared to 9 digits.
  const num = (v) => (Array.isArray(v) ? v.map(num) : Number(v.toPrecision(9)));
  const types = { int: 'integer', float: 'number', bool: 'boolean', enum: 'string', vec3: 'array' };
  for (const r of rows) {
    const p = props[r.name];
    const at = `Params.${r.name}`;
    assert.equal(p.type, types[r.type], `${at}: type`);
    assert.equal(p['x-unit'], r.unit, `${at}: x-unit`);
    assert.equal(p.description, r.help, `${at}: description`);
    if (r.type === 'enum') {
      assert.deepEqual(p.enum, r.choices, `${at}: enum`);
      assert.equal(p.default, r.default, `${at}: default`);
    } else if (r.type === 'bool') {
      assert.equal(p.default, r.default, `${at}: default`);
    } else {
      const range = r.type === 'vec3' ? p.items : p;
      if (r.type === 'vec3') assert.deepEqual([p.minItems, p.maxItems], [3, 3], `${at}: three items`);
      assert.deepEqual(num([range.minimum, range.maximum]), num([r.min, r.max]), `${at}: range`);
      assert.deepEqual(num(p.default), num(r.default), `${at}: default`);
    }
  }
});

test('openapi.yaml passes @redocly/cli lint with no errors', async () => {
  // The recommended ruleset. One warning stays: info-license (the project names no licence).
  const redocly = join(process.env.CLOTHD_SOURCE, 'node_modules', '.bin', 'redocly');
  const r = await execFileP(redocly, ['lint', '--format', 'summary', join(process.env.CLOTHD_SOURCE, 'proto', 'openapi.yaml')], {
    env: { ...process.env, REDOCLY_TELEMETRY: 'off', REDOCLY_SUPPRESS_UPDATE_NOTICE: 'true' },
  }).catch((e) => e);
  const out = `${r.stdout}${r.stderr}`;
  console.log(out.trim());
  assert.equal(r.code ?? 0, 0, out);
  assert.doesNotMatch(out, /\d+ errors?/, out);
});

test('every answer the API tests get is checked against openapi.yaml (the harness)', () => {
  // checkAnswer is what call() runs on every answer; here it is shown to refuse what the spec
  // does not say: a status the operation does not list, a body that does not match.
  assert.throws(() => checkAnswer('POST', '/v1/sim/pause', 422, PROBLEM, { type: 'urn:clothd:problem:x', title: 't', status: 422, detail: 'd' }),
    /lists no 422/);
  assert.throws(() => checkAnswer('GET', '/v1/health', 200, 'application/json', { status: 'ok' }), /does not match/);
  assert.throws(() => checkAnswer('GET', '/v1/nothing', 404, PROBLEM, { status: 404 }), /does not match/);
  checkAnswer('DELETE', '/v1/sim', 405, PROBLEM, { type: 'urn:clothd:problem:method-not-allowed', title: 't', status: 405, detail: 'd' });
});
