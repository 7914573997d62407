/* params_json.c - the settings table's rows to and from JSON (see params_json.h). */
#include <stdio.h>
#include <string.h>

#include "core/json_read.h"
#include "core/json_write.h"
#include "core/params_json.h"

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

/* A parameter's value that it cannot take - out of its range, not one of its choices, or of another
 * JSON type (a string; null, as JSON.stringify writes a client's NaN) - is 422 naming it. Elsewhere
 * (rock fields, ids, recordings) a wrong JSON type is 400: proto/PROTOCOL.md, "Errors". */
#define PARAM_WRONG_TYPE 422

/* One member onto a parameter: type checked, then range checked by the table; either refusal 422. */
static int param_from_value(const setting *s, void *field, const json_t *v, problem *pr)
{
    double d[3] = {0, 0, 0};
    char why[200];
    switch (s->type) {
    case SET_VEC3: {
        float f[3];
        if (vec3_from_json(v, f, s->name, pr) != 0) {
            if (pr->status == 400) pr->status = PARAM_WRONG_TYPE; /* (an array of 3 numbers it is not) */
            return -1;
        }
        for (int k = 0; k < 3; k++) d[k] = json_number_value(json_array_get(v, (size_t)k));
        break;
    }
    case SET_BOOL:
        if (!json_is_boolean(v)) return problem_set(pr, PARAM_WRONG_TYPE, "wrong-type", s->name, "%s must be true or false, not %s", s->name, json_type_word(v));
        d[0] = json_is_true(v);
        break;
    case SET_ENUM: {
        const int k = json_is_string(v) ? setting_choice(s, json_string_value(v)) : -2;
        if (k == -2) return problem_set(pr, PARAM_WRONG_TYPE, "wrong-type", s->name, "%s must be a string, not %s", s->name, json_type_word(v));
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
            return problem_set(pr, PARAM_WRONG_TYPE, "wrong-type", s->name, "%s must be a number, not %s", s->name, json_type_word(v));
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

