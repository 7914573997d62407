// clothd-client: the HTTP API (client.js), the stream (stream.js), the errors (errors.js), the
// frame and recording decoders (frame.mjs, recording.mjs) and the exports of recordings to USD and
// MCAP (recording-export.js) of clothd, for pages and node. See clients/js/README.md.
export * from './errors.js';
export { Client, Scene, SceneRoutes, SCENE_ID, RECORDING_ID, REQUEST_ID, DEFAULT_TIMEOUT_MS } from './client.js';
export { Stream, PROTOCOL, DEFAULT_SCENE, SCENE_DELETED, BACKOFF_MIN_MS, BACKOFF_MAX_MS } from './stream.js';
export { exportUsd, exportMcap, UsdWriter, safeStem } from './recording-export.js';
export { decodeFrame, createDecoder, ENCODINGS, HEADER_SIZE } from './frame.mjs';
export { readRecording, buildRecording, RecordingError } from './recording.mjs';
