// stream.js - clothd's WebSocket stream (PROTOCOL.md, "The stream") in a page or in node 20+
// (the `ws` package where there is no global WebSocket): finds the port (GET /v1/health), opens
// the stream with the client's token, subscribes, decodes binary frames with frame.mjs,
// passes text messages on, sends grabs, and reconnects by itself with backoff (0.25 s doubling to
// 8 s) when the daemon goes away, until stop().
//
// Nothing a server sends can stop it: a frame that does not decode, a message that is not JSON or
// of an unknown type, a protocol other than clothd.v1 - each is reported to onProblem and the
// stream goes on.
//
// Frames are decoded as they come (push), or, with `pull: true` (a page that draws at its own
// rate), held undecoded until takeFrame(): a frame that arrives before the last one was taken
// replaces it, undecoded and counted in stats.skipped (a delta keyframe so replaced is still
// decoded into the decoder, which keeps it: the deltas after it need it).
//
// delta frames are decoded with the zstddec package's decoder (imported when the first comes,
// or given), meshopt frames with the meshoptimizer package's; `{"type": "keyframe"}` is
// keyframe().
import { createDecoder, DELTA_HEAD, HEADER_SIZE, isDeltaKeyKind } from './frame.mjs';

export const PROTOCOL = 'clothd.v1';
export const DEFAULT_SCENE = 'default';
/** Scene ids the server takes (checked here, before any request). */
export const SCENE_ID = /^[a-z0-9][a-z0-9_-]{0,62}$/;
/** Throws a TypeError for an id the server would refuse. */
export function checkSceneId(id) {
  if (typeof id !== 'string' || !SCENE_ID.test(id))
    throw new TypeError(`scene id ${JSON.stringify(id)} is not one clothd takes ([a-z0-9][a-z0-9_-]{0,62})`);
}
/** The close reason (with code 1001) of a stream whose scene was deleted. */
export const SCENE_DELETED = 'scene deleted';
export const BACKOFF_MIN_MS = 250;
export const BACKOFF_MAX_MS = 8000;
const OPEN = 1; // WebSocket.OPEN, the same in the browser and in ws

const HANDLERS = {
  hello: 'onHello', frame: 'onFrame', frameReady: 'onFrameReady', event: 'onEvent',
  message: 'onMessage', status: 'onStatus', problem: 'onProblem',
};

/** The decoders some encodings need (flags bits 0-1 -> how to load one, given or imported). */
const CODECS = {
  2: { option: 'meshopt', what: "meshopt frames need the meshoptimizer package's decoder",
    load: async (given) => { const d = given ?? (await import('meshoptimizer')).MeshoptDecoder; await d.ready; return d; } },
  3: { option: 'zstd', what: "delta frames need the zstddec package's decoder",
    load: async (given) => { const d = given ?? new (await import('zstddec')).ZSTDDecoder(); await d.init(); return d; } },
};
const CODEC_OF = { meshopt: 2, delta: 3 };

const view = (data) => (data instanceof ArrayBuffer ? new Uint8Array(data)
  : new Uint8Array(data.buffer, data.byteOffset, data.byteLength));

let wsClass = null;
async function webSocketClass() {
  if (globalThis.WebSocket) return globalThis.WebSocket;
  if (!wsClass) {
    try {
      wsClass = (await import('ws')).default;
    } catch (e) {
      throw new Error(`there is no WebSocket here: node needs the ws package (npm install ws): ${e.message}`);
    }
  }
  return wsClass;
}

/**
 * @typedef {object} StreamHandlers
 * @property {(hello: object) => void} [onHello] the hello: everything a late joiner needs
 * @property {(frame: object, ms: number) => void} [onFrame] a decoded frame (decodeFrame's result) and the decode time
 * @property {() => void} [onFrameReady] with pull: a frame waits for takeFrame()
 * @property {(event: object) => void} [onEvent] an event message
 * @property {(message: object) => void} [onMessage] `subscribed` and `error` messages
 * @property {(state: 'connecting'|'open'|'closed', detail: string) => void} [onStatus]
 * @property {(text: string) => void} [onProblem] something the server sent that does not fit the protocol
 */

