/* commands.c - the command table and the checks made from its columns (see commands.h). */
#include <ctype.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "core/clock.h"
#include "core/json_read.h"
#include "core/json_write.h"
#include "core/params_json.h"
#include "core/rock_json.h"
#include "core/settings.h"
#include "core/stream_msg.h"
#include "sim/changes.h"
#include "sim/commands.h"
#include "sim/controls.h"
#include "sim/recordings.h"
#include "sim/scenes.h"

#define JSON_TYPE "application/json"
#define PROBLEM_TYPE "application/problem+json"
#define OCTETS "application/octet-stream"
#define RECORDING_TYPE "application/vnd.clothd.recording"

/* The answer of a "wake" nobody waits for: it is freed. */
static void free_wake(scene_cmd *cmd, void *arg)
{
    (void)arg;
    json_decref(cmd->result);
    free(cmd->blob);
    free(cmd);
}

/* ---- answers ---- */

static int reply_text(api_reply *out, int status, const char *ctype, char *body, size_t len)
{
    out->status = status;
    out->ctype = ctype;
    out->body = body;
    out->len = len;
    return API_NOW;
}

static int reply_json(api_reply *out, int status, json_t *o)
{
    char *s = json_dumps(o, JSON_DUMP_FLAGS);
    json_decref(o);
    return reply_text(out, status, JSON_TYPE, s, s ? strlen(s) : 0);
}

void api_problem(api_reply *out, const problem *pr)
{
    char *s = problem_body(pr);
    reply_text(out, pr->status, PROBLEM_TYPE, s, s ? strlen(s) : 0);
}

static int reply_problem(api_reply *out, const problem *pr)
{
    api_problem(out, pr);
    return API_NOW;
}

/* A published text of the request's scene. */
static int reply_doc(const api_request *rq, scene_doc doc, api_reply *out)
{
    size_t len = 0;
    char *j = scene_doc_copy(rq->sc, doc, &len);
    return reply_text(out, 200, JSON_TYPE, j, len);
}

/* ---- the rows' request functions: answers from what the scene published ---- */

static int rq_health(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    const api_daemon *d = rq->daemon;
    const int ok = scenes_healthy(d->scenes);
    json_t *stream = d->stream_port ? json_pack("{s:i, s:s, s:s}", "port", d->stream_port, "path", STREAM_PATH,
                                                "protocol", STREAM_PROTOCOL)
                                    : json_null();
    return reply_json(out, ok ? 200 : 503,
                      json_pack("{s:s, s:s, s:s, s:s, s:s, s:o}", "status", ok ? "ok" : "unhealthy", "backend",
                                d->backend, "device", d->device, "backend_note", d->backend_note, "version", d->version,
                                "stream", stream));
}

/* Liveness: the sim thread turned within liveness_timeout s (simloop_last_turn). It says nothing
 * but that: a probe needs no token. */
static int rq_livez(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    const api_daemon *d = rq->daemon;
    const double last = d->loop && d->last_turn ? d->last_turn(d->loop) : 0;
    const double ago = clock_mono() - last;
    if (last > 0 && ago <= (double)d->liveness_timeout) return reply_json(out, 200, json_pack("{s:s}", "status", "live"));
    problem pr;
    if (last > 0)
        problem_set(&pr, 503, "not-live", NULL, "the simulation thread has not turned for %.1f s (liveness_timeout: %d s)",
                    ago, d->liveness_timeout);
    else
        problem_set(&pr, 503, "not-live", NULL, "the simulation thread has not started");
    return reply_problem(out, &pr);
}

/* Readiness: serving (not starting, not stopping), and room for another scene (scenes_room). */
static int rq_readyz(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    const api_daemon *d = rq->daemon;
    const int life = d->life ? atomic_load(d->life) : DAEMON_SERVING;
    problem pr;
    if (life != DAEMON_SERVING) {
        problem_set(&pr, 503, "not-ready", NULL, "%s",
                    life == DAEMON_STARTING ? "the daemon is starting" : "the daemon is stopping");
        return reply_problem(out, &pr);
    }
    if (scenes_room(d->scenes, &pr) != 0) return reply_problem(out, &pr);
    return reply_json(out, 200, json_pack("{s:s, s:i, s:i}", "status", "ready", "scenes", scenes_count(d->scenes),
                                          "max_scenes", scenes_max(d->scenes)));
}

