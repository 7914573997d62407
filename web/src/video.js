// video.js - frames drawn one by one encoded as a WebM video: WebCodecs' VideoEncoder (VP9, or
// VP8 where the browser has no VP9 encoder) and webm-muxer's WebM writer (an npm package, served
// as vendor/webm-muxer.mjs like the page's other packages). Frame j of the video carries the
// timestamp j / fps whatever the wall clock did while it was drawn, so a recording stepped frame
// by frame becomes a video of its frames at its own frame rate.

/** The codecs tried, best first: WebCodecs' codec string and the WebM CodecID. */
const CODECS = [['vp09.00.10.08', 'V_VP9'], ['vp8', 'V_VP8']];

/** Says, in a sentence, why this browser cannot encode the video; null when it can (so far as asked). */
export function webCodecsMissing() {
  if (typeof VideoEncoder === 'undefined' || typeof VideoFrame === 'undefined')
    return 'this browser has no WebCodecs (VideoEncoder, VideoFrame): the video export needs Chromium 94+, Firefox 130+ or Safari 16.4+, in a secure context (https or localhost)';
  return null;
}

/**
 * Encodes `count` frames into one WebM. `draw(j)` draws frame j and answers the canvas holding it,
 * read in the same task (a WebGL canvas keeps its drawing only until the task ends).
 * @param {{count: number, fps: number, draw(j: number): HTMLCanvasElement, progress?(j: number): void,
 *   bitrate?: number}} o
 * @returns {Promise<{bytes: ArrayBuffer, codec: string, width: number, height: number, frames: number}>}
 */
export async function encodeWebm({ count, fps, draw, progress, bitrate }) {
  const missing = webCodecsMissing();
  if (missing) throw new Error(missing);
  if (!(count >= 1)) throw new Error('no frames to encode');
  if (!(fps > 0)) throw new Error(`no frame rate (${fps})`);
  const { Muxer, ArrayBufferTarget } = await import('webm-muxer');

  // The size of the first frame, made even (VP8/VP9 want it; the frames are cropped to it). It is
  // drawn again below: its drawing is gone after the awaits in between.
  const first = draw(0);
  const width = first.width & ~1, height = first.height & ~1;
  if (width < 2 || height < 2) throw new Error(`the canvas is too small to encode (${first.width} x ${first.height})`);
  const base = { width, height, framerate: fps, bitrate: bitrate ?? Math.round(Math.min(8e6, width * height * fps * 0.1)), latencyMode: 'quality' };
  let chosen = null;
  for (const [codec, webm] of CODECS) {
    const { supported } = await VideoEncoder.isConfigSupported({ ...base, codec }).catch(() => ({ supported: false }));
    if (supported) { chosen = { config: { ...base, codec }, webm }; break; }
  }
  if (!chosen) throw new Error("this browser's WebCodecs has no VP9 or VP8 encoder for WebM");

  const target = new ArrayBufferTarget();
  const muxer = new Muxer({ target, video: { codec: chosen.webm, width, height, frameRate: fps } });
  let failed = null;
  const encoder = new VideoEncoder({
    output: (chunk, meta) => muxer.addVideoChunk(chunk, meta),
    error: (e) => { failed ??= e; },
  });
  encoder.configure(chosen.config);
  const step = 1e6 / fps; // microseconds
  try {
    for (let j = 0; j < count; j++) {
      if (failed) throw failed;
      const canvas = draw(j);
      const frame = new VideoFrame(canvas, {
        timestamp: Math.round(j * step), duration: Math.round(step),
        visibleRect: { x: 0, y: 0, width, height },
      });
      encoder.encode(frame, { keyFrame: j % Math.max(1, Math.round(fps)) === 0 }); // a keyframe a second
      frame.close();
      progress?.(j);
      // Not too far ahead of the encoder: each queued frame holds a copy of the canvas.
      while (encoder.encodeQueueSize > 4 && !failed)
        await new Promise((r) => { encoder.addEventListener('dequeue', r, { once: true }); setTimeout(r, 50); });
    }
    await encoder.flush();
    if (failed) throw failed;
  } finally {
    if (encoder.state !== 'closed') encoder.close();
  }
  muxer.finalize();
  return { bytes: target.buffer, codec: chosen.config.codec, width, height, frames: count };
}