/**
 * @typedef {object} StreamOptions
 * @property {{encoding?: 'f32'|'q16'|'meshopt'|'delta', max_fps?: number, scalar?: 'none'|'speed'|'strain',
 *   quantum?: number, max_kbps?: number|null}} [subscription]
 *   sent on every (re)connect; the server's default (f32, 60 fps, no scalar) otherwise
 * @property {boolean} [pull] hold frames undecoded until takeFrame()
 * @property {{decodeVertexBuffer: Function, ready: Promise<void>}} [meshopt] the meshoptimizer
 *   package's MeshoptDecoder (default: imported when the first meshopt frame comes)
 * @property {{decode: Function, init: () => Promise<void>}} [zstd] the zstddec package's
 *   ZSTDDecoder for delta frames (default: imported when the first delta frame comes)
 * @property {string} [scene] the scene (client.scene(id).stream() sets it)
 */

export class Stream {
  /**
   * @param {import('./client.js').Client} client
   * @param {StreamHandlers} [handlers]
   * @param {StreamOptions} [options]
   */
  constructor(client, handlers = {}, options = {}) {
    this.client = client;
    this.h = handlers;
    this.scene = options.scene ?? DEFAULT_SCENE;
    /** {from, to} while a switchScene() waits for the new scene's hello. */
    this.switching = null;
    this.pull = options.pull ?? false;
    this.subscription = { ...options.subscription };
    /** {positions, scalar, scratch}: arrays frames decode into when they are large enough. */
    this.targets = {};
    this.ws = null;
    this.hello = null;
    this.subscribed = null;
    this.closedByUs = false;
    this.backoff = BACKOFF_MIN_MS;
    this.retryTimer = null;
    this.retryMs = null;
    this.connecting = false;
    this.listeners = new Set();
    this.codecsGiven = { meshopt: options.meshopt ?? null, zstd: options.zstd ?? null };
    /** The decoders' options (meshopt, zstd, and the targets' arrays), read at each decode. */
    this.decodeOptions = {};
    this.decoder = createDecoder(this.decodeOptions);
    this.codecLoads = {};
    this.awaitingCodec = null;
    this.pending = null;
    this.pendingGrab = null;
    this.lastData = null;
    this.stats = { frames: 0, decoded: 0, skipped: 0, bytes: 0, badFrames: 0, badMessages: 0, reconnects: 0, decodeMs: { f32: [], q16: [], meshopt: [], delta: [] } };
    if (CODEC_OF[this.subscription.encoding]) this.loadCodec(CODEC_OF[this.subscription.encoding]);
  }

  /** Adds a listener of one kind (hello, frame, frameReady, event, message, status, problem); returns its remover. */
  on(kind, fn) {
    const entry = { kind, fn };
    this.listeners.add(entry);
    return () => this.listeners.delete(entry);
  }

  /** @private */
  emit(kind, ...args) {
    this.h[HANDLERS[kind]]?.(...args);
    for (const l of [...this.listeners]) if (l.kind === kind) l.fn(...args);
  }

  /**
   * The next message of a kind that matches: resolves with it, or rejects after `timeout` ms.
   * @param {string} kind @param {(m: any) => boolean} [match] @param {{timeout?: number}} [options]
   */
  waitFor(kind, match = () => true, { timeout = 15000 } = {}) {
    return new Promise((resolve, reject) => {
      const timer = setTimeout(() => { off(); reject(new Error(`no ${kind} message in ${timeout} ms`)); }, timeout);
      const off = this.on(kind, (m) => {
        if (!match(m)) return;
        clearTimeout(timer);
        off();
        resolve(m);
      });
    });
  }

