/* pjson.h - JSON for the API: parameters and rocks to and from JSON (driven by the parameter
 * table), problem details (RFC 9457), and the mapping of engine statuses to HTTP. */
#ifndef CLOTHD_PJSON_H
#define CLOTHD_PJSON_H

#include <jansson.h>

#include "clothsim/clothsim.h"
#include "settings.h"

/* Floats print with 9 significant digits: enough to round-trip a float32, and short. */
#define PJSON_DUMP_FLAGS (JSON_COMPACT | JSON_REAL_PRECISION(9))

/* An RFC 9457 problem: HTTP status, a type slug (urn:clothd:problem:<slug>), title, detail, and
 * the offending parameter when there is one. */
typedef struct problem {
    int status;
    const char *slug;
    char detail[300];
    char param[64];
} problem;

/* Fills a problem and returns -1 (for `return fail(...)`). */
int problem_set(problem *pr, int status, const char *slug, const char *param, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 5, 6)))
#endif
    ;
const char *problem_title(const char *slug);
/* The problem+json body. */
char *problem_body(const problem *pr);
/* The problem for a refused engine call (its status, error text and parameter). */
int problem_from_engine(problem *pr, cs_status st, const char *error, const char *param);

/* A request body as a JSON object, whatever its Content-Type: required, or optional (then an
 * empty or blank body means {} and no member may be given). 0 with *out (a new reference), or -1
 * with the problem (400). */
int request_body_object(const char *body, size_t len, int required, json_t **out, problem *pr);

/* A JSON string of s without the bytes that are not part of well-formed UTF-8 (jansson refuses
 * the whole string otherwise). Texts that quote a client's input are cut to a fixed size (a
 * problem's detail and param, "%.64s"), and a cut may fall inside a character. NULL only when
 * out of memory. */
json_t *json_text(const char *s);

/* A float as the shortest decimal that reads back as the same float (9.81f is 9.81, not
 * 9.81000042). */
json_t *json_float(float f);
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

/* A rock as the API shows it. */
json_t *rock_to_json(const cs_rock *r);
/* Applies the members of obj onto def: position, velocity, angular_velocity, orientation,
 * radius, density, kinematic. With `creating`, position and radius are required. */
int rock_from_json(const json_t *obj, cs_rock_def *def, int creating, problem *pr);

/* A vector of three finite numbers that fit a float. */
int vec3_from_json(const json_t *v, float out[3], const char *name, problem *pr);
/* A whole number in [lo, hi]. */
int int_from_json(const json_t *v, double lo, double hi, const char *name, long long *out, problem *pr);
/* Members of obj must all be in `allowed` (NULL-terminated); else 400 naming the first other. */
int only_fields(const json_t *obj, const char *const *allowed, problem *pr);

#endif
