/* json_read.c - reading a request's JSON (see json_read.h). */
#include <ctype.h>
#include <math.h>
#include <string.h>

#include "core/json_read.h"

const char *json_type_word(const json_t *v)
{
    switch (json_typeof(v)) {
    case JSON_OBJECT: return "an object";
    case JSON_ARRAY: return "an array";
    case JSON_STRING: return "a string";
    case JSON_INTEGER:
    case JSON_REAL: return "a number";
    case JSON_TRUE:
    case JSON_FALSE: return "a boolean";
    default: return "null";
    }
}

int vec3_from_json(const json_t *v, float out[3], const char *name, problem *pr)
{
    if (!json_is_array(v) || json_array_size(v) != 3)
        return problem_set(pr, 400, "wrong-type", name, "%s must be an array of 3 numbers", name);
    for (size_t k = 0; k < 3; k++) {
        const json_t *e = json_array_get(v, k);
        if (!json_is_number(e)) return problem_set(pr, 400, "wrong-type", name, "%s must be an array of 3 numbers", name);
        const double d = json_number_value(e);
        if (!isfinite(d) || !isfinite((float)d))
            return problem_set(pr, 422, "out-of-range", name, "%s holds a number too large for a float", name);
        out[k] = (float)d;
    }
    return 0;
}

int int_from_json(const json_t *v, double lo, double hi, const char *name, long long *out, problem *pr)
{
    if (!json_is_number(v)) return problem_set(pr, 400, "wrong-type", name, "%s must be a number, not %s", name, json_type_word(v));
    const double d = json_number_value(v);
    if (d != floor(d) || d < lo || d > hi)
        return problem_set(pr, 422, "out-of-range", name, "%s must be a whole number from %.0f to %.0f", name, lo, hi);
    *out = (long long)d;
    return 0;
}

int only_fields(const json_t *obj, const char *const *allowed, problem *pr)
{
    const char *key;
    json_t *v;
    json_object_foreach((json_t *)obj, key, v) {
        int ok = 0;
        for (const char *const *a = allowed; *a && !ok; a++) ok = strcmp(*a, key) == 0;
        if (!ok) return problem_set(pr, 400, "unknown-field", key, "unknown field '%s'", key);
    }
    return 0;
}

int request_body_object(const char *body, size_t len, int required, json_t **out, problem *pr)
{
    *out = NULL;
    size_t n = len;
    while (n && isspace((unsigned char)body[n - 1])) n--;
    if (n == 0) {
        if (required) return problem_set(pr, 400, "invalid-json", NULL, "a JSON body is required");
        *out = json_object();
        return 0;
    }
    json_error_t err;
    json_t *o = json_loadb(body, len, JSON_REJECT_DUPLICATES, &err);
    if (!o)
        return problem_set(pr, 400, "invalid-json", NULL, "malformed JSON at line %d, column %d: %s", err.line,
                           err.column, err.text);
    if (!json_is_object(o)) {
        json_decref(o);
        return problem_set(pr, 400, "wrong-type", NULL, "the body must be a JSON object");
    }
    if (!required && json_object_size(o)) {
        const char *key = json_object_iter_key(json_object_iter(o));
        problem_set(pr, 400, "unknown-field", key, "this request takes no field ('%s' given)", key);
        json_decref(o);
        return -1;
    }
    *out = o;
    return 0;
}

int scene_id_valid(const char *id)
{
    const size_t n = id ? strlen(id) : 0;
    if (n == 0 || n > 63) return 0;
    for (size_t k = 0; k < n; k++) {
        const char c = id[k];
        const int ok = (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || (k > 0 && (c == '_' || c == '-'));
        if (!ok) return 0;
    }
    return 1;
}
