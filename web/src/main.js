// main.js - the clothd viewer: wires the JavaScript client (clients/js: every HTTP call and the
// stream), the 3D view (view.js), the mouse (interact.js), the panel (panel.js), the chart
// (chart.js) and the HUD. Everything goes through the public API and stream of PROTOCOL.md; no
// physics here.
//
// Scenes: the page shows one scene of the daemon, the one its URL names (#scene=ID; `default`
// without one), so a link opens that scene and back/forward move between the scenes shown. The
// scene picker (scenes.js) lists, creates and deletes scenes; overview.html shows them all.
//
// Recordings (recordings.js, player.js): a recording from a dropped file or from the server plays
// through the same drawing path as the live stream (`draw` below: hello, events, frames), with
// the live stream closed meanwhile; "Back to live" opens it again, and its hello brings the scene
// as it is now. Exports (export.js): the frame shown as PLY or glTF, a recording's range as
// animated glTF or as a frame-exact WebM video (video.js). Capture and inspection: a PNG
// screenshot and a WebM of the live view (the canvas), camera presets with the camera kept in the
// URL, a vertex probe (the vertex under the cursor from GET /v1/cloth/state) and the stretch
// colouring (view.js).
import { Client, SCENE_ID, DEFAULT_SCENE } from 'clothd/client';
import { ScenePicker } from './scenes.js';
import { View, MODES } from './view.js';
import { Interaction } from './interact.js';
import { Panel } from './panel.js';
import { EnergyChart } from './chart.js';
import { RecordingBar } from './recordings.js';
import { structuralStrain } from './topology.js';

const $ = (id) => document.getElementById(id);

// ---- messages: the connection state, and problems (refused calls, bad frames) for a while ----
const problems = [];
function problem(text, level = 'warn') {
  console[level === 'info' ? 'info' : 'warn'](`clothd viewer: ${text}`);
  problems.push({ text, at: Date.now() });
  const el = document.createElement('div');
  el.textContent = text;
  $('problems').appendChild(el);
  while ($('problems').children.length > 4) $('problems').firstChild.remove();
  setTimeout(() => el.remove(), 8000);
}
function status(text) {
  $('status').textContent = text;
  $('status').classList.toggle('show', !!text);
}

function askToken(reason) {
  const form = $('token');
  $('token-reason').textContent = `${reason} Enter the token (clothd --token-file).`;
  form.hidden = false;
  $('token-input').focus();
  return new Promise((resolve) => {
    form.onsubmit = (e) => {
      e.preventDefault();
      form.hidden = true;
      resolve($('token-input').value.trim() || null);
    };
  });
}

// The token, once asked for, is kept for the tab.
const TOKEN_KEY = 'clothd.token';
const api = new Client({
  token: sessionStorage.getItem(TOKEN_KEY),
  requestIdPrefix: `viewer-${Math.random().toString(36).slice(2, 8)}`,
  async askToken(reason) {
    const token = await askToken(reason);
    if (token) sessionStorage.setItem(TOKEN_KEY, token);
    return token;
  },
});
const refused = (what) => (e) => problem(`${what} refused: ${e.message}`);

// The scene of the URL, and its routes (every per-scene call goes through `cur`).
function sceneOfUrl() {
  const id = new URLSearchParams(location.hash.slice(1)).get('scene');
  return id && SCENE_ID.test(id) ? id : DEFAULT_SCENE;
}
// The orbit camera rides in the URL beside the scene (#scene=ID&cam=eye x,y,z,target x,y,z), so a
// reload or a shared link shows what was seen.
function cameraOfUrl() {
  const cam = new URLSearchParams(location.hash.slice(1)).get('cam');
  const v = cam?.split(',').map(Number);
  return v?.length === 6 && v.every(Number.isFinite) ? v : null;
}
function keepCameraInUrl() {
  const h = new URLSearchParams(location.hash.slice(1));
  h.set('scene', sceneOfUrl());
  h.set('cam', view.cameraState().map((x) => +x.toFixed(4)).join(','));
  history.replaceState(history.state, '', `${location.pathname}${location.search}#${h.toString().replaceAll('%2C', ',')}`);
}
let cur = api.scene(sceneOfUrl());

// ---- state mirrored from the server ----
const state = { framed: false, scene: null, params: {}, torn: new Set(), running: true, health: null, sim: null, subscribed: null };
const rockSpeed = { id: null, last: null, speed: null };

