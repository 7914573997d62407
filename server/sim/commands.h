/* commands.h - the commands that change the simulation, as JSON objects {"op": ..., ...}.
 *
 * A request arrives as a partial command (a patch of parameters, of a rock); command_apply merges
 * it with the current state, applies it to the engine and returns the complete command - the one
 * the journal keeps - so applying a journaled command again (clothd replay) does exactly the same.
 *
 * ops that change the state: params {params}, scene {scene}, reset, rock_add {rock},
 * rock_set {id, rock}, rock_remove {id}, rocks_clear, pins {preset} | {vertices, pinned},
 * grab {vertex, target}, release. scene and reset rebuild the cloth (step 0). */
#ifndef CLOTHD_COMMANDS_H
#define CLOTHD_COMMANDS_H

#include <jansson.h>

#include "clothsim/clothsim.h"
#include "core/problem.h"
#include "core/settings.h"

/* Applies cmd to sim and loop (the scene's daemon-loop settings: a params command sets them too).
 * On success returns 0 with *journal (the complete command, or NULL for
 * none: every op here is journaled) and *result (the response body, without applied_step; NULL
 * for none). On refusal returns -1 with the problem; the simulation is unchanged. The engine's
 * own limits hold (cs_sim_set_rock_limit: max_rocks; rock ids; the memory limit). */
int command_apply(cs_sim *sim, loop_settings *loop, const json_t *cmd, json_t **journal, json_t **result, problem *pr);

/* Whether an op rebuilds the cloth (the journal starts afresh after it). */
int command_rebuilds(const char *op);

/* The command an API request makes of its body (len bytes, any Content-Type; see
 * request_body_object): params {params: body} (PATCH /v1/params), scene {scene: body},
 * rock_add {rock: body}, rock_set {id, rock: body}, pins and grab {the body's members}, and
 * rock_remove {id}, rocks_clear, reset, release with an empty body or {}. id is the {id} of the
 * path (rock_set, rock_remove). What can be checked without the simulation is checked here (a
 * bad body, a params patch of unknown names or wrong types); command_apply checks the rest on
 * the sim thread. 0 with *cmd (a new reference), or -1 with the problem. */
int command_from_request(const char *op, const char *body, size_t len, long long id, json_t **cmd, problem *pr);

/* The body of POST /v1/sim/step: {"frames": N} or {"substeps": N}, N from 1 to 100000. 0 with
 * *frames (1 for frames, 0 for substeps) and *n, or -1 with the problem. */
int step_from_json(const json_t *body, int *frames, long long *n, problem *pr);

#endif
