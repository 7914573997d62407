// client.js - clothd's HTTP API (proto/PROTOCOL.md, proto/openapi.yaml) from a page or from node
// 20+: one method per route, JSON in and out, the server's answer bodies returned as they are,
// every refusal thrown as an error of errors.js, an X-Request-Id on every request, the bearer
// token (asked for on a 401 when the page gives askToken), and a timeout on every call.
//
// Scenes: the daemon of today runs one scene, `default`, behind the routes without a prefix.
// Every per-scene method lives in SceneRoutes; the client's own are those of `default` (the
// unprefixed routes), and client.scene(id) gives a handle whose methods build
// /v1/scenes/{id}/... paths for any other id. A server without scenes answers those 404
// (NotFound), as it answers scenes(), createScene() and deleteScene(): the server decides, so a
// server that has scenes needs no new client.
import { errorFromAnswer, ConnectionError, ProtocolError, TimeoutError } from './errors.js';
import { Stream, DEFAULT_SCENE, SCENE_ID, checkSceneId } from './stream.js';

export { SCENE_ID };
/** Recording ids the server takes: the scene ids' slug. */
export const RECORDING_ID = SCENE_ID;
/** Throws a TypeError for a recording id the server would refuse (before any request). */
function checkRecordingId(id) {
  if (typeof id !== 'string' || !RECORDING_ID.test(id))
    throw new TypeError(`recording id ${JSON.stringify(id)} is not one clothd takes ([a-z0-9][a-z0-9_-]{0,62})`);
}
/** X-Request-Id values the server echoes. */
export const REQUEST_ID = /^[A-Za-z0-9._:/+=-]{1,128}$/;
export const DEFAULT_TIMEOUT_MS = 30000;

const LITTLE_ENDIAN = new Uint8Array(new Uint16Array([1]).buffer)[0] === 1;

function checkRequestId(id) {
  if (typeof id !== 'string' || !REQUEST_ID.test(id))
    throw new TypeError(`X-Request-Id ${JSON.stringify(id)} is not 1-128 characters of letters, digits and -_.:/+=`);
}

const isBinary = (b) => b instanceof ArrayBuffer || ArrayBuffer.isView(b) || (typeof Blob !== 'undefined' && b instanceof Blob);

/** n x 3 float32 from little-endian bytes. */
function float32s(bytes, offset, count) {
  if (LITTLE_ENDIAN && (bytes.byteOffset + offset) % 4 === 0) return new Float32Array(bytes.buffer, bytes.byteOffset + offset, count).slice();
  const dv = new DataView(bytes.buffer, bytes.byteOffset + offset, 4 * count), out = new Float32Array(count);
  for (let k = 0; k < count; k++) out[k] = dv.getFloat32(4 * k, true);
  return out;
}

/**
 * The routes of one scene. Answers are the server's JSON bodies as PROTOCOL.md describes them;
 * binary answers are Uint8Arrays.
 */
export class SceneRoutes {
  /** @param {Client|null} client @param {string} id */
  constructor(client, id) {
    checkSceneId(id);
    this.client = client;
    /** The scene's id. */
    this.id = id;
    /** Where its routes are: /v1 for `default` (the routes without a prefix), else /v1/scenes/{id}. */
    this.prefix = id === DEFAULT_SCENE ? '/v1' : `/v1/scenes/${id}`;
  }

  /** @private */
  call(method, route, body, options) {
    return this.client.request(method, this.prefix + route, body, options);
  }

  /** GET /sim: state, step, time, energy, real-time factor; `hash: true` computes the state hash. */
  sim({ hash = false } = {}) { return this.call('GET', hash ? '/sim?hash=1' : '/sim'); }
  /** POST /sim/pause: answers as sim(), with the state hash. */
  pause() { return this.call('POST', '/sim/pause'); }
  /** POST /sim/resume. */
  resume() { return this.call('POST', '/sim/resume'); }
  /**
   * POST /sim/step while paused (Conflict while running): `{frames: N}` or `{substeps: N}`. Answers
   * once they ran, or once something ended the step (`interrupted`). No timeout unless the client
   * has a stepTimeout: a long step answers when it is done.
   * @param {{frames: number}|{substeps: number}} [count]
   */
  step(count = { frames: 1 }) { return this.call('POST', '/sim/step', count, { timeout: this.client.options.stepTimeout }); }
  /** DELETE /sim/step: ends the step in progress; `{cancelled, step, frame}`. */
  cancelStep() { return this.call('DELETE', '/sim/step'); }
  /** POST /sim/reset: rebuilds the scene, no rocks, step 0. */
  reset() { return this.call('POST', '/sim/reset'); }