static int rq_sim(const api_request *rq, api_reply *out, scene_cmd *later)
{
    if (rq->hash) {
        later->def = command_find("hash");
        return API_LATER;
    }
    return reply_doc(rq, DOC_SIM, out);
}

static int rq_params(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    return reply_doc(rq, DOC_PARAMS, out);
}

static int rq_fields(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    return reply_doc(rq, DOC_FIELDS, out);
}

static int rq_schema(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)rq, (void)later;
    return reply_json(out, 200, schema_to_json());
}

static int rq_rocks(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    cs_rock *rocks;
    const int n = scene_rocks(rq->sc, &rocks);
    json_t *list = rocks_to_json(rocks, n);
    free(rocks);
    return reply_json(out, 200, json_pack("{s:o}", "rocks", list));
}

static int rq_rock(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    cs_rock *rocks;
    const int n = scene_rocks(rq->sc, &rocks);
    json_t *found = NULL;
    for (int k = 0; k < n && !found; k++)
        if (rocks[k].id == (uint32_t)rq->id) found = rock_to_json(&rocks[k]);
    free(rocks);
    if (found) return reply_json(out, 200, found);
    problem pr;
    problem_set(&pr, 404, "not-found", "id", "no rock with id %lld", rq->id);
    return reply_problem(out, &pr);
}

static int rq_journal(const api_request *rq, api_reply *out, scene_cmd *later)
{
    if (rq->binary) {
        later->def = command_find("bundle");
        return API_LATER;
    }
    size_t len = 0;
    char *j = journal_json(rq->sc->journal, &len);
    return reply_text(out, 200, JSON_TYPE, j, len);
}

static int rq_metrics(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    const api_daemon *d = rq->daemon;
    const int max = scenes_max(d->scenes);
    scene **all = malloc(sizeof *all * (size_t)max);
    metrics_scene *each = malloc(sizeof *each * (size_t)max);
    const int n = all && each ? scenes_list(d->scenes, all, max) : 0;
    for (int k = 0; k < n; k++) {
        each[k].id = all[k]->id;
        scene_gauges(all[k], &each[k].g);
    }
    char *extra = d->more_metrics ? d->more_metrics(d->more_ctx) : NULL;
    uint64_t cap = 0;
    const uint64_t used = scenes_bytes(d->scenes, &cap);
    const metrics_daemon about = {d->version, d->backend, scenes_count(d->scenes), max, used, cap};
    size_t len = 0;
    char *text = metrics_render(d->m, &about, each, n, extra, &len);
    free(extra);
    for (int k = 0; k < n; k++) scene_release(all[k]);
    free(all);
    free(each);
    return reply_text(out, 200, "text/plain; version=0.0.4; charset=utf-8", text, len);
}

/* ---- the daemon's scenes ---- */

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

static int rq_scenes(const api_request *rq, api_reply *out, scene_cmd *later)
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

static int rq_scene_create(const api_request *rq, api_reply *out, scene_cmd *later)
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

static int rq_scene_delete(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    problem pr;
    if (scenes_remove(rq->daemon->scenes, rq->scene_id) != 0) {
        problem_set(&pr, 404, "not-found", "scene", "no scene '%s'", rq->scene_id);
        return reply_problem(out, &pr);
    }
    return reply_json(out, 200, json_pack("{s:s, s:b}", "id", rq->scene_id, "deleted", 1));
}

/* ---- recordings ---- */

static int no_recordings(api_reply *out)
{
    problem pr;
    problem_set(&pr, 503, "unavailable", NULL, "this clothd keeps no recordings");
    return reply_problem(out, &pr);
}

static int rq_recording_start(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    recordings *r = rq->daemon->recordings;
    if (!r) return no_recordings(out);
    problem pr;
    json_t *answer;
    char rid[SCENE_ID_MAX];
    if (recordings_start(r, rq->sc, rq->object, &answer, rid, &pr) != 0) return reply_problem(out, &pr);
    /* A paused scene publishes only after a command: this one has it hand the recording its
     * first pose now (a running one does with its next frame). */
    scene_cmd *wake = calloc(1, sizeof *wake);
    if (wake) {
        wake->def = command_find("wake");
        wake->done = free_wake;
        scene_submit(rq->sc, wake);
    }
    snprintf(out->location, sizeof out->location, "/v1/recordings/%s", rid);
    return reply_json(out, 201, answer);
}