  /**
   * Decoded frames as they come, newest first: a frame that comes before the loop asks for the
   * next replaces the one waiting. Ends when the stream is stopped.
   */
  async *frames() {
    let next = null, wake = null;
    const offFrame = this.on('frame', (f) => { next = f; wake?.(); });
    const offStatus = this.on('status', () => wake?.());
    try {
      for (;;) {
        while (!next) {
          if (this.closedByUs) return;
          await new Promise((r) => { wake = r; });
          wake = null;
        }
        const f = next;
        next = null;
        yield f;
      }
    } finally {
      offFrame();
      offStatus();
    }
  }

  /**
   * Connects, and keeps connecting until stop(). Started already: nothing more. Stopped while an
   * attempt was still on its way (stop() then start(), as the viewer does around a recording):
   * that attempt goes on, and no second connection opens beside it.
   */
  start() {
    const started = this.connecting || (!this.closedByUs && (this.ws || this.retryTimer));
    this.closedByUs = false;
    if (!started) this.connect();
    return this;
  }

  stop() {
    this.closedByUs = true;
    clearTimeout(this.retryTimer);
    this.retryTimer = null;
    if (this.ws) this.ws.close();
    else this.emit('status', 'closed', 'stopped');
  }

  /** @private */
  async connect() {
    this.connecting = true;
    try {
      await this.open();
    } finally {
      this.connecting = false;
    }
  }

  /** @private One attempt: the port from GET /v1/health, then the WebSocket. */
  async open() {
    clearTimeout(this.retryTimer);
    this.retryTimer = null;
    if (this.closedByUs) return;
    this.emit('status', 'connecting', '');
    let url, stream, WS;
    try {
      url = new URL(this.client.base || globalThis.location?.href);
    } catch {
      return this.fail(`no URL to find the stream from: give the client a base (new Client({ base: 'http://host:port' }))`);
    }
    try {
      // Another scene's stream: the server says whether it has that scene (404 otherwise).
      if (this.scene !== DEFAULT_SCENE) await this.client.scene(this.scene).sim();
      stream = (await this.client.health()).stream;
    } catch (e) {
      // 503 (unhealthy) still answers the stream's port; a scene that does not exist ends it.
      if (e.status === 503 && e.body?.stream) stream = e.body.stream;
      else if (e.status === 404 && this.scene !== DEFAULT_SCENE) return this.fail(`no scene ${JSON.stringify(this.scene)} on this clothd (${e.message})`);
      else return this.retry(`no answer from clothd (${e.message})`);
    }
    if (!stream) return this.retry('this clothd has no stream');
    try {
      WS = await webSocketClass();
    } catch (e) {
      return this.fail(e.message);
    }
    if (this.closedByUs) return;
    url.protocol = url.protocol === 'https:' ? 'wss:' : 'ws:';
    url.port = String(stream.port);
    url.pathname = stream.path || '/stream';
    url.search = this.scene === DEFAULT_SCENE ? '' : `?scene=${encodeURIComponent(this.scene)}`;
    url.hash = '';
    let ws;
    try {
      // The token rides in the subprotocol list (a page cannot set Authorization on a
      // WebSocket); the server answers with clothd.v1 alone.
      const token = this.client.token;
      ws = new WS(url.href, token ? [PROTOCOL, `bearer.${token}`] : PROTOCOL);
    } catch (e) {
      return this.retry(`cannot open ${url.href}: ${e.message}`);
    }
    ws.binaryType = 'arraybuffer';
    this.ws = ws;
    this.pending = null;
    this.decoder = createDecoder(this.decodeOptions); // a new connection brings its own keyframe
    ws.onopen = () => {
      if (Object.keys(this.subscription).length) this.send({ type: 'subscribe', ...this.subscription });
    };
    ws.onmessage = (m) => (typeof m.data === 'string' ? this.onText(m.data) : this.onBinary(m.data));
    ws.onerror = () => {}; // the close that follows says it
    ws.onclose = (e) => {
      if (this.ws !== ws) return;
      this.ws = null;
      const switched = this.switching; // on its way to another scene already: that one opens
      this.switching = null;
      if (e.code === 1001 && e.reason === SCENE_DELETED && !switched) this.fail(`scene ${JSON.stringify(this.scene)} was deleted`);
      else if (!this.closedByUs) this.retry(e.reason || `stream closed (${e.code})`);
      else this.emit('status', 'closed', 'stopped');
    };
  }

