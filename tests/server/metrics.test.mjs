// metrics.test.mjs - /metrics stays well-formed and bounded whatever clients send (docs/security.md
// "Limits"): label values come from closed sets (methods HTTP defines, else "other"; routes from
// the route table) and are escaped as the text format asks; Prometheus' own promtool checks a
// scrape taken after hostile traffic (skipped, saying so, only where promtool is missing:
// scripts/deps.sh installs it).
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { spawnSync } from 'node:child_process';
import net from 'node:net';
import { readdirSync } from 'node:fs';
import { start, stop, call, until, rssKiB } from './harness.mjs';

function raw(d, text) {
  const { port } = new URL(d.url);
  return new Promise((resolve) => {
    const sock = net.connect(Number(port), '127.0.0.1', () => sock.write(text));
    let out = '';
    sock.on('data', (b) => (out += b));
    sock.on('error', () => {});
    sock.on('close', () => resolve(out));
  });
}

const promtool = spawnSync('promtool', ['--version']).error ? null : 'promtool';

test('hostile methods and paths neither break nor grow /metrics; promtool checks the scrape', async (t) => {
  const d = await start(['--paused']);
  const hostile = ['A"B', 'A\\B', 'X\nY', 'GET\x01', 'é', 'BREW', 'get'];
  for (const m of hostile) await raw(d, `${m} /v1/sim HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n`);
  // 300 distinct made-up methods and 300 distinct unknown paths: no series of their own.
  for (let k = 0; k < 300; k++) {
    await raw(d, `M${k}X /v1/sim HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n`);
    await raw(d, `GET /v1/nothing-${k}"} 1\n HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n`);
  }
  const text = (await call(d, 'GET', '/metrics')).text;
  const series = text.split('\n').filter((l) => l.startsWith('clothd_http_requests_total{'));
  const labels = series.map((l) => Object.fromEntries([...l.matchAll(/(\w+)="((?:[^"\\]|\\.)*)"/g)].map((m) => [m[1], m[2]])));
  const methods = new Set(labels.map((l) => l.method));
  const routes = new Set(labels.map((l) => l.route));
  for (const m of methods) assert.ok(['GET', 'HEAD', 'POST', 'PUT', 'PATCH', 'DELETE', 'OPTIONS', 'other'].includes(m), m);
  assert.ok(methods.has('other'));
  const { stdout } = spawnSync(process.env.CLOTHD_BIN, ['routes'], { encoding: 'utf8' });
  const table = new Set(stdout.trim().split('\n').map((l) => l.split(' ')[1]));
  for (const r of routes) assert.ok(table.has(r) || r === 'unknown' || r === 'static', r);
  assert.ok(series.length < 20, `${series.length} series after 600 hostile requests`);
  // Every line of the exposition is a comment or `name{labels} value`.
  for (const line of text.trim().split('\n'))
    assert.match(line, /^(# (HELP|TYPE) \w+ .+|\w+(\{(\w+="(?:[^"\\\n]|\\[\\"n])*",?)*\})? -?[\d.e+-]+|\w+(\{.*\})? (NaN|[+-]Inf))$/, line);
  await stop(d);
  if (!promtool) {
    t.skip('promtool not found (Debian package prometheus; scripts/deps.sh lists it): the scrape was not checked by it');
    return;
  }
  const check = spawnSync(promtool, ['check', 'metrics'], { input: text, encoding: 'utf8' });
  console.log(`promtool check metrics: exit ${check.status}${check.stdout}${check.stderr}`);
  // Exit 0: no errors. Lint remarks (promtool prints them and exits 3) would fail it too.
  assert.equal(check.status, 0, `${check.stdout}${check.stderr}`);
});

test('the daemon\'s series: build info, the process_* family, capacity gauges, simulated seconds per scene; promtool', async (t) => {
  const d = await start(['--nx', '16', '--ny', '16', '--auto-drop-interval', '0', '--max-scenes', '3', '--max-state-mb', '64']);
  const health = (await call(d, 'GET', '/v1/health')).json;
  const scrape = async () => (await call(d, 'GET', '/metrics')).text;
  const value = (text, series) => {
    const m = new RegExp(`^${series.replace(/[{}]/g, '\\$&')} ([\\d.e+-]+)$`, 'm').exec(text);
    assert.ok(m, `${series} in\n${text}`);
    return Number(m[1]);
  };
  let text = await scrape();
  assert.equal(value(text, `clothd_build_info{version="${health.version}",backend="cpu"}`), 1);
  assert.equal(value(text, 'clothd_scenes'), 1);
  assert.equal(value(text, 'clothd_scenes_max'), 3);
  assert.equal(value(text, 'clothd_state_max_bytes'), 64 * 1024 * 1024);
  const one = value(text, 'clothd_state_bytes');
  assert.ok(one > 0 && one < 64 * 1024 * 1024, `${one}`);
  const rss = value(text, 'process_resident_memory_bytes');
  const kib = rssKiB(d.proc.pid);
  assert.ok(rss > 0.5 * kib * 1024 && rss < 2 * kib * 1024, `${rss} bytes against VmRSS ${kib} KiB`);
  const fds = value(text, 'process_open_fds');
  assert.equal(fds, readdirSync(`/proc/${d.proc.pid}/fd`).length);
  const startTime = value(text, 'process_start_time_seconds');
  assert.ok(Math.abs(startTime - Date.now() / 1000) < 60, `${startTime}`);
  assert.ok(value(text, 'process_cpu_seconds_total') >= 0);
  // Simulated seconds count up while the scene runs; a second scene gets its own series and the
  // capacity gauges follow it.
  const s0 = value(text, 'clothd_sim_seconds_total{scene="default"}');
  await until('simulated time to pass', async () => value(await scrape(), 'clothd_sim_seconds_total{scene="default"}') > s0);
  assert.equal((await call(d, 'POST', '/v1/scenes', { id: 'two' })).status, 201);
  text = await scrape();
  assert.equal(value(text, 'clothd_scenes'), 2);
  assert.ok(value(text, 'clothd_state_bytes') > one);
  assert.ok(value(text, 'clothd_sim_seconds_total{scene="two"}') >= 0);
  await stop(d);
  if (!promtool) {
    t.skip('promtool not found: the scrape was not checked by it');
    return;
  }
  const check = spawnSync(promtool, ['check', 'metrics'], { input: text, encoding: 'utf8' });
  assert.equal(check.status, 0, `${check.stdout}${check.stderr}`);
});

test('threads 0 counts the threads: one for a small scene in real time, every core for a step, and back', async () => {
  const d = await start(['--threads', '0', '--nx', '16', '--ny', '16', '--auto-drop-interval', '0']);
  const threads = async () => {
    const m = /^clothd_sim_threads (\d+)$/m.exec((await call(d, 'GET', '/metrics')).text);
    assert.ok(m, 'clothd_sim_threads');
    return Number(m[1]);
  };
  const cores = Number((await call(d, 'GET', '/v1/health')).json.device.match(/(\d+) thread/)[1]);
  assert.ok(cores >= 1, `${cores}`);
  // A 16 x 16 cloth in real time is a few percent of one core: one thread, and it stays one.
  assert.equal(await threads(), 1);
  const sim0 = (await call(d, 'GET', '/v1/sim')).json.sim_time;
  await until('two simulated seconds', async () => (await call(d, 'GET', '/v1/sim')).json.sim_time > sim0 + 2);
  assert.equal(await threads(), 1);
  // A step runs as fast as it can: every thread the backend has, while it lasts.
  assert.equal((await call(d, 'POST', '/v1/sim/pause')).status, 200);
  const step = call(d, 'POST', '/v1/sim/step', { frames: 100000 });
  await until('the step on every thread', async () => (await threads()) === cores);
  assert.equal((await call(d, 'DELETE', '/v1/sim/step')).json.cancelled, true);
  await step;
  assert.equal((await call(d, 'POST', '/v1/sim/resume')).status, 200);
  // (one fewer a window of AUTOTHREADS_WINDOW, 1 s)
  await until('one thread again once the step is over and the scene runs in real time', async () => (await threads()) === 1,
    { timeout: 20000 + 2000 * cores });
  await stop(d);
});