static int rq_recordings(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    recordings *r = rq->daemon->recordings;
    if (!r) return no_recordings(out);
    return reply_json(out, 200, recordings_list(r));
}

static int rq_recording_get(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    recordings *r = rq->daemon->recordings;
    if (!r) return no_recordings(out);
    problem pr;
    unsigned char *bytes;
    size_t len;
    void *copy;
    if (recordings_bytes(r, rq->rid, &bytes, &len, &copy, &pr) != 0) {
        reply_problem(out, &pr);
        if (pr.status == 503) out->retry_after = 1;
        return API_NOW;
    }
    snprintf(out->disposition, sizeof out->disposition, "attachment; filename=\"%s.clr\"", rq->rid);
    out->release = recordings_release;
    out->release_cls = copy;
    return reply_text(out, 200, RECORDING_TYPE, (char *)bytes, len);
}

static int rq_recording_delete(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    recordings *r = rq->daemon->recordings;
    if (!r) return no_recordings(out);
    problem pr;
    if (recordings_delete(r, rq->rid, &pr) != 0) return reply_problem(out, &pr);
    return reply_json(out, 200, json_pack("{s:s, s:b}", "id", rq->rid, "deleted", 1));
}

/* ---- the rows' request functions: commands for the sim thread ---- */

/* The row's own command, as it came (a control with no body, or its body as is). */
static int rq_queue(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)out;
    if (rq->object) later->body = json_incref(rq->object);
    return API_LATER;
}

static int rq_step(const api_request *rq, api_reply *out, scene_cmd *later)
{
    int frames;
    long long n;
    problem pr;
    /* Refused here: it reaches no step in progress. */
    if (step_from_json(rq->object, &frames, &n, &pr) != 0) return reply_problem(out, &pr);
    return rq_queue(rq, out, later);
}

static int rq_cloth_state(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)out;
    later->body = json_pack("{s:b}", "binary", rq->binary);
    return API_LATER;
}

static int rq_snapshot_put(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)out;
    later->blob_in = (const unsigned char *)rq->body;
    later->blob_in_len = rq->len;
    return API_LATER;
}

/* A journaled command from the (parsed) body: its member or members, the path's id, its op. */
static int make_change(const command *d, json_t *object, long long id, json_t **cmd, problem *pr)
{
    *cmd = NULL;
    if (d->change == change_params) {
        /* Refused here without bothering the sim thread; the sim thread merges the patch with the
         * parameters of the moment it applies it (so a 422 there may be no 422 here). */
        clothd_config defaults;
        settings_default(&defaults);
        if (params_from_json(object, SET_LIVE, &defaults.scene, pr) != 0 && pr->status == 400) return -1;
    }
    json_t *c;
    if (d->member) c = json_pack("{s:O}", d->member, object);
    else if (d->body == BODY_OBJECT) c = json_copy(object);
    else c = json_object();
    if (c && (d->flags & CMD_ROCK_ID)) json_object_set_new(c, "id", json_integer((json_int_t)id));
    if (!c || json_object_set_new(c, "op", json_string(d->op)) != 0) {
        json_decref(c);
        return problem_set(pr, 500, "internal", NULL, "out of memory");
    }
    *cmd = c;
    return 0;
}

static int rq_change(const api_request *rq, api_reply *out, scene_cmd *later)
{
    problem pr;
    json_t *empty = rq->object ? NULL : json_object();
    const int bad = make_change(rq->def, rq->object ? rq->object : empty, rq->id, &later->body, &pr);
    json_decref(empty);
    if (bad) return reply_problem(out, &pr);
    return API_LATER;
}

/* ---- the table ---- */

#define GET "GET"
#define NONE ACCESS_NONE
#define VIEW ACCESS_VIEW
#define CONTROL ACCESS_CONTROL
#define D SCOPE_DAEMON
#define S SCOPE_SCENE

