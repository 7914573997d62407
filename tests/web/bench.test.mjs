// bench.test.mjs - the viewer's speed in headless Chromium (software WebGL, SwiftShader) against a
// real clothd, printed as figures (docs/performance.md "Viewer" quotes them) and saved to
// $CLOTHD_ARTIFACTS/viewer-bench.json. It asserts only that each figure was measured; speed is
// not a pass/fail matter on a shared machine.
//   decode: the page's own decoder on one frame into the GPU buffer's array, per encoding, for a
//     64 x 64, a 128 x 128 and a 256 x 256 cloth (median and 90th percentile of 30 runs of 10 decodes; delta,
//     whose frames need their keyframe, as the page's stream decodes 30 or more of them, and at
//     256 x 256 also 40 delta frames decoded again in a blank page, the sim paused and the
//     viewer closed: "delta, alone" - the last test, as it closes the viewer);
//   drawn:  frames drawn per second at 128 x 128 (a) with the sim in slow motion (time_scale 0.25,
//     so frames still come at 60 per second but clothd takes a quarter of a core), (b) with the
//     sim in real time beside the browser on the same cores, and a bare three.js 128 x 128 lit
//     plane with its normals recomputed every frame, in the same browser, as the reference.
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { writeFileSync } from 'node:fs';
import { cpus } from 'node:os';
import { start, stop, ok, until } from '../server/harness.mjs';
import { WEB_ROOT, missing, launch, openViewer, artifact } from './browser.mjs';

// A benchmark: under ASan and UBSan its figures are not the build's to quote, a 256 x 256 frame
// takes the sim seconds, and the viewer against the sanitized daemon is web.e2e's and
// web.playback's to exercise - so it runs in the normal build only.
const why = process.env.CLOTHD_SANITIZED === '1' ? 'a benchmark: the normal build measures the viewer' : missing();
const DELTA_FRAMES = 30;
let daemon, browser, page;
const figures = { machine: `${cpus().length} x ${cpus()[0]?.model ?? 'cpu'}`, decode: {}, drawn: {} };
const SLOW = { frame_rate: 240, substeps: 16, time_scale: 0.25, auto_substeps: false };
const REAL = { frame_rate: 60, substeps: 30, time_scale: 1, auto_substeps: true };

before(async () => {
  if (why) return;
  // The soft first material and contact per vertex: the sim in slow motion stays cheap (16
  // substeps at 240 frames/s), as the figures before them were measured.
  daemon = await start(['--nx', '128', '--ny', '128', '--areal-density', '1', '--k-structural', '400', '--k-shear', '80',
    '--k-contact', '400', '--contact-model', 'vertex'], { webRoot: WEB_ROOT });
  browser = await launch();
  page = await openViewer(browser.context, daemon.url + '/');
});

after(async () => {
  if (!why) {
    writeFileSync(artifact('viewer-bench.json'), JSON.stringify(figures, null, 2));
    console.log(`viewer speed (${figures.machine}, headless Chromium, SwiftShader)`);
    for (const [size, encs] of Object.entries(figures.decode))
      for (const [enc, d] of Object.entries(encs))
        console.log(`  decode ${size} ${enc.padEnd(12)} median ${d.median.toFixed(2)} ms${d.mean === undefined ? '' : `, mean ${d.mean.toFixed(3)} ms`}, p90 ${d.p90.toFixed(2)} ms (${d.bytes} bytes${d.wasm === undefined ? "" : d.wasm ? ", WebAssembly" : ", JavaScript"})`);
    for (const [what, d] of Object.entries(figures.drawn))
      console.log(`  drawn  ${what.padEnd(34)} ${d.drawn.toFixed(1)} frames/s (received ${d.received?.toFixed(1) ?? '-'})`);
  }
  await browser?.close();
  if (daemon) await stop(daemon);
});

const opts = { skip: why ?? false };