const view = new View($('view'));
// Frames: q16 on this machine (loopback: bytes are free, decoding is cheapest), delta from
// anywhere else (a real network: a third of q16's bytes on a moving cloth, docs/performance.md
// "The stream").
const LOOPBACK = /^(localhost|127(\.\d{1,3}){3}|\[::1\])$/.test(location.hostname);
const ENCODING = LOOPBACK ? 'q16' : 'delta';
const viewValues = { mode: 'surface', camera: 'orbit', encoding: ENCODING, dropRadius: 0.1, dropDensity: 2500, chart: true, preset: 'fit', probe: true, shadows: false, stretchRange: 5 };
let chart = null, panel = null;
/** The recording playing (a Player of player.js), or null: live. */
let playback = null;
/** The frame shown (decodeFrame's result): what the exports take, with the view's triangles. */
let shownFrame = null;

// A live scene's layout reaches the stream's decode targets and the panel; a recording's only
// the view.
function applyScene(scene, torn, rocks, live = true) {
  const rebuild = !view.cloth || !state.scene || view.cloth.nx !== scene.nx || view.cloth.ny !== scene.ny;
  const reframe = !state.scene || ['nx', 'ny', 'size_x', 'size_y', 'height', 'orientation'].some((k) => state.scene[k] !== scene[k]);
  state.scene = { ...scene };
  delete state.scene.applied_step;
  state.torn = new Set(torn);
  if (rocks) {
    view.rockInfo.clear();
    for (const r of rocks) view.rockInfo.set(r.id, { kinematic: r.kinematic });
  }
  if (rebuild) view.buildCloth(scene.nx, scene.ny, state.torn);
  else view.setTorn(state.torn);
  if (reframe) {
    view.frameScene(state.scene);
    // The curtain is seed 004's scene: the first one shown opens in 2D, springs and points
    // coloured by speed.
    if (!state.framed && scene.orientation === 'vertical') {
      setViewValue('camera', '2d');
      setViewValue('mode', 'springs');
    }
    // A camera in the URL (a reload, a link) wins over the first framing.
    if (!state.framed && cameraOfUrl() && view.setCameraState(cameraOfUrl())) setViewValue('camera', 'orbit');
    state.framed = true;
  }
  if (!live) return;
  stream.targets = view.frameTargets();
  panel?.setScene(state.scene);
}

// The shown scene's live parameters (a new scene starts from them): the schema's live rows.
let liveNames = null;
function liveParams() {
  if (!liveNames) return undefined;
  const out = {};
  for (const k of liveNames) if (state.params[k] !== undefined) out[k] = state.params[k];
  return out;
}

// A recording's parameters are drawn (the ground) but not taken as the live scene's.
function applyParams(params, live = true) {
  if (!live) {
    if ('ground' in params || 'ground_z' in params) view.setGround(params.ground, params.ground_z);
    return;
  }
  Object.assign(state.params, params);
  view.setGround(state.params.ground, state.params.ground_z);
  panel?.setParams(params);
}

function setRunning(running) {
  state.running = running;
  panel?.setRunning(running);
}

function setViewValue(name, value) {
  viewValues[name] = value;
  if (name === 'mode') {
    view.setMode(value);
    stream.subscribe({ scalar: MODES[value] });
  } else if (name === 'camera') view.setCamera2d(value === '2d');
  else if (name === 'shadows') view.setShadows(value);
  else if (name === 'stretchRange') view.setStretchRange(value / 100);
  else if (name === 'preset') { view.preset(value); viewValues.camera = 'orbit'; keepCameraInUrl(); }
  else if (name === 'encoding') stream.subscribe({ encoding: value });
  else if (name === 'chart') $('chart').hidden = !value;
  panel?.gui.controllersRecursive().forEach((c) => c.object === viewValues && c.updateDisplay());
}