static const command table[] = {
    /* op           method    scope path           body         access   flags                             member  interrupts  blob_type  request          change              control */
    {"health",      GET,      D, "/v1/health",     BODY_IGNORED, NONE,   0,                                NULL,   NULL,       NULL,   rq_health,       NULL,               NULL},
    {"livez",       GET,      D, "/livez",         BODY_IGNORED, NONE,   0,                                NULL,   NULL,       NULL,   rq_livez,        NULL,               NULL},
    {"readyz",      GET,      D, "/readyz",        BODY_IGNORED, NONE,   0,                                NULL,   NULL,       NULL,   rq_readyz,       NULL,               NULL},
    {"sim",         GET,      S, "/sim",           BODY_IGNORED, VIEW,   0,                                NULL,   NULL,       NULL,   rq_sim,          NULL,               NULL},
    {"pause",       "POST",   S, "/sim/pause",     BODY_NONE,    CONTROL, CMD_ANSWER_SIM | CMD_AFTER_FAILURE, NULL, "pause",   JSON_TYPE, rq_queue,     NULL,               control_pause},
    {"resume",      "POST",   S, "/sim/resume",    BODY_NONE,    CONTROL, CMD_ANSWER_SIM,                  NULL,   "command",  JSON_TYPE, rq_queue,     NULL,               control_resume},
    {"step",        "POST",   S, "/sim/step",      BODY_OBJECT,  CONTROL, CMD_PAUSED,                      NULL,   "step",     NULL,   rq_step,         NULL,               control_step},
    {"step_cancel", "DELETE", S, "/sim/step",      BODY_NONE,    CONTROL, 0,                               NULL,   NULL,       NULL,   rq_queue,        NULL,               control_step_cancel},
    {"reset",       "POST",   S, "/sim/reset",     BODY_NONE,    CONTROL, CMD_REBUILDS,                    NULL,   "command",  NULL,   rq_change,       change_reset,       NULL},
    {"params_get",  GET,      S, "/params",        BODY_IGNORED, VIEW,   0,                                NULL,   NULL,       NULL,   rq_params,       NULL,               NULL},
    {"params",      "PATCH",  S, "/params",        BODY_OBJECT,  CONTROL, 0,                               "params", "command", NULL,   rq_change,       change_params,      NULL},
    {"schema",      GET,      S, "/params/schema", BODY_IGNORED, VIEW,   0,                                NULL,   NULL,       NULL,   rq_schema,       NULL,               NULL},
    {"scene_get",   GET,      S, "/scene",         BODY_IGNORED, VIEW,   0,                                NULL,   NULL,       NULL,   rq_fields,       NULL,               NULL},
    {"scene",       "PUT",    S, "/scene",         BODY_OBJECT,  CONTROL, CMD_REBUILDS,                    "scene", "command", NULL,   rq_change,       change_scene,       NULL},
    {"rocks_get",   GET,      S, "/rocks",         BODY_IGNORED, VIEW,   0,                                NULL,   NULL,       NULL,   rq_rocks,        NULL,               NULL},
    {"rock_add",    "POST",   S, "/rocks",         BODY_OBJECT,  CONTROL, CMD_CREATED,                     "rock", "command",  NULL,   rq_change,       change_rock_add,    NULL},
    {"rocks_clear", "DELETE", S, "/rocks",         BODY_NONE,    CONTROL, 0,                               NULL,   "command",  NULL,   rq_change,       change_rocks_clear, NULL},
    {"rock_get",    GET,      S, "/rocks/{id}",    BODY_IGNORED, VIEW,   CMD_ROCK_ID,                      NULL,   NULL,       NULL,   rq_rock,         NULL,               NULL},
    {"rock_set",    "PATCH",  S, "/rocks/{id}",    BODY_OBJECT,  CONTROL, CMD_ROCK_ID,                     "rock", "command",  NULL,   rq_change,       change_rock_set,    NULL},
    {"rock_remove", "DELETE", S, "/rocks/{id}",    BODY_NONE,    CONTROL, CMD_ROCK_ID,                     NULL,   "command",  NULL,   rq_change,       change_rock_remove, NULL},
    {"pins",        "PUT",    S, "/pins",          BODY_OBJECT,  CONTROL, 0,                               NULL,   "command",  NULL,   rq_change,       change_pins,        NULL},
    {"grab",        "PUT",    S, "/grab",          BODY_OBJECT,  CONTROL, 0,                               NULL,   "command",  NULL,   rq_change,       change_grab,        NULL},
    {"release",     "DELETE", S, "/grab",          BODY_NONE,    CONTROL, 0,                               NULL,   "command",  NULL,   rq_change,       change_release,     NULL},
    {"cloth_state", GET,      S, "/cloth/state",   BODY_IGNORED, VIEW,   CMD_OCTETS_ASKED,                 NULL,   NULL,       NULL,   rq_cloth_state,  NULL,               control_cloth_state},
    {"snapshot_get", GET,     S, "/snapshot",      BODY_IGNORED, VIEW,   0,                                NULL,   NULL,       OCTETS, rq_queue,        NULL,               control_snapshot_get},
    {"snapshot_put", "PUT",   S, "/snapshot",      BODY_BYTES,   CONTROL, CMD_CHANGES,                     NULL,   "command",  NULL,   rq_snapshot_put, NULL,               control_snapshot_put},
    {"journal",     GET,      S, "/journal",       BODY_IGNORED, VIEW,   0,                                NULL,   NULL,       NULL,   rq_journal,      NULL,               NULL},
    {"metrics",     GET,      D, "/metrics",       BODY_IGNORED, VIEW,   0,                                NULL,   NULL,       NULL,   rq_metrics,      NULL,               NULL},
    {"scenes",      GET,      D, "/v1/scenes",     BODY_IGNORED, VIEW,   0,                                NULL,   NULL,       NULL,   rq_scenes,       NULL,               NULL},
    {"scene_create", "POST",  D, "/v1/scenes",     BODY_OBJECT,  CONTROL, CMD_CREATED,                     NULL,   NULL,       NULL,   rq_scene_create, NULL,               NULL},
    {"scene_delete", "DELETE", D, "/v1/scenes/{scene}", BODY_NONE, CONTROL, 0,                             NULL,   NULL,       NULL,   rq_scene_delete, NULL,               NULL},
    {"recording_start", "POST", S, "/recordings",  BODY_OBJECT,  CONTROL, CMD_CREATED,                     NULL,   NULL,       NULL,   rq_recording_start, NULL,            NULL},
    {"recordings",  GET,      D, "/v1/recordings", BODY_IGNORED, VIEW,   0,                                NULL,   NULL,       NULL,   rq_recordings,   NULL,               NULL},
    {"recording_get", GET,    D, "/v1/recordings/{rid}", BODY_IGNORED, VIEW, 0,                            NULL,   NULL,       RECORDING_TYPE, rq_recording_get, NULL,      NULL},
    {"recording_delete", "DELETE", D, "/v1/recordings/{rid}", BODY_NONE, CONTROL, 0,                       NULL,   NULL,       NULL,   rq_recording_delete, NULL,           NULL},
    /* Not routes: queued by another row's request (GET /v1/sim?hash=1, GET /v1/journal as bytes)
     * or by the stream (a client that wants a pose now). */
    {"hash",        NULL,     S, NULL,             BODY_IGNORED, VIEW,   CMD_ANSWER_SIM | CMD_HASH | CMD_AFTER_FAILURE, NULL, NULL, JSON_TYPE, NULL, NULL,     control_publish},
    {"bundle",      NULL,     S, NULL,             BODY_IGNORED, VIEW,   CMD_AFTER_FAILURE,                NULL,   NULL,       OCTETS, NULL,            NULL,               control_bundle},
    {"publish",     NULL,     S, NULL,             BODY_IGNORED, VIEW,   CMD_AFTER_FAILURE,                NULL,   NULL,       NULL,   NULL,            NULL,               control_pose},
    /* (a recording that starts: the publication after it hands the recording its first pose) */
    {"wake",        NULL,     S, NULL,             BODY_IGNORED, VIEW,   0,                                NULL,   NULL,       NULL,   NULL,            NULL,               control_publish},
};
#define N_COMMANDS (sizeof table / sizeof table[0])

