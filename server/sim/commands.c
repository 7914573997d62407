/* commands.c - applying commands to the engine, and the complete form the journal keeps. */
#include <string.h>

#include "core/json_read.h"
#include "core/json_write.h"
#include "core/params_json.h"
#include "core/rock_json.h"
#include "sim/commands.h"

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

static int op_params(cs_sim *sim, loop_settings *loop, const json_t *cmd, json_t **journal, json_t **result, problem *pr)
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

static int op_scene(cs_sim *sim, const json_t *cmd, json_t **journal, json_t **result, problem *pr)
{
    static const char *const fields[] = {"op", "scene", NULL};
    if (only_fields(cmd, fields, pr) != 0) return -1;
    scene_config sc;
    memset(&sc, 0, sizeof sc);
    cs_sim_scene(sim, &sc.fields);
    cs_sim_params(sim, &sc.params);
    /* No scene member (a journal written by hand): a patch of nothing. */
    const json_t *patch = json_object_get(cmd, "scene");
    json_t *none = patch ? NULL : json_object();
    const int bad = params_from_json(patch ? patch : none, SET_SCENE, &sc, pr);
    json_decref(none);
    if (bad) return -1;
    const cs_status st = cs_sim_set_scene(sim, &sc.fields);
    if (st != CS_OK) return refused(sim, st, pr);
    json_t *full = params_to_json(SET_SCENE, &sc);
    *journal = json_pack("{s:s, s:O}", "op", "scene", "scene", full);
    *result = full;
    return 0;
}

