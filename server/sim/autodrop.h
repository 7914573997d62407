/* autodrop.h - the automatic drops of the default scene: every auto_drop_interval simulated
 * seconds a rock of a random size falls onto the cloth (or is thrown at a hanging one), the
 * oldest going once auto_drop_max are there. The spots come from a splitmix64 sequence seeded
 * with `seed`, restarted whenever the cloth is rebuilt, a snapshot restored or the seed changed
 * (scene_reseed), so the same settings drop the same rocks. Each drop is a journaled command
 * ("by": "auto"), which is how clothd replay repeats it. */
#ifndef CLOTHD_AUTODROP_H
#define CLOTHD_AUTODROP_H

#include "sim/scene.h"

/* After a frame of sc: a drop, when one is due (the sim thread). */
void autodrop_after_frame(scene *sc);

#endif
