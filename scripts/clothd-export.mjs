#!/usr/bin/env node
// clothd-export.mjs - a clothd recording (.clr) as USD text or MCAP, no daemon needed
// (clients/js/src/recording-export.js; docs/using.md "Recordings"):
//
//   node scripts/clothd-export.mjs run.clr run.usda     # Blender, Houdini, Omniverse
//   node scripts/clothd-export.mjs run.clr run.mcap     # Foxglove, Lichtblick
//   node scripts/clothd-export.mjs run.clr out/ [--format usd|mcap]   # out/<recording id>.usda
//
// The format is the output's extension (.usda/.usd or .mcap) or --format. Into a directory, the
// file is named after the recording's id with every character outside [A-Za-z0-9._-] as `_`.
// The file is written as <out>.part and renamed when done. Exit status: 0 exported whole; 3
// exported up to the last whole frame of a cut or corrupt recording (stderr says where it
// stopped); 1 nothing exported (not a recording, no frames, a write failed); 2 usage.
import { createWriteStream, readFileSync, statSync, renameSync, rmSync } from 'node:fs';
import { open } from 'node:fs/promises';
import { once } from 'node:events';
import { basename, join } from 'node:path';
import { exportUsd, exportMcap, safeStem } from '../clients/js/src/recording-export.js';
import { triangleIndices } from '../web/src/topology.js';

const EXT = { usd: '.usda', mcap: '.mcap' };
const usage = () => {
  process.stderr.write('usage: clothd-export.mjs RECORDING.clr OUT.usda|OUT.mcap|DIR [--format usd|mcap]\n');
  process.exit(2);
};

const args = process.argv.slice(2);
let format = null;
const fi = args.indexOf('--format');
if (fi >= 0) {
  format = args[fi + 1];
  args.splice(fi, 2);
  if (!EXT[format]) usage();
}
if (args.length !== 2) usage();
const [input, output] = args;

let bytes;
try {
  bytes = readFileSync(input);
} catch (e) {
  process.stderr.write(`clothd-export: ${input}: ${e.message}\n`);
  process.exit(1);
}
let out = output;
let isDir = false;
try { isDir = statSync(output).isDirectory(); } catch { /* a new file */ }
if (!format) format = /\.mcap$/i.test(output) ? 'mcap' : /\.usda?$/i.test(output) ? 'usd' : isDir ? 'usd' : null;
if (!format) {
  process.stderr.write(`clothd-export: ${output}: name it .usda or .mcap, or say --format usd|mcap\n`);
  process.exit(2);
}
if (isDir) {
  // The recording's own name, escaped: it never leaves the directory.
  let id = null;
  try {
    const { readRecording } = await import('../proto/recording.mjs');
    id = readRecording(bytes, { salvage: true }).info.id;
  } catch { /* the export below says what is wrong */ }
  out = join(output, safeStem(id ?? basename(input).replace(/\.clr$/i, '')) + EXT[format]);
}
const part = `${out}.part`;

async function usd() {
  const stream = createWriteStream(part);
  const failed = once(stream, 'error').then(([e]) => { throw e; });
  const sink = { write: (s) => (stream.write(s) ? undefined : Promise.race([once(stream, 'drain'), failed])) };
  const result = await exportUsd(bytes, sink, { triangles: triangleIndices });
  stream.end();
  await Promise.race([once(stream, 'finish'), failed]);
  return result;
}

async function mcap() {
  const file = await open(part, 'w');
  let position = 0n;
  const writable = {
    position: () => position,
    write: async (buffer) => { await file.write(buffer); position += BigInt(buffer.byteLength); },
  };
  try {
    return await exportMcap(bytes, writable, { triangles: triangleIndices });
  } finally {
    await file.close();
  }
}

let result;
try {
  result = await (format === 'mcap' ? mcap() : usd());
} catch (e) {
  rmSync(part, { force: true });
  process.stderr.write(`clothd-export: ${input}: ${e.message}\n`);
  process.exit(1);
}
renameSync(part, out);
const what = `${out}: ${result.written} frames (of ${result.frames} decoded)`;
if (result.cut) {
  process.stderr.write(`clothd-export: warning: ${result.problem}\n${what}\n`);
  process.exit(3);
}
process.stdout.write(`${what}\n`);