// ---- the drawing path: the live stream's messages and a recording's records both go here ----
const draw = {
  hello(h, live = true) {
    applyScene(h.scene, h.torn, h.rocks, live);
    applyParams(h.params ?? {}, live);
    if (live) setRunning(h.state === 'running');
  },
  frame(f, live = true) {
    if (!view.showFrame(f)) return;
    shownFrame = f;
    if (live && rockSpeed.id !== null) {
      const r = f.rocks.find((x) => x.id === rockSpeed.id);
      if (r && rockSpeed.last && f.simTime > rockSpeed.last.t) {
        const p = rockSpeed.last.p;
        rockSpeed.speed = Math.hypot(r.position[0] - p[0], r.position[1] - p[1], r.position[2] - p[2]) / (f.simTime - rockSpeed.last.t);
      }
      rockSpeed.last = r ? { t: f.simTime, p: r.position } : null;
      if (!r) rockSpeed.speed = null;
    }
  },
  event(ev, live = true) {
    const res = ev.result ?? {};
    switch (ev.event) {
      case 'params': applyParams(res.params ?? {}, live); break;
      case 'scene': applyScene(res, [], [], live); if (live) chart?.clear(); break;
      case 'reset': applyScene(state.scene, [], [], live); if (live) chart?.clear(); break;
      case 'snapshot_restored': applyScene(ev.scene, ev.torn, ev.rocks, live); applyParams(ev.params ?? {}, live); if (live) chart?.clear(); break;
      case 'rock_add': case 'rock_set':
        if (res.rock) view.rockInfo.set(res.rock.id, { kinematic: res.rock.kinematic });
        break;
      case 'rock_remove': view.rockInfo.delete(res.id ?? ev.command?.id); break;
      case 'rocks_clear': view.rockInfo.clear(); break;
      case 'paused': if (live) setRunning(false); break;
      case 'resumed': if (live) setRunning(true); break;
      case 'torn':
        for (const id of ev.springs ?? []) state.torn.add(id);
        view.setTorn(state.torn);
        break;
      case 'instability': if (live) problem(`instability: ${typeof ev.detail === 'string' ? ev.detail : JSON.stringify(ev.detail)}`); break;
      default: break; // pins, grab, release, stepped: the frames show them
    }
  },
};
/** The same path for a recording's records. */
const drawRecorded = { hello: (h) => draw.hello(h, false), event: (e) => draw.event(e, false), frame: (f) => draw.frame(f, false) };

// ---- the stream (closed while a recording plays) ----
const stream = cur.stream({
  onStatus(s, detail) {
    if (playback) return status('');
    status(s === 'open' ? '' : s === 'connecting' ? 'connecting to clothd…' : `disconnected: ${detail}`);
  },
  onHello(h) {
    if (playback || (h.scene_id && h.scene_id !== cur.id)) return; // the scene before a switch
    draw.hello(h);
  },
  onFrame(f) {
    if (!playback) draw.frame(f);
  },
  onEvent(ev) {
    if (playback || (ev.scene_id && ev.scene_id !== cur.id)) return;
    draw.event(ev);
  },
  onMessage(m) {
    if (m.type === 'subscribed') state.subscribed = m;
    else if (m.type === 'error') problem(`stream refused ${m.about ?? 'a message'}: ${m.detail}`);
  },
  onProblem(text) {
    problem(text);
    if (stream.scene !== cur.id) showScene(stream.scene, { replace: true }); // a switch refused
  },
}, { pull: true, subscription: { encoding: ENCODING, max_fps: 60, scalar: 'none' } });

let webm = null; // the MediaRecorder while a WebM records
let webmBytes = 0; // what the recorder has delivered so far (a test waits on it)
function saveBlob(blob, name) {
  const a = document.createElement('a');
  a.href = URL.createObjectURL(blob);
  a.download = name;
  a.click();
  setTimeout(() => URL.revokeObjectURL(a.href), 10000);
}