  /** @private A condition no retry mends: says so and stops. */
  fail(reason) {
    this.closedByUs = true;
    this.emit('problem', reason);
    this.emit('status', 'closed', reason);
  }

  /** @private */
  retry(reason) {
    if (this.closedByUs) return;
    const wait = Math.round(this.backoff * (0.75 + 0.5 * Math.random())); // +-25%: clients part ways
    this.backoff = Math.min(this.backoff * 2, BACKOFF_MAX_MS);
    this.stats.reconnects++;
    /** The wait before the next attempt, in ms. */
    this.retryMs = wait;
    this.emit('status', 'closed', `${reason}; reconnecting in ${(wait / 1000).toFixed(1)} s`);
    this.retryTimer = setTimeout(() => this.connect(), wait);
  }

  /** Sends a client message (an object, as JSON); false when the stream is not open. */
  send(message) {
    if (this.ws?.readyState !== OPEN) return false;
    this.ws.send(JSON.stringify(message));
    return true;
  }

  /** Changes the subscription (any subset of encoding, max_fps, scalar); kept across reconnects. */
  subscribe(change) {
    Object.assign(this.subscription, change);
    if (CODEC_OF[change.encoding]) this.loadCodec(CODEC_OF[change.encoding]);
    return this.send({ type: 'subscribe', ...change });
  }

  /**
   * Streams another scene on the same connection (`{"type": "subscribe", "scene": id}`), keeping
   * the subscription; reconnects open that scene's stream. Frames that still come from the scene
   * before are dropped until the new scene's hello. A server without that scene answers an error
   * (404): the stream stays on the scene it had, and onProblem says so.
   */
  switchScene(id) {
    checkSceneId(id);
    if (id === this.scene && !this.switching) return true;
    this.switching = { from: this.switching?.from ?? this.scene, to: id };
    this.scene = id;
    this.pending = null;
    if (this.send({ type: 'subscribe', scene: id })) return true;
    this.switching = null; // not open: the next connection opens it
    return false;
  }

  /** Asks for a delta keyframe now (the server sends at most a few a second). */
  keyframe() {
    return this.send({ type: 'keyframe' });
  }

  /** Moves a grabbed vertex at mouse rate; while the socket is still sending, only the newest target goes. */
  grab(vertex, target) {
    this.pendingGrab = { type: 'grab', vertex, target };
    this.flushGrab();
  }

  /** @private */
  flushGrab() {
    if (this.pendingGrab && this.ws && this.ws.bufferedAmount < 1024 && this.send(this.pendingGrab)) this.pendingGrab = null;
  }

  release() {
    this.pendingGrab = null;
    return this.send({ type: 'release' });
  }

  /** Feeds one message as if it had come from the server (a test's way to send bad frames). */
  inject(data) {
    if (typeof data === 'string') this.onText(data);
    else this.decode(data);
  }

