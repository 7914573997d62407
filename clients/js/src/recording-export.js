// recording-export.js - a clothd recording (CLR1, recording.mjs) into the tools people use
// (DESIGN section 10): USD text (.usda: Blender, Houdini, Omniverse) and MCAP (Foxglove,
// Lichtblick). Both stream: frames are decoded one at a time and each is written to the sink and
// dropped, so a long recording exports without the file in memory (the recording itself is held,
// as recording.mjs reads it).
//
//   const r = await exportUsd(bytes, sink, { triangles });   // sink: {write(string)} (may return a promise)
//   const r = await exportMcap(bytes, writable, { triangles }); // writable: @mcap/core's IWritable
//   r -> {frames, written, cut, problem, timeCodes: [first, last]}
//
// `triangles(nx, ny, torn)` is the viewer's rule (web/src/topology.js triangleIndices: two
// triangles per grid quad, drawn while their springs are intact; PROTOCOL.md "hello").
//
// A cut recording (no index) or one corrupt past its hello exports up to its last whole frame and
// says so (`cut`, `problem`); a recording without frames is an Error. The USD layer: UsdWriter
// below; MCAP: one channel `/clothd/<scene>` of foxglove.SceneUpdate, JSON-encoded with
// @foxglove/schemas' JSON Schema (exportMcap below). docs/using.md has both for users.
import { readRecording, RecordingError } from './recording.mjs';
import { createDecoder } from './frame.mjs';

export { RecordingError };

const CODECS = {
  2: async (given) => ['meshopt', given ?? await (async () => { const d = (await import('meshoptimizer')).MeshoptDecoder; await d.ready; return d; })()],
  3: async (given) => ['zstd', given ?? await (async () => { const d = new (await import('zstddec')).ZSTDDecoder(); await d.init(); return d; })()],
};

/** The decoders the frames of `r` need ({zstd, meshopt}; given ones are used, the rest imported). */
async function codecsFor(r, given = {}) {
  const codes = new Set();
  for (let k = 0; k < r.frames.length; k++) codes.add(r.frame(k)[6] & 3);
  const out = {};
  for (const code of codes) {
    if (!CODECS[code]) continue;
    const [name, d] = await CODECS[code](given[code === 2 ? 'meshopt' : 'zstd']);
    out[name] = d;
  }
  return out;
}

/** A name safe as a file name's stem: [A-Za-z0-9._-] kept, the rest `_`, no leading dot, 1..64 chars. */
export function safeStem(name, fallback = 'recording') {
  const s = String(name ?? '').replace(/[^A-Za-z0-9._-]+/g, '_').replace(/^[.]+/, '_').slice(0, 64);
  return s && s !== '_' ? s : fallback;
}

/**
 * Each frame's time code: its sim time past the first, in frames of `rate` (integral for frames a
 * frame period apart), going on by one frame where the sim time goes back (a reset, a scene or a
 * snapshot restored between two frames), so that time codes never decrease.
 */
function timeCodes(r, rate) {
  const out = new Float64Array(r.frames.length);
  let sum = 0;
  for (let k = 1; k < out.length; k++) {
    const d = (r.frames[k].simTime - r.frames[k - 1].simTime) * rate;
    sum += d >= 0 ? d : 1;
    out[k] = Math.round(sum * 1e6) / 1e6;
  }
  return out;
}

/**
 * The frames of a recording, decoded one at a time, with the cloth's topology at each: a
 * generator of {k, frame, timeCode, topology: {nx, ny, torn: Set, version}} (timeCodes above). A
 * frame followed by one at the same time code is skipped (the later wins: a command between two
 * frames). Stops quietly at a frame that does not decode, setting `state.problem`.
 */