// ---- actions of the panel and the mouse ----
const actions = {
  async playPause() {
    const res = await (state.running ? cur.pause() : cur.resume()).catch(refused('pause/resume'));
    if (res) setRunning(res.state === 'running');
  },
  async step() {
    if (state.running) {
      const res = await cur.pause().catch(refused('pause'));
      if (!res) return;
      setRunning(false);
    }
    await cur.step({ frames: 1 }).catch(refused('step'));
  },
  reset: () => cur.reset().catch(refused('reset')),
  clearRocks: () => cur.clearRocks().catch(refused('remove rocks')),
  async download() {
    const bytes = await cur.snapshot().catch(refused('snapshot'));
    if (!bytes) return;
    const a = document.createElement('a');
    a.href = URL.createObjectURL(new Blob([bytes]));
    a.download = `clothd-step-${state.sim?.step ?? 0}.snapshot`;
    a.click();
    setTimeout(() => URL.revokeObjectURL(a.href), 10000);
  },
  async screenshot() {
    const blob = await view.screenshot().catch((e) => problem(`screenshot: ${e.message}`));
    if (blob) saveBlob(blob, `clothd-${cur.id}-step-${view.lastStep ?? 0}.png`);
  },
  // A WebM of the live view: MediaRecorder on the canvas's stream, from the click to the next.
  webm() {
    if (webm) { webm.stop(); return; }
    const type = typeof MediaRecorder === 'undefined' ? null
      : ['video/webm;codecs=vp9', 'video/webm;codecs=vp8', 'video/webm'].find((t) => MediaRecorder.isTypeSupported(t));
    if (!type) return problem('this browser cannot record WebM (no MediaRecorder for video/webm)');
    const rec = new MediaRecorder(view.renderer.domElement.captureStream(30), { mimeType: type });
    const chunks = [], name = `clothd-${cur.id}-step-${view.lastStep ?? 0}.webm`;
    webmBytes = 0;
    rec.ondataavailable = (e) => { if (e.data.size) { chunks.push(e.data); webmBytes += e.data.size; } };
    rec.onstop = () => {
      webm = null;
      panel?.setWebm(false);
      // Stopped before the encoder gave anything (a click straight after the first, a slow
      // machine): say so rather than download an empty file.
      if (!chunks.length) return problem('the WebM caught no frames: record for longer');
      saveBlob(new Blob(chunks, { type: 'video/webm' }), name);
    };
    rec.onerror = (e) => problem(`WebM recording: ${e.error?.message ?? 'failed'}`);
    rec.start(500);
    webm = rec;
    panel?.setWebm(true);
  },
  upload() {
    const input = $('snapshot-file');
    input.value = '';
    input.onchange = async () => {
      const file = input.files[0];
      if (file) await cur.restoreSnapshot(await file.arrayBuffer()).catch(refused('snapshot upload'));
    };
    input.click();
  },
};

let rockMove = null; // {id, position, busy}: the newest position wins
const mouse = {
  // Dropped just in front of the clicked surface, toward the camera, and further back when that
  // would overlap the cloth or a rock: the daemon refuses such a placement (409), so the drop
  // backs off until it is clear, and retries a few times more if the daemon still disagrees.
  async dropRock(point, dir) {
    if (playback) return null; // a recording is shown: the live scene is not under the mouse
    const r = viewValues.dropRadius, sc = state.scene;
    const spacing = sc ? Math.max(sc.size_x / (sc.nx - 1), sc.size_y / (sc.ny - 1)) : 0.05;
    const margin = (state.params.contact_offset ?? 0.01) + spacing;
    // Backing off: up over a horizontal cloth (above the pile), toward the camera in front of a
    // hanging one.
    const off = sc?.orientation === 'vertical' ? dir.map((d) => -d) : [0, 0, 1];
    const start = point.map((x, k) => x - dir[k] * (r * 1.5 + 0.05));
    let lift = 0;
    const at = (l) => start.map((x, k) => x + off[k] * l);
    for (let k = 0; k < 40 && view.clearance(at(lift)) < r + margin; k++) lift += r / 2;
    for (let tries = 0; ; tries++) {
      try {
        return await cur.addRock({ position: at(lift), radius: r, density: viewValues.dropDensity });
      } catch (e) {
        if (e.status !== 409 || tries >= 4) return refused('rock')(e);
        lift += 2 * r;
      }
    }
  },
  selectRock(id) {
    rockSpeed.id = rockSpeed.id === id ? null : id;
    rockSpeed.last = null;
    rockSpeed.speed = null;
    view.select(rockSpeed.id);
  },
  grab: (vertex, target) => { if (!playback) stream.grab(vertex, target); },
  release: () => stream.release(),
  async moveRock(id, position) {
    if (playback) return;
    if (rockMove?.busy) { rockMove.next = position; return; }
    rockMove = { busy: true, next: null };
    for (let p = position; p; p = rockMove.next, rockMove.next = null)
      await cur.setRock(id, { position: p }).catch(refused('rock move'));
    rockMove = null;
  },
  groundZ: () => (state.params.ground ? state.params.ground_z : null),
};
const interaction = new Interaction(view, $('view'), mouse);
view.orbit.addEventListener('end', keepCameraInUrl);

