// player.js - plays a recording (a CLR1 file, proto/recording.mjs reads it; PROTOCOL.md
// "Recordings") through the page's live drawing path: the hello record goes where a live hello
// goes, the text records (events) where live events go, the frames through the same decoder
// (proto/frame.mjs createDecoder, with the meshopt and zstd decoders the stream uses) to the same
// view. No DOM here.
//
// Seeking to frame k decodes k's keyframe (frames[k].key; itself for f32, q16, meshopt and delta
// keyframes) and then k, and applies the events before k (frames[k].textsBefore): going forward
// only the events not yet applied, going back from the hello again (events are few; no frame in
// between is decoded).
import { readRecording, RecordingError } from 'clothd/recording';
import { createDecoder } from 'clothd/frame';

export { RecordingError };

/** The playback speeds offered (times sim time per wall second). */
export const SPEEDS = [0.25, 0.5, 1, 2, 4];

const CODECS = {
  2: async () => { const { MeshoptDecoder } = await import('meshoptimizer'); await MeshoptDecoder.ready; return ['meshopt', MeshoptDecoder]; },
  3: async () => { const { ZSTDDecoder } = await import('zstddec'); const d = new ZSTDDecoder(); await d.init(); return ['zstd', d]; },
};
let codecsLoaded = null;

/** The decoders the frames of a recording need (flags bits 0-1 of each), loaded once per page. */
async function codecsFor(r) {
  const codes = new Set();
  for (let k = 0; k < r.frames.length; k++) codes.add(r.frame(k)[6] & 3);
  codecsLoaded ??= {};
  const out = {};
  for (const code of codes) {
    if (!CODECS[code]) continue;
    codecsLoaded[code] ??= CODECS[code]();
    const [name, decoder] = await codecsLoaded[code];
    out[name] = decoder;
  }
  return out;
}

export class Player {
  /**
   * Reads a recording's bytes; throws RecordingError (the reader's message, with the offset) for
   * a file that is not one, or one without frames.
   * @param {ArrayBuffer|Uint8Array} bytes
   * @param {{hello(h: object): void, event(e: object): void, frame(f: object): void}} draw the
   *   page's drawing path
   * @param {string} [name] what the page calls it (the file's or the server's name)
   */
  static async open(bytes, draw, name = 'recording') {
    const r = readRecording(bytes);
    if (!r.frames.length) throw new RecordingError(`${name} has no frames${r.complete ? '' : ' (it is cut after its hello)'}`, 16);
    return new Player(r, await codecsFor(r), draw, name);
  }

  constructor(r, codecs, draw, name) {
    this.r = r;
    this.codecs = codecs;
    this.draw = draw;
    this.name = name;
    this.info = r.hello.recording ?? {};
    this.t0 = r.frames[0].simTime;
    this.decoder = createDecoder({ ...codecs });
    this.heldKey = -1;  // the ordinal of the delta keyframe the decoder holds
    this.k = -1;        // the frame shown
    this.texts = 0;     // text records applied (the hello is text 0)
    this.t = 0;         // sim seconds past the first frame, while playing
    this.playing = false;
    this.speed = 1;
  }

  get count() { return this.r.frames.length; }
  get complete() { return this.r.complete; }
  get duration() { return this.r.duration; }
  /** The shown frame's sim time (the daemon's own), and past the first frame. */
  get simTime() { return this.k < 0 ? null : this.r.frames[this.k].simTime; }

  /** Frame k decoded by `decoder`, which holds the delta keyframe of ordinal `held.key`. */
  decodeWith(decoder, held, k) {
    const f = this.r.frames[k];
    if (f.key !== k && held.key !== f.key) {
      decoder.decode(this.r.frame(f.key));
      held.key = f.key;
    }
    const out = decoder.decode(this.r.frame(k));
    if (out.delta?.keyframe) held.key = k;
    return out;
  }

  /** Shows frame k: its events, then the frame. Throws what the decoder throws (a bad frame). */
  show(k) {
    k = Math.max(0, Math.min(this.count - 1, k | 0));
    const f = this.r.frames[k];
    if (this.k < 0 || f.textsBefore < this.texts) {
      this.draw.hello(this.r.hello);
      this.texts = 1;
    }
    for (; this.texts < f.textsBefore; this.texts++) this.draw.event(this.r.text(this.texts));
    const held = { key: this.heldKey };
    const frame = this.decodeWith(this.decoder, held, k);
    this.heldKey = held.key;
    this.k = k;
    this.draw.frame(frame);
    return frame;
  }

  /** Moves to frame k (the timeline), playing on from there when playing. */
  seek(k) {
    const frame = this.show(k);
    this.t = this.r.frames[this.k].simTime - this.t0;
    return frame;
  }

  play() {
    if (this.k >= this.count - 1) this.seek(0); // at the end: from the start
    this.playing = true;
  }

  pause() { this.playing = false; }

  /**
   * Advances playback by `dt` wall seconds at `speed`; answers whether the shown frame changed.
   * At the last frame playback stops there.
   */
  tick(dt) {
    if (!this.playing) return false;
    this.t += dt * this.speed;
    if (this.t >= this.duration) {
      this.t = this.duration;
      this.playing = false;
    }
    const k = this.r.seek(this.t);
    if (k === this.k) return false;
    this.show(k);
    return true;
  }

  /**
   * The positions of frames from..to (from, from + stride, ... up to to), each its own array, with
   * their sim times: decoded by a decoder of their own (the shown frame stays as it is).
   * @returns {{positions: Float32Array[], times: number[], ordinals: number[]}}
   */
  framesOf(from, to, stride = 1) {
    const decoder = createDecoder({ ...this.codecs }), held = { key: -1 };
    const positions = [], times = [], ordinals = [];
    for (let k = from; k <= to; k += stride) {
      const f = this.decodeWith(decoder, held, k);
      positions.push(f.positions);
      times.push(f.simTime);
      ordinals.push(k);
    }
    return { positions, times, ordinals };
  }
}