  /** @private */
  onText(text) {
    let m;
    try {
      m = JSON.parse(text);
    } catch {
      this.stats.badMessages++;
      return this.emit('problem', `a stream message is not JSON: ${String(text).slice(0, 80)}`);
    }
    if (m === null || typeof m !== 'object' || Array.isArray(m)) {
      this.stats.badMessages++;
      return this.emit('problem', 'a stream message is not a JSON object');
    }
    switch (m.type) {
      case 'hello':
        if (this.switching && m.scene_id === this.switching.to) this.switching = null;
        if (m.protocol !== PROTOCOL) {
          this.emit('problem', `clothd speaks ${m.protocol}, this client ${PROTOCOL}: reload the page after an upgrade`);
          this.ws?.close(4000, 'protocol mismatch');
          return;
        }
        this.backoff = BACKOFF_MIN_MS;
        this.hello = m;
        this.emit('status', 'open', '');
        return this.emit('hello', m);
      case 'event':
        return this.emit('event', m);
      case 'subscribed':
        this.subscribed = m;
        return this.emit('message', m);
      case 'error':
        if (this.switching && m.about === 'subscribe' && m.param === 'scene') {
          this.emit('problem', `cannot stream scene ${JSON.stringify(this.switching.to)}: ${m.detail}`);
          this.scene = this.switching.from;
          this.switching = null;
        }
        return this.emit('message', m);
      default:
        this.stats.badMessages++;
        return this.emit('problem', `unknown stream message type ${JSON.stringify(m.type)}`);
    }
  }

  /** @private */
  onBinary(data) {
    if (this.switching) return; // the scene before's, sent before the server switched
    this.lastData = data;
    this.stats.frames++;
    this.stats.bytes += data.byteLength;
    this.flushGrab();
    if (!this.pull) return this.decode(data);
    if (this.pending) {
      this.stats.skipped++;
      if (isKeyframe(view(this.pending))) this.decode(this.pending, { quiet: true });
    }
    this.pending = data;
    this.emit('frameReady');
  }

  /** With pull: decodes the newest frame not yet taken and hands it to onFrame; false when there is none. */
  takeFrame() {
    this.flushGrab();
    const data = this.pending;
    if (!data) return false;
    this.pending = null;
    this.decode(data);
    return true;
  }

  /** @private The decoder an encoding needs (flags bits 0-1): the one given, else its package's. */
  loadCodec(code) {
    const codec = CODECS[code];
    this.codecLoads[code] ??= (async () => {
      this.decodeOptions[codec.option] = await codec.load(this.codecsGiven[codec.option]);
      const data = this.awaitingCodec;
      this.awaitingCodec = null;
      if (data && !this.pull) this.decode(data);
      else if (data && !this.pending) {
        this.pending = data;
        this.emit('frameReady');
      }
    })().catch((e) => this.emit('problem', `${codec.what}: ${e.message}`));
    return this.codecLoads[code];
  }

  /** @private One frame: frame.mjs's decoder (createDecoder) for every encoding it has. */
  decode(data, { quiet = false } = {}) {
    const bytes = view(data);
    const code = bytes.length >= 8 ? bytes[6] & 3 : 0;
    if (CODECS[code] && !this.decodeOptions[CODECS[code].option]) {
      // Decoded once the decoder is there: the newest only, or the keyframe the deltas need.
      if (!this.awaitingCodec || !isKeyframe(view(this.awaitingCodec)) || isKeyframe(bytes)) this.awaitingCodec = data;
      this.loadCodec(code);
      return;
    }
    Object.assign(this.decodeOptions, this.targets);
    const t0 = performance.now();
    let frame;
    try {
      frame = this.decoder.decode(bytes);
      if (quiet) return;
    } catch (e) {
      this.stats.badFrames++;
      return this.emit('problem', `bad frame (${bytes.length} bytes): ${e.message}`);
    }
    const ms = performance.now() - t0;
    const samples = this.stats.decodeMs[frame.encoding];
    if (samples) {
      samples.push(ms);
      if (samples.length > 600) samples.splice(0, samples.length - 300);
    }
    this.stats.decoded++;
    this.emit('frame', frame, ms);
  }
}

/** Whether a frame is a delta keyframe (encoding 3, kind 2; or 0, the first layout's). */
function isKeyframe(bytes) {
  if (bytes.length < HEADER_SIZE + DELTA_HEAD || (bytes[6] & 3) !== 3) return false;
  return isDeltaKeyKind(new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength).getUint32(HEADER_SIZE, true));
}
