// support.mjs - what the deploy tests share: scripts/install.sh into a temporary prefix (once per
// test file), and the installed clothd-serve started the way a container or a service starts it:
// settings from the environment only, ephemeral ports, the CPU backend, a temporary state
// directory and secrets directory.
import { after } from 'node:test';
import { execFile, execFileSync, spawn } from 'node:child_process';
import { chmodSync, mkdirSync, mkdtempSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { promisify } from 'node:util';
import { sanitizerReport } from '../server/harness.mjs';

export const SOURCE = process.env.CLOTHD_SOURCE;
export const BUILD = process.env.CLOTHD_BUILD_DIR;
export const CLOTHD = process.env.CLOTHD_BIN;
if (!SOURCE || !BUILD || !CLOTHD) throw new Error('CLOTHD_SOURCE, CLOTHD_BUILD_DIR and CLOTHD_BIN must be set (ctest sets them)');

export const run = promisify(execFile);

const temps = [];
export function tempDir(tag = 'deploy') {
  const dir = mkdtempSync(join(tmpdir(), `clothd-${tag}-`));
  temps.push(dir);
  return dir;
}

// The environment without the test runner's CLOTHD_* variables (clothd reads every CLOTHD_* one)
// nor systemd's, which clothd-serve reads.
export function cleanEnv(extra = {}) {
  const systemd = ['CREDENTIALS_DIRECTORY', 'STATE_DIRECTORY'];
  const base = Object.fromEntries(Object.entries(process.env).filter(([k]) => !k.startsWith('CLOTHD_') && !systemd.includes(k)));
  return { ...base, OMP_WAIT_POLICY: 'passive', ...extra };
}

let installed = null;
// scripts/install.sh PREFIX from this build; the prefix, once per process.
export function install() {
  if (!installed) {
    installed = join(tempDir('prefix'), 'opt');
    execFileSync(join(SOURCE, 'scripts/install.sh'), [installed], {
      env: cleanEnv({ CLOTHD_BUILD_DIR: BUILD }), stdio: ['ignore', 'inherit', 'inherit'],
    });
  }
  return installed;
}

export function tokenFile(path, text) {
  writeFileSync(path, `${text}\n`);
  chmodSync(path, 0o600);
  return path;
}

// A place for the service to run: an empty secrets directory and a state directory.
export function site() {
  const dir = tempDir('site');
  const secrets = join(dir, 'secrets');
  const state = join(dir, 'state');
  mkdirSync(secrets);
  mkdirSync(state);
  return { dir, secrets, state, stateFile: join(state, 'state.bin') };
}

// The environment clothd-serve gets in the tests: ephemeral ports, CPU backend, the site's dirs.
export function serveEnv(where, extra = {}) {
  return cleanEnv({
    CLOTHD_PORT: '0', CLOTHD_STREAM_PORT: '0', CLOTHD_BACKEND: 'cpu', CLOTHD_THREADS: '1',
    CLOTHD_SECRETS_DIR: where.secrets, CLOTHD_STATE_FILE: where.stateFile, ...extra,
  });
}

// Daemons a failed test left running are stopped when the file's tests end.
const running = new Set();
after(() => {
  for (const p of running) p.kill('SIGKILL');
  for (const dir of temps) rmSync(dir, { recursive: true, force: true });
});

// Starts PREFIX/bin/clothd-serve; resolves once clothd has logged where it listens and its last
// start line (the viewer's address). d.url reaches it over loopback whatever address it listens
// on; d.listen is that address.
export function serve(prefix, env, args = []) {
  const proc = spawn(join(prefix, 'bin/clothd-serve'), args, { stdio: ['ignore', 'pipe', 'pipe'], env });
  running.add(proc);
  proc.on('exit', () => running.delete(proc));
  const d = { proc, log: '', url: null, listen: null, exited: null };
  // 'close', not 'exit': by then stderr has been read to its end (a sanitizer's report is last).
  d.exitPromise = new Promise((resolve) => proc.on('close', (code, signal) => resolve((d.exited = { code, signal }))));
  return new Promise((resolve, reject) => {
    proc.stderr.setEncoding('utf8');
    proc.stderr.on('data', (chunk) => {
      d.log += chunk;
      const m = /listening on http:\/\/([0-9.]+):(\d+)/.exec(d.log);
      if (m && !d.url && /clothd: viewer: http:\/\/\S+\/\n/.test(d.log)) {
        d.listen = m[1];
        d.url = `http://127.0.0.1:${m[2]}`;
        resolve(d);
      }
    });
    d.exitPromise.then((e) => {
      if (!d.url) reject(new Error(`clothd-serve exited (${JSON.stringify(e)}) before listening:\n${d.log}`));
    });
  });
}

// Runs clothd-serve expecting it to refuse to start; resolves to { code, log }.
export function refused(prefix, env, args = []) {
  return new Promise((resolve, reject) => {
    const proc = spawn(join(prefix, 'bin/clothd-serve'), args, { stdio: ['ignore', 'ignore', 'pipe'], env });
    let log = '';
    proc.stderr.setEncoding('utf8');
    proc.stderr.on('data', (c) => {
      log += c;
      if (/listening on http:\/\//.test(log)) {
        proc.kill('SIGTERM');
        reject(new Error(`clothd-serve started when it should have refused:\n${log}`));
      }
    });
    proc.on('close', (code) => {
      const report = sanitizerReport(log);
      if (report) reject(new Error(`clothd-serve (exit ${code}): sanitizer report from clothd:\n${report}`));
      else resolve({ code, log });
    });
  });
}

// Stops it; returns its exit status. A sanitizer's report in its log (the ASan/UBSan build that
// scripts/test.sh also runs the suite on) fails the test, whatever the status.
export async function stop(d, signal = 'SIGTERM') {
  if (!d.exited) d.proc.kill(signal);
  const e = await d.exitPromise;
  const report = sanitizerReport(d.log);
  if (report) throw new Error(`clothd-serve (${JSON.stringify(e)}): sanitizer report from clothd:\n${report}`);
  return e;
}

export async function get(d, path, token) {
  const res = await fetch(d.url + path, { headers: token ? { Authorization: `Bearer ${token}` } : {} });
  const text = await res.text();
  let json;
  try { json = JSON.parse(text); } catch { json = undefined; }
  return { status: res.status, text, json };
}
