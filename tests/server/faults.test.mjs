// faults.test.mjs - what clothd does when things go wrong: a non-finite state (rolled back within
// one frame), a backend failure (unhealthy, state saved, exit 3, resumed on restart), a crash in
// the middle of saving the state file, a save that cannot be written, and a state file that is
// corrupt, foreign or from another version. Faults are injected by clothd-testhooks, the same
// daemon with the hooks of server/testhooks.h; the last test shows the shipped clothd has none.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { execFileSync } from 'node:child_process';
import { chmodSync, mkdirSync, readdirSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { get } from 'node:http';
import { dirname, join } from 'node:path';
import WebSocket from 'ws';
import { start, stop, call, ok, until, refusedStart, tempDir, CLOTHD, TESTHOOKS } from './harness.mjs';

const hooks = TESTHOOKS ? {} : { skip: 'CLOTHD_TESTHOOKS_BIN is not set (ctest sets it to build/tests/server/clothd-testhooks)' };
const small = ['--nx', '16', '--ny', '16', '--auto-drop-interval', '0'];

// The stream's text messages, kept as they come.
function listen(port) {
  return new Promise((resolve, reject) => {
    const ws = new WebSocket(`ws://127.0.0.1:${port}/stream`, 'clothd.v1');
    const c = { ws, texts: [] };
    ws.on('message', (data, binary) => {
      if (!binary) c.texts.push(JSON.parse(data.toString()));
    });
    ws.on('open', () => resolve(c));
    ws.on('error', reject);
  });
}
const streamEvent = (c, name) => until(`a stream ${name} event`, () => c.texts.find((m) => m.type === 'event' && m.event === name));

// GET on a new connection, as a supervisor's probe makes it (fetch would reuse one).
function probe(d, path) {
  return new Promise((resolve, reject) => {
    get(d.url + path, { agent: false }, (res) => {
      let body = '';
      res.setEncoding('utf8');
      res.on('data', (chunk) => (body += chunk));
      res.on('end', () => resolve({ status: res.statusCode, json: JSON.parse(body) }));
    }).on('error', reject);
  });
}

async function cloth(d) {
  const r = await call(d, 'GET', '/v1/cloth/state', undefined, { Accept: 'application/octet-stream' });
  assert.equal(r.status, 200);
  return r.buf;
}

const allFinite = (buf) => new Float32Array(buf.buffer, buf.byteOffset, buf.length / 4).every(Number.isFinite);

test('a NaN is rolled back within one frame to the checkpoint: paused, last_event, stream, log', hooks, async () => {
  // Checkpoints every 10 frames; the hook writes a NaN into the cloth after frame 25.
  const d = await start([...small, '--paused', '--checkpoint-interval', '10'], { bin: TESTHOOKS, env: { CLOTHD_TEST_NAN_FRAME: '25' } });
  const c = await listen((await ok(d, 'GET', '/v1/health')).stream.port);
  const { substeps } = await ok(d, 'GET', '/v1/sim');
  const at20 = await ok(d, 'POST', '/v1/sim/step', { frames: 20 }); // frame 20: a checkpoint
  assert.equal(at20.frame, 20);
  const cloth20 = await cloth(d);

  const r = await ok(d, 'POST', '/v1/sim/step', { frames: 10 });
  assert.match(d.log, /test hook: NaN written into vertex \d+ after frame 25/);
  // Found by the frame after the NaN (frame 26), and the state is frame 20's again.
  assert.equal(r.event.type, 'instability');
  assert.equal(r.event.step, 26 * substeps);
  assert.equal(r.event.restored_step, 20 * substeps);
  assert.match(r.event.detail, /rolled back to the last checkpoint and paused/);
  assert.equal(r.step, 20 * substeps);
  assert.equal(r.frame, 20);
  assert.equal(r.state_hash, at20.state_hash);
  const now = await cloth(d);
  assert.ok(allFinite(now));
  assert.ok(now.equals(cloth20));

  const sim = await ok(d, 'GET', '/v1/sim');
  assert.equal(sim.state, 'paused');
  assert.equal(sim.step, 20 * substeps);
  assert.equal(sim.state_hash, at20.state_hash);
  assert.deepEqual(sim.last_event, r.event);
  assert.deepEqual((await streamEvent(c, 'instability')).detail, r.event);
  assert.match(d.log, new RegExp(`instability at step ${26 * substeps}: rolled back to step ${20 * substeps} and paused`));

  // It goes on from there (the hook fires once).
  const on = await ok(d, 'POST', '/v1/sim/step', { frames: 10 });
  assert.equal(on.event, undefined);
  assert.equal(on.step, 30 * substeps);
  c.ws.close();
  await stop(d);
});

test('while running, a NaN pauses the daemon at the checkpoint before it', hooks, async () => {
  const d = await start([...small, '--checkpoint-interval', '10', '--time-scale', '4'], { bin: TESTHOOKS, env: { CLOTHD_TEST_NAN_FRAME: '30' } });
  const sim = await until('the rollback', async () => {
    const s = await ok(d, 'GET', '/v1/sim');
    return s.last_event ? s : null;
  });
  const { substeps } = sim;
  assert.equal(sim.last_event.type, 'instability');
  assert.equal(sim.last_event.step, 31 * substeps);
  assert.equal(sim.last_event.restored_step, 30 * substeps);
  const after = await ok(d, 'GET', '/v1/sim');
  assert.equal(after.state, 'paused');
  assert.equal(after.step, 30 * substeps);
  assert.equal(after.frame, 30);
  assert.ok(allFinite(await cloth(d)));
  await stop(d);
});

test('a backend failure: 503 while it saves, the last checkpoint saved, exit 3, a restart resumes it', hooks, async () => {
  const dir = tempDir();
  const state = join(dir, 'state.bin');
  // The backend fails as a lost GPU does after frame 23; the save is held 3 s before its rename
  // so that the unhealthy daemon can be watched.
  const d = await start([...small, '--paused', '--checkpoint-interval', '10', '--state-file', state], {
    bin: TESTHOOKS,
    env: { CLOTHD_TEST_BACKEND_FAIL_FRAME: '23', CLOTHD_TEST_SAVE_PAUSE_MS: '3000' },
  });
  const c = await listen((await ok(d, 'GET', '/v1/health')).stream.port);
  const { substeps } = await ok(d, 'GET', '/v1/sim');
  const at20 = await ok(d, 'POST', '/v1/sim/step', { frames: 20 }); // the last checkpoint before the failure
  assert.equal((await probe(d, '/v1/health')).status, 200);

  const r = await call(d, 'POST', '/v1/sim/step', { frames: 10 });
  assert.equal(r.status, 503);
  assert.equal(r.json.type, 'urn:clothd:problem:unavailable');
  await until('the save', () => /pausing 3000 ms before the rename/.test(d.log));
  const health = await probe(d, '/v1/health');
  assert.equal(health.status, 503);
  assert.equal(health.json.status, 'unhealthy');
  // Commands are refused while it saves; reads answer.
  const patch = await call(d, 'PATCH', '/v1/params', { drag: 0.5 });
  assert.equal(patch.status, 503);
  assert.equal(patch.json.type, 'urn:clothd:problem:unavailable');
  const sim = await ok(d, 'GET', '/v1/sim');
  assert.equal(sim.last_event.type, 'backend_failure');
  assert.equal(sim.last_event.step, 23 * substeps);
  assert.match(sim.last_event.detail, /device state lost/);
  assert.deepEqual((await streamEvent(c, 'backend_failure')).detail, sim.last_event);

  const exit = await d.exitPromise;
  assert.equal(exit.code, 3);
  assert.match(d.log, /backend failure at step \d+: .*device state lost/);
  assert.match(d.log, /saving the last checkpoint/);
  assert.match(d.log, /state saved to /);
  assert.deepEqual(readdirSync(dir), ['state.bin']);

  // What a supervisor does: start it again with the same state file.
  const again = await start(['--paused', '--state-file', state]);
  const resumed = await ok(again, 'GET', '/v1/sim');
  assert.equal(resumed.step, 20 * substeps);
  assert.equal(resumed.frame, 20);
  assert.equal(resumed.state_hash, at20.state_hash);
  assert.equal((await call(again, 'GET', '/v1/health')).status, 200);
  await stop(again);
});

// A good state file at frame 20; returns its path, bytes and the daemon's answer at that frame.
async function goodStateFile() {
  const dir = tempDir();
  const state = join(dir, 'state.bin');
  const a = await start([...small, '--paused', '--state-file', state]);
  const at = await ok(a, 'POST', '/v1/sim/step', { frames: 20 });
  assert.equal((await stop(a)).code, 0);
  return { dir, state, bytes: readFileSync(state), at };
}

test('SIGKILL in the middle of a save leaves the previous state file, and a restart resumes from it', hooks, async () => {
  const { dir, state, bytes, at } = await goodStateFile();
  const b = await start(['--paused', '--state-file', state], { bin: TESTHOOKS, env: { CLOTHD_TEST_SAVE_PAUSE_MS: '60000' } });
  assert.equal((await ok(b, 'GET', '/v1/sim')).step, at.step);
  await ok(b, 'POST', '/v1/sim/step', { frames: 15 });
  b.proc.kill('SIGTERM');
  await until('the save, held before its rename', () => /pausing 60000 ms before the rename/.test(b.log));
  const tmp = `state.bin.tmp.${b.proc.pid}`;
  assert.deepEqual(readdirSync(dir).sort(), ['state.bin', tmp]);
  assert.ok(!readFileSync(join(dir, tmp)).equals(bytes)); // the newer state, complete but not in place
  b.proc.kill('SIGKILL');
  assert.equal((await b.exitPromise).signal, 'SIGKILL');
  assert.ok(readFileSync(state).equals(bytes));

  const c = await start(['--paused', '--state-file', state]);
  const sim = await ok(c, 'GET', '/v1/sim');
  assert.equal(sim.step, at.step);
  assert.equal(sim.state_hash, at.state_hash);
  assert.match(c.log, new RegExp(`removed .*${tmp}, left by a save that did not finish`));
  assert.deepEqual(readdirSync(dir), ['state.bin']);
  await stop(c);
});

// The system calls of a save, as strace sees them: the temp file written and fsynced, renamed over
// the state file, then the directory fsynced - in that order - and the state file never opened
// for writing.
test('a save writes a temp file, fsyncs it, renames it over the state file, then fsyncs the directory', async (t) => {
  try {
    execFileSync('strace', ['-o', '/dev/null', 'true'], { stdio: 'ignore' });
  } catch {
    t.skip('strace is missing or cannot trace here');
    return;
  }
  const { dir, state, at: before } = await goodStateFile(); // the save replaces this file
  const trace = join(tempDir(), 'trace');
  // LeakSanitizer cannot run under ptrace (the sanitized build's clothd would exit 1 at its end).
  const env = process.env.CLOTHD_SANITIZED === '1'
    ? { ASAN_OPTIONS: [process.env.ASAN_OPTIONS, 'detect_leaks=0'].filter(Boolean).join(':') } : {};
  const e = await start(['--paused', '--state-file', state], {
    wrap: ['strace', '-f', '-qq', '-o', trace, '-e', 'trace=openat,open,fsync,fdatasync,close,rename,renameat,renameat2'],
    env,
  });
  assert.equal((await ok(e, 'GET', '/v1/sim')).step, before.step);
  const stepped = await ok(e, 'POST', '/v1/sim/step', { frames: 3 });
  // SIGTERM to the daemon itself (strace, its parent, would only detach).
  const pid = Number(readFileSync(`/proc/${e.proc.pid}/task/${e.proc.pid}/children`, 'utf8').trim().split(/\s+/)[0]);
  assert.ok(pid > 0);
  process.kill(pid, 'SIGTERM');
  const exited = await e.exitPromise;
  assert.equal(exited.code, 0, `clothd under strace ended ${JSON.stringify(exited)}:\n${e.log}`);
  assert.match(e.log, /state saved to/);

  const calls = readFileSync(trace, 'utf8').split('\n').map((l) => l.replace(/^\d+\s+/, ''));
  const at = (re, from = 0) => {
    const k = calls.findIndex((l, i) => i >= from && re.test(l));
    assert.ok(k >= 0, `no ${re} after line ${from} in the trace:\n${calls.join('\n')}`);
    return k;
  };
  const esc = (s) => s.replace(/[.*+?^${}()|[\]\\]/g, '\\$&');
  const tmp = `${state}.tmp.${pid}`;
  const open = at(new RegExp(`^open(at)?\\(.*"${esc(tmp)}", O_WRONLY\\|O_CREAT.* = (\\d+)$`));
  const fd = calls[open].match(/= (\d+)$/)[1];
  const sync = at(new RegExp(`^fsync\\(${fd}\\)\\s+= 0`), open);
  const close = at(new RegExp(`^close\\(${fd}\\)\\s+= 0`), sync);
  const rename = at(new RegExp(`^rename(at2?)?\\(.*"${esc(tmp)}", .*"${esc(state)}".*\\)\\s+= 0`), close);
  const dirOpen = at(new RegExp(`^open(at)?\\(.*"${esc(dir)}", .*O_DIRECTORY.* = (\\d+)$`), rename);
  const dfd = calls[dirOpen].match(/= (\d+)$/)[1];
  at(new RegExp(`^fsync\\(${dfd}\\)\\s+= 0`), dirOpen);
  // No rename before the temp file was synced, and the state file itself is never written in place.
  assert.equal(calls.findIndex((l) => /^rename/.test(l) && l.includes(tmp)), rename);
  assert.ok(!calls.some((l) => new RegExp(`"${esc(state)}", O_(WRONLY|RDWR)`).test(l)));
  // And what it wrote is the state it had: a restart resumes from it.
  const again = await start(['--paused', '--state-file', state]);
  const sim = await ok(again, 'GET', '/v1/sim');
  assert.equal(sim.step, stepped.step);
  assert.equal(sim.state_hash, stepped.state_hash);
  await stop(again);
  assert.deepEqual(readdirSync(dir), ['state.bin']);
  rmSync(dirname(trace), { recursive: true, force: true });
  rmSync(e.dir, { recursive: true, force: true });
});

test('a full disk: the save fails, is logged, exit 4, and the previous state file is intact', async (t) => {
  try {
    execFileSync('prlimit', ['--version']);
  } catch {
    t.skip('prlimit (util-linux) is missing');
    return;
  }
  const { dir, state, bytes, at } = await goodStateFile();
  // A file size limit below the state's size: the write fails part way (EFBIG), as on a full disk.
  assert.ok(bytes.length > 4096);
  const b = await start(['--paused', '--state-file', state], { wrap: ['prlimit', '--fsize=4096'] });
  assert.equal((await ok(b, 'GET', '/v1/sim')).step, at.step);
  await ok(b, 'POST', '/v1/sim/step', { frames: 5 });
  assert.equal((await stop(b)).code, 4);
  assert.match(b.log, /could not save the state to .*state\.bin: cannot write .*state\.bin\.tmp\.\d+: File too large; the previous state file, if any, is unchanged/);
  assert.ok(readFileSync(state).equals(bytes));
  assert.deepEqual(readdirSync(dir), ['state.bin']); // the partial temp file is gone
});

test('an unwritable state directory: the save fails, is logged, exit 4, and the previous state file is intact', async () => {
  const { dir, state, bytes } = await goodStateFile();
  const b = await start(['--paused', '--state-file', state]);
  await ok(b, 'POST', '/v1/sim/step', { frames: 5 });
  // Without write permission on the directory the temp file cannot be created. root ignores the
  // permission; for root the temp file's name is taken by a directory instead (EISDIR).
  const root = process.getuid?.() === 0;
  if (root) mkdirSync(join(dir, `state.bin.tmp.${b.proc.pid}`));
  else chmodSync(dir, 0o500);
  try {
    assert.equal((await stop(b)).code, 4);
  } finally {
    chmodSync(dir, 0o700);
  }
  assert.match(b.log, new RegExp(`could not save the state to .*state\\.bin: cannot create .*: ${root ? 'Is a directory' : 'Permission denied'}`));
  assert.ok(readFileSync(state).equals(bytes));
});

test('a corrupt, foreign or other-version state file is refused with a reason, unchanged', async () => {
  const { state, bytes } = await goodStateFile();
  const cases = [
    ['corrupt (one bit flipped)', (b) => { b[b.length >> 1] ^= 0x10; return b; }, /it is damaged \(snapshot checksum does not match/],
    // Cut past the trailer (a few hundred bytes at most), into the snapshot.
    ['truncated', (b) => b.subarray(0, b.length - 400), /it is damaged \(snapshot length does not match/],
    ['foreign', () => Buffer.from('{"hello": "this is not a state file"}\n'), /it is not a clothd state file/],
    ['empty', () => Buffer.alloc(0), /it is not a clothd state file/],
    ['another version', (b) => { b.writeUInt32LE(99, 4); return b; }, /it was written by another version of clothd \(snapshot format version 99/],
  ];
  for (const [what, spoil, reason] of cases) {
    const bad = spoil(Buffer.from(bytes));
    writeFileSync(state, bad);
    const r = await refusedStart(['--state-file', state]);
    assert.equal(r.code, 1, what);
    assert.match(r.log, /cannot resume from the state file .*state\.bin: /, what);
    assert.match(r.log, reason, what);
    assert.match(r.log, /--state-file-invalid fresh/, what);
    assert.ok(readFileSync(state).equals(bad), `${what}: the file is left as it was`);
  }
});

test('a state file past max_state_mb is refused and kept, even with state_file_invalid = fresh', async () => {
  // A 200 x 200 cloth costs some 70 MB: a good file, but more than a 2 MiB limit allows.
  const dir = tempDir();
  const state = join(dir, 'state.bin');
  const a = await start(['--paused', '--nx', '200', '--ny', '200', '--state-file', state]);
  assert.equal((await stop(a)).code, 0);
  const bytes = readFileSync(state);
  const r = await refusedStart([...small, '--max-state-mb', '2', '--state-file', state, '--state-file-invalid', 'fresh']);
  assert.equal(r.code, 1);
  assert.match(r.log, /cannot resume from the state file .*state\.bin: a 200 x 200 cloth needs \d+ MiB, more than the memory limit of 2 MiB \(raise max_state_mb to resume from it\)/);
  assert.deepEqual(readdirSync(dir), ['state.bin']); // not moved aside: it is not damaged
  assert.ok(readFileSync(state).equals(bytes));
  rmSync(dir, { recursive: true, force: true });
});

test('a state file that cannot be read is refused, even with state_file_invalid = fresh', async () => {
  // A directory where the file should be: it opens but cannot be read (EISDIR), for root too.
  const dir = tempDir();
  const state = join(dir, 'state.bin');
  mkdirSync(state);
  const r = await refusedStart([...small, '--state-file', state, '--state-file-invalid', 'fresh']);
  assert.equal(r.code, 1);
  assert.match(r.log, /cannot resume from the state file: .*state\.bin: could not read it \(Is a directory\)/);
  assert.deepEqual(readdirSync(dir), ['state.bin']);
  rmSync(dir, { recursive: true, force: true });
});

test('state_file_invalid = fresh moves a bad state file aside and starts afresh', async () => {
  const { dir, state, bytes } = await goodStateFile();
  const bad = Buffer.from(bytes);
  bad[100] ^= 0x01;
  writeFileSync(state, bad);
  const d = await start([...small, '--paused', '--state-file', state], { env: { CLOTHD_STATE_FILE_INVALID: 'fresh' } });
  assert.equal((await ok(d, 'GET', '/v1/sim')).step, 0);
  const files = readdirSync(dir);
  assert.equal(files.length, 1);
  assert.match(files[0], /^state\.bin\.bad-\d{8}T\d{6}Z$/);
  assert.ok(readFileSync(join(dir, files[0])).equals(bad)); // nothing lost
  assert.match(d.log, new RegExp(`state file .*state\\.bin is damaged \\(.*\\): moved to .*${files[0]}; starting afresh`));
  const at = await ok(d, 'POST', '/v1/sim/step', { frames: 3 });
  assert.equal((await stop(d)).code, 0);
  // The new state file is good.
  const e = await start(['--paused', '--state-file', state]);
  assert.equal((await ok(e, 'GET', '/v1/sim')).state_hash, at.state_hash);
  await stop(e);
  // The setting is in the schema like every other.
  const s = await start(['--paused']);
  const row = (await ok(s, 'GET', '/v1/params/schema')).params.find((p) => p.name === 'state_file_invalid');
  assert.equal(row.kind, 'startup');
  assert.equal(row.default, 'refuse');
  assert.deepEqual(row.choices, ['refuse', 'fresh']);
  await stop(s);
});

test('exit statuses: --help lists them, bad settings are 2', () => {
  const help = execFileSync(CLOTHD, ['--help'], { encoding: 'utf8' });
  assert.match(help, /exit status: 0 stopped by SIGTERM\/SIGINT .*; 1 could not start/);
  assert.match(help, /2 bad command line or settings; 3 the backend failed/);
  assert.match(help, /4 the state file could not be saved/);
  assert.match(help, /--state-file-invalid .*\(refuse\|fresh\)/);
  for (const args of [['--port', '70000'], ['--nope'], ['--state-file-invalid', 'maybe']]) {
    let code = 0;
    try {
      execFileSync(CLOTHD, args, { stdio: 'ignore', timeout: 20000 });
    } catch (e) {
      code = e.status;
    }
    assert.equal(code, 2, args.join(' '));
  }
});

test('the shipped clothd has no test hooks', async () => {
  const names = ['CLOTHD_TEST_NAN_FRAME', 'CLOTHD_TEST_BACKEND_FAIL_FRAME', 'CLOTHD_TEST_SAVE_PAUSE_MS', 'test hook'];
  const shipped = readFileSync(CLOTHD);
  for (const n of names) assert.ok(!shipped.includes(n), `${CLOTHD} contains "${n}"`);
  // The scan finds them where they are.
  if (TESTHOOKS) {
    const test = readFileSync(TESTHOOKS);
    for (const n of names) assert.ok(test.includes(n), `${TESTHOOKS} lacks "${n}"`);
  }
  // Nor are the hook functions linked in: the symbol tables (when nm is there and the binaries
  // are not stripped, which the positive check on the test daemon shows).
  const symbols = (bin) => {
    try {
      return execFileSync('nm', ['--defined-only', bin], { encoding: 'utf8', stdio: ['ignore', 'pipe', 'ignore'], maxBuffer: 1 << 26 });
    } catch {
      return '';
    }
  };
  const hookFunctions = /\b(testhooks_init|testhooks_before_frame|testhooks_before_rename|cs_test_poison|cs_test_break_backend)\b/;
  if (TESTHOOKS && hookFunctions.test(symbols(TESTHOOKS))) {
    const shipped = symbols(CLOTHD);
    assert.match(shipped, /\bcs_sim_create\b/); // a symbol table to look in
    assert.doesNotMatch(shipped, hookFunctions);
  }
  // And the variables do nothing to it.
  const dir = tempDir();
  const d = await start([...small, '--paused', '--checkpoint-interval', '10', '--state-file', join(dir, 'state.bin')], {
    env: { CLOTHD_TEST_NAN_FRAME: '5', CLOTHD_TEST_BACKEND_FAIL_FRAME: '7', CLOTHD_TEST_SAVE_PAUSE_MS: '60000' },
  });
  const r = await ok(d, 'POST', '/v1/sim/step', { frames: 20 });
  assert.equal(r.event, undefined);
  assert.equal(r.frame, 20);
  assert.equal((await ok(d, 'GET', '/v1/sim')).last_event, null);
  assert.equal((await call(d, 'GET', '/v1/health')).status, 200);
  assert.equal((await stop(d)).code, 0);
  assert.match(d.log, /ignoring environment variable CLOTHD_TEST_NAN_FRAME: no such setting/);
  assert.doesNotMatch(d.log, /test hook/);
  assert.match(d.log, /state saved to/);
});
