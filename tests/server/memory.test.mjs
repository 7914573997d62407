// memory.test.mjs - memory is bounded in bytes, not in counts (docs/security.md "Limits"): the journal
// keeps journal_max_mb of entries (then starts afresh from a new base snapshot, as at
// journal_max) and the stream's event ring stream_events_mb of events, so accepted commands of
// 1 MiB each do not pile up; and max_state_mb counts what a scene really costs (its state twice,
// checkpoints, the frames and their encodings, the backend's scratch, the answers built for it),
// so that the largest scene it accepts, worked through everything that allocates for it, grows the
// daemon by less than the cap.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { start, stop, call, ok, rssKiB, until } from './harness.mjs';
import { connect, next } from './wsclient.mjs';

// Under ASan, freed memory waits in a quarantine (256 MB by default) before it is reused, and the
// RSS would count everything freed: none keeps the measure closer to the daemon. Even so the RSS
// there is mostly the sanitizer's where many allocations come and go (shadow memory, redzones,
// its allocator's size classes: a 97 x 97 scene peaks at 15 MiB there, 6 MiB in the normal
// build), so those bounds (`rssBound`) are the normal build's to check; the sanitized run checks
// the same work for memory errors and leaks, and prints the figures.
const SANITIZED = process.env.CLOTHD_SANITIZED === '1';
const measured = SANITIZED ? { env: { ASAN_OPTIONS: [process.env.ASAN_OPTIONS, 'quarantine_size_mb=0'].filter(Boolean).join(':') } } : {};
function rssBound(grewKiB, boundKiB, what) {
  if (!SANITIZED) assert.ok(grewKiB < boundKiB, what);
}

const MiB = 1024;

test('journal_max_mb and stream_events_mb cap the journal and the event ring: large commands do not pile up', async () => {
  const d = await start(['--paused', '--nx', '8', '--ny', '8', '--auto-drop-interval', '0', '--journal-max-mb', '1',
    '--stream-events-mb', '1'], measured);
  // 262144 vertex ids (all vertex 0) in 512 KiB: accepted, journaled and sent as an event each.
  const body = `{"vertices":[${'0,'.repeat(262143)}0],"pinned":true}`;
  assert.ok(body.length > 512 << 10 && body.length < 1.01 * (512 << 10));
  const pins = async (k) => {
    for (let i = 0; i < k; i++) assert.equal((await call(d, 'PUT', '/v1/pins', body)).status, 200);
  };
  await pins(4); // the parser's and allocator's working memory reaches its size
  const rss0 = rssKiB(d.proc.pid);
  await pins(16);
  const grew = rssKiB(d.proc.pid) - rss0;
  console.log(`RSS growth over 16 more PUT /v1/pins of 512 KiB: ${grew} KiB`);
  // Without the caps each keeps 512 KiB in the journal and 512 KiB in the event ring: 16 MiB.
  // (The sanitized build's RSS here swings by tens of MiB with its allocator's caches per thread.)
  rssBound(grew, 8 * MiB, `RSS grew by ${grew} KiB`);
  // The journal started afresh at its cap: what it holds fits in 1 MiB.
  const j = await call(d, 'GET', '/v1/journal');
  assert.ok(j.json.entries.length <= 1 && j.buf.length < 1 << 20, `${j.json.entries.length} entries, ${j.buf.length} bytes`);
  await stop(d);
});

// Whether a square cloth of side k is accepted (a rebuild; 422 when it costs too much).
async function fits(d, k) {
  const r = await call(d, 'PUT', '/v1/scene', { nx: k, ny: k });
  if (r.status !== 200 && r.status !== 422) throw new Error(`PUT /v1/scene ${k} x ${k}: ${r.status} ${r.text}`);
  return r.status === 200;
}

