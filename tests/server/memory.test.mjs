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

// A 1 MiB array of vertex ids is parsed into a tree of some 20 MB of small blocks. Freed, glibc
// kept them in the arena of each thread that used them (the HTTP threads', the sim thread's):
// 24 such bodies left the RSS 70 to 90 MiB higher even with the journal and the event ring capped
// at 1 MiB each, 24 of 512 KiB about 45 MiB. server/http/http.c gives the free heap back
// (malloc_trim) after each request whose body is 128 KiB or more, and again 100-200 ms on (the sim
// thread may free the command after the answer). Measured from before the first large body, so
// the parser's working memory itself must go back. The journal and events are capped at 1 MiB
// here: at their defaults (64 and 16 MiB) they keep that much of such commands, by design.
const BODY = 512 << 10, IDS = 260000, BOUND = 12 * MiB;
test('large JSON bodies give their parse memory back: 24 PUT /v1/pins of 512 KiB grow RSS by less than 12 MiB', async () => {
  const d = await start(['--paused', '--nx', '8', '--ny', '8', '--auto-drop-interval', '0', '--journal-max-mb', '1',
    '--stream-events-mb', '1'], measured);
  const body = `{"vertices":[${'0,'.repeat(IDS - 1)}0],"pinned":true}`;
  assert.ok(body.length > 0.99 * BODY && body.length <= BODY);
  await ok(d, 'PUT', '/v1/pins', { vertices: [0], pinned: true });
  const rss0 = rssKiB(d.proc.pid);
  // Two at a time, so that both HTTP threads parse some.
  for (let i = 0; i < 24; i += 2) {
    const rs = await Promise.all([0, 1].map(() => call(d, 'PUT', '/v1/pins', body, {}, { spec: false })));
    for (const r of rs) assert.equal(r.status, 200, r.text.slice(0, 200));
  }
  // The last command's tree may be freed by the sim thread just after its answer: the daemon
  // trims again on its sweeper's next two turns (100-200 ms). Awaited, up to 2 s.
  const atEnd = rssKiB(d.proc.pid) - rss0;
  await until('the RSS back within the bound', () => rssKiB(d.proc.pid) - rss0 < BOUND, { timeout: 2000, every: 50 })
    .catch(() => {});
  const grew = rssKiB(d.proc.pid) - rss0;
  console.log(`RSS growth over 24 PUT /v1/pins of ${IDS} ids (${body.length} bytes) each: ${grew} KiB (${atEnd} KiB at the last answer)`);
  rssBound(grew, BOUND, `RSS grew by ${grew} KiB`);
  await stop(d);
});
