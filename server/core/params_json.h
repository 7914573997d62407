/* params_json.h - the rows of the settings table (settings.h) to and from the API's JSON: the
 * parameters (GET and PATCH /v1/params), the scene fields (GET and PUT /v1/scene), the
 * daemon-loop settings alone (the state file's trailer) and the schema (GET /v1/params/schema). */
#ifndef CLOTHD_PARAMS_JSON_H
#define CLOTHD_PARAMS_JSON_H

#include <jansson.h>

#include "core/problem.h"
#include "core/settings.h"

/* One row's value as JSON: number, integer, true/false, choice name, [x, y, z] or string. */
json_t *setting_to_json(const setting *s, const void *field);
/* Every row of a kind (scene or live) as one object. */
json_t *params_to_json(setting_kind kind, const scene_config *sc);
/* Applies the members of obj to sc: only rows of kind `kind`; unknown names and the wrong kind are
 * 400, wrong JSON types 400, values out of range 422. All or nothing: on failure sc is unchanged. */
int params_from_json(const json_t *obj, setting_kind kind, scene_config *sc, problem *pr);

/* The daemon-loop settings as one object, and back: members of obj onto *loop, all or nothing -
 * a name that is not a daemon-loop setting is 400, a value out of range 422. */
json_t *loop_to_json(const loop_settings *loop);
int loop_from_json(const json_t *obj, loop_settings *loop, problem *pr);

/* {params: [{name, type, unit, default, min, max, choices, kind, help}]}: the settings table. */
json_t *schema_to_json(void);

#endif
