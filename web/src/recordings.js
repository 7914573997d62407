// recordings.js - the recording bar at the foot of the page: open a recording (a .clr file chosen
// or dropped on the page, or one of the server's, GET /v1/recordings through the JavaScript
// client; the list is hidden where the server has no recordings, 404), play it (player.js:
// play, pause, a timeline to scrub, speed 0.25x .. 4x, its sim time and frame shown), export
// (export.js: the frame shown, live or recorded, as PLY or glTF; a range of the recording, from
// .. to on the timeline, as animated glTF or as a WebM video, frame-exact (video.js); clients/js
// recording-export.js: the whole recording as USD or MCAP), and go back to live.
//
// A file that is not a recording, or is corrupt, is said in the bar (the reader's message, with
// the offset) and the page goes on as it was; a file cut short (no index: a recording still
// running, or its daemon killed) plays the frames it has, and the bar says so.
import { NotFound, exportUsd, exportMcap } from 'clothd/client';
import { triangleIndices } from './topology.js';
import { Player, SPEEDS } from './player.js';
import { framePly, frameGlb, animationGlb, animationStride, animationCap, download, MAX_ANIMATION_FRAMES } from './export.js';
import { encodeWebm } from './video.js';

const el = (tag, props = {}, ...children) => {
  const e = Object.assign(document.createElement(tag), props);
  e.append(...children);
  return e;
};
const button = (text, title, onclick) => el('button', { type: 'button', textContent: text, title, onclick });

export class RecordingBar {
  /**
   * @param {HTMLElement} container
   * @param {import('clothd/client').Client} api
   * @param {{draw: object, enter(player), leave(), shown(): object|null, scene(): string,
   *   render(): HTMLCanvasElement}} hooks
   *   draw: the page's drawing path for recorded records; enter and leave: a recording starts,
   *   the page goes back to live; shown: the frame on the screen; scene: the live scene's id;
   *   render: draws the view now and answers its canvas (the video export)
   */
  constructor(container, api, hooks) {
    this.api = api;
    this.hooks = hooks;
    this.player = null;
    this.busy = false;

    // Always there: open, the server's list, the frame shown as a file.
    this.file = el('input', { type: 'file', id: 'rec-file', accept: '.clr,application/vnd.clothd.recording', title: 'a clothd recording (.clr)' });
    this.file.addEventListener('change', () => {
      const f = this.file.files[0];
      this.file.value = '';
      if (f) this.openFile(f);
    });
    this.list = el('select', { id: 'rec-list', title: "the server's recordings" });
    this.list.setAttribute('aria-label', "the server's recordings");
    this.server = el('span', { id: 'rec-server', hidden: true }, this.list,
      button('Play', 'download this recording and play it', () => this.openServer(this.list.value)),
      button('↻', 'list the recordings again', () => this.refreshList()));
    this.server.querySelector('button').id = 'rec-load';
    // Listed when asked, not at load: a server without recordings answers 404, which the
    // browser's console reports as an error of the page.
    this.serverButton = button("server's…", "list this clothd's recordings (GET /v1/recordings)", () => this.refreshList());
    this.serverButton.id = 'rec-server-open';
    const exportPly = button('Frame as PLY', 'the frame shown: positions and the intact triangles', () => this.exportFrame('ply'));
    const exportGlb = button('Frame as glTF', 'the frame shown: the cloth and the rocks, binary glTF (.glb)', () => this.exportFrame('glb'));
    exportPly.id = 'export-ply';
    exportGlb.id = 'export-glb';
    const openLabel = el('label', { htmlFor: 'rec-file', textContent: 'recording ' });
    const top = el('div', { className: 'rec-row' }, openLabel, this.file, this.serverButton, this.server, exportPly, exportGlb);

    // While a recording plays: the timeline.
    this.playButton = button('Play', 'play or pause', () => this.playPause());
    this.playButton.id = 'rec-play';
    this.scrub = el('input', { type: 'range', id: 'rec-scrub', min: 0, max: 0, step: 1, value: 0, title: 'frame' });
    this.scrub.setAttribute('aria-label', 'frame');
    this.scrub.addEventListener('input', () => this.seek(Number(this.scrub.value)));
    this.speed = el('select', { id: 'rec-speed', title: 'playback speed' },
      ...SPEEDS.map((s) => el('option', { value: String(s), textContent: `${s}x`, selected: s === 1 })));
    this.speed.setAttribute('aria-label', 'playback speed');
    this.speed.addEventListener('change', () => { if (this.player) this.player.speed = Number(this.speed.value); });
    this.time = el('span', { id: 'rec-time' });
    this.from = el('input', { type: 'number', id: 'rec-from', min: 0, step: 1, value: 0, size: 5, title: 'first frame of the range to export' });
    this.to = el('input', { type: 'number', id: 'rec-to', min: 0, step: 1, value: 0, size: 5, title: 'last frame of the range to export' });
    const fromHere = button('⇤', 'the range starts at the frame shown', () => { this.from.value = String(this.player?.k ?? 0); });
    const toHere = button('⇥', 'the range ends at the frame shown', () => { this.to.value = String(this.player?.k ?? 0); });
    const exportAnim = button('Range as animated glTF', '', () => this.exportRange());
    exportAnim.id = 'export-animation';
    const video = button('Range as WebM video', "the range's frames one by one as drawn, at the recording's frame rate (WebCodecs VP9 or VP8)", () => this.exportVideo());
    video.id = 'export-webm';
    const usd = button('Recording as USD', 'the whole recording as USD text (.usda): the cloth with its tears and the rocks, every frame (Blender, Houdini)', () => this.exportUsd());
    usd.id = 'export-usd';
    const mcap = button('Recording as MCAP', 'the whole recording as MCAP (foxglove.SceneUpdate messages): the cloth and the rocks, every frame (Foxglove, Lichtblick)', () => this.exportMcap());
    mcap.id = 'export-mcap';
    this.animNote = el('span', { className: 'rec-note', id: 'rec-cap' });
    const live = button('Back to live', 'close the recording and show the live scene again', () => this.backToLive());
    live.id = 'rec-live';
    this.playerRow = el('div', { className: 'rec-row', id: 'rec-player', hidden: true },
      this.playButton, this.scrub, this.speed, this.time, el('br'),
      'export frames ', this.from, fromHere, ' to ', this.to, toHere, ' ', exportAnim, this.animNote, ' ', video, ' ', usd, ' ', mcap, ' ', live);

    this.message = el('div', { id: 'rec-message', role: 'status' });
    container.append(top, this.playerRow, this.message);

    // A file dropped anywhere on the page.
    window.addEventListener('dragover', (e) => {
      if ([...(e.dataTransfer?.types ?? [])].includes('Files')) e.preventDefault();
    });
    window.addEventListener('drop', (e) => {
      const f = e.dataTransfer?.files?.[0];
      if (!f) return;
      e.preventDefault();
      this.openFile(f);
    });
  }