test('the largest scene max_state_mb 8 accepts grows RSS by less than 8 MiB, worked through all that allocates', async () => {
  // (A body may hold the whole snapshot: max_body is a limit of its own.)
  const d = await start(['--paused', '--nx', '4', '--ny', '4', '--auto-drop-interval', '0', '--max-state-mb', '8',
    '--checkpoint-interval', '5', '--max-body', String(64 << 20)], measured);
  d.streamPort = (await ok(d, 'GET', '/v1/health')).stream.port;
  // Everything that allocates per scene, done once on the tiny scene first: the baseline holds
  // the daemon's own buffers (threads, clients, the parser) and none of the scene's.
  const encodings = ['f32', 'q16', 'meshopt'], scalars = ['none', 'speed', 'strain'];
  const clients = [];
  for (const encoding of encodings) {
    for (const scalar of scalars) {
      const c = await connect(d);
      await next(c, 'text', (m) => m.type === 'hello');
      c.ws.send(JSON.stringify({ type: 'subscribe', encoding, scalar }));
      await next(c, 'text', (m) => m.type === 'subscribed');
      clients.push(c);
    }
  }
  const work = async () => {
    for (let k = 0; k < 3; k++) await ok(d, 'POST', '/v1/rocks', { position: [0.3 * k - 0.3, 0, 3], radius: 0.05 });
    await ok(d, 'POST', '/v1/sim/step', { frames: 12 }); // two checkpoints; frames for every client
    await ok(d, 'PUT', '/v1/grab', { vertex: 1, target: [0, 0, 1.2] });
    const snap = (await call(d, 'GET', '/v1/snapshot')).buf;
    await call(d, 'GET', '/v1/cloth/state');
    await call(d, 'GET', '/v1/cloth/state', undefined, { Accept: 'application/octet-stream' });
    await call(d, 'GET', '/v1/journal', undefined, { Accept: 'application/octet-stream' });
    await ok(d, 'PUT', '/v1/snapshot', snap, { 'Content-Type': 'application/octet-stream' });
    await ok(d, 'POST', '/v1/sim/step', { frames: 6 });
    for (const c of clients) await next(c, 'frame', (f) => f.nVertices > 0, 15000, c.frames.length - 1);
  };
  await work();
  const rss0 = rssKiB(d.proc.pid);
  // The largest square cloth it accepts.
  let lo = 4, hi = 600;
  while (hi - lo > 1) {
    const mid = (lo + hi) >> 1;
    if (await fits(d, mid)) lo = mid;
    else hi = mid;
  }
  assert.ok(await fits(d, lo));
  const side = lo;
  await work();
  const peak = rssKiB(d.proc.pid, 'VmHWM') - rss0;
  console.log(`max_state_mb 8: the largest cloth is ${side} x ${side}; peak RSS growth ${peak} KiB`);
  assert.ok(side >= 40, `${side} x ${side}: the estimate is not that generous`);
  rssBound(peak, 8 * MiB, `a ${side} x ${side} cloth grew the peak RSS by ${peak} KiB, more than max_state_mb`);
  for (const c of clients) c.ws.close();
  await stop(d);
});

// The workspaces count while the parameters use them (kernels/include/clothsim/clothsim.h,
// cs_scene_memory): self_collision's pair lists full (8 KiB a vertex, at least those of a 128 x 128
// cloth), implicit_euler's workspace.
test('max_state_mb counts the workspaces the parameters use: a change past it is 422 naming the parameter', async () => {
  // velocity_verlet to begin with: the explicit integrators need no workspace
  const d = await start(['--paused', '--nx', '48', '--ny', '48', '--auto-drop-interval', '0', '--max-state-mb', '16',
    '--integrator', 'velocity_verlet']);
  const stateBytes = async () => {
    const text = (await call(d, 'GET', '/metrics')).text;
    return Number(/^clothd_state_bytes (\S+)$/m.exec(text)[1]);
  };
  const b0 = await stateBytes();
  // 48 x 48 = 2304 vertices: self_collision's lists alone may take those of a 128 x 128 cloth,
  // 128 x 128 x 3 x 341 x 8 bytes = 134 MB
  const self = await call(d, 'PATCH', '/v1/params', { self_collision: true });
  assert.equal(self.status, 422, self.text);
  assert.equal(self.json.param, 'self_collision');
  assert.equal((await ok(d, 'GET', '/v1/params')).self_collision, false);
  assert.equal(await stateBytes(), b0);
  // implicit_euler's workspace (at least 50 floats a vertex) fits, and counts while in use
  await ok(d, 'PATCH', '/v1/params', { integrator: 'implicit_euler' });
  await ok(d, 'POST', '/v1/sim/step', { frames: 3 });
  const b1 = await stateBytes();
  assert.ok(b1 >= b0 + 2304 * 50 * 4, `${b0} -> ${b1}`);
  await ok(d, 'PATCH', '/v1/params', { integrator: 'velocity_verlet' });
  assert.equal(await stateBytes(), b0);
  await stop(d);
});

