#!/usr/bin/env node
// include-cycles.mjs - finds include cycles among the modules of a C tree (server/ by default).
//
// A module is a .c file and its .h (core/scene.c and core/scene.h are the module core/scene). A
// module depends on another when one of its files includes the other's header; a cycle is a path
// of such dependencies back to where it started - simloop.c including stream.h while stream.c
// includes simloop.h is one - and every cycle found is reported. An include is resolved as the
// compiler does: beside the including file, then at the tree's root (the include path the
// daemon's build gives); anything else (system headers, clothsim/, proto/) is outside the tree.
//
//   node scripts/include-cycles.mjs [DIR]    exit 0 when there is none, 1 listing each
import { existsSync, readdirSync, readFileSync } from 'node:fs';
import { dirname, join, relative } from 'node:path';
import { fileURLToPath } from 'node:url';

const module = (file) => file.replace(/\.[ch]$/, '');

// {module: Set of modules it depends on} for the .c and .h files under root.
export function dependencies(root) {
  const files = readdirSync(root, { recursive: true }).map(String).filter((f) => /\.[ch]$/.test(f));
  const deps = new Map(files.map((f) => [module(f), new Set()]));
  for (const f of files) {
    for (const [, inc] of readFileSync(join(root, f), 'utf8').matchAll(/^\s*#\s*include\s+"([^"]+)"/gm)) {
      const beside = relative(root, join(root, dirname(f), inc));
      const hit = [beside, inc].find((p) => !p.startsWith('..') && existsSync(join(root, p)));
      if (hit && module(hit) !== module(f)) deps.get(module(f)).add(module(hit));
    }
  }
  return deps;
}

// The cycles of a dependency map: each as the list of modules along it, its first repeated last
// (one per strongly connected component of more than one module, or a module that depends on itself).
export function cycles(deps) {
  let index = 0;
  const at = new Map(), low = new Map(), stack = [], on = new Set(), found = [];
  const visit = (v) => {
    at.set(v, index);
    low.set(v, index++);
    stack.push(v);
    on.add(v);
    for (const w of deps.get(v) ?? []) {
      if (!at.has(w)) {
        visit(w);
        low.set(v, Math.min(low.get(v), low.get(w)));
      } else if (on.has(w)) {
        low.set(v, Math.min(low.get(v), at.get(w)));
      }
    }
    if (low.get(v) !== at.get(v)) return;
    const component = [];
    for (let w = null; w !== v;) {
      w = stack.pop();
      on.delete(w);
      component.push(w);
    }
    if (component.length > 1 || deps.get(v)?.has(v)) found.push(path(deps, component));
  };
  for (const v of deps.keys()) if (!at.has(v)) visit(v);
  return found;
}

// One cycle through a component, as a path from its first module back to it.
function path(deps, component) {
  const inside = new Set(component), start = [...component].sort()[0];
  const seen = new Map([[start, null]]), queue = [start];
  while (queue.length) {
    const v = queue.shift();
    for (const w of deps.get(v)) {
      if (w === start) {
        const back = [start];
        for (let u = v; u !== null; u = seen.get(u)) back.push(u);
        return back.reverse();
      }
      if (inside.has(w) && !seen.has(w)) {
        seen.set(w, v);
        queue.push(w);
      }
    }
  }
  return [start, start];
}

if (process.argv[1] === fileURLToPath(import.meta.url)) {
  const root = process.argv[2] ?? join(dirname(fileURLToPath(import.meta.url)), '..', 'server');
  const found = cycles(dependencies(root));
  for (const c of found) console.log(`include cycle: ${c.join(' -> ')}`);
  if (!found.length) console.log(`no include cycle among the modules of ${root}`);
  process.exit(found.length ? 1 : 0);
}
