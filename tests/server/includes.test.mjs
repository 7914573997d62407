// includes.test.mjs - no include cycle among the modules of server/ (a .c file and its .h are one
// module; scripts/include-cycles.mjs says how includes are resolved), and the check itself finds
// the cycles it is for: two modules that include each other's headers through their rooms, three
// in a ring; and none in a layered tree, or where a module includes its own header.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdirSync, writeFileSync } from 'node:fs';
import { dirname, join } from 'node:path';
import { cycles, dependencies } from '../../scripts/include-cycles.mjs';
import { tempDir } from './harness.mjs';

function tree(files) {
  const root = tempDir();
  for (const [name, text] of Object.entries(files)) {
    mkdirSync(dirname(join(root, name)), { recursive: true });
    writeFileSync(join(root, name), text);
  }
  return root;
}

test('no include cycle among the modules of server/', () => {
  const deps = dependencies(join(process.env.CLOTHD_SOURCE, 'server'));
  assert.ok(deps.size > 20, 'the modules were found');
  assert.ok(deps.get('sim/scene').has('core/journal'), 'includes through the rooms were resolved');
  assert.deepEqual(cycles(deps), []);
});

test('the rooms are layered: core/ includes none of the others, sim/ only core/', () => {
  const deps = dependencies(join(process.env.CLOTHD_SOURCE, 'server'));
  for (const [m, on] of deps) {
    const rooms = new Set([...on].map((d) => d.split('/')[0]));
    if (m.startsWith('core/')) assert.deepEqual([...rooms].filter((r) => r !== 'core'), [], m);
    if (m.startsWith('sim/')) assert.deepEqual([...rooms].filter((r) => r !== 'core' && r !== 'sim'), [], m);
  }
});

test('the check finds a cycle, and nothing where there is none', () => {
  // sim/loop.c includes stream/out.h, stream/out.c includes sim/loop.h: the cycle clothd had.
  assert.deepEqual(cycles(dependencies(tree({
    'sim/loop.c': '#include "sim/loop.h"\n#include "stream/out.h"\n', 'sim/loop.h': '',
    'stream/out.c': '#include <stdio.h>\n#include "stream/out.h"\n#include "sim/loop.h"\n', 'stream/out.h': '',
  }))), [['sim/loop', 'stream/out', 'sim/loop']]);
  // Three in a ring, the includes written beside the file.
  assert.deepEqual(cycles(dependencies(tree({
    'a.h': '#include "b.h"\n', 'b.h': '#include "c.h"\n', 'c.c': '#include "a.h"\n', 'c.h': '',
  }))), [['a', 'b', 'c', 'a']]);
  assert.deepEqual(cycles(dependencies(tree({ 'self.h': '#include "self.h"\n' }))), []); // a module's own
  // A layered tree, a header included from two rooms, an include outside the tree: none.
  assert.deepEqual(cycles(dependencies(tree({
    'core/base.h': '', 'core/base.c': '#include "core/base.h"\n', 'sim/top.c': '#include "core/base.h"\n#include "clothsim/x.h"\n',
    'http/h.c': '#include "core/base.h"\n#include "sim/top.h"\n', 'sim/top.h': '#include "core/base.h"\n',
  }))), []);
});