size_t command_count(void) { return N_COMMANDS; }

const command *command_at(size_t i) { return i < N_COMMANDS ? &table[i] : NULL; }

const command *command_find(const char *op)
{
    for (size_t i = 0; op && i < N_COMMANDS; i++)
        if (strcmp(table[i].op, op) == 0) return &table[i];
    return NULL;
}

/* The routes' whole patterns, made once: as they address "default", and under the prefix that
 * names their scene. */
static char patterns[N_COMMANDS][48], scene_patterns[N_COMMANDS][64];
static pthread_once_t patterns_once = PTHREAD_ONCE_INIT;

static void make_patterns(void)
{
    for (size_t i = 0; i < N_COMMANDS; i++) {
        if (!table[i].path) continue;
        const int scoped = table[i].scope == SCOPE_SCENE;
        snprintf(patterns[i], sizeof patterns[i], "%s%s", scoped ? API_PREFIX : "", table[i].path);
        snprintf(scene_patterns[i], sizeof scene_patterns[i], "%s%s", scoped ? SCENES_PREFIX "{scene}" : "", table[i].path);
    }
}

const char *command_pattern(const command *c)
{
    pthread_once(&patterns_once, make_patterns);
    return c && c->path ? patterns[c - table] : NULL;
}

const char *command_scene_pattern(const command *c)
{
    pthread_once(&patterns_once, make_patterns);
    return c && c->path ? scene_patterns[c - table] : NULL;
}

