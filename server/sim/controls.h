/* controls.h - the commands of the scene itself, not journaled: its run state (pause, resume, a
 * step in progress and its cancel), snapshots, and reads the sim thread makes because they need
 * the engine (the cloth state, the journal bundle). Each runs on the sim thread with the scene's
 * command in c and fills its result (or fails it); 1 when it keeps c to answer later (a step now
 * in progress), else 0. The command table (commands.h) names them. */
#ifndef CLOTHD_CONTROLS_H
#define CLOTHD_CONTROLS_H

#include "sim/scene.h"

int control_pause(scene *sc, scene_cmd *c);
int control_resume(scene *sc, scene_cmd *c);
int control_step(scene *sc, scene_cmd *c);        /* body {frames} | {substeps} */
int control_step_cancel(scene *sc, scene_cmd *c); /* ends the step in progress; result {cancelled, step, frame} */
int control_snapshot_get(scene *sc, scene_cmd *c); /* blob: the snapshot */
int control_snapshot_put(scene *sc, scene_cmd *c); /* blob_in: a snapshot to restore */
int control_cloth_state(scene *sc, scene_cmd *c); /* body {"binary": bool}; blob: the state */
int control_bundle(scene *sc, scene_cmd *c);      /* blob: the journal bundle for clothd replay */
/* Nothing but the publication that follows every command (GET /v1/sim?hash=1, a stream client
 * that wants a pose now). */
int control_publish(scene *sc, scene_cmd *c);
/* The same for a stream whose scene's feed has no pose (its first client joins): the publication
 * that follows hands the sink a pose even when nothing changed since the last one it was handed
 * (the feed forgot that one when its last client left), when the scene is paused: running, its next
 * frame brings one, and a forced one would repeat the frame just handed out. */
int control_pose(scene *sc, scene_cmd *c);

#endif