  /** GET /params: every live parameter. */
  params() { return this.call('GET', '/params'); }
  /** PATCH /params: all of `changes` or none; `{applied_step, params}`. */
  setParams(changes) { return this.call('PATCH', '/params', changes); }
  /** GET /params/schema: `{params: [{name, type, unit, default, min, max, choices, kind, help}]}`. */
  paramsSchema() { return this.call('GET', '/params/schema'); }

  /** GET /scene: the scene fields. */
  getScene() { return this.call('GET', '/scene'); }
  /** PUT /scene: any subset of the fields; rebuilds the cloth, clears the rocks, step 0. */
  setScene(fields) { return this.call('PUT', '/scene', fields); }

  /** GET /rocks: `{rocks: [...]}`. */
  rocks() { return this.call('GET', '/rocks'); }
  /** POST /rocks: `{position, radius, velocity?, angular_velocity?, orientation?, density?, kinematic?}` -> `{id, rock, applied_step}`. */
  addRock(rock) { return this.call('POST', '/rocks', rock); }
  /** DELETE /rocks: `{applied_step, removed}`. */
  clearRocks() { return this.call('DELETE', '/rocks'); }
  /** GET /rocks/{id}. */
  rock(id) { return this.call('GET', `/rocks/${encodeURIComponent(id)}`); }
  /** PATCH /rocks/{id}: any fields of addRock's (a teleport keeps the velocity unless given). */
  setRock(id, changes) { return this.call('PATCH', `/rocks/${encodeURIComponent(id)}`, changes); }
  /** DELETE /rocks/{id}. */
  removeRock(id) { return this.call('DELETE', `/rocks/${encodeURIComponent(id)}`); }

  /** PUT /pins: `{preset}` (replaces every pin) or `{vertices: [...], pinned: bool}`; `{pinned, applied_step}`. */
  setPins(pins) { return this.call('PUT', '/pins', pins); }
  /** PUT /grab: pulls `vertex` toward `target` [x, y, z] (the stream's grab() does it without a round trip). */
  grab(vertex, target) { return this.call('PUT', '/grab', { vertex, target }); }
  /** DELETE /grab. */
  release() { return this.call('DELETE', '/grab'); }

  /** GET /cloth/state as JSON: `{step, nx, ny, positions: [[x, y, z], ...], velocities}`. */
  clothState() { return this.call('GET', '/cloth/state'); }
  /**
   * GET /cloth/state in its binary form: `{positions, velocities}`, each a Float32Array of 3 n
   * values in vertex order.
   */
  async clothStateBinary() {
    const bytes = await this.call('GET', '/cloth/state', undefined, { accept: 'application/octet-stream', as: 'bytes' });
    if (bytes.length % 24 !== 0)
      throw new ProtocolError(`the binary cloth state has ${bytes.length} bytes, not 24 per vertex`, { method: 'GET', path: `${this.prefix}/cloth/state` });
    const n = bytes.length / 24;
    return { positions: float32s(bytes, 0, 3 * n), velocities: float32s(bytes, 12 * n, 3 * n) };
  }

  /** GET /snapshot: the whole state as the server's versioned binary (Uint8Array). */
  snapshot() { return this.call('GET', '/snapshot', undefined, { accept: 'application/octet-stream', as: 'bytes' }); }
  /** PUT /snapshot: restores one, or changes nothing; `{applied_step, step, state_hash}`. */
  restoreSnapshot(bytes) { return this.call('PUT', '/snapshot', bytes); }

  /** GET /journal: `{base_step, entries: [{step, command}]}`. */
  journal() { return this.call('GET', '/journal'); }
  /** GET /journal as a replay bundle (Uint8Array) for `clothd replay`. */
  journalBundle() { return this.call('GET', '/journal', undefined, { accept: 'application/octet-stream', as: 'bytes' }); }

  /**
   * Starts a recording of this scene (PROTOCOL.md "Recordings"): POST /v1/recordings for
   * `default`, POST /v1/scenes/{id}/recordings for any other; `scene` records that scene instead
   * of this one. `seconds` of simulated time, `encoding` f32, q16, meshopt or delta (the server's
   * default: delta), `id` the recording's (`[a-z0-9][a-z0-9_-]{0,62}`; generated when absent).
   * Answers 201's `{id, scene, state: "recording", encoding, seconds, frames, bytes}`. A server
   * without recordings answers NotFound; past `max_recordings_mb` Unprocessable.
   * @param {{seconds: number, encoding?: 'f32'|'q16'|'meshopt'|'delta', id?: string, scene?: string}} spec
   */
  record({ seconds, encoding, id, scene } = {}) {
    if (id !== undefined) checkRecordingId(id);
    const body = { seconds };
    if (encoding !== undefined) body.encoding = encoding;
    if (id !== undefined) body.id = id;
    const routes = scene === undefined || scene === this.id ? this : new SceneRoutes(this.client, scene);
    return routes.call('POST', '/recordings', body);
  }

