/* pjson.c - JSON for the API, driven by the parameter table. */
#include <ctype.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pjson.h"
#include "settings.h"

static const struct {
    const char *slug, *title;
} titles[] = {
    {"invalid-json", "Malformed JSON"},
    {"unknown-field", "Unknown field"},
    {"wrong-type", "Wrong type"},
    {"out-of-range", "Value out of range"},
    {"unstable", "Change would be unstable"},
    {"limit", "Limit reached"},
    {"not-found", "Not found"},
    {"method-not-allowed", "Method not allowed"},
    {"wrong-state", "Wrong state"},
    {"too-large", "Request body too large"},
    {"bad-snapshot", "Bad snapshot"},
    {"unavailable", "Service unavailable"},
    {"busy", "Too busy"},
    {"internal", "Internal error"},
    {"unauthorized", "Unauthorized"},
    {"forbidden", "Forbidden"},
    {"rate-limited", "Too many requests"},
    {"host-not-allowed", "Host not allowed"},
    {"cross-site", "Cross-site request refused"},
    {"bad-request", "Malformed request"},
    {"uri-too-long", "Request target too long"},
    {"not-implemented", "Not implemented"},
    {"too-many-clients", "Too many clients"},
    {"upgrade-required", "Upgrade required"},
};

const char *problem_title(const char *slug)
{
    for (size_t i = 0; i < sizeof titles / sizeof titles[0]; i++)
        if (strcmp(titles[i].slug, slug) == 0) return titles[i].title;
    return "Error";
}

int problem_set(problem *pr, int status, const char *slug, const char *param, const char *fmt, ...)
{
    pr->status = status;
    pr->slug = slug;
    snprintf(pr->param, sizeof pr->param, "%s", param ? param : "");
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(pr->detail, sizeof pr->detail, fmt, ap);
    va_end(ap);
    return -1;
}

/* The length of the well-formed UTF-8 sequence s starts with (RFC 3629: no overlong forms, no
 * surrogates, nothing past U+10FFFF), or 0 when it starts with none. Reads no byte past a NUL. */
static size_t utf8_sequence(const unsigned char *s)
{
    const unsigned c = s[0];
    if (c < 0x80) return 1;
    size_t n;
    unsigned lo = 0x80, hi = 0xBF; /* the range of the second byte */
    if (c >= 0xC2 && c <= 0xDF) {
        n = 2;
    } else if (c >= 0xE0 && c <= 0xEF) {
        n = 3;
        if (c == 0xE0) lo = 0xA0;
        if (c == 0xED) hi = 0x9F;
    } else if (c >= 0xF0 && c <= 0xF4) {
        n = 4;
        if (c == 0xF0) lo = 0x90;
        if (c == 0xF4) hi = 0x8F;
    } else {
        return 0;
    }
    if (s[1] < lo || s[1] > hi) return 0;
    for (size_t k = 2; k < n; k++)
        if (s[k] < 0x80 || s[k] > 0xBF) return 0;
    return n;
}

json_t *json_text(const char *s)
{
    json_t *j = json_string(s);
    if (j || !s) return j;
    const size_t len = strlen(s);
    char *copy = malloc(len + 1);
    if (!copy) return NULL;
    size_t out = 0;
    for (const unsigned char *p = (const unsigned char *)s; *p;) {
        const size_t n = utf8_sequence(p);
        if (n == 0) {
            p++; /* a byte of a cut character: dropped */
            continue;
        }
        memcpy(copy + out, p, n);
        out += n;
        p += n;
    }
    copy[out] = '\0';
    j = json_string(copy);
    free(copy);
    return j;
}

char *problem_body(const problem *pr)
{
    char type[96];
    snprintf(type, sizeof type, "urn:clothd:problem:%s", pr->slug);
    json_t *o = json_pack("{s:s, s:s, s:i, s:o}", "type", type, "title", problem_title(pr->slug), "status",
                          pr->status, "detail", json_text(pr->detail));
    if (pr->param[0]) json_object_set_new(o, "param", json_text(pr->param));
    char *s = json_dumps(o, PJSON_DUMP_FLAGS);
    json_decref(o);
    return s;
}

int problem_from_engine(problem *pr, cs_status st, const char *error, const char *param)
{
    switch (st) {
    case CS_E_NOT_FOUND: return problem_set(pr, 404, "not-found", param, "%s", error);
    case CS_E_UNSTABLE: return problem_set(pr, 422, "unstable", param, "%s", error);
    case CS_E_LIMIT: return problem_set(pr, 422, "limit", param, "%s", error);
    case CS_E_INVALID:
    case CS_E_RANGE: return problem_set(pr, 422, "out-of-range", param, "%s", error);
    case CS_E_FORMAT:
    case CS_E_VERSION: return problem_set(pr, 400, "bad-snapshot", param, "%s", error);
    case CS_E_BACKEND:
    case CS_E_DEVICE: return problem_set(pr, 503, "unavailable", param, "%s", error);
    default: return problem_set(pr, 500, "internal", param, "%s", error);
    }
}

