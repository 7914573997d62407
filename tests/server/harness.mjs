// harness.mjs - starts the real clothd on 127.0.0.1 with ephemeral ports (--port 0,
// --stream-port 0) and the CPU backend, and talks to it over real sockets with fetch. Used by
// every tests/server/*.test.mjs.
import { execFile, spawn } from 'node:child_process';
import { mkdtempSync, readFileSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { promisify } from 'node:util';
import { after } from 'node:test';
import YAML from 'yaml';
import Ajv2020 from 'ajv/dist/2020.js';

export const CLOTHD = process.env.CLOTHD_BIN;
if (!CLOTHD) throw new Error('CLOTHD_BIN must name the clothd binary (ctest sets it)');
// The test daemon with fault-injection hooks (server/testhooks.h), built for the tests only;
// tests that need it skip without it.
export const TESTHOOKS = process.env.CLOTHD_TESTHOOKS_BIN;

// A sanitizer's report in clothd's stderr (the AddressSanitizer/UndefinedBehaviorSanitizer build
// that scripts/test.sh also runs the suite on): from the report on, or null. start(), stop() and
// execChecked() fail on one, whatever the exit status, so no report goes unseen.
const REPORT = /^.*(==\d+==ERROR: \w+Sanitizer|runtime error: |SUMMARY: \w+Sanitizer)/m;
export function sanitizerReport(text) {
  const m = REPORT.exec(text ?? '');
  return m ? text.slice(m.index) : null;
}
function reportError(what, report) {
  const e = new Error(`${what}: sanitizer report from clothd:\n${report}`);
  e.sanitizerReport = report; // a test that expects clothd to fail rethrows this one
  return e;
}

// Daemons started and not yet stopped. A test that fails before its stop() would leave its
// daemon running and the test process waiting on it until ctest's timeout. After the file's last
// test (and before the file's own after hooks, which run next and may stop daemons as they
// choose), a timer that does not keep the process alive kills whatever is left 30 s later.
const live = new Set();
after(() => {
  setTimeout(() => {
    for (const d of live) d.proc.kill('SIGKILL');
  }, 30000).unref();
});

export function tempDir() {
  return mkdtempSync(join(tmpdir(), 'clothd-test-'));
}

// Starts clothd and resolves once it logs the port it listens on. Extra flags follow the
// defaults, so they win. The daemon's log is kept in daemon.log for failure messages. bin: another
// daemon binary (TESTHOOKS); wrap: a command that execs it (e.g. ['prlimit', '--fsize=4096']).
// When it exits before listening, the error carries the daemon (its exit status and log).
export function start(flags = [], { env = {}, webRoot, bin = CLOTHD, wrap = [] } = {}) {
  const dir = tempDir();
  const args = ['--port', '0', '--stream-port', '0', '--backend', 'cpu', '--threads', '1', '--web-root', webRoot ?? dir,
    ...flags];
  // (nor a systemd notification socket the test runner may have been given: systemd.test.mjs
  // passes its own)
  const base = Object.fromEntries(Object.entries(process.env).filter(([k]) =>
    !k.startsWith('CLOTHD_') && !['NOTIFY_SOCKET', 'WATCHDOG_USEC', 'WATCHDOG_PID'].includes(k)));
  const command = [...wrap, bin, ...args];
  const proc = spawn(command[0], command.slice(1), {
    stdio: ['ignore', 'pipe', 'pipe'],
    env: { ...base, OMP_WAIT_POLICY: 'passive', ...env },
  });
  const daemon = { proc, dir, log: '', url: null, exited: null };
  live.add(daemon);
  proc.stdout.resume();
  daemon.exitPromise = new Promise((resolve) => {
    // 'close', not 'exit': by then stderr has been read to its end (a report is last).
    proc.on('close', (code, signal) => {
      live.delete(daemon);
      daemon.exited = { code, signal };
      resolve(daemon.exited);
    });
  });
  return new Promise((resolve, reject) => {
    proc.stderr.setEncoding('utf8');
    proc.stderr.on('data', (chunk) => {
      daemon.log += chunk;
      if (daemon.url) return; // (a busy daemon's access log: the whole log is not searched again)
      const m = /listening on http:\/\/([0-9.]+):(\d+)/.exec(daemon.log);
      if (m) {
        daemon.url = `http://${m[1]}:${m[2]}`;
        resolve(daemon);
      }
    });
    daemon.exitPromise.then((e) => {
      if (daemon.url) return;
      rmSync(daemon.dir, { recursive: true, force: true });
      const report = sanitizerReport(daemon.log);
      if (report) reject(reportError(`clothd exited (${JSON.stringify(e)}) before listening`, report));
      else reject(Object.assign(new Error(`clothd exited (${JSON.stringify(e)}) before listening:\n${daemon.log}`), { daemon }));
    });
  });
}

// Starts clothd expecting it to refuse to start; resolves with its exit status and log.
export async function refusedStart(flags = [], opts = {}) {
  let d;
  try {
    d = await start(flags, opts);
  } catch (e) {
    if (!e.daemon) throw e;
    return { code: e.daemon.exited.code, log: e.daemon.log };
  }
  await stop(d, 'SIGKILL');
  throw new Error(`clothd started where it should have refused:\n${d.log}`);
}

// Stops the daemon with a signal and waits for it to exit; returns its exit status.
export async function stop(daemon, signal = 'SIGTERM') {
  if (!daemon.exited) daemon.proc.kill(signal);
  const e = await daemon.exitPromise;
  rmSync(daemon.dir, { recursive: true, force: true });
  const report = sanitizerReport(daemon.log);
  if (report) throw reportError(`clothd (${JSON.stringify(e)})`, report);
  return e;
}

// Runs clothd to its end (a subcommand, a start that is refused): promisified execFile's
// signature and result, but a sanitizer report fails it even where the test expects a refusal.
const execFileP = promisify(execFile);
export async function execChecked(file, args, options) {
  let r;
  try {
    r = await execFileP(file, args, options);
  } catch (e) {
    const report = sanitizerReport(e.stderr);
    throw report ? reportError(`${file} ${args.join(' ')}`, report) : e;
  }
  const report = sanitizerReport(r.stderr);
  if (report) throw reportError(`${file} ${args.join(' ')}`, report);
  return r;
}

// proto/openapi.yaml, read once: every answer call() gets from the API is checked against it (its
// status must be one the operation lists, its body must match the schema of that status and
// content type), errors included. ajv takes the whole document as one schema, so the spec's own
// '#/components/...' references resolve; OpenAPI's other keywords are not JSON Schema and ajv
// leaves them be (strict off), as it does formats such as binary.
export const SPEC = YAML.parse(readFileSync(join(process.env.CLOTHD_SOURCE, 'proto', 'openapi.yaml'), 'utf8'));
const ajv = new Ajv2020({ strict: false, allErrors: true, validateFormats: false });
ajv.addSchema(SPEC, 'openapi.yaml');
const validators = new Map();
const pointer = (...parts) => parts.map((p) => `/${String(p).replaceAll('~', '~0').replaceAll('/', '~1')}`).join('');
// Statuses any operation may answer (PROTOCOL.md "Conventions"; the spec's description).
const ANY_OPERATION = ['405', '414', '501'];

// A path item of the spec ([template, item] of SPEC.paths) as [its location, the item itself],
// through its $ref when it has one.
export function specPathItem(entry) {
  if (!entry) return [[], undefined];
  const ref = entry[1].$ref;
  if (!ref) return [['paths', entry[0]], entry[1]];
  const parts = ref.slice(2).split('/');
  return [parts, parts.reduce((o, k) => o[k], SPEC)];
}

export function checkAnswer(method, path, status, type, json) {
  const route = path.split('?')[0];
  if (!route.startsWith('/v1/') && route !== '/metrics') return; // the viewer's files
  const what = `${method} ${path} -> ${status}`;
  const fail = (why) => { throw new Error(`${what}: ${why} (proto/openapi.yaml)`); };
  const validate = (ptr) => {
    if (!validators.has(ptr)) validators.set(ptr, ajv.compile({ $ref: `openapi.yaml#${ptr}` }));
    const v = validators.get(ptr);
    if (!v(json)) fail(`the body does not match ${ptr}: ${ajv.errorsText(v.errors)}: ${JSON.stringify(json).slice(0, 300)}`);
  };
  const problemPointer = pointer('components', 'responses', 'Problem', 'content', 'application/problem+json', 'schema');
  const entry = Object.entries(SPEC.paths).find(([tpl]) => new RegExp(`^${tpl.replace(/\{[^}]+\}/g, '[^/]+')}$`).test(route));
  // A path item may be a reference to one of components/pathItems (a scene's routes, with and
  // without the prefix that names the scene, share theirs).
  const [where, item] = specPathItem(entry);
  const op = item?.[method === 'HEAD' ? 'get' : method.toLowerCase()];
  let response = op?.responses[String(status)], at = op && pointer(...where, method === 'HEAD' ? 'get' : method.toLowerCase(),
    'responses', String(status));
  if (!op || (!response && ANY_OPERATION.includes(String(status)))) {
    // An unknown route or method: refused before routing (400, 401, 403, 429) or 404 / 405.
    if (status < 400) fail('a success from an unknown route or method');
    response = { $ref: '#/components/responses/Problem' };
  }
  if (!response) fail(`the operation lists no ${status}`);
  if (response.$ref) {
    at = pointer(...response.$ref.slice(2).split('/'));
    response = response.$ref.slice(2).split('/').reduce((o, k) => o[k], SPEC);
  }
  if (method === 'HEAD' || !response.content) return;
  const base = type.split(';')[0].trim();
  if (!response.content[base]) fail(`content type ${type} is not one of ${Object.keys(response.content).join(', ')}`);
  if (base.endsWith('json')) validate(at === undefined ? problemPointer : `${at}${pointer('content', base, 'schema')}`);
}

// One request. body: an object (sent as JSON), a string or a Buffer (sent as is). The answer is
// checked against proto/openapi.yaml (checkAnswer); { spec: false } leaves it unchecked, for a
// test that wants to see a broken answer itself.
export async function call(daemon, method, path, body, headers = {}, { spec = true } = {}) {
  const init = { method, headers: { ...headers } };
  if (body !== undefined) {
    init.body = typeof body === 'string' || body instanceof Uint8Array ? body : JSON.stringify(body);
  }
  const res = await fetch(daemon.url + path, init);
  const buf = Buffer.from(await res.arrayBuffer());
  const type = res.headers.get('content-type') || '';
  let json;
  if (type.includes('json')) json = JSON.parse(buf.toString('utf8'));
  if (spec) checkAnswer(method, path, res.status, type, json);
  return { status: res.status, headers: res.headers, type, buf, text: buf.toString('utf8'), json };
}

export async function ok(daemon, method, path, body, headers) {
  const r = await call(daemon, method, path, body, headers);
  if (r.status >= 300) throw new Error(`${method} ${path} -> ${r.status}: ${r.text}`);
  return r.json ?? r;
}

export async function pause(daemon) {
  return ok(daemon, 'POST', '/v1/sim/pause');
}

// The state hash of a paused daemon (published with every change while paused).
export async function hash(daemon) {
  const sim = await ok(daemon, 'GET', '/v1/sim');
  if (sim.state !== 'paused') throw new Error('hash() needs a paused daemon');
  return sim.state_hash;
}

// Waits for a condition by polling it (a condition, not a guess at how long something takes).
export async function until(what, fn, { timeout = 20000, every = 20 } = {}) {
  const t0 = Date.now();
  for (;;) {
    const v = await fn();
    if (v) return v;
    if (Date.now() - t0 > timeout) throw new Error(`timed out waiting for ${what}`);
    await new Promise((r) => setTimeout(r, every));
  }
}

export const PROBLEM = 'application/problem+json';

// A counter or gauge of /metrics' text: the series with these labels (`encoding="f32"`), or the
// sum over all of name's series when none are given.
export function metric(text, name, labels) {
  const series = labels === undefined ? '(?:\\{[^}]*\\})?' : `\\{${labels.replace(/[.*+?^${}()|[\]\\]/g, '\\$&')}\\}`;
  let sum = 0;
  for (const m of text.matchAll(new RegExp(`^${name}${series} ([\\d.e+-]+)$`, 'gm'))) sum += Number(m[1]);
  return sum;
}

// A process's resident memory in KiB (field VmRSS), or its peak (VmHWM); null once it is gone.
export function rssKiB(pid, field = 'VmRSS') {
  try {
    const m = new RegExp(`${field}:\\s+(\\d+) kB`).exec(readFileSync(`/proc/${pid}/status`, 'utf8'));
    return m ? Number(m[1]) : null;
  } catch {
    return null;
  }
}
