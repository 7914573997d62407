/* changes.h - the commands that change the simulation and are journaled, as JSON objects
 * {"op": ..., ...}: what each does to the engine and to the daemon-loop settings.
 *
 * A request arrives as a partial command (a patch of parameters, of a rock); a change merges it
 * with the current state, applies it and returns the complete command - the one the journal
 * keeps - so applying a journaled command again (clothd replay) does exactly the same.
 *
 *   params {params}                   PATCH /v1/params (the engine's and the daemon-loop settings)
 *   scene {scene}                     PUT /v1/scene (rebuilds the cloth: step 0)
 *   reset                             POST /v1/sim/reset (rebuilds the cloth: step 0)
 *   rock_add {rock[, by]}             POST /v1/rocks (by: "auto" for an automatic drop)
 *   rock_set {id, rock}               PATCH /v1/rocks/{id}
 *   rock_remove {id[, by]}            DELETE /v1/rocks/{id}
 *   rocks_clear                       DELETE /v1/rocks
 *   pins {preset} | {vertices, pinned}  PUT /v1/pins
 *   grab {vertex, target}, release    PUT and DELETE /v1/grab, and the stream's grab and release
 *
 * Each has the same signature: on success 0 with *journal (the complete command) and *result
 * (the answer's body, without applied_step); on refusal -1 with the problem, and the engine and
 * loop as they were. The engine's own limits hold (cs_sim_set_rock_limit: max_rocks; rock ids;
 * the memory limit). The command table (commands.h) names them; command_apply finds one by op. */
#ifndef CLOTHD_CHANGES_H
#define CLOTHD_CHANGES_H

#include <jansson.h>

#include "clothsim/clothsim.h"
#include "core/problem.h"
#include "core/settings.h"

#define CHANGE_ARGS cs_sim *sim, loop_settings *loop, const json_t *cmd, json_t **journal, json_t **result, problem *pr
int change_params(CHANGE_ARGS);
int change_scene(CHANGE_ARGS);
int change_reset(CHANGE_ARGS);
int change_rock_add(CHANGE_ARGS);
int change_rock_set(CHANGE_ARGS);
int change_rock_remove(CHANGE_ARGS);
int change_rocks_clear(CHANGE_ARGS);
int change_pins(CHANGE_ARGS);
int change_grab(CHANGE_ARGS);
int change_release(CHANGE_ARGS);
#undef CHANGE_ARGS

#endif
