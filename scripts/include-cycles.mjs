#!/usr/bin/env node
// include-cycles.mjs - finds include and call cycles among the modules of a C tree (server/ by
// default).
//
// A module is a .c file and its .h (core/scene.c and core/scene.h are the module core/scene), and
// with a header the .c files that define the functions it declares: including a header is calling
// what it declares, wherever that is defined. So a header with no .c of its own (rectap.h, a room's
// private header like recordings_internal.h) belongs to the modules that implement it, and those
// are one module (sim/recordings.c, rec_tap.c, rec_writer.c, rec_adopt.c, recordings.h,
// recordings_internal.h and rectap.h are the module sim/recordings, named after its first member
// with both a .c and a .h). A header that declares no function (sink.h: types, and a table of
// function pointers that another module fills in) is a module of its own: nothing is called
// through it.
//
// A module depends on another when one of its files includes the other's header; a cycle is a
// path of such dependencies back to where it started - simloop.c including stream.h while
// stream.c includes simloop.h is one, and so is scene.c including rectap.h (functions that
// rec_tap.c defines) while recordings.h includes scene.h - and every cycle found is reported. An
// include is resolved as the compiler does: beside the including file, then at the tree's root
// (the include path the daemon's build gives); anything else (system headers, clothsim/, proto/)
// is outside the tree. Declarations and definitions are found at file scope, comments, literals
// and preprocessor lines left out; static functions are no module's to give.
//
//   node scripts/include-cycles.mjs [DIR]    exit 0 when there is none, 1 listing each
import { existsSync, readdirSync, readFileSync } from 'node:fs';
import { dirname, join, relative } from 'node:path';
import { fileURLToPath } from 'node:url';

const module = (file) => file.replace(/\.[ch]$/, '');

// C text without its comments, string and character literals and preprocessor lines.
function code(text) {
  return text
    .replace(/\/\*[\s\S]*?\*\/|\/\/[^\n]*|"(?:\\.|[^"\\\n])*"|'(?:\\.|[^'\\\n])*'/g, (m) => (m[0] === '"' || m[0] === "'" ? '""' : ' '))
    .replace(/^[ \t]*#(?:[^\n]*\\\n)*[^\n]*/gm, '');
}

// The statements at file scope, each with what it had between braces left out, and whether a
// brace block followed it (a function's body, a struct's members, an initializer).
function fileScope(text) {
  const out = [];
  let depth = 0, cur = '';
  for (const ch of code(text)) {
    if (ch === '{') {
      if (depth++ === 0) out.push({ text: cur, block: true }), (cur = '');
    } else if (ch === '}') {
      depth = Math.max(0, depth - 1);
    } else if (depth === 0) {
      if (ch === ';') out.push({ text: cur, block: false }), (cur = '');
      else cur += ch;
    }
  }
  return out;
}

const notNames = new Set(['if', 'for', 'while', 'switch', 'return', 'sizeof', '_Alignof', '_Static_assert',
  '__attribute__', '__declspec', '__typeof__', 'typeof', '_Generic']);

const local = (statement) => /\b(typedef|static)\b/.test(statement);

// The function a prototype declares: the first identifier followed by its parameters (not a
// pointer to a function, `(*name)`; attributes may follow), or null.
function declaredName(statement) {
  if (local(statement) || /^\s*extern\s*""/.test(statement)) return null;
  for (const [, name] of statement.matchAll(/([A-Za-z_]\w*)\s*\(/g)) if (!notNames.has(name)) return name;
  return null;
}

// The functions a header declares (prototypes at file scope, not static).
function declared(text) {
  return fileScope(text).filter((st) => !st.block).map((st) => declaredName(st.text)).filter(Boolean);
}

// The functions a .c file defines (not static): a statement at file scope that ends with a name
// and its parameter list, a body following.
function defined(text) {
  const head = /([A-Za-z_]\w*)\s*\((?:[^()]|\([^()]*\))*\)\s*$/;
  return fileScope(text).filter((st) => st.block && !local(st.text)).map((st) => head.exec(st.text)?.[1])
    .filter((name) => name && !notNames.has(name));
}

// {module: Set of modules it depends on} for the .c and .h files under root; its `members` maps
// each module to its files.
export function dependencies(root) {
  const files = readdirSync(root, { recursive: true }).map(String).filter((f) => /\.[ch]$/.test(f)).sort();
  const text = new Map(files.map((f) => [f, readFileSync(join(root, f), 'utf8')]));
  const has = new Set(files);

  // Modules joined through the functions their headers declare and their .c files define.
  const parent = new Map(files.map((f) => [module(f), module(f)]));
  const find = (m) => (parent.get(m) === m ? m : find(parent.get(m)));
  const definers = new Map();
  for (const f of files.filter((f) => f.endsWith('.c')))
    for (const name of defined(text.get(f))) definers.set(name, [...(definers.get(name) ?? []), module(f)]);
  for (const h of files.filter((f) => f.endsWith('.h')))
    for (const name of declared(text.get(h)))
      for (const m of definers.get(name) ?? []) parent.set(find(module(h)), find(m));

  // Each module named after its first member with both a .c and a .h, else its first member.
  const groups = new Map();
  for (const m of parent.keys()) groups.set(find(m), [...(groups.get(find(m)) ?? []), m]);
  const name = new Map(), members = new Map();
  for (const group of groups.values()) {
    const whole = group.filter((m) => has.has(`${m}.c`) && has.has(`${m}.h`));
    const called = (whole.length ? whole : group)[0];
    for (const m of group) name.set(m, called);
    members.set(called, files.filter((f) => group.includes(module(f))));
  }

  const deps = new Map([...members.keys()].map((m) => [m, new Set()]));
  for (const f of files) {
    for (const [, inc] of text.get(f).matchAll(/^\s*#\s*include\s+"([^"]+)"/gm)) {
      const beside = relative(root, join(root, dirname(f), inc));
      const hit = [beside, inc].find((p) => !p.startsWith('..') && existsSync(join(root, p)));
      const [from, to] = [name.get(module(f)), hit && name.get(module(hit))];
      if (to && to !== from) deps.get(from).add(to);
    }
  }
  deps.members = members;
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
  const deps = dependencies(root);
  const found = cycles(deps);
  for (const c of found) {
    console.log(`include cycle: ${c.join(' -> ')}`);
    for (const m of new Set(c))
      if (deps.members.get(m).length > 2) console.log(`  ${m} is ${deps.members.get(m).join(', ')}`);
  }
  if (!found.length) console.log(`no include cycle among the modules of ${root}`);
  process.exit(found.length ? 1 : 0);
}
