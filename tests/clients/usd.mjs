// usd.mjs - TinyUSDZ (npm tinyusdz, a maintained C++ USD parser built to WebAssembly) for the
// tests that read the USD the exporters write: the stage it evaluates and the layer it parsed.
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { createRequire } from 'node:module';

// TinyUSDZ's npm build is made for browsers (emscripten -sENVIRONMENT=web): it is loaded here with
// the wasm bytes given and node hidden from its environment check for the moment it starts.
const require = createRequire(import.meta.url);
export async function tinyusdz() {
  const path = require.resolve('tinyusdz/tinyusdz.js');
  const hadWindow = 'window' in globalThis, type = process.type;
  globalThis.window = globalThis;
  process.type = 'renderer';
  try {
    const { default: init } = await import(path);
    return await init({ wasmBinary: readFileSync(path.replace(/\.js$/, '.wasm')) });
  } finally {
    process.type = type;
    if (!hadWindow) delete globalThis.window;
  }
}

/** What TinyUSDZ makes of a .usda: its stage (evaluated) and the layer as it prints it back. */
export function parseUsd(usd, bytes) {
  const stage = new usd.TinyUSDZLoaderNative();
  assert.ok(stage.loadFromBinary(bytes, 'export.usda'), `TinyUSDZ refuses the file: ${stage.error()}`);
  const layer = new usd.TinyUSDZLoaderNative();
  assert.ok(layer.loadAsLayerFromBinary(bytes, 'export.usda'), `TinyUSDZ refuses the layer: ${layer.error()}`);
  return { stage, text: layer.layerToString() };
}

/**
 * The time samples of `attr` in TinyUSDZ's print of the layer: Map time -> the value's numbers.
 * (A reading of TinyUSDZ's output, not of the exporter's: its numbers are the ones it parsed.)
 */
export function samples(text, attr) {
  const at = text.indexOf(`${attr}.timeSamples = {`);
  assert.ok(at >= 0, `no ${attr}.timeSamples in TinyUSDZ's layer`);
  const body = text.slice(text.indexOf('{', at) + 1, text.indexOf('\n        }', at));
  const out = new Map();
  for (const line of body.split('\n')) {
    const m = /^\s*([-0-9.e+]+):\s*(.*?),?\s*$/.exec(line);
    if (m) out.set(Number(m[1]), (m[2].match(/-?(?:\d+\.?\d*|\.\d+)(?:e[-+]?\d+)?|"[a-z]+"/gi) ?? []).map((x) => (x[0] === '"' ? x.slice(1, -1) : Number(x))));
  }
  return out;
}