// Memory is bounded by bytes whatever a body holds (issue 29; docs/operating.md "Memory after large
// bodies"): for each kind of large body - pins (PUT /v1/pins: an array of vertex ids, some 20 MB of
// small blocks a MiB once parsed, as much again for the journal's copy), rocks (POST /v1/rocks) and
// params (PATCH /v1/params: a number of a million digits, which the parser holds whole), snapshots
// (PUT /v1/snapshot: a new engine built beside the old) - bodies just under max_body, one in four
// refused (422 out of range, 400 for a corrupt snapshot) after it was parsed, two at a time (both
// HTTP threads parse some): after 24 of them (and after 200 more) the RSS is back within
// BODIES_BOUND of what it was before the first. Without the trim (server/http/http.c: malloc_trim
// after each body of 128 KiB or more, and again 100-200 ms on) 24 pins bodies left it 47 MiB
// higher (512 KiB each), 70-90 MiB (1 MiB). The journal and the event ring are capped at 1 MiB (at their defaults, 64 and
// 16 MiB, they keep that much of such commands, by design). Measured from before the first large
// body, so the parser's working memory itself must go back. Figures: docs/operating.md.
//
// The normal build runs the whole measure: 24 and then 200 more bodies of each kind at the
// default max_body, 1 MiB (50 s in all on a quiet 2 vCPU machine, 2026-12-06: a 1 MiB pins body
// takes about 0.13 s). Under the sanitizers, 24 of 512 KiB (bounds not checked: the figures printed).
// BODIES_BOUND: the most measured was 4.5 MiB (24 pins of 512 KiB; 4.2 MiB after 224 of 1 MiB);
// 16 MiB leaves room for the allocator and still fails at a third of what no trim leaves.
const LONG = !SANITIZED;
const LIMIT = LONG ? 1 << 20 : 512 << 10, BODIES_BOUND = 16 * MiB;
const RUNS = LONG ? [24, 200] : [24];
const SNAP_SIDE = LONG ? '130' : '91'; // a snapshot of 61 bytes a vertex, just under LIMIT
// A string of exactly n bytes: head, fill repeated, tail.
const sized = (n, head, fill, tail) => head + fill.repeat(Math.floor((n - head.length - tail.length) / fill.length)) + tail;
const N = LIMIT - 64;
const idsBody = (last) => sized(N, '{"vertices":[', '0,', `${last}],"pinned":true}`);
const digits = (head, number, tail) => sized(N, `${head}${number}`, '0', `1${tail}`);
const KINDS = [
  {
    kind: 'pins', flags: ['--nx', '8', '--ny', '8'],
    make: () => ({ ok: idsBody(0), bad: idsBody(64) }),
    send: (d, b, i) => call(d, 'PUT', '/v1/pins', i % 4 === 3 ? b.bad : b.ok, {}, { spec: false }),
    want: (i) => (i % 4 === 3 ? 422 : 200),
  },
  {
    // Up to 224 rocks apart on a 16 x 16 grid above the cloth (max_rocks 256); a refused one has
    // a negative radius.
    kind: 'rocks', flags: ['--nx', '8', '--ny', '8'],
    make: () => ({ ok: (i) => digits(`{"position":[${0.1 * (i % 16) - 0.75},${0.1 * Math.floor(i / 16) - 0.75},3],"radius":0.02,"density":`, '2500.', '}'),
      bad: digits('{"position":[0,0,3],"radius":', '-0.05', '}') }),
    send: (d, b, i) => call(d, 'POST', '/v1/rocks', i % 4 === 3 ? b.bad : b.ok(i), {}, { spec: false }),
    want: (i) => (i % 4 === 3 ? 422 : 201),
    between: (d) => ok(d, 'DELETE', '/v1/rocks'),
  },
  {
    kind: 'params', flags: ['--nx', '8', '--ny', '8'],
    make: () => ({ ok: digits('{"wind":[', '0.', ',0,0]}'), bad: digits('{"wind":[', '2000.', ',0,0]}') }),
    send: (d, b, i) => call(d, 'PATCH', '/v1/params', i % 4 === 3 ? b.bad : b.ok, {}, { spec: false }),
    want: (i) => (i % 4 === 3 ? 422 : 200),
  },
  {
    kind: 'snapshots', flags: ['--nx', SNAP_SIDE, '--ny', SNAP_SIDE],
    make: async (d) => {
      const snap = (await call(d, 'GET', '/v1/snapshot')).buf;
      assert.ok(snap.length > 0.95 * LIMIT && snap.length <= LIMIT, `a snapshot of ${snap.length} bytes`);
      const bad = Buffer.from(snap);
      bad[bad.length >> 1] ^= 0x55; // the checksum no longer holds
      return { ok: snap, bad };
    },
    send: (d, b, i) => call(d, 'PUT', '/v1/snapshot', i % 4 === 3 ? b.bad : b.ok, { 'Content-Type': 'application/octet-stream' }, { spec: false }),
    want: (i) => (i % 4 === 3 ? 400 : 200),
  },
];