  /** A message in the bar (level '', 'warn' or 'error'). It stays until the next one. */
  say(text, level = '') {
    this.message.textContent = text;
    this.message.className = level;
  }

  /**
   * GET /v1/recordings into the list. A server without recordings (404): the list stays hidden
   * and the button that asks is disabled, saying so.
   */
  async refreshList() {
    let answer;
    try {
      answer = await this.api.recordings();
    } catch (e) {
      this.server.hidden = true;
      if (e instanceof NotFound) {
        this.serverButton.disabled = true;
        this.serverButton.textContent = 'no recordings on this server';
        this.serverButton.title = `GET /v1/recordings: ${e.message}`;
      } else this.say(`recordings not listed: ${e.message}`, 'error');
      return;
    }
    this.serverButton.hidden = true;
    const keep = this.list.value;
    this.list.replaceChildren(...(answer.recordings ?? []).map((r) => el('option', {
      value: r.id, textContent: `${r.id} (${r.scene}, ${r.state}, ${r.frames} frames, ${Number(r.seconds ?? 0).toFixed(1)} s)`,
    })));
    if (keep) this.list.value = keep;
    this.server.hidden = false;
  }

  async openServer(rid) {
    if (!rid) return this.say('no recording chosen', 'error');
    this.say(`downloading ${rid}…`);
    let bytes;
    try {
      bytes = await this.api.recording(rid);
    } catch (e) {
      return this.say(`recording ${rid} not downloaded: ${e.message}`, 'error');
    }
    return this.open(bytes, rid);
  }

  async openFile(file) {
    let bytes;
    try {
      bytes = await file.arrayBuffer();
    } catch (e) {
      return this.say(`${file.name} not read: ${e.message}`, 'error');
    }
    return this.open(bytes, file.name);
  }