json_t *json_float(float f)
{
    if (!isfinite(f)) return json_null();
    char text[32];
    for (int digits = 6; digits < 9; digits++) {
        snprintf(text, sizeof text, "%.*g", digits, (double)f);
        const double d = strtod(text, NULL);
        if ((float)d == f) return json_real(d);
    }
    return json_real((double)f);
}

json_t *setting_to_json(const setting *s, const void *field)
{
    switch (s->type) {
    case SET_STR: return json_string(field);
    case SET_INT: return json_integer((json_int_t)setting_get(s, field, 0));
    case SET_BOOL: return json_boolean(setting_get(s, field, 0) != 0);
    case SET_ENUM: return json_string(s->choices[(int)setting_get(s, field, 0)]);
    case SET_VEC3:
        return json_pack("[o, o, o]", json_float((float)setting_get(s, field, 0)), json_float((float)setting_get(s, field, 1)),
                         json_float((float)setting_get(s, field, 2)));
    default: return json_float((float)setting_get(s, field, 0));
    }
}

json_t *params_to_json(setting_kind kind, const scene_config *sc)
{
    json_t *o = json_object();
    for (size_t i = 0; i < settings_count(); i++) {
        const setting *s = settings_at(i);
        if (s->kind == kind) json_object_set_new(o, s->name, setting_to_json(s, setting_field(s, NULL, (scene_config *)sc)));
    }
    return o;
}

static const char *type_word(const json_t *v)
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
    if (!json_is_number(v)) return problem_set(pr, 400, "wrong-type", name, "%s must be a number, not %s", name, type_word(v));
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

/* One member onto a parameter: type checked (400), then range checked by the table (422). */
static int param_from_value(const setting *s, void *field, const json_t *v, problem *pr)
{
    double d[3] = {0, 0, 0};
    char why[200];
    switch (s->type) {
    case SET_VEC3: {
        float f[3];
        if (vec3_from_json(v, f, s->name, pr) != 0) return -1;
        for (int k = 0; k < 3; k++) d[k] = json_number_value(json_array_get(v, (size_t)k));
        break;
    }
    case SET_BOOL:
        if (!json_is_boolean(v)) return problem_set(pr, 400, "wrong-type", s->name, "%s must be true or false", s->name);
        d[0] = json_is_true(v);
        break;
    case SET_ENUM: {
        const int k = json_is_string(v) ? setting_choice(s, json_string_value(v)) : -2;
        if (k == -2) return problem_set(pr, 400, "wrong-type", s->name, "%s must be a string", s->name);
        if (k < 0) {
            char list[160] = "";
            for (int c = 0; s->choices[c]; c++)
                snprintf(list + strlen(list), sizeof list - strlen(list), "%s%s", c ? ", " : "", s->choices[c]);
            return problem_set(pr, 422, "out-of-range", s->name, "%s must be one of %s", s->name, list);
        }
        d[0] = k;
        break;
    }
    default:
        if (!json_is_number(v))
            return problem_set(pr, 400, "wrong-type", s->name, "%s must be a number, not %s", s->name, type_word(v));
        d[0] = json_number_value(v);
        break;
    }
    if (setting_set(s, field, d, why, sizeof why) != 0) return problem_set(pr, 422, "out-of-range", s->name, "%s", why);
    return 0;
}

int params_from_json(const json_t *obj, setting_kind kind, scene_config *sc, problem *pr)
{
    if (!json_is_object(obj)) return problem_set(pr, 400, "wrong-type", NULL, "the body must be a JSON object");
    scene_config next = *sc;
    const char *key;
    json_t *v;
    json_object_foreach((json_t *)obj, key, v) {
        const setting *s = settings_find(key);
        if (!s || s->kind == SET_STARTUP) return problem_set(pr, 400, "unknown-field", key, "unknown parameter '%s'", key);
        if (s->kind != kind)
            return problem_set(pr, 400, "unknown-field", key, "%s is a %s parameter: change it with %s", key,
                               setting_kind_name(s->kind), s->kind == SET_SCENE ? "PUT /v1/scene" : "PATCH /v1/params");
        if (param_from_value(s, setting_field(s, NULL, &next), v, pr) != 0) return -1;
    }
    char why[200];
    const char *bad = NULL;
    if (kind == SET_LIVE && cs_params_validate(&next.params, &bad, why, sizeof why) != 0)
        return problem_set(pr, 422, "out-of-range", bad, "%s", why);
    *sc = next;
    return 0;
}

json_t *loop_to_json(const loop_settings *loop)
{
    json_t *o = json_object();
    for (size_t i = 0; i < settings_count(); i++) {
        const setting *s = settings_at(i);
        if (s->home == IN_LOOP) json_object_set_new(o, s->name, setting_to_json(s, (const char *)loop + s->offset));
    }
    return o;
}