// Times the page's decoder on the newest frame of each encoding: `runs` decodes of the same
// bytes into the cloth's own arrays (the browser's clock is coarse, 0.1 ms: one decode alone
// would mostly read 0.1 or 0.2).
async function decodeTimes(label, runs) {
  figures.decode[label] = {};
  for (const encoding of ['q16', 'meshopt', 'f32']) {
    await page.evaluate((e) => window.__clothd.setView('encoding', e), encoding);
    const code = { f32: 0, q16: 1, meshopt: 2 }[encoding];
    await until(`a ${encoding} frame`, () => page.evaluate((c) => {
      const d = window.__clothd.stream.lastData;
      return d && (new Uint8Array(d)[6] & 3) === c;
    }, code), { timeout: 60000, every: 100 });
    figures.decode[label][encoding] = await page.evaluate(async (runs) => {
      const { decodeFrame } = await import('clothd/frame');
      const { MeshoptDecoder } = await import('meshoptimizer');
      await MeshoptDecoder.ready;
      const c = window.__clothd, data = c.stream.lastData, targets = c.view.frameTargets();
      const ms = [];
      for (let k = 0; k < runs; k++) {
        const t0 = performance.now();
        for (let j = 0; j < 10; j++) decodeFrame(data, { meshopt: MeshoptDecoder, ...targets });
        ms.push((performance.now() - t0) / 10);
      }
      ms.sort((a, b) => a - b);
      return { median: ms[runs >> 1], p90: ms[Math.floor(runs * 0.9)], bytes: data.byteLength };
    }, runs);
  }
  // delta frames need the keyframe before them: timed as the page's stream decodes them, one by
  // one as they come (the client's own per-frame decode times).
  await page.evaluate(() => {
    window.__clothd.setView('encoding', 'delta');
    window.__clothd.stream.stats.decodeMs.delta.length = 0; // this cloth's only
  });
  await until(`${DELTA_FRAMES} delta frames decoded`,
    () => page.evaluate((k) => window.__clothd.stream.stats.decodeMs.delta.length >= k, DELTA_FRAMES),
    { timeout: 120000, every: 200 });
  figures.decode[label].delta = await page.evaluate(() => {
    const s = window.__clothd.stream, ms = [...s.stats.decodeMs.delta].sort((a, b) => a - b);
    return { median: ms[ms.length >> 1], p90: ms[Math.floor(ms.length * 0.9)], bytes: s.lastData.byteLength, bad: s.stats.badFrames };
  });
  assert.equal(figures.decode[label].delta.bad, 0);
  await page.evaluate(() => window.__clothd.setView('encoding', 'q16'));
}

async function drawnRate(seconds = 5) {
  return page.evaluate(async (s) => {
    const c = window.__clothd;
    const d0 = c.view.drawn, f0 = c.stream.stats.frames, t0 = performance.now();
    await new Promise((r) => setTimeout(r, s * 1000));
    const dt = (performance.now() - t0) / 1000;
    return { drawn: (c.view.drawn - d0) / dt, received: (c.stream.stats.frames - f0) / dt };
  }, seconds);
}

test('decode time of one frame, 128 x 128', opts, async () => {
  await ok(daemon, 'PATCH', '/v1/params', SLOW);
  await decodeTimes('128x128', 30);
  for (const d of Object.values(figures.decode['128x128'])) assert.ok(d.median > 0);
});

test('frames drawn per second, 128 x 128', opts, async () => {
  await ok(daemon, 'PATCH', '/v1/params', SLOW);
  figures.drawn['viewer, sim in slow motion'] = await drawnRate();
  await ok(daemon, 'PATCH', '/v1/params', REAL);
  figures.drawn['viewer, sim in real time beside it'] = await drawnRate();
  // The reference, the sim paused: a bare lit plane of the same size, normals every frame.
  await ok(daemon, 'POST', '/v1/sim/pause');
  const bare = await browser.context.newPage();
  await bare.goto(`${daemon.url}/style.css`); // any page of clothd's origin, for the module import
  await bare.setContent(`<body style="margin:0"><script type="module">
    import * as THREE from '/vendor/three.module.js';
    const r = new THREE.WebGLRenderer(); r.setSize(innerWidth, innerHeight); document.body.appendChild(r.domElement);
    const scene = new THREE.Scene(), cam = new THREE.PerspectiveCamera(45, innerWidth / innerHeight, 0.01, 100);
    cam.up.set(0, 0, 1); cam.position.set(1.8, -3, 2.4); cam.lookAt(0, 0, 0.6);
    scene.add(new THREE.HemisphereLight(0xdfe8ff, 0x302820, 1.4));
    const sun = new THREE.DirectionalLight(0xffffff, 2); sun.position.set(3, -4, 6); scene.add(sun);
    const g = new THREE.PlaneGeometry(2, 2, 127, 127), p = g.attributes.position;
    scene.add(new THREE.Mesh(g, new THREE.MeshLambertMaterial({ color: 0xc8553d, side: THREE.DoubleSide })));
    window.drawn = 0;
    (function loop(t) {
      for (let k = 0; k < p.count; k++) p.setZ(k, 0.8 + 0.1 * Math.sin(3 * p.getX(k) + t / 300));
      p.needsUpdate = true; g.computeVertexNormals(); r.render(scene, cam); window.drawn++;
      requestAnimationFrame(loop);
    })(0);
  </script></body>`);
  await bare.waitForFunction(() => window.drawn > 5);
  const d0 = await bare.evaluate(() => window.drawn);
  await new Promise((r) => setTimeout(r, 5000));
  figures.drawn['bare three.js lit plane (reference)'] = { drawn: ((await bare.evaluate(() => window.drawn)) - d0) / 5 };
  await bare.close();
  await ok(daemon, 'POST', '/v1/sim/resume');
  for (const d of Object.values(figures.drawn)) assert.ok(d.drawn > 0);
});