  /**
   * The stream of this scene (stream.js): not connected until start().
   * @param {import('./stream.js').StreamHandlers} [handlers]
   * @param {import('./stream.js').StreamOptions} [options]
   */
  stream(handlers = {}, options = {}) {
    return new Stream(this.client, handlers, { ...options, scene: this.id });
  }
}

/** A handle on one scene of the daemon (client.scene(id)). */
export class Scene extends SceneRoutes {}

/**
 * @typedef {object} ClientOptions
 * @property {string} [base] the server, e.g. http://127.0.0.1:8080 ('' in a page it serves: the page's origin)
 * @property {string|null} [token] the control or view token (Authorization: Bearer)
 * @property {(reason: string) => Promise<string|null>} [askToken] asked for a token on a 401 (or a
 *   403 `forbidden`); the request is sent again with the token it answers, up to 3 times
 * @property {number|null} [timeout] ms for each request, answer included (default 30000; null: none)
 * @property {number|null} [stepTimeout] ms for step() (default null: as long as the step takes)
 * @property {string} [requestIdPrefix] X-Request-Id is `<prefix>-<n>` (default `js-<6 random characters>`)
 * @property {typeof fetch} [fetch] the fetch to use (default globalThis.fetch)
 */

/** The client: the daemon-wide routes, and those of the `default` scene (without a prefix). */
export class Client extends SceneRoutes {
  /** @param {ClientOptions} [options] */
  constructor(options = {}) {
    super(null, DEFAULT_SCENE);
    this.client = this;
    this.base = (options.base ?? '').replace(/\/+$/, '');
    const prefix = options.requestIdPrefix ?? `js-${Math.random().toString(36).slice(2, 8)}`;
    checkRequestId(`${prefix}-1`);
    // Shared with every client withOptions() makes: a token learnt by one is known to all.
    this.shared = { token: options.token ?? null, askToken: options.askToken ?? null, seq: 0, prefix };
    this.options = {
      timeout: options.timeout === undefined ? DEFAULT_TIMEOUT_MS : options.timeout,
      stepTimeout: options.stepTimeout ?? null,
      requestId: null,
    };
    this.fetch = options.fetch ?? globalThis.fetch.bind(globalThis);
  }

  /** The token requests carry (learnt from askToken too), or null. */
  get token() { return this.shared.token; }
  set token(t) { this.shared.token = t; }

  /**
   * The same client with other settings: `{timeout, stepTimeout, requestId}` (requestId: the
   * X-Request-Id every request of the new client carries).
   */
  withOptions(changes) {
    if (changes.requestId != null) checkRequestId(changes.requestId);
    const c = Object.create(Client.prototype);
    Object.assign(c, this, { options: { ...this.options, ...changes } });
    c.client = c;
    return c;
  }

  /** The X-Request-Id of the next request. Events that carry it answer this client's own requests. */
  nextRequestId() { return `${this.shared.prefix}-${++this.shared.seq}`; }
  /** Whether a request id (an event's request_id) is one of this client's. */
  isOwnRequest(id) { return typeof id === 'string' && id.startsWith(`${this.shared.prefix}-`); }

  /** GET /v1/health: `{status, backend, device, version, stream: {port, path, protocol}}` (Unavailable, with the body, when unhealthy). */
  health() { return this.request('GET', '/v1/health'); }
  /** GET /livez: `{status: 'live'}` while the sim thread turns (Unavailable when it has stalled past liveness_timeout). */
  livez() { return this.request('GET', '/livez'); }
  /** GET /readyz: `{status: 'ready', scenes, max_scenes}` (Unavailable while starting or stopping, or with no room for another scene). */
  readyz() { return this.request('GET', '/readyz'); }
  /** GET /metrics: the Prometheus text. */
  metrics() { return this.request('GET', '/metrics', undefined, { as: 'text' }); }

  /** A handle on scene `id`; `default` is the client's own routes. */
  scene(id) { return new Scene(this, id); }
  /** GET /v1/scenes. */
  scenes() { return this.request('GET', '/v1/scenes'); }
  /** POST /v1/scenes `{id?, scene?, params?}`. */
  createScene(spec = {}) {
    if (spec.id !== undefined) checkSceneId(spec.id);
    return this.request('POST', '/v1/scenes', spec);
  }
  /** DELETE /v1/scenes/{id}. */
  deleteScene(id) {
    checkSceneId(id);
    return this.request('DELETE', `/v1/scenes/${id}`);
  }

