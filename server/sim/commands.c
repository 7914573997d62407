/* commands.c - the command table, the routes it makes and the checks made from its columns (see
 * commands.h); the rows' request functions are in the cmd_*.c files (commands_internal.h). */
#include <ctype.h>
#include <pthread.h>
#include <stdio.h>
#include <string.h>

#include "core/json_read.h"
#include "core/json_write.h"
#include "sim/changes.h"
#include "sim/commands.h"
#include "sim/commands_internal.h"
#include "sim/controls.h"
#include "sim/scenes.h"

#define PROBLEM_TYPE "application/problem+json"

/* ---- answers ---- */

int reply_text(api_reply *out, int status, const char *ctype, char *body, size_t len)
{
    out->status = status;
    out->ctype = ctype;
    out->body = body;
    out->len = len;
    return API_NOW;
}

int reply_json(api_reply *out, int status, json_t *o)
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

int reply_problem(api_reply *out, const problem *pr)
{
    api_problem(out, pr);
    return API_NOW;
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
    {"params",      "PATCH",  S, "/params",        BODY_OBJECT,  CONTROL, CMD_COSTS,                       "params", "command", NULL,   rq_change,       change_params,      NULL},
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
    if (d->flags & (CMD_REBUILDS | CMD_CHANGES | CMD_COSTS)) scenes_resized(sc->table, sc); /* its cost may have changed */
    return kept;
}

int command_wants_hash(const scene_cmd *c) { return (c->def->flags & CMD_HASH) != 0; }

void command_finish(scene *sc, scene_cmd *c)
{
    if (!c->failed && (c->def->flags & CMD_ANSWER_SIM)) c->blob = (unsigned char *)scene_doc_copy(sc, DOC_SIM, &c->blob_len);
    c->done(c, c->done_arg);
}