function* framesOf(r, decoder, tcs, state) {
  const hello = r.hello;
  const topo = { nx: hello.scene.nx | 0, ny: hello.scene.ny | 0, torn: new Set(hello.torn ?? []), version: 0 };
  let texts = 1, heldKey = -1;
  const tc = (k) => tcs[k];
  const apply = (ev) => {
    if (ev.type !== 'event') return;
    const set = (scene, torn) => {
      topo.nx = scene?.nx | 0 || topo.nx;
      topo.ny = scene?.ny | 0 || topo.ny;
      topo.torn = new Set(torn ?? []);
      topo.version++;
    };
    switch (ev.event) {
      case 'scene': set(ev.result, []); break;
      case 'reset': set(null, []); break;
      case 'snapshot_restored': set(ev.scene, ev.torn); break;
      case 'torn': {
        const before = topo.torn.size;
        for (const id of ev.springs ?? []) topo.torn.add(id);
        if (topo.torn.size !== before) topo.version++;
        break;
      }
      default: break;
    }
  };
  for (let k = 0; k < r.frames.length; k++) {
    const f = r.frames[k];
    let frame;
    try {
      for (; texts < f.textsBefore; texts++) apply(r.text(texts));
      if (f.key !== k && heldKey !== f.key) {
        decoder.decode(r.frame(f.key));
        heldKey = f.key;
      }
      frame = decoder.decode(r.frame(k));
      if (f.key === k) heldKey = k;
    } catch (e) {
      state.problem = `frame ${k} does not decode (${e.message}): exported the ${k} frames before it`;
      return;
    }
    state.decoded = k + 1;
    const t = tc(k);
    if (k + 1 < r.frames.length && tc(k + 1) === t) continue;
    yield { k, frame, timeCode: t, topology: topo };
  }
}

/**
 * Reads a recording for export: whole or up to its last whole frame; an Error when it has none.
 * `input` is the file's bytes, or what readRecording made of them (the viewer's player has it).
 */
function open(input) {
  const r = typeof input?.frame === 'function' && Array.isArray(input.frames) ? input : readRecording(input, { salvage: true });
  if (!r.frames.length) {
    throw new RecordingError(`the recording has no frames${r.problem ? ` (${r.problem})` : r.complete ? '' : ' (it is cut after its hello)'}: nothing to export`, 16);
  }
  const rate = Number(r.info.frame_rate) > 0 ? Number(r.info.frame_rate) : Number(r.hello.params?.frame_rate) > 0 ? Number(r.hello.params.frame_rate) : 60;
  return { r, rate };
}

function outcome(r, state, written, first, last) {
  const problems = [];
  if (r.problem) problems.push(r.problem); // (a reading without salvage has none)
  if (!r.complete && !r.problem) problems.push(`the recording is cut (no index): exported the ${r.frames.length} whole frames it has`);
  if (state.problem) problems.push(state.problem);
  return { frames: state.decoded, written, cut: problems.length > 0, problem: problems.join('; ') || null, timeCodes: [first, last] };
}

// ---- numbers ----

/**
 * A float32 value as the first of its 7, 8 and 9 significant digits (trailing zeros dropped) that
 * reads back to the same float32: `Math.fround(Number(f32(x))) === x` for every float32 x.
 */
export function f32(x) {
  if (x === 0) return Object.is(x, -0) ? '-0' : '0';
  if (!Number.isFinite(x)) return Number.isNaN(x) ? 'nan' : x > 0 ? 'inf' : '-inf';
  let s = x.toPrecision(7);
  if (Math.fround(Number(s)) !== x) {
    s = x.toPrecision(8);
    if (Math.fround(Number(s)) !== x) s = x.toPrecision(9);
  }
  return trimZeros(s);
}

/** "1.500000" -> "1.5", "2.000000e-7" -> "2e-7", "100.0000" -> "100". */
function trimZeros(s) {
  const dot = s.indexOf('.');
  if (dot < 0) return s;
  let e = s.indexOf('e');
  if (e < 0) e = s.length;
  let end = e;
  while (s.charCodeAt(end - 1) === 48) end--; // '0'
  if (end - 1 === dot) end--;
  return end === e ? s : s.slice(0, end) + s.slice(e);
}

/**
 * A string as a USD string literal: double-quoted, UTF-8, with `\\ \" \n \t \r` escaped; other
 * control characters become U+FFFD (parsers differ on `\x` escapes).
 */