// A new w x w cloth in real time, once the viewer shows it: its decode times.
async function decodeTimesAt(w) {
  await ok(daemon, 'PUT', '/v1/scene', { nx: w, ny: w });
  await ok(daemon, 'PATCH', '/v1/params', REAL);
  await until(`the ${w} x ${w} cloth`, () => page.evaluate((n) => window.__clothd.view.cloth.n === n && window.__clothd.view.cloth.hasFrame, w * w));
  await decodeTimes(`${w}x${w}`, 30);
  for (const d of Object.values(figures.decode[`${w}x${w}`])) assert.ok(d.median > 0);
}

test('decode time of one frame, 64 x 64 (the default cloth)', opts, () => decodeTimesAt(64));

test('decode time of one frame, 256 x 256', opts, async () => {
  await decodeTimesAt(256);
  // The same decode with nothing beside it: the viewer's page is closed (its drawing takes a core
  // of SwiftShader), a blank page of clothd's origin takes 40 delta frames off a stream of its
  // own, the sim is paused, and that page's frame.mjs decodes them again (from their first
  // keyframe on, 10 times over, each with a fresh decoder) into one array, timing each delta.
  const port = (await (await fetch(`${daemon.url}/v1/health`)).json()).stream.port;
  await page.close();
  page = await browser.context.newPage();
  await page.goto(`${daemon.url}/style.css`);
  const kept = await page.evaluate((p) => new Promise((resolve, reject) => {
    const ws = new WebSocket(`ws://127.0.0.1:${p}/stream`, 'clothd.v1'), frames = [];
    ws.binaryType = 'arraybuffer';
    ws.onopen = () => ws.send(JSON.stringify({ type: 'subscribe', encoding: 'delta' }));
    ws.onmessage = (m) => {
      if (typeof m.data !== 'string' && frames.push(m.data) >= 40) ws.close(), resolve(frames.length);
    };
    ws.onerror = () => reject(new Error('stream'));
    window.__kept = frames;
  }), port);
  assert.equal(kept, 40);
  await ok(daemon, 'POST', '/v1/sim/pause');
  figures.decode['256x256']['delta, alone'] = await page.evaluate(async () => {
    const { createDecoder } = await import('/proto/frame.mjs');
    const { ZSTDDecoder } = await import('/vendor/zstddec.mjs');
    const zstd = new ZSTDDecoder();
    await zstd.init();
    const frames = window.__kept.slice(window.__kept.findIndex((b) => (new DataView(b).getUint32(72, true) & ~2) === 0));
    const positions = new Float32Array(3 * 65536), ms = [];
    let wasm;
    for (let rep = 0; rep < 10; rep++) {
      const d = createDecoder({ zstd, positions });
      for (const b of frames) {
        const t0 = performance.now();
        const f = d.decode(b);
        if (!f.delta.keyframe && rep > 0) ms.push(performance.now() - t0);
      }
      wasm = d.wasm();
    }
    ms.sort((a, b) => a - b);
    // The page's clock ticks in 0.1 ms (with jitter): the mean of the 300-odd times is the finer figure.
    const mean = ms.reduce((a, b) => a + b, 0) / ms.length;
    return { median: ms[ms.length >> 1], mean, p90: ms[Math.floor(ms.length * 0.9)], bytes: frames[frames.length - 1].byteLength, deltas: ms.length, wasm };
  });
  await ok(daemon, 'POST', '/v1/sim/resume');
  assert.ok(figures.decode['256x256']['delta, alone'].deltas > 0);
});
