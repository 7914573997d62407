/* changes.c - the journaled commands: what each does to the engine and the daemon-loop settings,
 * and the complete form the journal keeps (see changes.h). */
#include <stdio.h>
#include <string.h>

#include "core/json_read.h"
#include "core/json_write.h"
#include "core/params_json.h"
#include "core/rock_json.h"
#include "sim/changes.h"

static int refused(cs_sim *sim, cs_status st, problem *pr)
{
    return problem_from_engine(pr, st, cs_sim_error(sim), cs_sim_error_param(sim));
}

static int get_id(const json_t *cmd, uint32_t *id, problem *pr)
{
    long long v;
    const json_t *j = json_object_get(cmd, "id");
    if (!j) return problem_set(pr, 400, "wrong-type", "id", "id is required");
    if (int_from_json(j, 0, 4294967295.0, "id", &v, pr) != 0) return -1;
    *id = (uint32_t)v;
    return 0;
}

int change_params(cs_sim *sim, loop_settings *loop, const json_t *cmd, json_t **journal, json_t **result, problem *pr)
{
    static const char *const fields[] = {"op", "params", NULL};
    if (only_fields(cmd, fields, pr) != 0) return -1;
    scene_config sc;
    cs_sim_scene(sim, &sc.fields);
    cs_sim_params(sim, &sc.params);
    sc.loop = *loop;
    if (params_from_json(json_object_get(cmd, "params"), SET_LIVE, &sc, pr) != 0) return -1;
    const cs_status st = cs_sim_set_params(sim, &sc.params);
    if (st != CS_OK) return refused(sim, st, pr);
    *loop = sc.loop;
    json_t *full = params_to_json(SET_LIVE, &sc);
    *journal = json_pack("{s:s, s:O}", "op", "params", "params", full);
    *result = json_pack("{s:o}", "params", full);
    return 0;
}

/* PUT /v1/scene's "preset": a name of cs_preset_find's table; its index, -1 for none, -2 refused. */
static int scene_preset(const json_t *patch, problem *pr)
{
    const json_t *name = patch ? json_object_get(patch, "preset") : NULL;
    if (!name) return -1;
    if (!json_is_string(name)) return problem_set(pr, 400, "wrong-type", "preset", "preset must be a string"), -2;
    const int k = cs_preset_find(json_string_value(name));
    if (k < 0) {
        char names[256] = "";
        for (int i = 0; i < cs_preset_count(); i++)
            snprintf(names + strlen(names), sizeof names - strlen(names), "%s%s", i ? ", " : "", cs_preset_name(i));
        return problem_set(pr, 422, "out-of-range", "preset", "preset must be one of %s", names), -2;
    }
    return k;
}

int change_scene(cs_sim *sim, loop_settings *loop, const json_t *cmd, json_t **journal, json_t **result, problem *pr)
{
    static const char *const fields[] = {"op", "scene", NULL};
    if (only_fields(cmd, fields, pr) != 0) return -1;
    scene_config sc;
    memset(&sc, 0, sizeof sc);
    cs_sim_scene(sim, &sc.fields);
    cs_sim_params(sim, &sc.params);
    /* No scene member (a journal written by hand): a patch of nothing. A preset sets its scene
     * fields and live parameters first, the patch's own fields then override them. */
    const json_t *patch = json_object_get(cmd, "scene");
    const int preset = scene_preset(json_is_object(patch) ? patch : NULL, pr);
    if (preset == -2) return -1;
    json_t *rest = patch ? json_deep_copy(patch) : json_object();
    if (!rest) return problem_set(pr, 500, "internal", NULL, "out of memory");
    if (json_is_object(rest)) json_object_del(rest, "preset");
    cs_params before;
    cs_sim_params(sim, &before);
    if (preset >= 0) cs_preset_scene(preset, &sc.fields, &sc.params);
    const int bad = params_from_json(rest, SET_SCENE, &sc, pr);
    json_decref(rest);
    if (bad) return -1;
    cs_status st = preset >= 0 ? cs_sim_set_params(sim, &sc.params) : CS_OK;
    if (st == CS_OK) st = cs_sim_set_scene(sim, &sc.fields);
    if (st != CS_OK) {
        const int r = refused(sim, st, pr);
        cs_sim_set_params(sim, &before); /* nothing changed */
        return r;
    }
    if (preset >= 0 && (st = cs_preset_populate(sim, preset)) != CS_OK) return refused(sim, st, pr);
    if (preset >= 0) loop->auto_drop_interval = 0.0f; /* the preset's own rocks only */
    json_t *full = params_to_json(SET_SCENE, &sc);
    if (preset >= 0) json_object_set_new(full, "preset", json_string(cs_preset_name(preset)));
    *journal = json_pack("{s:s, s:O}", "op", "scene", "scene", full);
    *result = full;
    return 0;
}