  /** Reads a recording and shows its first frame; a bad one changes nothing but the message. */
  async open(bytes, name) {
    if (this.busy) return;
    this.busy = true;
    let player;
    try {
      player = await Player.open(bytes, this.hooks.draw, name);
    } catch (e) {
      this.busy = false;
      return this.say(`${name} is not a recording the viewer can play: ${e.message}`, 'error');
    }
    this.player?.pause();
    this.player = player;
    this.hooks.enter(player);
    try {
      player.seek(0);
    } catch (e) {
      this.busy = false;
      this.backToLive();
      return this.say(`${name}: its first frame does not decode (${e.message}); back to live`, 'error');
    }
    this.busy = false;
    this.scrub.max = String(player.count - 1);
    this.from.max = this.to.max = String(player.count - 1);
    this.from.value = '0';
    this.to.value = String(player.count - 1);
    player.speed = Number(this.speed.value);
    const n = player.r.hello.scene.nx * player.r.hello.scene.ny;
    const cap = animationCap(n);
    this.animNote.textContent = ` (at most ${cap} frames: a longer range takes every n-th)`;
    this.animNote.title = `each frame is 12 bytes per vertex (${n} vertices); at most ${MAX_ANIMATION_FRAMES} frames in one file`;
    this.playerRow.hidden = false;
    const what = `${player.count} frames, ${player.duration.toFixed(2)} s of sim time, ${player.info.encoding ?? 'unknown'} encoding` +
      (player.info.scene ? `, scene ${player.info.scene}` : '');
    this.say(player.complete ? `${name}: ${what}`
      : `${name} is cut (no index: still recording, or its daemon stopped): playing the ${what} it has`, player.complete ? '' : 'warn');
    this.update();
  }

  playPause() {
    const p = this.player;
    if (!p) return;
    if (p.playing) p.pause();
    else p.play();
    this.update();
  }

  seek(k) {
    const p = this.player;
    if (!p) return;
    try {
      p.seek(k);
    } catch (e) {
      p.pause();
      this.say(`frame ${k} does not decode: ${e.message}`, 'error');
    }
    this.update();
  }

  /** Each animation frame of the page: advances playback. */
  tick(dt) {
    const p = this.player;
    if (!p || !p.playing) return;
    try {
      p.tick(dt);
    } catch (e) {
      p.pause();
      this.say(`frame ${p.r.seek(p.t)} does not decode: ${e.message}`, 'error');
    }
    this.update();
  }

  update() {
    const p = this.player;
    if (!p) return;
    this.playButton.textContent = p.playing ? 'Pause' : 'Play';
    this.scrub.value = String(p.k);
    const t = p.simTime;
    this.time.textContent = `frame ${p.k + 1} / ${p.count} · ${(t - p.t0).toFixed(3)} s of ${p.duration.toFixed(3)} s · sim time ${t.toFixed(3)} s`;
    this.time.dataset.frame = String(p.k);
    this.time.dataset.frames = String(p.count);
    this.time.dataset.simTime = String(t);
  }

  backToLive() {
    if (!this.player) return;
    this.player.pause();
    this.player = null;
    this.playerRow.hidden = true;
    this.say('');
    this.hooks.leave();
  }

  /** The frame shown as PLY or glb, with the triangles drawn now. */
  async exportFrame(kind) {
    const f = this.hooks.shown();
    if (!f) return this.say('no frame to export yet', 'error');
    const base = this.player ? `${stem(this.player.name)}-frame-${this.player.k}` : `clothd-${this.hooks.scene()}-step-${f.step}`;
    try {
      if (kind === 'ply') download(framePly(f.positions, f.index), `${base}.ply`);
      else download(await frameGlb(f.positions, f.index, f.rocks), `${base}.glb`, 'model/gltf-binary');
    } catch (e) {
      this.say(`export failed: ${e.message}`, 'error');
    }
  }

  /**
   * Frames from..to of the recording as one animated glb, with the triangles of the range's last
   * frame (shown first: springs torn during the range are left out of the whole clip).
   */
  async exportRange() {
    const p = this.player;
    if (!p) return;
    const range = this.range();
    if (!range) return;
    const [from, to] = range;
    try {
      p.pause();
      this.seek(to);
      const f = this.hooks.shown();
      const stride = animationStride(to - from + 1, f.positions.length / 3);
      const run = p.framesOf(from, to, stride);
      const bytes = await animationGlb(run.positions, run.times, f.index, run.ordinals.map((k) => `frame-${k}`));
      download(bytes, `${stem(p.name)}-frames-${from}-${to}.glb`, 'model/gltf-binary');
      this.say(`exported frames ${from} .. ${to}${stride > 1 ? `, every ${stride}th (${run.ordinals.length} frames)` : ` (${run.ordinals.length} frames)`}`);
    } catch (e) {
      this.say(`export failed: ${e.message}`, 'error');
    }
  }