void command_print_routes(FILE *out)
{
    for (size_t i = 0; i < N_COMMANDS; i++)
        if (table[i].method) fprintf(out, "%s %s\n", table[i].method, command_pattern(&table[i]));
    for (size_t i = 0; i < N_COMMANDS; i++)
        if (table[i].method && table[i].scope == SCOPE_SCENE)
            fprintf(out, "%s %s\n", table[i].method, command_scene_pattern(&table[i]));
}

/* ---- routes ---- */

/* Whether path matches pattern; {id} takes one segment of digits (into *id, -1 if not digits),
 * {scene} and {rid} one segment of text (into scene, SCENE_ID_MAX + 1 bytes: cut short, it stays
 * invalid). */
static int path_matches(const char *pattern, const char *path, long long *id, char *scene)
{
    const char *brace = strchr(pattern, '{');
    if (!brace) return strcmp(pattern, path) == 0;
    const int text = strncmp(brace, "{scene}", 7) == 0 || strncmp(brace, "{rid}", 5) == 0;
    const size_t pre = (size_t)(brace - pattern), plen = (size_t)(strchr(brace, '}') - brace) + 1;
    if (strncmp(pattern, path, pre) != 0) return 0;
    const char *seg = path + pre;
    const char *slash = strchr(seg, '/');
    const size_t seglen = slash ? (size_t)(slash - seg) : strlen(seg);
    if (seglen == 0 || strcmp(slash ? slash : "", brace + plen) != 0) return 0;
    if (text) {
        snprintf(scene, SCENE_ID_MAX + 1, "%.*s", (int)(seglen < SCENE_ID_MAX ? seglen : SCENE_ID_MAX), seg);
        return 1;
    }
    *id = -1;
    if (seglen <= 10) {
        long long v = 0;
        size_t k = 0;
        for (; k < seglen && isdigit((unsigned char)seg[k]); k++) v = v * 10 + (seg[k] - '0');
        if (k == seglen) *id = v;
    }
    return 1;
}

/* Whether a row's route takes path, with what it addresses: the scene named (into scene) or NULL
 * for the routes of "default"; *prefixed when the path names it. */
static int route_of(const command *c, const char *path, long long *id, char *scene, int *prefixed)
{
    *prefixed = 0;
    if (!c->method) return 0;
    if (c->scope == SCOPE_DAEMON) return path_matches(c->path, path, id, scene);
    const size_t n = strlen(SCENES_PREFIX);
    if (strncmp(path, SCENES_PREFIX, n) == 0) {
        const char *slash = strchr(path + n, '/');
        if (!slash || slash == path + n || !path_matches(c->path, slash, id, scene)) return 0;
        const size_t len = (size_t)(slash - (path + n));
        snprintf(scene, SCENE_ID_MAX + 1, "%.*s", (int)(len < SCENE_ID_MAX ? len : SCENE_ID_MAX), path + n);
        *prefixed = 1;
        return 1;
    }
    const size_t p = strlen(API_PREFIX);
    if (strncmp(path, API_PREFIX, p) != 0 || !path_matches(c->path, path + p, id, scene)) return 0;
    snprintf(scene, SCENE_ID_MAX + 1, "%s", SCENE_DEFAULT);
    return 1;
}