int change_rock_add(cs_sim *sim, loop_settings *loop, const json_t *cmd, json_t **journal, json_t **result, problem *pr)
{
    (void)loop;
    static const char *const fields[] = {"op", "rock", "by", NULL};
    if (only_fields(cmd, fields, pr) != 0) return -1;
    cs_rock_def d;
    cs_rock_def_default(&d);
    if (rock_from_json(json_object_get(cmd, "rock"), &d, 1, pr) != 0) return -1;
    uint32_t id = 0;
    const cs_status st = cs_rock_add(sim, &d, &id);
    if (st != CS_OK) return refused(sim, st, pr);
    cs_rock r;
    cs_rock_get(sim, id, &r);
    *journal = json_pack("{s:s, s:o}", "op", "rock_add", "rock", rock_def_to_json(&d));
    const json_t *by = json_object_get(cmd, "by");
    if (json_is_string(by)) json_object_set(*journal, "by", (json_t *)by);
    *result = json_pack("{s:I, s:o}", "id", (json_int_t)id, "rock", rock_to_json(&r));
    return 0;
}

int change_rock_set(cs_sim *sim, loop_settings *loop, const json_t *cmd, json_t **journal, json_t **result, problem *pr)
{
    (void)loop;
    static const char *const fields[] = {"op", "id", "rock", NULL};
    if (only_fields(cmd, fields, pr) != 0) return -1;
    uint32_t id = 0;
    if (get_id(cmd, &id, pr) != 0) return -1;
    cs_rock r;
    cs_status st = cs_rock_get(sim, id, &r);
    if (st != CS_OK) return refused(sim, st, pr);
    const json_t *patch = json_object_get(cmd, "rock");
    json_t *none = patch ? NULL : json_object();
    const int bad = rock_from_json(patch ? patch : none, &r.def, 0, pr);
    json_decref(none);
    if (bad) return -1;
    if ((st = cs_rock_set(sim, id, &r.def)) != CS_OK) return refused(sim, st, pr);
    *journal = json_pack("{s:s, s:I, s:o}", "op", "rock_set", "id", (json_int_t)id, "rock", rock_def_to_json(&r.def));
    cs_rock_get(sim, id, &r);
    *result = json_pack("{s:o}", "rock", rock_to_json(&r));
    return 0;
}

int change_rock_remove(cs_sim *sim, loop_settings *loop, const json_t *cmd, json_t **journal, json_t **result, problem *pr)
{
    (void)loop;
    static const char *const fields[] = {"op", "id", "by", NULL};
    if (only_fields(cmd, fields, pr) != 0) return -1;
    uint32_t id = 0;
    if (get_id(cmd, &id, pr) != 0) return -1;
    const cs_status st = cs_rock_remove(sim, id);
    if (st != CS_OK) return refused(sim, st, pr);
    *journal = json_incref((json_t *)cmd); /* read only from here on: the journal keeps its text */
    *result = json_pack("{s:I}", "id", (json_int_t)id);
    return 0;
}