/* A request whose connection the peer reset before any answer (seen once under ASan, on a loaded
 * machine, and not reproduced since) is sent once more, and said so: this test is about memory,
 * not the transport. A daemon that crashed answers the second try no better, and stop() still
 * fails on any sanitizer report in its log. */
async function sendAgainOnReset(sendIt, what) {
  try {
    return await sendIt();
  } catch (e) {
    if (!['ECONNRESET', 'EPIPE'].includes(e.cause?.code)) throw e;
    console.log(`${what}: the connection was reset (${e.cause.code}) before an answer; sent again`);
    return sendIt();
  }
}

for (const { kind, flags, make, send, want, between } of KINDS) {
  test(`large bodies give their memory back: ${RUNS.join(' and ')} ${kind} bodies of ${LIMIT >> 10} KiB grow RSS by less than ${BODIES_BOUND / MiB} MiB`, async () => {
    const d = await start(['--paused', ...flags, '--auto-drop-interval', '0', '--journal-max-mb', '1', '--stream-events-mb', '1', '--max-body', String(LIMIT)], measured);
    const bodies = await make(d);
    for (const b of [bodies.ok, bodies.bad]) {
      const len = typeof b === 'function' ? b(0).length : b.length;
      assert.ok(len > 0.95 * LIMIT && len <= LIMIT, `${kind}: a body of ${len} bytes`);
    }
    await ok(d, 'PUT', '/v1/pins', { vertices: [0], pinned: true }); // one small command first
    const rss0 = rssKiB(d.proc.pid);
    const figures = [];
    let sent = 0;
    for (const n of RUNS) {
      if (between) await between(d);
      for (let i = 0; i < n; i += 2) {
        const rs = await Promise.all([i, i + 1].map((k) => sendAgainOnReset(() => send(d, bodies, k), `${kind} ${k}`)));
        rs.forEach((r, k) => assert.equal(r.status, want(i + k), `${kind} ${i + k}: ${r.text.slice(0, 200)}`));
      }
      sent += n;
      // The last command's tree may be freed by the sim thread just after its answer: the daemon
      // trims again on its sweeper's next two turns (100-200 ms). Awaited: the RSS settled (no
      // new low for 300 ms, three turns), up to 2 s.
      const atEnd = rssKiB(d.proc.pid) - rss0;
      let low = Infinity, lowAt = Date.now();
      await until('the RSS settled', () => {
        const now = rssKiB(d.proc.pid);
        if (now < low) low = now, lowAt = Date.now();
        return Date.now() - lowAt >= 300;
      }, { timeout: 2000, every: 50 }).catch(() => {});
      const grew = rssKiB(d.proc.pid) - rss0;
      figures.push(`${grew} KiB after ${sent} (${atEnd} KiB at the last answer)`);
      rssBound(grew, BODIES_BOUND, `${kind}: RSS grew by ${grew} KiB after ${sent} bodies`);
    }
    console.log(`${kind}: RSS ${rss0} KiB before; grew by ${figures.join(', ')}; peak ${rssKiB(d.proc.pid, 'VmHWM')} KiB`);
    await stop(d);
  });
}
