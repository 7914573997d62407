// overview.js - overview.html: every scene of the daemon as a small live thumbnail. The list is
// GET /v1/scenes every two seconds; each scene shown has a stream of its own (one WebSocket per
// scene, through clients/js) subscribed at THUMB_FPS q16 frames a second, drawn as the cloth's
// grid lines and rocks on a 2D canvas (no three.js: a thumbnail costs a canvas, a socket and a
// few hundred microseconds a frame). Clicking a thumbnail opens the scene in the viewer
// (./#scene=ID). Each thumbnail is one stream client: a daemon shows at most stream_max_clients
// of them, less the viewers connected.
import { Client } from 'clothd/client';

export const THUMB_FPS = 3;
const REFRESH_MS = 2000;
const W = 200, H = 140;

const api = new Client({ token: sessionStorage.getItem('clothd.token') });
const tiles = new Map(); // id -> {el, canvas, label, stream, nx, ny, info}
const cost = { frames: 0, busyMs: 0, since: performance.now() };
const $ = (id) => document.getElementById(id);

// A view from the front and above: x to the right, z up, y going back and up the canvas.
const project = (x, y, z) => [x + 0.45 * y, z + 0.3 * y];

function draw(t, f) {
  const t0 = performance.now();
  const ctx = t.canvas.getContext('2d');
  ctx.fillStyle = '#12151b';
  ctx.fillRect(0, 0, W, H);
  const p = f.positions, n = f.nVertices;
  let u0 = Infinity, u1 = -Infinity, v0 = Infinity, v1 = -Infinity;
  const uv = new Float32Array(2 * n);
  for (let k = 0; k < n; k++) {
    const [u, v] = project(p[3 * k], p[3 * k + 1], p[3 * k + 2]);
    uv[2 * k] = u;
    uv[2 * k + 1] = v;
    if (u < u0) u0 = u;
    if (u > u1) u1 = u;
    if (v < v0) v0 = v;
    if (v > v1) v1 = v;
  }
  const s = 0.9 * Math.min(W / Math.max(u1 - u0, 1e-6), H / Math.max(v1 - v0, 1e-6));
  const ox = W / 2 - s * (u0 + u1) / 2, oy = H / 2 + s * (v0 + v1) / 2;
  const X = (k) => ox + s * uv[2 * k], Y = (k) => oy - s * uv[2 * k + 1];
  const nx = t.nx && t.nx * t.ny === n ? t.nx : n, ny = n / nx;
  ctx.strokeStyle = '#9fc3e8';
  ctx.lineWidth = 0.6;
  ctx.beginPath();
  // At most about 32 grid lines either way (a 64 x 64 cloth reads as well, at a quarter of the work).
  const stride = Math.max(1, Math.floor(Math.max(nx, ny) / 32));
  for (let j = 0; j < ny; j += stride) {
    ctx.moveTo(X(j * nx), Y(j * nx));
    for (let i = 1; i < nx; i++) ctx.lineTo(X(j * nx + i), Y(j * nx + i));
  }
  for (let i = 0; i < nx; i += stride) {
    ctx.moveTo(X(i), Y(i));
    for (let j = 1; j < ny; j++) ctx.lineTo(X(j * nx + i), Y(j * nx + i));
  }
  ctx.stroke();
  ctx.fillStyle = '#c9905a';
  for (const r of f.rocks ?? []) {
    const [u, v] = project(...r.position);
    ctx.beginPath();
    ctx.arc(ox + s * u, oy - s * v, Math.max(1.5, s * r.radius), 0, 2 * Math.PI);
    ctx.fill();
  }
  t.frames++;
  cost.frames++;
  cost.busyMs += performance.now() - t0;
}

function label(t) {
  const i = t.info;
  t.label.textContent = i ? `${i.id} · ${i.state} · ${i.n_vertices} vertices · ${i.n_rocks} rocks` : t.id;
}

function addTile(info) {
  const el = document.createElement('a');
  el.className = 'thumb';
  el.href = `./#scene=${info.id}`;
  el.dataset.scene = info.id;
  const canvas = document.createElement('canvas');
  canvas.width = W;
  canvas.height = H;
  const caption = document.createElement('div');
  el.append(canvas, caption);
  $('thumbs').append(el);
  const t = { id: info.id, el, canvas, label: caption, info, nx: 0, ny: 0, frames: 0 };
  t.stream = api.scene(info.id).stream({
    onHello(h) {
      t.nx = h.scene?.nx ?? 0;
      t.ny = h.scene?.ny ?? 0;
    },
    onFrame(f, ms) {
      cost.busyMs += ms;
      draw(t, f);
    },
    onStatus(s, detail) { if (s === 'closed') t.label.textContent = `${t.id}: ${detail}`; },
  }, { subscription: { encoding: 'q16', max_fps: THUMB_FPS, scalar: 'none' } }).start();
  tiles.set(info.id, t);
  label(t);
}

async function refresh() {
  let scenes;
  try {
    ({ scenes } = await api.scenes());
    $('overview-status').textContent = `${scenes.length} scene${scenes.length === 1 ? '' : 's'}`;
  } catch (e) {
    $('overview-status').textContent = `cannot list the scenes: ${e.message}`;
    return;
  }
  const ids = new Set(scenes.map((s) => s.id));
  for (const [id, t] of tiles) {
    if (ids.has(id)) continue;
    t.stream.stop();
    t.el.remove();
    tiles.delete(id);
  }
  for (const s of scenes) {
    const t = tiles.get(s.id);
    if (t) {
      t.info = s;
      label(t);
    } else addTile(s);
  }
}

// For the tests and the benchmark: the thumbnails, frames drawn and the time spent on them.
window.__overview = {
  tiles,
  cost,
  ready: false,
};
await refresh();
window.__overview.ready = true;
setInterval(refresh, REFRESH_MS);