  /**
   * GET /v1/recordings: `{recordings: [{id, scene, state, encoding, frames, seconds, bytes}]}`
   * (`state` recording, done or stopped; `seconds` the sim time its frames span so far). A
   * server without recordings answers NotFound.
   */
  recordings() { return this.request('GET', '/v1/recordings'); }
  /**
   * GET /v1/recordings/{rid}: the recording's file (CLR1, recording.mjs reads it) as an
   * ArrayBuffer; while it still records, the bytes so far (a file without its index).
   * @param {string} rid @returns {Promise<ArrayBuffer>}
   */
  recording(rid) {
    checkRecordingId(rid); // thrown here, as every id check of the client: before any request
    return this.request('GET', `/v1/recordings/${rid}`, undefined,
      { accept: 'application/vnd.clothd.recording, application/octet-stream', as: 'bytes' })
      .then((bytes) => (bytes.byteOffset === 0 && bytes.byteLength === bytes.buffer.byteLength ? bytes.buffer : bytes.slice().buffer));
  }
  /** DELETE /v1/recordings/{rid}: `{id, deleted: true}` (a running one stops first). */
  deleteRecording(rid) {
    checkRecordingId(rid);
    return this.request('DELETE', `/v1/recordings/${rid}`);
  }

  /**
   * One request. body: an object (sent as JSON) or bytes (ArrayBuffer, a typed array, a Blob).
   * options.as: 'json' (default; null for an empty answer), 'bytes' (Uint8Array) or 'text'.
   * @param {string} method @param {string} path e.g. /v1/sim
   * @param {any} [body]
   * @param {{accept?: string, as?: 'json'|'bytes'|'text', timeout?: number|null, requestId?: string,
   *   signal?: AbortSignal, headers?: Record<string, string>}} [options]
   */
  async request(method, path, body, options = {}) {
    const timeout = options.timeout !== undefined ? options.timeout : this.options.timeout;
    for (let attempt = 0; ; attempt++) {
      const requestId = options.requestId ?? this.options.requestId ?? this.nextRequestId();
      const headers = { 'X-Request-Id': requestId, ...options.headers };
      if (this.token) headers.Authorization = `Bearer ${this.token}`;
      if (options.accept) headers.Accept = options.accept;
      let payload;
      if (isBinary(body)) {
        payload = body;
        headers['Content-Type'] = 'application/octet-stream';
      } else if (body !== undefined) {
        payload = JSON.stringify(body);
        headers['Content-Type'] = 'application/json';
      }
      const ctrl = new AbortController();
      let timedOut = false;
      const timer = timeout == null ? null : setTimeout(() => { timedOut = true; ctrl.abort(); }, timeout);
      const onAbort = () => ctrl.abort(options.signal.reason);
      options.signal?.addEventListener('abort', onAbort, { once: true });
      const info = { method, path, requestId };
      let res, text = null, bytes = null;
      try {
        res = await this.fetch(this.base + path, { method, headers, body: payload, cache: 'no-store', signal: ctrl.signal });
        if (res.ok && options.as === 'bytes') bytes = new Uint8Array(await res.arrayBuffer());
        else text = await res.text();
      } catch (e) {
        if (timedOut) throw new TimeoutError(`${method} ${path}: no answer within ${timeout} ms`, { ...info, cause: e });
        if (options.signal?.aborted) throw e;
        throw new ConnectionError(`${method} ${path}: cannot reach clothd at ${this.base || 'this page\'s origin'} (${e.cause?.message ?? e.message})`, { ...info, cause: e });
      } finally {
        clearTimeout(timer);
        options.signal?.removeEventListener('abort', onAbort);
      }
      if (!res.ok) {
        const error = errorFromAnswer(res.status, res.headers.get('content-type') ?? '', text, {
          ...info, retryAfter: res.headers.get('retry-after'), allow: res.headers.get('allow'),
        });
        const ask = this.shared.askToken && attempt < 3 && (res.status === 401 || (res.status === 403 && error.slug === 'forbidden'));
        if (ask) {
          const token = await this.shared.askToken(error.detail || 'This clothd needs a token.');
          if (token) {
            this.token = token;
            continue;
          }
        }
        throw error;
      }
      if (options.as === 'bytes') return bytes;
      if (options.as === 'text') return text;
      if (!text) return null;
      try {
        return JSON.parse(text);
      } catch {
        throw new ProtocolError(`${method} ${path}: the answer (${res.status}) is not JSON: ${text.slice(0, 80)}`, { ...info, status: res.status, body: text });
      }
    }
  }
}