static int op_rock_add(cs_sim *sim, const json_t *cmd, json_t **journal, json_t **result, problem *pr)
{
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

static int op_rock_set(cs_sim *sim, const json_t *cmd, json_t **journal, json_t **result, problem *pr)
{
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

static int op_rock_remove(cs_sim *sim, const json_t *cmd, json_t **journal, json_t **result, problem *pr)
{
    static const char *const fields[] = {"op", "id", "by", NULL};
    if (only_fields(cmd, fields, pr) != 0) return -1;
    uint32_t id = 0;
    if (get_id(cmd, &id, pr) != 0) return -1;
    const cs_status st = cs_rock_remove(sim, id);
    if (st != CS_OK) return refused(sim, st, pr);
    *journal = json_deep_copy(cmd);
    *result = json_pack("{s:I}", "id", (json_int_t)id);
    return 0;
}

static int op_pins(cs_sim *sim, const json_t *cmd, json_t **journal, json_t **result, problem *pr)
{
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
    *journal = json_deep_copy(cmd);
    *result = json_pack("{s:i}", "pinned", count);
    return 0;
}

static int op_grab(cs_sim *sim, const json_t *cmd, json_t **journal, json_t **result, problem *pr)
{
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

static int op_simple(cs_sim *sim, const json_t *cmd, const char *op, json_t **journal, json_t **result, problem *pr)
{
    static const char *const fields[] = {"op", NULL};
    if (only_fields(cmd, fields, pr) != 0) return -1;
    cs_status st = CS_OK;
    if (strcmp(op, "reset") == 0) st = cs_sim_reset(sim);
    else if (strcmp(op, "release") == 0) st = cs_release(sim);
    if (st != CS_OK) return refused(sim, st, pr);
    if (strcmp(op, "rocks_clear") == 0) {
        const int32_t n = cs_rock_clear(sim);
        *result = json_pack("{s:i}", "removed", (int)n);
    } else {
        *result = json_object();
    }
    *journal = json_pack("{s:s}", "op", op);
    return 0;
}

int command_rebuilds(const char *op) { return strcmp(op, "scene") == 0 || strcmp(op, "reset") == 0; }

int command_apply(cs_sim *sim, loop_settings *loop, const json_t *cmd, json_t **journal, json_t **result, problem *pr)
{
    *journal = *result = NULL;
    const char *op = json_string_value(json_object_get(cmd, "op"));
    if (!op) return problem_set(pr, 400, "wrong-type", "op", "a command needs an op");
    if (strcmp(op, "params") == 0) return op_params(sim, loop, cmd, journal, result, pr);
    if (strcmp(op, "scene") == 0) return op_scene(sim, cmd, journal, result, pr);
    if (strcmp(op, "rock_add") == 0) return op_rock_add(sim, cmd, journal, result, pr);
    if (strcmp(op, "rock_set") == 0) return op_rock_set(sim, cmd, journal, result, pr);
    if (strcmp(op, "rock_remove") == 0) return op_rock_remove(sim, cmd, journal, result, pr);
    if (strcmp(op, "pins") == 0) return op_pins(sim, cmd, journal, result, pr);
    if (strcmp(op, "grab") == 0) return op_grab(sim, cmd, journal, result, pr);
    if (strcmp(op, "reset") == 0 || strcmp(op, "release") == 0 || strcmp(op, "rocks_clear") == 0)
        return op_simple(sim, cmd, op, journal, result, pr);
    return problem_set(pr, 400, "unknown-field", "op", "unknown op '%s'", op);
}

/* ---- requests ---- */

static const struct request_op {
    const char *op;
    int body;           /* 1: a JSON object is required; 0: an empty body or {} */
    const char *member; /* the member the body becomes; NULL: its members are the command's */
    int takes_id;       /* the {id} of the path */
} request_ops[] = {
    {"params", 1, "params", 0},   {"scene", 1, "scene", 0},      {"rock_add", 1, "rock", 0},
    {"rock_set", 1, "rock", 1},   {"rock_remove", 0, NULL, 1},   {"rocks_clear", 0, NULL, 0},
    {"reset", 0, NULL, 0},        {"pins", 1, NULL, 0},          {"grab", 1, NULL, 0},
    {"release", 0, NULL, 0},
};

int command_from_request(const char *op, const char *body, size_t len, long long id, json_t **cmd, problem *pr)
{
    *cmd = NULL;
    const struct request_op *ro = NULL;
    for (size_t k = 0; k < sizeof request_ops / sizeof request_ops[0] && !ro; k++)
        if (strcmp(request_ops[k].op, op) == 0) ro = &request_ops[k];
    if (!ro) return problem_set(pr, 500, "internal", NULL, "no request makes the op '%s'", op);
    json_t *b;
    if (request_body_object(body, len, ro->body, &b, pr) != 0) return -1;
    if (strcmp(op, "params") == 0) {
        /* Refused here without bothering the sim thread; the sim thread merges the patch with the
         * parameters of the moment it applies it (so a 422 there may be no 422 here). */
        clothd_config defaults;
        settings_default(&defaults);
        if (params_from_json(b, SET_LIVE, &defaults.scene, pr) != 0 && pr->status == 400) {
            json_decref(b);
            return -1;
        }
    }
    json_t *c;
    if (ro->member) {
        c = json_object();
        json_object_set_new(c, ro->member, b);
    } else if (ro->body) {
        c = b;
    } else {
        json_decref(b);
        c = json_object();
    }
    if (ro->takes_id) json_object_set_new(c, "id", json_integer((json_int_t)id));
    if (!c || json_object_set_new(c, "op", json_string(op)) != 0) {
        json_decref(c);
        return problem_set(pr, 500, "internal", NULL, "out of memory");
    }
    *cmd = c;
    return 0;
}

int step_from_json(const json_t *body, int *frames, long long *n, problem *pr)
{
    static const char *const fields[] = {"frames", "substeps", NULL};
    if (!json_is_object(body) || only_fields(body, fields, pr) != 0) {
        if (!json_is_object(body)) problem_set(pr, 400, "wrong-type", NULL, "give either {\"frames\": N} or {\"substeps\": N}");
        return -1;
    }
    const json_t *f = json_object_get(body, "frames"), *s = json_object_get(body, "substeps");
    if ((f && s) || (!f && !s)) return problem_set(pr, 400, "wrong-type", NULL, "give either {\"frames\": N} or {\"substeps\": N}");
    if (int_from_json(f ? f : s, 1, 100000, f ? "frames" : "substeps", n, pr) != 0) return -1;
    *frames = f != NULL;
    return 0;
}
