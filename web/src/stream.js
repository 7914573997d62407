// stream.js - the WebSocket stream of PROTOCOL.md from the page: finds the port (GET /v1/health),
// subscribes, decodes binary frames (proto/frame.mjs) into arrays the caller lends, passes text
// messages on, sends grabs, and reconnects by itself with backoff when the daemon goes away.
//
// Nothing a server sends can freeze the page: a frame that does not decode, a message that is not
// JSON or of an unknown type, a protocol other than clothd.v1 - each is reported through
// onProblem (shown in the page and logged) and the stream goes on.
import { decodeFrame } from 'clothd/frame';
import { MeshoptDecoder } from 'meshoptimizer';

export const PROTOCOL = 'clothd.v1';
const BACKOFF_MIN_MS = 250, BACKOFF_MAX_MS = 8000;

export class Stream {
  /**
   * @param {import('./api.js').Api} api
   * @param {{onHello, onFrame, onEvent, onMessage, onStatus, onProblem}} handlers
   *   onStatus(state, detail): 'connecting' | 'open' | 'closed'
   */
  constructor(api, handlers) {
    this.api = api;
    this.h = handlers;
    this.subscription = { encoding: 'q16', max_fps: 60, scalar: 'none' };
    this.targets = {};             // {positions, scalar}: arrays frames decode into when they fit
    this.ws = null;
    this.closedByUs = false;
    this.backoff = BACKOFF_MIN_MS;
    this.retryTimer = null;
    this.meshoptReady = false;
    MeshoptDecoder.ready.then(() => { this.meshoptReady = true; }, (e) => this.h.onProblem?.(`meshopt decoder: ${e.message}`));
    this.stats = { frames: 0, decoded: 0, skipped: 0, bytes: 0, badFrames: 0, badMessages: 0, decodeMs: { f32: [], q16: [], meshopt: [] } };
  }

  start() {
    this.closedByUs = false;
    this.connect();
  }

  stop() {
    this.closedByUs = true;
    clearTimeout(this.retryTimer);
    this.ws?.close();
  }

  async connect() {
    clearTimeout(this.retryTimer);
    this.h.onStatus?.('connecting', '');
    let port, path;
    try {
      const health = await this.api.get('/v1/health');
      ({ port, path } = health.stream);
    } catch (e) {
      // 503 (unhealthy) still answers the stream's port; anything else: try again later.
      if (e.problem?.stream) ({ port, path } = e.problem.stream);
      else return this.retry(`no answer from clothd (${e.message})`);
    }
    const url = new URL(location.href);
    url.protocol = location.protocol === 'https:' ? 'wss:' : 'ws:';
    url.port = String(port);
    url.pathname = path || '/stream';
    url.search = '';
    url.hash = '';
    let ws;
    try {
      // The token rides in the subprotocol list (a browser cannot set Authorization on a WebSocket);
      // the server answers with clothd.v1 alone.
      ws = new WebSocket(url.href, this.api.token ? [PROTOCOL, `bearer.${this.api.token}`] : PROTOCOL);
    } catch (e) {
      return this.retry(`cannot open ${url.href}: ${e.message}`);
    }
    ws.binaryType = 'arraybuffer';
    this.ws = ws;
    this.pending = null;
    ws.onopen = () => this.send({ type: 'subscribe', ...this.subscription });
    ws.onmessage = (m) => (m.data instanceof ArrayBuffer ? this.onBinary(m.data) : this.onText(m.data));
    ws.onclose = (e) => {
      if (this.ws !== ws) return;
      this.ws = null;
      if (!this.closedByUs) this.retry(e.reason || `stream closed (${e.code})`);
      else this.h.onStatus?.('closed', 'stopped');
    };
  }