export function usdString(s) {
  const esc = { '\\': '\\\\', '"': '\\"', '\n': '\\n', '\t': '\\t', '\r': '\\r' };
  return `"${String(s).replace(/[\\"\u0000-\u001f\u007f]/g, (c) => esc[c] ?? '\ufffd')}"`;
}

// ---- USD ----

/**
 * Writes USD text (.usda) one frame at a time. The layer: `upAxis = "Z"`, `metersPerUnit = 1`,
 * `timeCodesPerSecond`, start/endTimeCode; `/clothd` (Xform, the default prim) holds `cloth` (Mesh:
 * time-sampled `points` written as each frame comes; `faceVertexCounts`/`faceVertexIndices`
 * time-sampled at the first frame and where the topology changes; `extent` per frame) and a
 * `rock_<id>` Xform per rock (time-sampled `xformOp:translate` and `xformOp:orient`, quatf real
 * first; `visibility` where it comes and goes) over a Sphere `sphere` of its radius. USD wants an
 * attribute's samples together: the points go to the sink as they come; the small rest (rock
 * poses, 32 bytes a rock a frame; the springs torn at each change; extents) is kept until end().
 */
export class UsdWriter {
  /**
   * @param {{write(s: string): void|Promise<void>}} sink
   * @param {{timeCodesPerSecond: number, startTimeCode: number, endTimeCode: number, doc?: string,
   *   triangles: (nx: number, ny: number, torn: Set<number>) => Uint32Array, customData?: Object<string, string>}} meta
   */
  constructor(sink, meta) {
    this.sink = sink;
    this.meta = meta;
    this.triangles = meta.triangles;
    this.topology = []; // {tc, nx, ny, full: number[]|null, added: number[]}
    this.last = null;   // {nx, ny, torn: Set, version}
    this.rocks = new Map(); // id -> {radius, tcs: number[], poses: number[] (7 each), vis: [tc, visible][] }
    this.extents = [];
    this.present = new Set();
    this.first = null;
    this.lastTc = null;
    this.count = 0;
  }

  async begin() {
    const m = this.meta;
    const data = Object.entries(m.customData ?? {}).map(([k, v]) => `        string ${/^[A-Za-z_][A-Za-z0-9_]*$/.test(k) ? k : 'key'} = ${usdString(v)}\n`).join('');
    await this.sink.write(`#usda 1.0
(
    defaultPrim = "clothd"
    doc = ${usdString(m.doc ?? 'clothd recording')}
    endTimeCode = ${m.endTimeCode}
    metersPerUnit = 1
    startTimeCode = ${m.startTimeCode}
    timeCodesPerSecond = ${m.timeCodesPerSecond}
    upAxis = "Z"
)

def Xform "clothd" (
    customData = {
${data}    }
)
{
    def Mesh "cloth"
    {
        uniform bool doubleSided = 1
        uniform token subdivisionScheme = "none"
        point3f[] points.timeSamples = {
`);
  }

  /**
   * One frame: its positions go to the sink now.
   * @param {number} tc its time code (increasing)
   * @param {Float32Array} positions 3 per vertex
   * @param {{nx: number, ny: number, torn: Set<number>, version: number}} topology
   * @param {{id: number, position: number[], radius: number, orientation: number[]}[]} rocks
   */
  async frame(tc, positions, topology, rocks) {
    if (this.lastTc !== null && !(tc > this.lastTc)) throw new Error(`time code ${tc} after ${this.lastTc}`);
    this.first ??= tc;
    this.lastTc = tc;
    this.count++;
    const parts = new Array(positions.length / 3);
    let lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
    for (let v = 0, p = 0; p < positions.length; v++, p += 3) {
      const x = positions[p], y = positions[p + 1], z = positions[p + 2];
      parts[v] = `(${f32(x)}, ${f32(y)}, ${f32(z)})`;
      if (x < lo[0]) lo[0] = x; if (x > hi[0]) hi[0] = x;
      if (y < lo[1]) lo[1] = y; if (y > hi[1]) hi[1] = y;
      if (z < lo[2]) lo[2] = z; if (z > hi[2]) hi[2] = z;
    }
    if (!parts.length) lo = hi = [0, 0, 0];
    this.extents.push(tc, ...lo, ...hi);
    this.noteTopology(tc, topology);
    this.noteRocks(tc, rocks);
    await this.sink.write(`            ${tc}: [${parts.join(', ')}],\n`);
  }