// ---- the vertex probe: the cloth vertex under the cursor, its position, speed and strain from
// GET /v1/cloth/state (binary; one request at a time, the newest cursor wins) ----
const probe = { busy: false, again: false, shown: null, x: 0, y: 0 };
async function runProbe() {
  if (probe.busy) { probe.again = true; return; }
  probe.busy = true;
  const el = $('probe');
  try {
    do {
      probe.again = false;
      const v = playback || !viewValues.probe ? -1 : view.vertexAt(probe.x, probe.y);
      if (v < 0) { el.hidden = true; probe.shown = null; continue; }
      const s = await cur.clothStateBinary();
      const sc = state.scene, p = s.positions, u = s.velocities;
      if (!sc || p.length !== 3 * sc.nx * sc.ny) continue;
      // strain as PROTOCOL.md's scalar: the largest (|d| - L0) / L0 of the vertex's intact
      // structural springs (L0 the grid spacing), 0 when none is stretched (topology.js).
      const i = v % sc.nx, j = Math.floor(v / sc.nx);
      const strain = structuralStrain(p, sc.nx, sc.ny, sc.size_x / (sc.nx - 1), sc.size_y / (sc.ny - 1), v, false, state.torn);
      const q = probe.shown = { vertex: v, position: Array.from(p.slice(3 * v, 3 * v + 3)),
        speed: Math.hypot(u[3 * v], u[3 * v + 1], u[3 * v + 2]), strain };
      el.textContent = `vertex   ${v} (i ${i}, j ${j})\nposition ${q.position.map((x) => x.toFixed(4)).join(' ')} m\nspeed    ${q.speed.toFixed(4)} m/s\nstrain   ${(100 * q.strain).toFixed(2)} %`;
      el.style.left = `${probe.x + 16}px`;
      el.style.top = `${probe.y + 16}px`;
      el.hidden = false;
    } while (probe.again);
  } catch {
    el.hidden = true;
    probe.shown = null;
  } finally {
    probe.busy = false;
  }
}
$('view').addEventListener('pointermove', (e) => {
  if (e.buttons) return;
  probe.x = e.clientX; probe.y = e.clientY;
  runProbe();
});
$('view').addEventListener('pointerleave', () => { $('probe').hidden = true; probe.shown = null; });

// ---- recordings: playback and exports (recordings.js) ----
const bar = new RecordingBar($('rec'), api, {
  draw: drawRecorded,
  // A recording starts: the live stream closes (its frames and events would draw over it) and
  // decodes nowhere near the view's arrays.
  enter(player) {
    playback = player;
    stream.targets = {};
    stream.stop();
    status('');
  },
  // Back to live: the stream opens again; its hello sets the scene, the torn springs and the
  // rocks as they are now.
  leave() {
    playback = null;
    shownFrame = null;
    rockSpeed.last = null;
    stream.start();
  },
  // The frame shown, for the exports: positions (the view's own array), triangles, rocks.
  shown: () => (view.cloth?.hasFrame && shownFrame
    ? { positions: view.cloth.position.array, index: view.cloth.index, rocks: shownFrame.rocks, step: shownFrame.step, simTime: shownFrame.simTime }
    : null),
  scene: () => cur.id,
  render: () => view.render(),
});

// ---- the scene shown: the URL's, switched on the same stream ----
function showScene(id, { replace = false } = {}) {
  if (id !== sceneOfUrl()) {
    const url = `${location.pathname}${location.search}#scene=${id}`;
    if (replace) history.replaceState(null, '', url);
    else history.pushState(null, '', url);
  }
  if (id === cur.id) return;
  if (playback) bar.backToLive();
  cur = api.scene(id);
  state.scene = null; // the new scene's hello rebuilds the cloth and frames it
  state.sim = null;
  rockSpeed.id = null;
  chart?.clear();
  if (!stream.switchScene(id)) stream.start(); // not open (its scene deleted): it opens this one
  picker?.setCurrent(id);
  document.title = id === DEFAULT_SCENE ? 'clothd' : `clothd: ${id}`;
}
window.addEventListener('hashchange', () => showScene(sceneOfUrl(), { replace: true }));
window.addEventListener('popstate', () => showScene(sceneOfUrl(), { replace: true }));
let picker = null;