  retry(reason) {
    const wait = Math.round(this.backoff * (0.75 + 0.5 * Math.random()));
    this.backoff = Math.min(this.backoff * 2, BACKOFF_MAX_MS);
    this.h.onStatus?.('closed', `${reason}; reconnecting in ${(wait / 1000).toFixed(1)} s`);
    this.retryTimer = setTimeout(() => this.connect(), wait);
  }

  send(message) {
    if (this.ws?.readyState !== WebSocket.OPEN) return false;
    this.ws.send(JSON.stringify(message));
    return true;
  }

  /** Changes the subscription (any subset of encoding, max_fps, scalar); kept across reconnects. */
  subscribe(change) {
    Object.assign(this.subscription, change);
    this.send({ type: 'subscribe', ...change });
  }

  /** Moves a grabbed vertex; while the socket is still sending, only the newest target goes. */
  grab(vertex, target) {
    this.pendingGrab = { type: 'grab', vertex, target };
    this.flushGrab();
  }

  flushGrab() {
    if (this.pendingGrab && this.ws && this.ws.bufferedAmount < 1024) {
      this.send(this.pendingGrab);
      this.pendingGrab = null;
    }
  }

  release() {
    this.pendingGrab = null;
    this.send({ type: 'release' });
  }

  /** Feeds one message as if it had come from the server (the tests' way to send bad frames). */
  inject(data) {
    if (typeof data === 'string') this.onText(data);
    else this.decode(data);
  }

  onText(text) {
    let m;
    try {
      m = JSON.parse(text);
    } catch {
      this.stats.badMessages++;
      return this.h.onProblem?.(`a stream message is not JSON: ${String(text).slice(0, 80)}`);
    }
    if (m === null || typeof m !== 'object') {
      this.stats.badMessages++;
      return this.h.onProblem?.('a stream message is not a JSON object');
    }
    switch (m.type) {
      case 'hello':
        if (m.protocol !== PROTOCOL) {
          this.h.onProblem?.(`clothd speaks ${m.protocol}, this page ${PROTOCOL}: reload the page after an upgrade`);
          this.ws?.close(4000, 'protocol mismatch');
          return;
        }
        this.backoff = BACKOFF_MIN_MS;
        this.h.onStatus?.('open', '');
        this.h.onHello?.(m);
        return;
      case 'event':
        return this.h.onEvent?.(m);
      case 'subscribed':
      case 'error':
        return this.h.onMessage?.(m);
      default:
        this.stats.badMessages++;
        return this.h.onProblem?.(`unknown stream message type ${JSON.stringify(m.type)}`);
    }
  }

  /**
   * A binary message waits here until the page draws (takeFrame): frames that arrive faster
   * than the page draws are counted and skipped, never decoded.
   */
  onBinary(data) {
    this.lastData = data;
    this.stats.frames++;
    this.stats.bytes += data.byteLength;
    if (this.pending) this.stats.skipped++;
    this.pending = data;
    this.h.onFrameReady?.();
  }

  /** Decodes the newest frame not yet taken and hands it to onFrame; false when there is none. */
  takeFrame() {
    this.flushGrab();
    const data = this.pending;
    if (!data) return false;
    this.pending = null;
    this.decode(data);
    return true;
  }

  decode(data) {
    this.lastBytes = data.byteLength;
    const t0 = performance.now();
    let frame;
    try {
      const bytes = new Uint8Array(data);
      if (bytes.length >= 8 && (bytes[6] & 3) === 2 && !this.meshoptReady) return; // decoder still loading
      frame = decodeFrame(data, { meshopt: MeshoptDecoder, ...this.targets });
    } catch (e) {
      this.stats.badFrames++;
      return this.h.onProblem?.(`bad frame (${data.byteLength} bytes): ${e.message}`);
    }
    const ms = performance.now() - t0;
    const samples = this.stats.decodeMs[frame.encoding];
    samples.push(ms);
    if (samples.length > 600) samples.splice(0, samples.length - 300);
    this.stats.decoded++;
    this.h.onFrame?.(frame, ms);
  }
}