  noteTopology(tc, t) {
    const last = this.last;
    if (last && last.version === t.version && last.nx === t.nx && last.ny === t.ny) return;
    let full = null, added = [];
    if (!last || last.nx !== t.nx || last.ny !== t.ny || [...last.torn].some((id) => !t.torn.has(id))) full = [...t.torn];
    else for (const id of t.torn) if (!last.torn.has(id)) added.push(id);
    this.last = { nx: t.nx, ny: t.ny, torn: new Set(t.torn), version: t.version };
    if (full || added.length) this.topology.push({ tc, nx: t.nx, ny: t.ny, full, added });
  }

  noteRocks(tc, rocks) {
    const now = new Set();
    for (const r of rocks) {
      now.add(r.id);
      let rock = this.rocks.get(r.id);
      if (!rock) this.rocks.set(r.id, rock = { radius: r.radius, tcs: [], poses: [], vis: this.first === tc ? [] : [[this.first, false]] });
      if (!this.present.has(r.id) && rock.vis.length) rock.vis.push([tc, true]);
      rock.tcs.push(tc);
      const [x, y, z] = r.position, [qx, qy, qz, qw] = r.orientation;
      rock.poses.push(x, y, z, qw, qx, qy, qz);
    }
    for (const id of this.present) if (!now.has(id)) this.rocks.get(id).vis.push([tc, false]);
    this.present = now;
  }

  async end() {
    const w = (s) => this.sink.write(s);
    await w('        }\n');
    const ext = this.extents;
    let s = '        float3[] extent.timeSamples = {\n';
    for (let k = 0; k < ext.length; k += 7)
      s += `            ${ext[k]}: [(${f32(ext[k + 1])}, ${f32(ext[k + 2])}, ${f32(ext[k + 3])}), (${f32(ext[k + 4])}, ${f32(ext[k + 5])}, ${f32(ext[k + 6])})],\n`;
    await w(s + '        }\n');
    // The topology at each change, rebuilt from the springs torn since the one before.
    for (const which of ['faceVertexCounts', 'faceVertexIndices']) {
      await w(`        int[] ${which}.timeSamples = {\n`);
      let torn = new Set();
      for (const c of this.topology) {
        if (c.full) torn = new Set(c.full);
        for (const id of c.added) torn.add(id);
        const tri = this.triangles(c.nx, c.ny, torn);
        await w(`            ${c.tc}: [${which === 'faceVertexCounts' ? new Array(tri.length / 3).fill(3).join(', ') : tri.join(', ')}],\n`);
      }
      await w('        }\n');
    }
    await w('    }\n');
    for (const [id, rock] of [...this.rocks].sort((a, b) => a[0] - b[0])) {
      const translate = [], orient = [];
      for (let k = 0; k < rock.tcs.length; k++) {
        const p = rock.poses, at = 7 * k;
        translate.push(`            ${rock.tcs[k]}: (${f32(p[at])}, ${f32(p[at + 1])}, ${f32(p[at + 2])}),\n`);
        orient.push(`            ${rock.tcs[k]}: (${f32(p[at + 3])}, ${f32(p[at + 4])}, ${f32(p[at + 5])}, ${f32(p[at + 6])}),\n`);
      }
      const vis = rock.vis.length
        ? `        token visibility.timeSamples = {\n${rock.vis.map(([t, v]) => `            ${t}: "${v ? 'inherited' : 'invisible'}",\n`).join('')}        }\n`
        : '';
      const r = f32(rock.radius);
      await w(`
    def Xform "rock_${id >>> 0}"
    {
        float3 xformOp:translate.timeSamples = {
${translate.join('')}        }
        quatf xformOp:orient.timeSamples = {
${orient.join('')}        }
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:orient"]
${vis}
        def Sphere "sphere"
        {
            float3[] extent = [(-${r}, -${r}, -${r}), (${r}, ${r}, ${r})]
            double radius = ${r}
        }
    }
`);
    }
    await w('}\n');
  }
}

