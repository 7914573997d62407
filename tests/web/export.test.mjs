// export.test.mjs - the animated export's frame cap (web/src/export.js), in node: how many frames
// one file takes and which, worked out by hand from its two limits (600 frames; 128 MiB of morph
// targets at 12 bytes per vertex).
// Run: node --test tests/web/export.test.mjs
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { animationCap, animationStride, MAX_ANIMATION_FRAMES } from '../../web/src/export.js';

test('the cap: 600 frames, fewer where 128 MiB of targets runs out first', () => {
  assert.equal(MAX_ANIMATION_FRAMES, 600);
  assert.equal(animationCap(64 * 64), 600);            // 600 x 49 152 B = 28 MiB
  assert.equal(animationCap(128 * 128), 600);          // 600 x 196 608 B = 112.5 MiB
  assert.equal(animationCap(256 * 256), 170);          // 134 217 728 / 786 432 = 170.67
  assert.equal(animationCap(4096 * 4096), 2);          // never fewer than two frames
});

test('the stride: every frame while they fit, else every n-th from the first', () => {
  const taken = (count, n) => {
    const s = animationStride(count, n);
    return { s, frames: Math.floor((count - 1) / s) + 1 };
  };
  assert.deepEqual(taken(1, 4096), { s: 1, frames: 1 });
  assert.deepEqual(taken(600, 4096), { s: 1, frames: 600 });
  assert.deepEqual(taken(601, 4096), { s: 2, frames: 301 }); // 0, 2, .., 600
  assert.deepEqual(taken(1200, 4096), { s: 3, frames: 400 });
  assert.deepEqual(taken(600, 256 * 256), { s: 4, frames: 150 }); // 599 / 169 -> 4
  assert.deepEqual(taken(171, 256 * 256), { s: 2, frames: 86 });
  assert.deepEqual(taken(170, 256 * 256), { s: 1, frames: 170 });
});