int change_pins(cs_sim *sim, loop_settings *loop, const json_t *cmd, json_t **journal, json_t **result, problem *pr)
{
    (void)loop;
    static const char *const fields[] = {"op", "preset", "vertices", "pinned", NULL};
    if (only_fields(cmd, fields, pr) != 0) return -1;
    const json_t *preset = json_object_get(cmd, "preset"), *verts = json_object_get(cmd, "vertices");
    cs_status st;
    if (preset && verts) return problem_set(pr, 400, "unknown-field", "vertices", "give either preset or vertices, not both");
    if (preset) {
        const int k = json_is_string(preset) ? cs_param_choice(cs_param_find("pins"), json_string_value(preset)) : -2;
        if (k == -2) return problem_set(pr, 400, "wrong-type", "preset", "preset must be a string");
        if (k < 0) return problem_set(pr, 422, "out-of-range", "preset", "preset must be corners, edges, top-edge or none");
        if ((st = cs_pins_preset(sim, (cs_pins)k)) != CS_OK) return refused(sim, st, pr);
    } else {
        const json_t *pinned = json_object_get(cmd, "pinned");
        if (!json_is_array(verts)) return problem_set(pr, 400, "wrong-type", "vertices", "vertices must be an array of vertex indices");
        if (!json_is_boolean(pinned)) return problem_set(pr, 400, "wrong-type", "pinned", "pinned must be true or false");
        cs_info info;
        cs_sim_info(sim, &info);
        const size_t n = json_array_size(verts);
        int32_t *list = malloc(sizeof *list * (n ? n : 1));
        if (!list) return problem_set(pr, 500, "internal", NULL, "out of memory");
        for (size_t k = 0; k < n; k++) {
            long long v;
            if (int_from_json(json_array_get(verts, k), 0, info.n_vertices - 1, "vertices", &v, pr) != 0) {
                free(list);
                return -1;
            }
            list[k] = (int32_t)v;
        }
        st = cs_pin(sim, list, n, json_is_true(pinned));
        free(list);
        if (st != CS_OK) return refused(sim, st, pr);
    }
    cs_info info;
    cs_sim_info(sim, &info);
    int count = 0;
    for (int32_t v = 0; v < info.n_vertices; v++) count += cs_is_pinned(sim, v);
    *journal = json_incref((json_t *)cmd); /* read only from here on: the journal keeps its text */
    *result = json_pack("{s:i}", "pinned", count);
    return 0;
}

int change_grab(cs_sim *sim, loop_settings *loop, const json_t *cmd, json_t **journal, json_t **result, problem *pr)
{
    (void)loop;
    static const char *const fields[] = {"op", "vertex", "target", NULL};
    if (only_fields(cmd, fields, pr) != 0) return -1;
    cs_info info;
    cs_sim_info(sim, &info);
    long long v;
    float target[3];
    const json_t *jv = json_object_get(cmd, "vertex"), *jt = json_object_get(cmd, "target");
    if (!jv) return problem_set(pr, 400, "wrong-type", "vertex", "vertex is required");
    if (!jt) return problem_set(pr, 400, "wrong-type", "target", "target is required");
    if (int_from_json(jv, 0, info.n_vertices - 1, "vertex", &v, pr) != 0) return -1;
    if (vec3_from_json(jt, target, "target", pr) != 0) return -1;
    const cs_status st = cs_grab(sim, (int32_t)v, target);
    if (st != CS_OK) return refused(sim, st, pr);
    *journal = json_pack("{s:s, s:I, s:[o,o,o]}", "op", "grab", "vertex", (json_int_t)v, "target", json_float(target[0]),
                         json_float(target[1]), json_float(target[2]));
    *result = json_pack("{s:I, s:[o,o,o]}", "vertex", (json_int_t)v, "target", json_float(target[0]),
                        json_float(target[1]), json_float(target[2]));
    return 0;
}

/* A command of no members but its op: the engine's call (none for NULL), then the journal's entry
 * and an empty result. */
static int bare(cs_sim *sim, const json_t *cmd, const char *op, cs_status (*call)(cs_sim *), json_t **journal,
                json_t **result, problem *pr)
{
    static const char *const fields[] = {"op", NULL};
    if (only_fields(cmd, fields, pr) != 0) return -1;
    const cs_status st = call ? call(sim) : CS_OK;
    if (st != CS_OK) return refused(sim, st, pr);
    *journal = json_pack("{s:s}", "op", op);
    *result = json_object();
    return 0;
}

int change_reset(cs_sim *sim, loop_settings *loop, const json_t *cmd, json_t **journal, json_t **result, problem *pr)
{
    (void)loop;
    return bare(sim, cmd, "reset", cs_sim_reset, journal, result, pr);
}

int change_release(cs_sim *sim, loop_settings *loop, const json_t *cmd, json_t **journal, json_t **result, problem *pr)
{
    (void)loop;
    return bare(sim, cmd, "release", cs_release, journal, result, pr);
}

int change_rocks_clear(cs_sim *sim, loop_settings *loop, const json_t *cmd, json_t **journal, json_t **result, problem *pr)
{
    (void)loop;
    if (bare(sim, cmd, "rocks_clear", NULL, journal, result, pr) != 0) return -1;
    json_object_set_new(*result, "removed", json_integer(cs_rock_clear(sim)));
    return 0;
}