/**
 * A recording as USD text, streamed to `sink`.
 * @param {ArrayBuffer|ArrayBufferView|object} bytes the .clr file (whole, or as much as there is),
 *   or recording.mjs readRecording's result
 * @param {{write(s: string): void|Promise<void>}} sink
 * @param {{triangles: Function, codecs?: {zstd?: object, meshopt?: object}}} options
 * @returns {Promise<{frames: number, written: number, cut: boolean, problem: string|null, timeCodes: number[]}>}
 *   frames: decoded; written: time samples (frames at one time code count once)
 */
export async function exportUsd(bytes, sink, options) {
  if (typeof options?.triangles !== 'function') throw new TypeError('exportUsd needs options.triangles (web/src/topology.js triangleIndices)');
  const { r, rate } = open(bytes);
  const decoder = createDecoder(await codecsFor(r, options.codecs));
  const tcs = timeCodes(r, rate);
  const end = tcs[tcs.length - 1];
  const info = r.info;
  const writer = new UsdWriter(sink, {
    timeCodesPerSecond: rate, startTimeCode: 0, endTimeCode: end, triangles: options.triangles,
    doc: `clothd recording ${info.id ?? ''} of scene ${info.scene ?? r.hello.scene_id ?? ''}`,
    customData: { recording: String(info.id ?? ''), scene: String(info.scene ?? r.hello.scene_id ?? ''), encoding: String(info.encoding ?? '') },
  });
  await writer.begin();
  const state = { decoded: 0, problem: null };
  for (const { frame, timeCode, topology } of framesOf(r, decoder, tcs, state)) {
    await writer.frame(timeCode, frame.positions, topology, frame.rocks);
  }
  await writer.end();
  // A cut export ends earlier than the header said: the header keeps the recording's span (USD
  // holds the last sample), the result says where it stopped.
  return outcome(r, state, writer.count, writer.first, writer.lastTc);
}

// ---- MCAP ----

/** The foxglove.SceneUpdate JSON Schema, from @foxglove/schemas. */
async function sceneUpdateSchema() {
  const m = await import('@foxglove/schemas/jsonschema.js');
  return (m.default ?? m).SceneUpdate;
}

/**
 * A recording as MCAP: one channel `/clothd/<scene>` (the scene's id, characters outside
 * [A-Za-z0-9_-] as `_`) of foxglove.SceneUpdate messages, JSON-encoded (message encoding `json`,
 * schema encoding `jsonschema`, the schema of @foxglove/schemas), one per frame at log and publish
 * time `started_ns` + the frame's sim time past the first (its time code in seconds): entity
 * `cloth` (a TriangleListPrimitive of the intact triangles, indexed) and entity `rock-<id>` per rock (a SpherePrimitive, size =
 * diameter), in frame `clothd` (z up, metres); a rock that goes is deleted. Chunks are compressed
 * with zstd (@foxglove/wasm-zstd, level 3) where that package imports, else not
 * (`compression: 'none'` asks for none; `'zstd'` fails without it).
 * @param {ArrayBuffer|ArrayBufferView|object} bytes the file, or readRecording's result
 * @param {{write(buffer: Uint8Array): Promise<unknown>, position(): bigint}} writable @mcap/core's IWritable
 * @param {{triangles: Function, codecs?: object, compression?: 'zstd'|'none'}} options
 */
