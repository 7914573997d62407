/* json_read.h - reading the values of a request's JSON, each with the problem (400 or 422) that
 * says what is wrong when it does not fit. */
#ifndef CLOTHD_JSON_READ_H
#define CLOTHD_JSON_READ_H

#include <stddef.h>

#include <jansson.h>

#include "core/problem.h"

/* A request body as a JSON object, whatever its Content-Type: required, or optional (then an
 * empty or blank body means {} and no member may be given). 0 with *out (a new reference), or -1
 * with the problem: 400, or 422 naming the field of a bare NaN, Infinity or 1e999 (not JSON). */
int request_body_object(const char *body, size_t len, int required, json_t **out, problem *pr);

/* A vector of three finite numbers that fit a float. */
int vec3_from_json(const json_t *v, float out[3], const char *name, problem *pr);
/* A whole number in [lo, hi]. */
int int_from_json(const json_t *v, double lo, double hi, const char *name, long long *out, problem *pr);
/* Members of obj must all be in `allowed` (NULL-terminated); else 400 naming the first other. */
int only_fields(const json_t *obj, const char *const *allowed, problem *pr);
/* Whether id is a scene id: [a-z0-9][a-z0-9_-]{0,62} (so 63 characters at most). */
int scene_id_valid(const char *id);
/* The scene the routes without a scene prefix address, the one the daemon starts with, and the
 * one a state file of the formats before 4 holds. */
#define SCENE_DEFAULT "default"
/* "an object", "a number", ...: what a value is, for a reason. */
const char *json_type_word(const json_t *v);

#endif
