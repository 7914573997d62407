/* controls.c - the scene's own commands (see controls.h). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "core/clock.h"
#include "core/params_json.h"
#include "core/rock_json.h"
#include "sim/controls.h"

static void fail(scene_cmd *c, int status, const char *slug, const char *detail)
{
    c->failed = 1;
    problem_set(&c->pr, status, slug, NULL, "%s", detail);
}

int control_pause(scene *sc, scene_cmd *c)
{
    cs_info info;
    cs_sim_info(sc->engine, &info);
    sc->paused = 1;
    scene_emit(sc, json_pack("{s:s, s:I}", "event", "paused", "step", (json_int_t)info.step), c->request_id);
    return 0;
}

int control_resume(scene *sc, scene_cmd *c)
{
    cs_info info;
    sc->paused = 0;
    sc->due = clock_mono();
    sc->rtf_wall = sc->due;
    cs_sim_info(sc->engine, &info);
    sc->rtf_sim = info.time;
    scene_emit(sc, json_pack("{s:s, s:I}", "event", "resumed", "step", (json_int_t)info.step), c->request_id);
    return 0;
}

int control_step(scene *sc, scene_cmd *c) { return scene_step_start(sc, c); }

int control_step_cancel(scene *sc, scene_cmd *c)
{
    const int stepping = sc->job.cmd != NULL;
    scene_end_step(sc, "cancel");
    cs_info info;
    cs_sim_info(sc->engine, &info);
    c->result = json_pack("{s:b, s:I, s:I}", "cancelled", stepping, "step", (json_int_t)info.step, "frame",
                          (json_int_t)sc->frame);
    return 0;
}

int control_snapshot_get(scene *sc, scene_cmd *c)
{
    const size_t need = cs_snapshot_size(sc->engine);
    c->blob = malloc(need);
    const cs_status st = c->blob ? cs_snapshot_save(sc->engine, c->blob, need, &c->blob_len) : CS_E_NOMEM;
    if (st == CS_E_NONFINITE)
        fail(c, 409, "wrong-state",
             "the state is not finite (a command made its accelerations overflow): the next step rolls it back to the "
             "last checkpoint");
    else if (st != CS_OK)
        fail(c, 500, "internal", "could not write the snapshot");
    return 0;
}

int control_snapshot_put(scene *sc, scene_cmd *c)
{
    const cs_status st = cs_snapshot_load(sc->engine, c->blob_in, c->blob_in_len);
    if (st != CS_OK) {
        c->failed = 1;
        problem_from_engine(&c->pr, st, cs_sim_error(sc->engine), cs_sim_error_param(sc->engine));
        return 0;
    }
    loop_from_snapshot(&sc->loop, c->blob_in, c->blob_in_len); /* one written before they left its table */
    cs_info info;
    cs_sim_info(sc->engine, &info);
    sc->frame = info.step / (uint64_t)info.substeps;
    scene_reseed(sc);
    scene_rebase(sc);
    char hex[17];
    cs_hash_hex(cs_state_hash(sc->engine), hex);
    c->result = json_pack("{s:I, s:I, s:s}", "applied_step", (json_int_t)info.step, "step", (json_int_t)info.step,
                          "state_hash", hex);
    /* Everything may have changed: the event carries what a viewer needs to redraw, like hello. */
    scene_config cfg;
    scene_config_of(sc, &cfg);
    json_t *rocks = json_array();
    for (int32_t r = 0; r < cs_rock_count(sc->engine); r++) {
        cs_rock k;
        if (cs_rock_at(sc->engine, r, &k) == CS_OK) json_array_append_new(rocks, rock_to_json(&k));
    }
    const int64_t n_torn = cs_read_torn(sc->engine, NULL, 0);
    uint32_t *ids = malloc(sizeof *ids * (size_t)(n_torn ? n_torn : 1));
    json_t *torn = json_array();
    if (ids) {
        cs_read_torn(sc->engine, ids, (size_t)n_torn);
        for (int64_t k = 0; k < n_torn; k++) json_array_append_new(torn, json_integer(ids[k]));
        free(ids);
    }
    scene_emit(sc, json_pack("{s:s, s:I, s:o, s:o, s:o, s:o}", "event", "snapshot_restored", "applied_step",
                             (json_int_t)info.step, "scene", params_to_json(SET_SCENE, &cfg), "params",
                             params_to_json(SET_LIVE, &cfg), "rocks", rocks, "torn", torn),
               c->request_id);
    return 0;
}

/* GET /v1/cloth/state's JSON, formatted by hand: jansson would build n small arrays twice over. */
static char *cloth_json(const float *pos, const float *vel, size_t n, uint64_t step, const cs_scene *fields, size_t *len)
{
    const size_t cap = (size_t)scene_cloth_json_cap(n);
    char *s = malloc(cap);
    if (!s) return NULL;
    size_t at = (size_t)snprintf(s, cap, "{\"step\":%llu,\"nx\":%d,\"ny\":%d,\"positions\":[", (unsigned long long)step,
                                 (int)fields->nx, (int)fields->ny);
    for (int part = 0; part < 2; part++) {
        const float *a = part ? vel : pos;
        if (part) at += (size_t)snprintf(s + at, cap - at, "],\"velocities\":[");
        for (size_t v = 0; v < n; v++)
            at += (size_t)snprintf(s + at, cap - at, "%s[%.9g,%.9g,%.9g]", v ? "," : "", a[3 * v], a[3 * v + 1], a[3 * v + 2]);
    }
    at += (size_t)snprintf(s + at, cap - at, "]}");
    *len = at;
    return s;
}

int control_cloth_state(scene *sc, scene_cmd *c)
{
    cs_info info;
    cs_sim_info(sc->engine, &info);
    cs_scene fields;
    cs_sim_scene(sc->engine, &fields);
    const size_t n = (size_t)info.n_vertices;
    float *pos = malloc(sizeof(float) * 3 * n), *vel = malloc(sizeof(float) * 3 * n);
    if (!pos || !vel || cs_read_positions(sc->engine, pos, 3 * n) != CS_OK ||
        cs_read_velocities(sc->engine, vel, 3 * n) != CS_OK) {
        free(pos);
        free(vel);
        fail(c, 500, "internal", "could not read the cloth's state");
        return 0;
    }
    if (json_is_true(json_object_get(c->body, "binary"))) {
        c->blob_len = sizeof(float) * 6 * n;
        c->blob = malloc(c->blob_len);
        if (c->blob) {
            memcpy(c->blob, pos, sizeof(float) * 3 * n);
            memcpy(c->blob + sizeof(float) * 3 * n, vel, sizeof(float) * 3 * n);
        }
    } else {
        c->blob = (unsigned char *)cloth_json(pos, vel, n, info.step, &fields, &c->blob_len);
    }
    if (!c->blob) fail(c, 500, "internal", "out of memory");
    free(pos);
    free(vel);
    return 0;
}

int control_bundle(scene *sc, scene_cmd *c)
{
    cs_info info;
    cs_sim_info(sc->engine, &info);
    c->blob = journal_bundle(sc->journal, info.step, &c->blob_len);
    if (!c->blob) fail(c, 500, "internal", "out of memory");
    return 0;
}

int control_publish(scene *sc, scene_cmd *c)
{
    (void)sc, (void)c;
    return 0;
}

int control_pose(scene *sc, scene_cmd *c)
{
    (void)c;
    sc->pose_asked = sc->paused; /* a running scene hands out a new pose with its next frame */
    return 0;
}