  /** The range of the from .. to boxes within the recording, or null (and the bar says why). */
  range() {
    const p = this.player;
    const from = Math.max(0, Math.min(p.count - 1, Math.floor(Number(this.from.value))));
    const to = Math.max(0, Math.min(p.count - 1, Math.floor(Number(this.to.value))));
    if (!(to >= from)) {
      this.say(`the range ${this.from.value} .. ${this.to.value} is empty`, 'error');
      return null;
    }
    return [from, to];
  }

  /**
   * Frames from..to of the recording as a WebM video, frame-exact: the player shows each frame in
   * turn, the view draws it as the page shows it (colouring, camera, shadows) and the encoder takes
   * it with the timestamp (k - from) / frame_rate, the recording's frame rate (video.js). The frame
   * shown before comes back after.
   */
  async exportVideo() {
    const p = this.player;
    if (!p || this.busy) return;
    const range = this.range();
    if (!range) return;
    const [from, to] = range;
    const fps = p.info.frame_rate > 0 ? p.info.frame_rate
      : p.count > 1 && p.duration > 0 ? (p.count - 1) / p.duration : 60;
    this.busy = true;
    p.pause();
    const back = p.k;
    this.say(`encoding frames ${from} .. ${to} as WebM…`);
    try {
      const out = await encodeWebm({
        count: to - from + 1, fps,
        draw: (j) => { p.show(from + j); return this.hooks.render(); },
        progress: (j) => { if (j % 10 === 0) this.say(`encoding frame ${from + j} of ${from} .. ${to} as WebM…`); },
      });
      download(out.bytes, `${stem(p.name)}-frames-${from}-${to}.webm`, 'video/webm');
      this.say(`exported frames ${from} .. ${to} as WebM (${out.frames} frames, ${out.codec.startsWith('vp09') ? 'VP9' : 'VP8'}, ${out.width} x ${out.height}, ${+fps.toFixed(3)} frames/s)`);
    } catch (e) {
      this.say(`WebM export failed: ${e.message}`, 'error');
    } finally {
      this.busy = false;
      try { p.seek(back); } catch { /* the bar says what failed */ }
      this.update();
    }
  }

  /**
   * The whole recording as USD text (clients/js recording-export.js), streamed into chunks that
   * the download's Blob takes; a cut recording exports what it has, and the bar says so.
   */
  async exportUsd() {
    const p = this.player;
    if (!p || this.busy) return;
    this.busy = true;
    p.pause();
    this.say(`exporting ${p.count} frames as USD…`);
    try {
      const chunks = [];
      const r = await exportUsd(p.r, { write: (s) => { chunks.push(s); } }, { triangles: triangleIndices, codecs: p.codecs });
      download(new Blob(chunks), `${stem(p.name)}.usda`, 'model/vnd.usda');
      this.say(`exported ${r.written} frames as USD${r.problem ? ` (${r.problem})` : ''}`, r.cut ? 'warn' : '');
    } catch (e) {
      this.say(`USD export failed: ${e.message}`, 'error');
    } finally {
      this.busy = false;
      this.update();
    }
  }

  /**
   * The whole recording as MCAP (clients/js recording-export.js: one foxglove.SceneUpdate message
   * a frame, @mcap/core's writer; chunks uncompressed in the browser).
   */
  async exportMcap() {
    const p = this.player;
    if (!p || this.busy) return;
    this.busy = true;
    p.pause();
    this.say(`exporting ${p.count} frames as MCAP…`);
    try {
      const out = new MemoryWritable();
      const r = await exportMcap(p.r, out, { triangles: triangleIndices, codecs: p.codecs });
      download(new Blob(out.chunks), `${stem(p.name)}.mcap`, 'application/octet-stream');
      this.say(`exported ${r.written} frames as MCAP${r.problem ? ` (${r.problem})` : ''}`, r.cut ? 'warn' : '');
    } catch (e) {
      this.say(`MCAP export failed: ${e.message}`, 'error');
    } finally {
      this.busy = false;
      this.update();
    }
  }
}

/** @mcap/core's IWritable into memory: the chunks it writes, for the download's Blob. */
class MemoryWritable {
  chunks = [];
  size = 0n;
  async write(buffer) {
    this.chunks.push(buffer.slice());
    this.size += BigInt(buffer.byteLength);
  }
  position() { return this.size; }
}

const stem = (name) => String(name).replace(/\.clr$/i, '').replace(/[^A-Za-z0-9._-]+/g, '_') || 'recording';