export async function exportMcap(bytes, writable, options) {
  if (typeof options?.triangles !== 'function') throw new TypeError('exportMcap needs options.triangles (web/src/topology.js triangleIndices)');
  const { r, rate } = open(bytes);
  const decoder = createDecoder(await codecsFor(r, options.codecs));
  const { McapWriter } = await import('@mcap/core');
  const schema = await sceneUpdateSchema();
  let compressChunk;
  if (options.compression !== 'none') {
    try {
      const m = await import('@foxglove/wasm-zstd');
      const zstd = m.default ?? m;
      await zstd.isLoaded;
      compressChunk = (data) => ({ compression: 'zstd', compressedData: zstd.compress(data, 3) });
    } catch (e) {
      if (options.compression === 'zstd') throw e;
    }
  }
  const writer = new McapWriter({ writable, compressChunk, useStatistics: true, useChunks: true, useChunkIndex: true, useMessageIndex: true });
  await writer.start({ profile: '', library: 'clothd' });
  const schemaId = await writer.registerSchema({ name: 'foxglove.SceneUpdate', encoding: 'jsonschema', data: new TextEncoder().encode(JSON.stringify(schema)) });
  const scene = String(r.info.scene ?? r.hello.scene_id ?? 'default');
  const channelId = await writer.registerChannel({
    schemaId, topic: `/clothd/${scene.replace(/[^A-Za-z0-9_-]/g, '_') || 'scene'}`, messageEncoding: 'json',
    metadata: new Map([['recording', String(r.info.id ?? '')], ['scene', scene]]),
  });
  const started = Number(r.info.started_ns); // a JSON number: to the double nearest, 256 ns apart now
  const base = BigInt(Number.isFinite(started) && started > 0 ? Math.trunc(started) : 0);
  const tcs = timeCodes(r, rate);
  const state = { decoded: 0, problem: null };
  const enc = new TextEncoder();
  let tri = null, triVersion = -1, triDims = '', written = 0, first = null, last = null, seq = 0;
  let present = new Set();
  for (const { frame, timeCode, topology: topo } of framesOf(r, decoder, tcs, state)) {
    const ns = base + BigInt(Math.round((timeCode / rate) * 1e9));
    const stamp = { sec: Number(ns / 1000000000n), nsec: Number(ns % 1000000000n) };
    if (topo.version !== triVersion || `${topo.nx}x${topo.ny}` !== triDims) {
      tri = Array.from(options.triangles(topo.nx, topo.ny, topo.torn));
      triVersion = topo.version;
      triDims = `${topo.nx}x${topo.ny}`;
    }
    const p = frame.positions, points = new Array(p.length / 3);
    for (let v = 0; v < points.length; v++) points[v] = { x: p[3 * v], y: p[3 * v + 1], z: p[3 * v + 2] };
    const entity = (id, extra) => ({ timestamp: stamp, frame_id: 'clothd', id, lifetime: { sec: 0, nsec: 0 }, frame_locked: false, metadata: [],
      arrows: [], cubes: [], spheres: [], cylinders: [], lines: [], triangles: [], texts: [], models: [], ...extra });
    const identity = { position: { x: 0, y: 0, z: 0 }, orientation: { x: 0, y: 0, z: 0, w: 1 } };
    const entities = [entity('cloth', { triangles: [{ pose: identity, points, color: { r: 0.78, g: 0.33, b: 0.24, a: 1 }, colors: [], indices: tri }] })];
    const now = new Set();
    for (const rock of frame.rocks) {
      now.add(rock.id);
      const [x, y, z] = rock.position, [qx, qy, qz, qw] = rock.orientation, d = 2 * rock.radius;
      entities.push(entity(`rock-${rock.id >>> 0}`, { spheres: [{ pose: { position: { x, y, z }, orientation: { x: qx, y: qy, z: qz, w: qw } },
        size: { x: d, y: d, z: d }, color: { r: 0.85, g: 0.64, b: 0.25, a: 1 } }] }));
    }
    const deletions = [...present].filter((id) => !now.has(id)).map((id) => ({ timestamp: stamp, type: 0, id: `rock-${id >>> 0}` }));
    present = now;
    await writer.addMessage({ channelId, sequence: seq++, logTime: ns, publishTime: ns, data: enc.encode(JSON.stringify({ deletions, entities })) });
    written++;
    first ??= Number(ns - base) / 1e9;
    last = Number(ns - base) / 1e9;
  }
  await writer.end();
  return { ...outcome(r, state, written, first, last), compression: compressChunk ? 'zstd' : 'none' };
}