void command_route(const char *method, const char *path, route_match *m)
{
    memset(m, 0, sizeof *m);
    m->label = "unknown";
    m->id = -1;
    const char *want = strcmp(method, "HEAD") == 0 ? "GET" : method;
    for (size_t i = 0; i < N_COMMANDS; i++) {
        long long id = -1;
        char scene[SCENE_ID_MAX + 1] = "";
        int prefixed;
        if (!route_of(&table[i], path, &id, scene, &prefixed)) continue;
        m->path_known = 1;
        m->label = prefixed ? command_scene_pattern(&table[i]) : command_pattern(&table[i]);
        if (strcmp(table[i].method, want) == 0) {
            m->def = &table[i];
            m->id = id;
            if (table[i].path && strstr(table[i].path, "{rid}")) {
                memcpy(m->rid_buf, scene, sizeof m->rid_buf);
                m->rid = m->rid_buf;
            } else {
                memcpy(m->scene_buf, scene, sizeof m->scene_buf);
                m->scene = scene[0] ? m->scene_buf : NULL;
            }
            m->allow[0] = '\0';
            m->path_known = 0;
            return;
        }
        const int get = strcmp(table[i].method, "GET") == 0;
        snprintf(m->allow + strlen(m->allow), sizeof m->allow - strlen(m->allow), "%s%s%s", m->allow[0] ? ", " : "",
                 table[i].method, get ? ", HEAD" : "");
    }
}

int command_is_api(const char *path)
{
    const size_t n = strlen(API_PREFIX);
    if (strncmp(path, API_PREFIX, n) == 0 && (path[n] == '/' || path[n] == '\0')) return 1;
    for (size_t i = 0; i < N_COMMANDS; i++)
        if (table[i].method && table[i].scope == SCOPE_DAEMON && strcmp(table[i].path, path) == 0) return 1;
    return 0;
}

int command_method_changes(const char *method)
{
    return strcmp(method, "GET") != 0 && strcmp(method, "HEAD") != 0 && strcmp(method, "OPTIONS") != 0;
}

access_level command_access(const char *method, const char *path)
{
    route_match m;
    command_route(method, path, &m);
    if (m.def) return m.def->access;
    for (size_t i = 0; m.path_known && i < N_COMMANDS; i++) {
        long long id;
        char scene[SCENE_ID_MAX + 1];
        int prefixed;
        if (route_of(&table[i], path, &id, scene, &prefixed) && table[i].access == ACCESS_NONE) return ACCESS_NONE;
    }
    return command_method_changes(method) ? ACCESS_CONTROL : ACCESS_VIEW;
}

/* The body as the row's policy wants it: *object for BODY_OBJECT (a new reference), NULL for the
 * others; 0, or -1 with the problem. */
static int body_of(const command *d, const char *body, size_t len, json_t **object, problem *pr)
{
    *object = NULL;
    switch (d->body) {
    case BODY_NONE: {
        json_t *empty;
        if (request_body_object(body, len, 0, &empty, pr) != 0) return -1;
        json_decref(empty);
        return 0;
    }
    case BODY_OBJECT: return request_body_object(body, len, 1, object, pr);
    case BODY_BYTES:
        if (len == 0) return problem_set(pr, 400, "bad-snapshot", NULL, "the body must be a snapshot (GET /v1/snapshot)");
        return 0;
    default: return 0;
    }
}

int command_request(const api_request *rq, api_reply *now, scene_cmd *later)
{
    const command *d = rq->def;
    problem pr;
    if ((d->flags & CMD_ROCK_ID) && (rq->id < 1 || rq->id > 4294967295LL)) {
        problem_set(&pr, 404, "not-found", "id", "no rock with that id");
        return reply_problem(now, &pr);
    }
    api_request with = *rq;
    if (body_of(d, rq->body, rq->len, &with.object, &pr) != 0) return reply_problem(now, &pr);
    memset(later, 0, sizeof *later);
    later->def = d;
    const int r = d->request(&with, now, later);
    json_decref(with.object);
    return r;
}

int command_from_request(const char *op, const char *body, size_t len, long long id, json_t **cmd, problem *pr)
{
    *cmd = NULL;
    const command *d = command_find(op);
    if (!d || !d->change) return problem_set(pr, 500, "internal", NULL, "no request makes the op '%s'", op);
    json_t *object;
    if (body_of(d, body, len, &object, pr) != 0) return -1;
    json_t *empty = object ? NULL : json_object();
    const int rc = make_change(d, object ? object : empty, id, cmd, pr);
    json_decref(object);
    json_decref(empty);
    return rc;
}