int loop_from_json(const json_t *obj, loop_settings *loop, problem *pr)
{
    const char *key;
    json_t *v;
    json_object_foreach((json_t *)obj, key, v) {
        const setting *s = settings_find(key);
        if (!s || s->home != IN_LOOP) return problem_set(pr, 400, "unknown-field", key, "'%s' is not a daemon-loop setting", key);
    }
    clothd_config c;
    settings_default(&c);
    c.scene.loop = *loop;
    if (params_from_json(obj, SET_LIVE, &c.scene, pr) != 0) return -1;
    *loop = c.scene.loop;
    return 0;
}

json_t *schema_to_json(void)
{
    clothd_config defaults;
    settings_default(&defaults);
    json_t *list = json_array();
    for (size_t i = 0; i < settings_count(); i++) {
        const setting *s = settings_at(i);
        json_t *choices = json_null();
        if (s->choices) {
            choices = json_array();
            for (int c = 0; s->choices[c]; c++) json_array_append_new(choices, json_string(s->choices[c]));
        }
        const int ranged = s->type != SET_ENUM && s->type != SET_BOOL && s->type != SET_STR;
        json_t *def = setting_to_json(s, setting_field(s, &defaults.set, &defaults.scene));
        json_array_append_new(
            list, json_pack("{s:s, s:s, s:s, s:o, s:o, s:o, s:o, s:s, s:s}", "name", s->name, "type",
                            setting_type_name(s->type), "unit", s->unit, "default", def, "min",
                            ranged ? json_real(s->min) : json_null(), "max", ranged ? json_real(s->max) : json_null(),
                            "choices", choices, "kind", setting_kind_name(s->kind), "help", s->help));
    }
    return json_pack("{s:o}", "params", list);
}

static json_t *floats(const float *v, int n)
{
    json_t *a = json_array();
    for (int k = 0; k < n; k++) json_array_append_new(a, json_float(v[k]));
    return a;
}

json_t *rock_to_json(const cs_rock *r)
{
    const cs_rock_def *d = &r->def;
    return json_pack("{s:I, s:b, s:o, s:o, s:o, s:o, s:o, s:o, s:o}", "id", (json_int_t)r->id, "kinematic",
                     d->kinematic, "position", floats(d->position, 3), "velocity", floats(d->velocity, 3),
                     "angular_velocity", floats(d->angular_velocity, 3), "orientation", floats(d->orientation, 4),
                     "radius", json_float(d->radius), "density", json_float(d->density), "mass", json_float(r->mass));
}

static int positive_float(const json_t *v, const char *name, float *out, problem *pr)
{
    if (!json_is_number(v)) return problem_set(pr, 400, "wrong-type", name, "%s must be a number", name);
    const double d = json_number_value(v);
    if (!(d > 0) || !isfinite((float)d)) return problem_set(pr, 422, "out-of-range", name, "%s must be a positive number", name);
    *out = (float)d;
    return 0;
}

int rock_from_json(const json_t *obj, cs_rock_def *def, int creating, problem *pr)
{
    static const char *const fields[] = {"position", "velocity", "angular_velocity", "orientation", "radius",
                                         "density",  "kinematic", NULL};
    if (!json_is_object(obj)) return problem_set(pr, 400, "wrong-type", NULL, "the body must be a JSON object");
    if (only_fields(obj, fields, pr) != 0) return -1;
    if (creating && !json_object_get(obj, "position")) return problem_set(pr, 422, "out-of-range", "position", "position is required");
    if (creating && !json_object_get(obj, "radius")) return problem_set(pr, 422, "out-of-range", "radius", "radius is required");
    cs_rock_def d = *def;
    const json_t *v;
    if ((v = json_object_get(obj, "position")) && vec3_from_json(v, d.position, "position", pr) != 0) return -1;
    if ((v = json_object_get(obj, "velocity")) && vec3_from_json(v, d.velocity, "velocity", pr) != 0) return -1;
    if ((v = json_object_get(obj, "angular_velocity")) && vec3_from_json(v, d.angular_velocity, "angular_velocity", pr) != 0)
        return -1;
    if ((v = json_object_get(obj, "orientation"))) {
        if (!json_is_array(v) || json_array_size(v) != 4)
            return problem_set(pr, 400, "wrong-type", "orientation", "orientation must be an array of 4 numbers");
        for (size_t k = 0; k < 4; k++) {
            const json_t *e = json_array_get(v, k);
            if (!json_is_number(e))
                return problem_set(pr, 400, "wrong-type", "orientation", "orientation must be an array of 4 numbers");
            d.orientation[k] = (float)json_number_value(e);
        }
    }
    if ((v = json_object_get(obj, "radius")) && positive_float(v, "radius", &d.radius, pr) != 0) return -1;
    if ((v = json_object_get(obj, "density")) && positive_float(v, "density", &d.density, pr) != 0) return -1;
    if ((v = json_object_get(obj, "kinematic"))) {
        if (!json_is_boolean(v)) return problem_set(pr, 400, "wrong-type", "kinematic", "kinematic must be true or false");
        d.kinematic = json_is_true(v);
    }
    *def = d;
    return 0;
}
