// systemd.test.mjs - clothd under systemd's Type=notify and WatchdogSec= (docs/operating.md
// "systemd"): with $NOTIFY_SOCKET it sends READY=1 once it serves, WATCHDOG=1 from the sim
// thread's heartbeat at half of $WATCHDOG_USEC, and STOPPING=1 on SIGTERM; to an abstract socket
// ('@name') and to a path. The receiver is a real AF_UNIX datagram socket (node has none: a small
// python3 one, as systemd's own is) and the daemon the real one.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { spawn, spawnSync } from 'node:child_process';
import { join } from 'node:path';
import { rmSync } from 'node:fs';
import { start, stop, until, tempDir, TESTHOOKS } from './harness.mjs';

const small = ['--nx', '16', '--ny', '16', '--auto-drop-interval', '0', '--paused'];
const python = spawnSync('python3', ['--version']).error ? null : 'python3';
const needs = python ? {} : { skip: 'python3 not found: no AF_UNIX datagram receiver' };

// Binds a datagram socket (an abstract name when it starts with '@') and keeps each datagram.
function receiver(name) {
  const code = `
import socket, sys
s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
n = sys.argv[1]
s.bind('\\0' + n[1:] if n.startswith('@') else n)
print('bound', flush=True)
while True:
    d = s.recv(4096)
    print(repr(d.decode()), flush=True)
`;
  const proc = spawn(python, ['-c', code, name], { stdio: ['ignore', 'pipe', 'inherit'] });
  const r = { proc, out: '', messages: [] };
  proc.stdout.setEncoding('utf8');
  proc.stdout.on('data', (c) => {
    r.out += c;
    r.messages = r.out.split('\n').filter((l) => l.startsWith("'")).map((l) => l.slice(1, -1).replaceAll('\\n', '\n'));
  });
  r.ready = until('the receiver bound', () => r.out.startsWith('bound'));
  return r;
}
const count = (r, m) => r.messages.filter((x) => x.split('\n').includes(m)).length;

test('Type=notify: READY=1 once serving, WATCHDOG=1 from the sim thread at half of WATCHDOG_USEC, STOPPING=1; abstract socket', needs, async () => {
  const name = `@clothd-test-${process.pid}-${Date.now()}`;
  const r = receiver(name);
  await r.ready;
  const d = await start(small, { env: { NOTIFY_SOCKET: name, WATCHDOG_USEC: '400000' } });
  await until('READY=1', () => count(r, 'READY=1') === 1);
  const ready = r.messages.find((x) => x.includes('READY=1'));
  assert.match(ready, new RegExp(`STATUS=serving on port ${new URL(d.url).port}`));
  // 0.4 s watchdog: a WATCHDOG=1 every 0.2 s, even while every scene is paused (the idle thread turns).
  const t0 = Date.now();
  await until('five WATCHDOG=1', () => count(r, 'WATCHDOG=1') >= 5);
  assert.ok(Date.now() - t0 < 3000, `${Date.now() - t0} ms for five`);
  assert.match(d.log, /systemd: notifying @clothd-test-\S+, WATCHDOG=1 every 0\.200 s/);
  await stop(d);
  await until('STOPPING=1', () => count(r, 'STOPPING=1') === 1);
  r.proc.kill();
});

test('a path socket; no WATCHDOG=1 for another process\'s WATCHDOG_PID; a wedged sim thread sends none', needs, async () => {
  const dir = tempDir();
  const path = join(dir, 'notify');
  const r = receiver(path);
  await r.ready;
  const d = await start(small, { env: { NOTIFY_SOCKET: path, WATCHDOG_USEC: '200000', WATCHDOG_PID: '1' } });
  await until('READY=1', () => count(r, 'READY=1') === 1);
  await stop(d);
  await until('STOPPING=1', () => count(r, 'STOPPING=1') === 1);
  assert.equal(count(r, 'WATCHDOG=1'), 0);
  r.proc.kill();
  rmSync(dir, { recursive: true, force: true });
  if (!TESTHOOKS) return;
  // The sim thread wedged for 1.5 s after frame 3: the WATCHDOG=1 stop meanwhile (systemd would
  // kill it after WatchdogSec), and come back when it goes on.
  const name = `@clothd-test-wedge-${process.pid}-${Date.now()}`;
  const w = receiver(name);
  await w.ready;
  const e = await start(['--nx', '16', '--ny', '16', '--auto-drop-interval', '0'], {
    bin: TESTHOOKS, env: { NOTIFY_SOCKET: name, WATCHDOG_USEC: '200000', CLOTHD_TEST_WEDGE_FRAME: '3', CLOTHD_TEST_WEDGE_MS: '1500' },
  });
  await until('the wedge', () => /sim thread wedged/.test(e.log));
  const during = count(w, 'WATCHDOG=1');
  await until('the thread goes on', () => /sim thread goes on/.test(e.log));
  assert.ok(count(w, 'WATCHDOG=1') - during <= 1, 'no WATCHDOG=1 while wedged (one may be in flight)');
  await until('WATCHDOG=1 again', () => count(w, 'WATCHDOG=1') >= during + 3);
  await stop(e);
  w.proc.kill();
});