// ---- HUD and chart: the received and drawn rates, GET /v1/sim four times a second ----
const rates = { at: performance.now(), frames: 0, bytes: 0, drawn: 0, received: 0, drawnRate: 0, bytesRate: 0 };
function hud() {
  const now = performance.now(), dt = (now - rates.at) / 1000;
  const s = stream.stats;
  rates.received = (s.frames - rates.frames) / dt;
  rates.bytesRate = (s.bytes - rates.bytes) / dt;
  rates.drawnRate = (view.drawn - rates.drawn) / dt;
  Object.assign(rates, { at: now, frames: s.frames, bytes: s.bytes, drawn: view.drawn });
  const sim = state.sim, h = state.health;
  const kb = rates.bytesRate / 1024;
  $('hud').textContent = [
    `frames  ${rates.received.toFixed(1)}/s received, ${rates.drawnRate.toFixed(1)}/s drawn`,
    `sim     ${sim ? `${sim.state}, step ${sim.step}, ${sim.realtime_factor != null ? `${sim.realtime_factor.toFixed(2)}x real time` : ''}` : '-'}`,
    `backend ${h ? `${h.backend}: ${h.device}` : '-'}`,
    `scene   ${cur.id}`,
    `cloth   ${sim ? `${sim.n_vertices} vertices, ${sim.n_torn} torn springs, ${sim.n_rocks} rocks` : '-'}`,
    sim?.solver?.substeps ? `solver  ${sim.solver.substeps} substeps, ${sim.solver.newton} Newton, ${sim.solver.iterations} CG iterations, residual ${sim.solver.residual.toExponential(1)}`
      : `solver  ${sim ? `${sim.substeps} substeps a frame` : '-'}`,
    playback ? `stream  closed: playing ${playback.name} (${playback.info.encoding ?? '?'}), frame ${playback.k + 1} of ${playback.count}`
      : `stream  ${kb >= 1024 ? `${(kb / 1024).toFixed(2)} MB/s` : `${kb.toFixed(0)} kB/s`}, ${state.subscribed?.encoding ?? stream.subscription.encoding}`,
  ].join('\n');
}

async function pollSim() {
  try {
    state.sim = await cur.sim();
    if (state.sim.state === 'running' !== state.running) setRunning(state.sim.state === 'running');
    if (viewValues.chart && chart && !playback) chart.push(state.sim.sim_time, state.sim.energy, rockSpeed.speed);
  } catch {
    state.sim = null; // the stream's status says why
  }
}

let lastLoop = performance.now();
function loop() {
  const now = performance.now();
  if (playback) bar.tick(Math.min(0.25, (now - lastLoop) / 1000));
  else stream.takeFrame();
  lastLoop = now;
  view.draw();
  requestAnimationFrame(loop);
}

// ---- start: the schema for the panel, then the stream ----
async function start() {
  let schema;
  for (let wait = 500; ; wait = Math.min(wait * 2, 8000)) {
    try {
      [schema, state.health] = await Promise.all([cur.paramsSchema(), api.health()]);
      break;
    } catch (e) {
      status(`cannot reach clothd (${e.message}); trying again`);
      await new Promise((r) => setTimeout(r, wait));
    }
  }
  liveNames = (schema.params ?? []).filter((p) => p.kind === 'live').map((p) => p.name);
  panel = new Panel($('panel'), schema, {
    patchParams: (p) => cur.setParams(p),
    putScene: (s) => cur.setScene(s),
    refreshParams: async () => applyParams(await cur.params()),
    actions,
    view: { values: viewValues, onChange: setViewValue },
  });
  chart = new EnergyChart($('chart'));
  picker = new ScenePicker($('scenes'), api, {
    current: () => cur.id,
    show: (id) => showScene(id),
    // A new scene takes the shown one's scene fields and live parameters.
    settings: () => ({ scene: state.scene ? { ...state.scene } : undefined, params: liveParams() }),
    problem,
  });
  picker.setCurrent(cur.id);
  if (state.scene) panel.setScene(state.scene);
  panel.setParams(state.params);
  panel.setRunning(state.running);
  setInterval(hud, 500);
  setInterval(pollSim, 250);
  setInterval(() => api.health().then((h) => (state.health = h), () => {}), 5000);
  window.__clothd.panel = panel;
  window.__clothd.picker = picker;
  window.__clothd.ready = true;
}

// Hooks for the tests and the benchmark (tests/web/e2e.test.mjs): read-only views of the page's
// own state, and inject() to feed the stream a message as if the server had sent it.
window.__clothd = {
  ready: false, api, scene: () => cur.id, stream, view, interaction, state, rates, problems,
  inject: (data) => stream.inject(data),
  playback: () => playback, bar,
  rockMoving: () => rockMove !== null,
  setView: setViewValue,
  probe: () => probe.shown,
  webmBytes: () => webmBytes,
};

stream.start();
requestAnimationFrame(loop);
start();
