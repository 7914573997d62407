#!/usr/bin/env node
// check-links.mjs - every relative link in the repository's Markdown leads somewhere (ctest docs.links).
//   node scripts/check-links.mjs [FILE.md ...]
// Reads the Markdown files git knows (tracked, or new and not ignored; or the files named) and fails when a
// relative link's file does not exist, or its #anchor matches no heading of the target Markdown
// file. Anchors follow GitHub's slugs: the heading's text lowercased, inline Markdown (code ticks,
// emphasis, links) reduced to its text, every character but letters, digits, spaces, '-' and '_'
// dropped, spaces turned to '-', and a repeated slug numbered (-1, -2, ...). Links inside code
// (fenced blocks, `spans`) are not links; http(s), mailto and other schemes are not checked.
// Node 18+, no dependencies.
import { execFileSync } from 'node:child_process';
import { existsSync, readdirSync, readFileSync, statSync } from 'node:fs';
import { dirname, join, relative, resolve } from 'node:path';
import { fileURLToPath } from 'node:url';

const root = resolve(dirname(fileURLToPath(import.meta.url)), '..');

function trackedMarkdown() {
  let out;
  try {
    out = execFileSync('git', ['ls-files', '-z', '--cached', '--others', '--exclude-standard', '--', '*.md'],
      { cwd: root, encoding: 'utf8', stdio: ['ignore', 'pipe', 'ignore'] }).split('\0');
  } catch {
    out = walk(''); // not a git checkout (a source archive): every .md outside builds and packages
  }
  return out.filter((f) => f && !f.split('/').includes('node_modules')).sort();
}

function walk(dir) {
  const found = [];
  for (const e of readdirSync(join(root, dir), { withFileTypes: true })) {
    const rel = dir ? `${dir}/${e.name}` : e.name;
    if (e.isDirectory()) {
      if (!/^(\.|node_modules$|build)/.test(e.name)) found.push(...walk(rel));
    } else if (/\.md$/i.test(e.name)) found.push(rel);
  }
  return found;
}

// The text outside fenced code blocks, line by line (a fenced line becomes empty, so line numbers hold).
function prose(text) {
  const lines = text.split('\n');
  let fence = null;
  return lines.map((line) => {
    const m = /^ {0,3}(`{3,}|~{3,})/.exec(line);
    if (fence) {
      if (m && m[1][0] === fence[0] && m[1].length >= fence.length && /^\s*$/.test(line.slice(m.index + m[0].length))) fence = null;
      return '';
    }
    if (m) { fence = m[1]; return ''; }
    return line;
  });
}

export function slug(heading) {
  const text = heading
    .replace(/!?\[([^\]]*)\]\([^)]*\)/g, '$1') // links and images: their text
    .replace(/<[^>]+>/g, '') // inline HTML tags
    .replace(/[`*]/g, '') // code ticks, emphasis (underscores are kept, as GitHub keeps them)
    .trim()
    .toLowerCase();
  return text.replace(/[^\p{L}\p{N}\p{M} _-]/gu, '').replace(/ /g, '-');
}

const anchorCache = new Map();
function anchors(file) {
  if (anchorCache.has(file)) return anchorCache.get(file);
  const seen = new Map();
  const set = new Set();
  for (const line of prose(readFileSync(file, 'utf8'))) {
    const m = /^ {0,3}#{1,6}\s+(.*?)\s*#*\s*$/.exec(line);
    if (!m) continue;
    const base = slug(m[1]);
    const n = seen.get(base) ?? 0;
    seen.set(base, n + 1);
    set.add(n === 0 ? base : `${base}-${n}`);
  }
  for (const line of prose(readFileSync(file, 'utf8'))) {
    // explicit anchors: <a name="x"> or id="x"
    for (const m of line.matchAll(/<a\s+(?:name|id)="([^"]+)"/g)) set.add(m[1]);
  }
  anchorCache.set(file, set);
  return set;
}

// [text](target) and [text](target "title"), and reference definitions [id]: target.
function links(line) {
  const found = [];
  const bare = line.replace(/`[^`]*`/g, (s) => ' '.repeat(s.length)); // code spans are not links
  for (const m of bare.matchAll(/\]\(\s*<?([^)\s>]*)>?(?:\s+"[^"]*")?\s*\)/g)) found.push(m[1]);
  const def = /^ {0,3}\[[^\]]+\]:\s*<?(\S+?)>?(\s|$)/.exec(bare);
  if (def) found.push(def[1]);
  return found;
}

function check(files) {
  const problems = [];
  let count = 0;
  for (const rel of files) {
    const file = resolve(root, rel);
    const lines = prose(readFileSync(file, 'utf8'));
    lines.forEach((line, i) => {
      for (const target of links(line)) {
        if (!target || /^[a-z][a-z0-9+.-]*:/i.test(target)) continue; // http:, mailto:, ...
        count++;
        const hash = target.indexOf('#');
        const path = decodeURI(hash < 0 ? target : target.slice(0, hash));
        const anchor = hash < 0 ? null : decodeURIComponent(target.slice(hash + 1));
        const where = `${relative(root, file)}:${i + 1}`;
        const dest = path === '' ? file : path.startsWith('/') ? join(root, path) : resolve(dirname(file), path);
        if (!existsSync(dest)) {
          problems.push(`${where}: ${target}: no such file ${relative(root, dest)}`);
          continue;
        }
        if (anchor === null || anchor === '') continue;
        if (statSync(dest).isDirectory() || !/\.md$/i.test(dest)) {
          if (/^L\d+(-L\d+)?$/.test(anchor)) continue; // a line of a source file
          problems.push(`${where}: ${target}: #${anchor} in a file that is not Markdown`);
          continue;
        }
        if (!anchors(dest).has(anchor)) {
          problems.push(`${where}: ${target}: no heading "#${anchor}" in ${relative(root, dest)}`);
        }
      }
    });
  }
  return { problems, count };
}

const files = process.argv.length > 2 ? process.argv.slice(2) : trackedMarkdown();
const { problems, count } = check(files);
for (const p of problems) console.error(p);
if (problems.length) {
  console.error(`check-links: ${problems.length} broken of ${count} relative links in ${files.length} files`);
  process.exit(1);
}
console.log(`check-links: ${count} relative links in ${files.length} files, all found`);
