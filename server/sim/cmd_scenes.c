/* cmd_scenes.c - the daemon's scenes: GET and POST /v1/scenes, DELETE /v1/scenes/{scene} (the
 * rows' request functions, commands_internal.h). */
#include <stdio.h>
#include <stdlib.h>

#include "core/json_read.h"
#include "sim/commands.h"
#include "sim/commands_internal.h"
#include "sim/scenes.h"

/* A scene as GET /v1/scenes lists it, from what it published. */
static json_t *scene_entry(scene *sc)
{
    size_t len = 0;
    char *doc = scene_doc_copy(sc, DOC_SIM, &len);
    json_t *sim = doc ? json_loadb(doc, len, 0, NULL) : NULL;
    free(doc);
    json_t *e = json_pack("{s:s}", "id", sc->id);
    static const char *const keep[] = {"state", "step", "sim_time", "n_vertices", "n_rocks", "realtime_factor", NULL};
    for (int k = 0; keep[k]; k++) {
        json_t *v = json_object_get(sim, keep[k]);
        if (v) json_object_set(e, keep[k], v);
    }
    json_decref(sim);
    return e;
}

int rq_scenes(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    scenes *t = rq->daemon->scenes;
    const int max = scenes_max(t);
    scene **all = malloc(sizeof *all * (size_t)(max > 0 ? max : 1));
    const int n = all ? scenes_list(t, all, max) : 0;
    json_t *list = json_array();
    for (int k = 0; k < n; k++) {
        json_array_append_new(list, scene_entry(all[k]));
        scene_release(all[k]);
    }
    free(all);
    uint64_t cap;
    const uint64_t bytes = scenes_bytes(t, &cap);
    return reply_json(out, 200,
                      json_pack("{s:o, s:i, s:f, s:f}", "scenes", list, "max_scenes", max, "state_mb",
                                (double)bytes / 1048576.0, "max_state_mb", (double)cap / 1048576.0));
}

int rq_scene_create(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    static const char *const fields[] = {"id", "scene", "params", NULL};
    problem pr;
    const json_t *o = rq->object, *id = json_object_get(o, "id"), *sf = json_object_get(o, "scene"),
                 *pf = json_object_get(o, "params");
    if (only_fields(o, fields, &pr) != 0) return reply_problem(out, &pr);
    if (id && !json_is_string(id)) {
        problem_set(&pr, 400, "wrong-type", "id", "id must be a string, not %s", json_type_word(id));
        return reply_problem(out, &pr);
    }
    if ((sf && !json_is_object(sf)) || (pf && !json_is_object(pf))) {
        const char *which = sf && !json_is_object(sf) ? "scene" : "params";
        problem_set(&pr, 400, "wrong-type", which, "%s must be an object of %s", which,
                    sf && !json_is_object(sf) ? "scene fields" : "live parameters");
        return reply_problem(out, &pr);
    }
    scene *sc;
    if (scenes_create(rq->daemon->scenes, json_string_value(id), sf, pf, &sc, &pr) != 0) return reply_problem(out, &pr);
    size_t len = 0;
    char *doc = scene_doc_copy(sc, DOC_SIM, &len);
    json_t *sim = doc ? json_loadb(doc, len, 0, NULL) : NULL;
    free(doc);
    if (!sim) sim = json_object();
    json_object_set_new(sim, "id", json_string(sc->id));
    snprintf(out->location, sizeof out->location, "%s%s", SCENES_PREFIX, sc->id);
    scene_release(sc);
    return reply_json(out, 201, sim);
}

int rq_scene_delete(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    problem pr;
    if (scenes_remove(rq->daemon->scenes, rq->scene_id) != 0) {
        problem_set(&pr, 404, "not-found", "scene", "no scene '%s'", rq->scene_id);
        return reply_problem(out, &pr);
    }
    return reply_json(out, 200, json_pack("{s:s, s:b}", "id", rq->scene_id, "deleted", 1));
}