void command_answer(scene_cmd *c, int binary, api_reply *out)
{
    const command *d = c->def;
    memset(out, 0, sizeof *out);
    if (c->failed) {
        api_problem(out, &c->pr);
        if (strcmp(c->pr.slug, "busy") == 0) out->retry_after = 1; /* the queue drains within a slice */
    } else if (c->blob) {
        const char *type = d->blob_type ? d->blob_type : JSON_TYPE;
        if ((d->flags & CMD_OCTETS_ASKED) && binary) type = OCTETS;
        reply_text(out, 200, type, (char *)c->blob, c->blob_len);
        c->blob = NULL;
    } else {
        reply_json(out, (d->flags & CMD_CREATED) ? 201 : 200, c->result ? c->result : json_object());
        c->result = NULL;
    }
}

/* ---- the sim thread ---- */

int command_apply(cs_sim *sim, loop_settings *loop, const json_t *cmd, json_t **journal, json_t **result, problem *pr)
{
    *journal = *result = NULL;
    const char *op = json_string_value(json_object_get(cmd, "op"));
    if (!op) return problem_set(pr, 400, "wrong-type", "op", "a command needs an op");
    const command *d = command_find(op);
    if (!d || !d->change) return problem_set(pr, 400, "unknown-field", "op", "unknown op '%s'", op);
    return d->change(sim, loop, cmd, journal, result, pr);
}

int command_change(scene *sc, const json_t *cmd, const char *request_id, json_t **result, problem *pr)
{
    cs_info info;
    cs_sim_info(sc->engine, &info);
    json_t *entry = NULL;
    const int32_t seed_before = sc->loop.seed;
    if (command_apply(sc->engine, &sc->loop, cmd, &entry, result, pr) != 0) return -1;
    const char *op = json_string_value(json_object_get(entry, "op"));
    if (command_find(op)->flags & CMD_REBUILDS) {
        sc->frame = 0;
        scene_reseed(sc);
        scene_rebase(sc);
    } else {
        journal_append(sc->journal, info.step, entry);
        if (journal_full(sc->journal)) scene_rebase(sc);
        if (sc->loop.seed != seed_before) scene_reseed(sc);
        const loop_settings *p = &sc->loop;
        if (p->auto_drop_interval > 0 && sc->next_drop > info.time + p->auto_drop_interval)
            sc->next_drop = info.time + p->auto_drop_interval;
    }
    if (*result) json_object_set_new(*result, "applied_step", json_integer((json_int_t)info.step));
    scene_emit(sc, json_pack("{s:s, s:I, s:O, s:O}", "event", op, "applied_step", (json_int_t)info.step, "command", entry,
                             "result", *result ? *result : json_null()),
               request_id);
    json_decref(entry);
    return 0;
}

int command_run(scene *sc, scene_cmd *c)
{
    const command *d = c->def;
    /* After a backend failure, until the daemon has stopped the sim thread: nothing touches the
     * lost engine. Pauses, publications and the journal (kept in memory) still answer. */
    if (!scene_healthy(sc) && !(d->flags & CMD_AFTER_FAILURE)) {
        c->failed = 1;
        problem_set(&c->pr, 503, "unavailable", NULL, "the backend has failed; the daemon is saving the state and exiting");
        return 0;
    }
    if (sc->job.cmd && d->interrupts) scene_end_step(sc, d->interrupts);
    if ((d->flags & CMD_PAUSED) && !sc->paused) {
        c->failed = 1;
        problem_set(&c->pr, 409, "wrong-state", NULL, "%s only while paused: POST /v1/sim/pause first", d->op);
        return 0;
    }
    if (d->change || (d->flags & CMD_CHANGES)) sc->changes++;
    int kept = 0;
    if (d->change) {
        if (command_change(sc, c->body, c->request_id, &c->result, &c->pr) != 0) c->failed = 1;
    } else {
        kept = d->control(sc, c);
    }
    if (d->flags & (CMD_REBUILDS | CMD_CHANGES)) scenes_resized(sc->table, sc); /* it may have been resized */
    return kept;
}

int command_wants_hash(const scene_cmd *c) { return (c->def->flags & CMD_HASH) != 0; }

void command_finish(scene *sc, scene_cmd *c)
{
    if (!c->failed && (c->def->flags & CMD_ANSWER_SIM)) c->blob = (unsigned char *)scene_doc_copy(sc, DOC_SIM, &c->blob_len);
    c->done(c, c->done_arg);
}
