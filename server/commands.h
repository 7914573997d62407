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
#include "pjson.h"

typedef struct command_limits {
    int32_t max_rocks;
} command_limits;

/* Applies cmd to sim. On success returns 0 with *journal (the complete command, or NULL for
 * none: every op here is journaled) and *result (the response body, without applied_step; NULL
 * for none). On refusal returns -1 with the problem; the simulation is unchanged. */
int command_apply(cs_sim *sim, const json_t *cmd, const command_limits *lim, json_t **journal, json_t **result,
                  problem *pr);

/* Whether an op rebuilds the cloth (the journal starts afresh after it). */
int command_rebuilds(const char *op);

#endif
