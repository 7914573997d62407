/* scene.c - a scene and what the daemon keeps beside its engine (see scene.h). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "core/clock.h"
#include "core/json_read.h"
#include "core/json_write.h"
#include "core/log.h"
#include "core/params_json.h"
#include "core/rock_json.h"
#include "core/stream_msg.h"
#include "sim/scene.h"

#define ENERGY_EVERY 0.1 /* s of wall time between energy evaluations while running */

/* ---- lifecycle ---- */

scene *scene_new(const char *id, cs_sim *engine, const loop_settings *loop, int paused, const clothd_settings *set)
{
    scene *sc = calloc(1, sizeof *sc);
    if (!sc) {
        cs_sim_destroy(engine);
        return NULL;
    }
    snprintf(sc->id, sizeof sc->id, "%s", id);
    atomic_init(&sc->refs, 1);
    sc->engine = engine;
    sc->loop = *loop;
    sc->queue_max = set->queue_max;
    sc->healthy = 1;
    sc->changes = 1; /* the first pose a listener asks for is new */
    sc->paused = paused;
    pthread_mutex_init(&sc->qlock, NULL);
    pthread_mutex_init(&sc->plock, NULL);
    pthread_mutex_init(&sc->rlock, NULL);
    sc->journal = journal_new((size_t)set->journal_max, (size_t)set->journal_max_mb << 20);
    if (!sc->journal) {
        scene_release(sc);
        return NULL;
    }
    cs_info info;
    cs_sim_info(engine, &info);
    sc->frame = info.step / (uint64_t)info.substeps;
    scene_reseed(sc);
    scene_rebase(sc);
    scene_publish(sc, sc->paused);
    return sc;
}

int scene_add_sink(scene *sc, frame_sink sink)
{
    if (!sink.ops) return 0;
    int r = 0;
    pthread_mutex_lock(&sc->qlock);
    const int n = atomic_load(&sc->n_sinks);
    int there = 0, lender = 0;
    for (int s = 0; s < n; s++) {
        there |= sc->sinks[s].ops == sink.ops && sc->sinks[s].ctx == sink.ctx;
        lender |= sc->sinks[s].ops->begin != NULL;
    }
    if (sc->sinks_closed || (!there && (n == SCENE_SINKS || (lender && sink.ops->begin)))) {
        r = -1;
    } else if (!there) {
        sc->sinks[n] = sink;
        atomic_store(&sc->n_sinks, n + 1); /* the sim thread sees the sink once it sees the count */
    }
    pthread_mutex_unlock(&sc->qlock);
    return r;
}

void scene_set_sink(scene *sc, frame_sink sink)
{
    if (scene_add_sink(sc, sink) != 0) log_msg("scene %s: no room for one more sink", sc->id);
}

void scene_set_frame_hook(scene *sc, void (*hook)(cs_sim *engine, uint64_t frame)) { sc->before_frame = hook; }

scene *scene_hold(scene *sc)
{
    atomic_fetch_add(&sc->refs, 1);
    return sc;
}

void scene_release(scene *sc)
{
    if (!sc || atomic_fetch_sub(&sc->refs, 1) != 1) return;
    cs_sim_destroy(sc->engine);
    journal_free(sc->journal);
    free(sc->checkpoint);
    json_decref(sc->last_event);
    json_decref(sc->job.before_event);
    for (int d = 0; d < DOC_COUNT; d++) free(sc->docs[d]);
    free(sc->torn);
    free(sc->scratch);
    free(sc->rocks);
    pose_free(&sc->own_pose);
    pthread_mutex_destroy(&sc->qlock);
    pthread_mutex_destroy(&sc->plock);
    pthread_mutex_destroy(&sc->rlock);
    free(sc);
}

/* ---- the queue ---- */

static void refuse_as(scene_cmd *c, int status, const char *slug, const char *param, const char *detail)
{
    c->failed = 1;
    c->result = NULL;
    c->blob = NULL;
    problem_set(&c->pr, status, slug, param, "%s", detail);
    c->done(c, c->done_arg);
}

static void refuse(scene_cmd *c, const char *slug, const char *detail) { refuse_as(c, 503, slug, NULL, detail); }

static void refuse_deleted(scene *sc, scene_cmd *c)
{
    char detail[128];
    snprintf(detail, sizeof detail, "the scene '%s' was deleted", sc->id);
    refuse_as(c, 404, "not-found", "scene", detail);
}

void scene_submit(scene *sc, scene_cmd *cmd)
{
    cmd->next = NULL;
    pthread_mutex_lock(&sc->qlock);
    const int deleted = sc->deleted, closed = sc->closed || deleted, full = sc->queued >= sc->queue_max;
    if (!closed && !full) {
        if (sc->tail) sc->tail->next = cmd;
        else sc->head = cmd;
        sc->tail = cmd;
        sc->queued++;
    }
    void (*wake)(void *) = sc->wake;
    void *ctx = sc->wake_ctx;
    pthread_mutex_unlock(&sc->qlock);
    if (!closed && !full) {
        if (wake) wake(ctx);
        return;
    }
    if (deleted) {
        refuse_deleted(sc, cmd);
        return;
    }
    if (closed) {
        refuse(cmd, "unavailable", "clothd is shutting down");
        return;
    }
    char detail[160];
    snprintf(detail, sizeof detail, "the simulation has queue_max (%d) commands waiting already; retry in a second",
             sc->queue_max);
    refuse(cmd, "busy", detail);
}

void scene_set_wake(scene *sc, void (*wake)(void *ctx), void *ctx)
{
    pthread_mutex_lock(&sc->qlock);
    sc->wake = wake;
    sc->wake_ctx = ctx;
    pthread_mutex_unlock(&sc->qlock);
}

scene_cmd *scene_take_queue(scene *sc)
{
    pthread_mutex_lock(&sc->qlock);
    scene_cmd *list = sc->head;
    sc->head = sc->tail = NULL;
    sc->queued = 0;
    pthread_mutex_unlock(&sc->qlock);
    return list;
}

void scene_close(scene *sc)
{
    pthread_mutex_lock(&sc->qlock);
    sc->closed = 1;
    pthread_mutex_unlock(&sc->qlock);
}

void scene_refuse_queued(scene *sc)
{
    for (scene_cmd *c = scene_take_queue(sc), *next; c; c = next) {
        next = c->next;
        refuse(c, "unavailable", "clothd is shutting down");
    }
}

void scene_mark_deleted(scene *sc)
{
    pthread_mutex_lock(&sc->qlock);
    sc->deleted = 1;
    pthread_mutex_unlock(&sc->qlock);
}

int scene_is_deleted(scene *sc)
{
    pthread_mutex_lock(&sc->qlock);
    const int deleted = sc->deleted;
    pthread_mutex_unlock(&sc->qlock);
    return deleted;
}

void scene_drop_deleted(scene *sc)
{
    pthread_mutex_lock(&sc->qlock);
    frame_sink sinks[SCENE_SINKS];
    const int n = atomic_load(&sc->n_sinks);
    memcpy(sinks, sc->sinks, sizeof *sinks * (size_t)n);
    sc->sinks_closed = 1;
    atomic_store(&sc->n_sinks, 0);
    pthread_mutex_unlock(&sc->qlock);
    for (int s = 0; s < n; s++)
        if (sinks[s].ops->gone) sinks[s].ops->gone(sinks[s].ctx);
    scene_end_step(sc, "deleted");
    for (scene_cmd *c = scene_take_queue(sc), *next; c; c = next) {
        next = c->next;
        refuse_deleted(sc, c);
    }
}

/* ---- published reads ---- */

char *scene_doc_copy(scene *sc, scene_doc doc, size_t *len)
{
    pthread_mutex_lock(&sc->plock);
    char *s = sc->docs[doc] ? malloc(sc->doc_len[doc] + 1) : NULL;
    if (s) {
        memcpy(s, sc->docs[doc], sc->doc_len[doc] + 1);
        *len = sc->doc_len[doc];
    }
    pthread_mutex_unlock(&sc->plock);
    return s;
}

int scene_rocks(scene *sc, cs_rock **out)
{
    pthread_mutex_lock(&sc->plock);
    const int n = sc->n_rocks;
    *out = n ? malloc(sizeof **out * (size_t)n) : NULL;
    if (*out) memcpy(*out, sc->rocks, sizeof **out * (size_t)n);
    pthread_mutex_unlock(&sc->plock);
    return *out || n == 0 ? n : 0;
}

void scene_gauges(scene *sc, metrics_gauges *g)
{
    pthread_mutex_lock(&sc->plock);
    *g = sc->gauges;
    g->healthy = sc->healthy;
    pthread_mutex_unlock(&sc->plock);
}

int scene_healthy(scene *sc)
{
    pthread_mutex_lock(&sc->plock);
    const int h = sc->healthy;
    pthread_mutex_unlock(&sc->plock);
    return h;
}

/* Replaces a published text (the old one is freed; kept when the new one could not be made). */
static void set_doc(scene *sc, scene_doc doc, char *text)
{
    if (!text) return;
    pthread_mutex_lock(&sc->plock);
    char *old = sc->docs[doc];
    sc->docs[doc] = text;
    sc->doc_len[doc] = strlen(text);
    pthread_mutex_unlock(&sc->plock);
    free(old);
}

/* ---- events ---- */

void scene_emit(scene *sc, json_t *ev, const char *request_id)
{
    const int n = atomic_load(&sc->n_sinks);
    if (n == 0) {
        json_decref(ev);
        return;
    }
    json_object_set_new(ev, "type", json_string("event"));
    json_object_set_new(ev, "request_id", request_id && request_id[0] ? json_string(request_id) : json_null());
    json_object_set_new(ev, "scene_id", json_string(sc->id));
    char *text = json_dumps(ev, JSON_DUMP_FLAGS);
    json_decref(ev);
    for (int s = 0; text && s < n; s++)
        if (sc->sinks[s].ops->event) sc->sinks[s].ops->event(sc->sinks[s].ctx, text);
    free(text);
}

json_t *scene_hello(scene *sc, const cs_rock *rocks, int n_rocks)
{
    size_t len;
    char *fields = scene_doc_copy(sc, DOC_FIELDS, &len), *params = scene_doc_copy(sc, DOC_PARAMS, &len);
    char *sim = scene_doc_copy(sc, DOC_SIM, &len), *torn = scene_doc_copy(sc, DOC_TORN, &len);
    json_t *list;
    if (rocks) {
        list = rocks_to_json(rocks, n_rocks);
    } else {
        cs_rock *copy;
        const int n = scene_rocks(sc, &copy);
        list = rocks_to_json(copy, n);
        free(copy);
    }
    json_t *sj = sim ? json_loads(sim, 0, NULL) : NULL;
    json_t *o = json_pack("{s:s, s:s, s:s, s:o, s:o, s:o, s:o, s:O*, s:O*}", "type", "hello", "protocol", STREAM_PROTOCOL,
                          "scene_id", sc->id, "scene", fields ? json_loads(fields, 0, NULL) : json_null(), "params",
                          params ? json_loads(params, 0, NULL) : json_null(), "rocks", list, "torn",
                          torn ? json_loads(torn, 0, NULL) : json_array(), "state", json_object_get(sj, "state"), "step",
                          json_object_get(sj, "step"));
    json_decref(sj);
    free(fields);
    free(params);
    free(sim);
    free(torn);
    return o;
}

void scene_set_event(scene *sc, json_t *ev)
{
    json_decref(sc->last_event);
    sc->last_event = ev;
}

/* ---- the state the daemon keeps ---- */

void scene_config_of(const scene *sc, scene_config *out)
{
    cs_sim_scene(sc->engine, &out->fields);
    cs_sim_params(sc->engine, &out->params);
    out->loop = sc->loop;
}

void scene_take_checkpoint(scene *sc)
{
    const size_t need = cs_snapshot_size(sc->engine);
    if (need > sc->checkpoint_cap) {
        unsigned char *b = realloc(sc->checkpoint, need);
        if (!b) {
            log_msg("checkpoint: out of memory (%zu bytes); keeping the previous one", need);
            return;
        }
        sc->checkpoint = b;
        sc->checkpoint_cap = need;
    }
    if (cs_snapshot_save(sc->engine, sc->checkpoint, sc->checkpoint_cap, &sc->checkpoint_len) == CS_OK)
        sc->checkpoint_frame = sc->frame;
    else
        log_msg("checkpoint failed: %s; keeping the previous one", cs_sim_error(sc->engine));
    sc->frames_since_checkpoint = 0;
}

void scene_rebase(scene *sc)
{
    scene_take_checkpoint(sc);
    cs_info info;
    cs_sim_info(sc->engine, &info);
    if (journal_rebase(sc->journal, sc->checkpoint, sc->checkpoint_len, info.step) != 0)
        log_msg("journal: out of memory while starting afresh");
}

void scene_reseed(scene *sc)
{
    const loop_settings *p = &sc->loop;
    cs_info info;
    cs_sim_info(sc->engine, &info);
    sc->seed = p->seed;
    sc->rng = (uint64_t)p->seed;
    sc->n_autos = 0;
    sc->next_drop = info.time + (p->auto_drop_interval < 1.0f ? p->auto_drop_interval : 1.0);
}

/* ---- publishing ---- */

/* Keeps the list of torn springs (and its published JSON); returns the newly torn ones as a JSON
 * array (NULL when none are new: a rebuild or restore only replaces the list). */
static json_t *update_torn(scene *sc)
{
    cs_info info;
    cs_sim_info(sc->engine, &info);
    if (info.n_torn == sc->n_torn) return NULL;
    uint32_t *now = malloc(sizeof *now * (size_t)(info.n_torn ? info.n_torn : 1));
    if (!now) return NULL;
    const int64_t n = cs_read_torn(sc->engine, now, (size_t)info.n_torn);
    json_t *fresh = n > sc->n_torn ? json_array() : NULL;
    for (int64_t a = 0, b = 0; fresh && a < n; a++) {
        while (b < sc->n_torn && sc->torn[b] < now[a]) b++;
        if (b >= sc->n_torn || sc->torn[b] != now[a]) json_array_append_new(fresh, json_integer(now[a]));
    }
    free(sc->torn);
    sc->torn = now;
    sc->n_torn = n;
    json_t *all = json_array();
    for (int64_t k = 0; k < n; k++) json_array_append_new(all, json_integer(now[k]));
    set_doc(sc, DOC_TORN, json_dumps(all, JSON_DUMP_FLAGS));
    json_decref(all);
    return fresh;
}

static float *scratch(scene *sc, size_t floats)
{
    if (floats > sc->scratch_cap) {
        float *g = realloc(sc->scratch, sizeof(float) * floats);
        if (!g) return NULL;
        sc->scratch = g;
        sc->scratch_cap = floats;
    }
    return sc->scratch;
}

/* The scalars: speed (255 at SCALAR_SPEED_FULL) and strain, the largest stretch of a vertex's
 * intact structural springs (255 at SCALAR_STRAIN_FULL). */
static void fill_scalars(scene *sc, pose *f, unsigned want)
{
    const int32_t n = f->n;
    float *buf;
    f->has[SCALAR_SPEED] = f->has[SCALAR_STRAIN] = 0;
    if ((want & (1u << SCALAR_SPEED)) && (buf = scratch(sc, 3 * (size_t)n)) &&
        cs_read_velocities(sc->engine, buf, 3 * (size_t)n) == CS_OK) {
        for (int32_t v = 0; v < n; v++) {
            const float s = sqrtf(buf[3 * v] * buf[3 * v] + buf[3 * v + 1] * buf[3 * v + 1] + buf[3 * v + 2] * buf[3 * v + 2]);
            const float q = s / SCALAR_SPEED_FULL * 255.0f;
            f->scalar[SCALAR_SPEED][v] = (uint8_t)(q < 255.0f ? q : 255.0f);
        }
        f->has[SCALAR_SPEED] = 1;
    }
    if ((want & (1u << SCALAR_STRAIN)) && (buf = scratch(sc, (size_t)n)) && cs_read_strain(sc->engine, buf, (size_t)n) == CS_OK) {
        for (int32_t v = 0; v < n; v++) {
            const float q = buf[v] / SCALAR_STRAIN_FULL * 255.0f;
            f->scalar[SCALAR_STRAIN][v] = (uint8_t)(q < 255.0f ? q : 255.0f);
        }
        f->has[SCALAR_STRAIN] = 1;
    }
}

/* Hands the current positions, rocks and scalars to the sink that lends a buffer (when someone
 * listens and there is something new for it) and the positions and rocks to the copiers that want
 * them (the recordings: when one runs and the scene changed since the last pose they were handed,
 * or one has none yet); in the order of sink.h. */
static void publish_pose(scene *sc, const cs_info *info, const cs_rock *rocks, int n_rocks)
{
    const int n = atomic_load(&sc->n_sinks);
    const frame_sink *lender = NULL;
    int lent_at = 0;
    unsigned want = 0;
    pose *f = NULL;
    for (int s = 0; s < n && !lender; s++)
        if (sc->sinks[s].ops->begin) lender = &sc->sinks[s], lent_at = s;
    if (lender) f = lender->ops->begin(lender->ctx, &want);
    if (f && !sc->pose_asked && sc->changes == sc->framed_changes[lent_at] && (want & ~sc->framed_scalars) == 0) {
        lender->ops->discard(lender->ctx, f);
        f = NULL;
    }
    int takes[SCENE_SINKS] = {0}, any = 0;
    for (int s = 0; s < n; s++) {
        const frame_sink *k = &sc->sinks[s];
        takes[s] = k->ops->take && k->ops->want(k->ctx, sc->changes != sc->framed_changes[s]);
        any |= takes[s];
    }
    if (!f && !any) return;
    pose *p = f ? f : &sc->own_pose;
    if (pose_reserve(p, info->n_vertices, n_rocks) != 0 ||
        cs_read_positions(sc->engine, p->xyz, 3 * (size_t)info->n_vertices) != CS_OK) {
        if (f) lender->ops->discard(lender->ctx, f); /* listeners keep the pose they have */
        return;
    }
    p->wall_ns = clock_wall_ns();
    p->frame = sc->frame;
    p->step = info->step;
    p->sim_time = info->time;
    p->n = info->n_vertices;
    cs_scene shape;
    cs_sim_scene(sc->engine, &shape);
    p->nx = shape.nx;
    p->n_rocks = n_rocks;
    for (int r = 0; r < n_rocks; r++) {
        pose_rock *k = &p->rocks[r];
        k->id = rocks[r].id;
        memcpy(k->position, rocks[r].def.position, sizeof k->position);
        k->radius = rocks[r].def.radius;
        memcpy(k->orientation, rocks[r].def.orientation, sizeof k->orientation);
    }
    pose_bbox(p);
    for (int s = 0; s < n; s++) {
        if (!takes[s]) continue;
        const frame_sink *k = &sc->sinks[s];
        k->ops->take(k->ctx, p, rocks, n_rocks, sc->changes != sc->framed_changes[s]);
        sc->framed_changes[s] = sc->changes;
    }
    if (!f) return;
    fill_scalars(sc, f, want);
    sc->framed_changes[lent_at] = sc->changes;
    sc->framed_scalars = want;
    sc->pose_asked = 0;
    lender->ops->publish(lender->ctx, f);
}

void scene_publish(scene *sc, int with_hash)
{
    cs_info info;
    cs_sim_info(sc->engine, &info);
    const double t = clock_mono();
    if ((sc->paused && !sc->job.cmd) || t - sc->last_energy >= ENERGY_EVERY) {
        cs_energy_get(sc->engine, &sc->energy);
        sc->last_energy = t;
    }
    char hex[17];
    json_t *hash = json_null();
    if (with_hash && scene_healthy(sc)) { /* a lost backend has no state to hash */
        cs_hash_hex(cs_state_hash(sc->engine), hex);
        hash = json_string(hex);
    }
    json_t *o = json_pack(
        "{s:s, s:I, s:I, s:f, s:f, s:f, s:i, s:f, s:s, s:i, s:i, s:I, s:i,"
        " s:{s:f, s:f, s:f, s:f}, s:o, s:O, s:{s:i, s:i, s:i, s:f}}",
        "state", sc->paused ? "paused" : "running", "step", (json_int_t)info.step, "frame", (json_int_t)sc->frame,
        "sim_time", info.time, "dt", info.dt, "dt_max", info.dt_max, "substeps", (int)info.substeps,
        "realtime_factor", sc->paused ? 0.0 : sc->rtf, "backend", cs_sim_backend(sc->engine), "n_vertices",
        (int)info.n_vertices, "n_springs", (int)info.n_springs, "n_torn", (json_int_t)info.n_torn, "n_rocks",
        (int)info.n_rocks, "energy", "kinetic", sc->energy.kinetic, "spring", sc->energy.spring, "gravity",
        sc->energy.gravity, "total", sc->energy.total, "state_hash", hash, "last_event",
        sc->last_event ? sc->last_event : json_null(), "solver", "substeps", (int)info.solver.substeps, "newton",
        (int)info.solver.newton, "iterations", (int)info.solver.cg, "residual", (double)info.solver.residual);
    set_doc(sc, DOC_SIM, json_dumps(o, JSON_DUMP_FLAGS));
    json_decref(o);

    scene_config cfg;
    scene_config_of(sc, &cfg);
    json_t *pj = params_to_json(SET_LIVE, &cfg), *sj = params_to_json(SET_SCENE, &cfg);
    set_doc(sc, DOC_PARAMS, json_dumps(pj, JSON_DUMP_FLAGS));
    set_doc(sc, DOC_FIELDS, json_dumps(sj, JSON_DUMP_FLAGS));
    json_decref(pj);
    json_decref(sj);

    const int n_rocks = cs_rock_count(sc->engine);
    cs_rock *rocks = n_rocks ? malloc(sizeof *rocks * (size_t)n_rocks) : NULL;
    for (int r = 0; rocks && r < n_rocks; r++) cs_rock_at(sc->engine, r, &rocks[r]);
    json_t *torn = update_torn(sc);
    if (torn) scene_emit(sc, json_pack("{s:s, s:I, s:o}", "event", "torn", "step", (json_int_t)info.step, "springs", torn), NULL);
    publish_pose(sc, &info, rocks, rocks ? n_rocks : 0);

    pthread_mutex_lock(&sc->plock);
    cs_rock *old_rocks = sc->rocks;
    if (rocks || n_rocks == 0) sc->rocks = rocks, sc->n_rocks = n_rocks;
    else old_rocks = NULL;
    sc->gauges.realtime_factor = sc->paused ? 0.0 : sc->rtf;
    sc->gauges.rocks = n_rocks;
    sc->gauges.vertices = info.n_vertices;
    sc->gauges.torn = info.n_torn;
    sc->gauges.paused = sc->paused;
    sc->gauges.sim_time = info.time;
    pthread_mutex_unlock(&sc->plock);
    free(old_rocks);
    sc->last_publish = t;
}

/* ---- stepping and its failures ---- */

/* The non-finite state guard: back to the last checkpoint, paused, event published. */
static void roll_back(scene *sc)
{
    cs_info bad;
    cs_sim_info(sc->engine, &bad);
    const cs_status st = cs_snapshot_load(sc->engine, sc->checkpoint, sc->checkpoint_len);
    if (st == CS_OK) sc->frame = sc->checkpoint_frame;
    cs_info now;
    cs_sim_info(sc->engine, &now);
    sc->paused = 1;
    scene_set_event(sc, json_pack("{s:s, s:I, s:I, s:s}", "type", "instability", "step", (json_int_t)bad.step,
                                  "restored_step", (json_int_t)now.step, "detail",
                                  st == CS_OK ? "the state stopped being finite; rolled back to the last checkpoint and paused"
                                              : "the state stopped being finite and the checkpoint could not be restored"));
    scene_emit(sc, json_pack("{s:s, s:O}", "event", "instability", "detail", sc->last_event), NULL);
    if (st != CS_OK) {
        /* The good checkpoint is kept (no rebase, which would replace it with this state). */
        log_msg("instability at step %llu: the checkpoint could not be restored (%s); paused",
                (unsigned long long)bad.step, cs_sim_error(sc->engine));
        return;
    }
    log_msg("instability at step %llu: rolled back to step %llu and paused", (unsigned long long)bad.step,
            (unsigned long long)now.step);
    scene_rebase(sc);
}

/* A failure that loses the backend: unhealthy, paused, and the sim thread tells the daemon. */
static void backend_lost(scene *sc)
{
    cs_info info;
    cs_sim_info(sc->engine, &info);
    log_msg("backend failure at step %llu: %s", (unsigned long long)info.step, cs_sim_error(sc->engine));
    pthread_mutex_lock(&sc->plock);
    sc->healthy = 0;
    pthread_mutex_unlock(&sc->plock);
    sc->paused_before_failure = sc->paused;
    sc->paused = 1;
    sc->lost = 1;
    scene_set_event(sc, json_pack("{s:s, s:I, s:s}", "type", "backend_failure", "step", (json_int_t)info.step, "detail",
                                  cs_sim_error(sc->engine)));
    scene_emit(sc, json_pack("{s:s, s:O}", "event", "backend_failure", "detail", sc->last_event), NULL);
}

/* The step count has reached CS_STEP_MAX: paused, with the event (a snapshot brought it there). */
static void step_limit(scene *sc)
{
    cs_info info;
    cs_sim_info(sc->engine, &info);
    sc->paused = 1;
    scene_set_event(sc, json_pack("{s:s, s:I, s:s}", "type", "step_limit", "step", (json_int_t)info.step, "detail",
                                  cs_sim_error(sc->engine)));
    scene_emit(sc, json_pack("{s:s, s:O}", "event", "step_limit", "detail", sc->last_event), NULL);
    log_msg("step %llu: %s; paused", (unsigned long long)info.step, cs_sim_error(sc->engine));
}

cs_status scene_run_substeps(scene *sc, int64_t n)
{
    const double t0 = clock_mono();
    const cs_status st = cs_sim_step(sc->engine, n);
    return scene_ran_substeps(sc, n, st, clock_mono() - t0);
}

cs_status scene_ran_substeps(scene *sc, int64_t n, cs_status st, double took)
{
    sc->changes++;
    cs_info info;
    cs_sim_info(sc->engine, &info);
    if (st == CS_OK && info.n_vertices > 0) {
        /* Down at once, up by half at most: a call the scheduler held up (a loaded machine) says
         * little about the next one. */
        const double c = took / ((double)n * (double)info.n_vertices);
        sc->cost = sc->cost <= 0 || c < sc->cost ? c : (c < 1.5 * sc->cost ? c : 1.5 * sc->cost);
    }
    sc->frame_wall += took;
    sc->failed_as = st == CS_E_NONFINITE ? "instability" : st == CS_E_LIMIT ? "step_limit" : NULL;
    if (st == CS_E_NONFINITE) roll_back(sc);
    else if (st == CS_E_LIMIT) step_limit(sc);
    else if (st != CS_OK) backend_lost(sc);
    return st;
}

/* ---- a step in progress ---- */

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

int scene_step_start(scene *sc, scene_cmd *c)
{
    long long n = 0;
    int frames = 0;
    if (step_from_json(c->body, &frames, &n, &c->pr) != 0) {
        c->failed = 1;
        return 0;
    }
    cs_info info;
    cs_sim_info(sc->engine, &info);
    const uint64_t substeps = (uint64_t)n * (frames ? (uint64_t)info.substeps : 1);
    if (substeps > CS_STEP_MAX - info.step) {
        c->failed = 1;
        problem_set(&c->pr, 422, "limit", frames ? "frames" : "substeps",
                    "%llu more substeps would take the step count (%llu) past 2^63 - 1", (unsigned long long)substeps,
                    (unsigned long long)info.step);
        return 0;
    }
    sc->job = (step_job){c, frames, n, 0, info.step, json_incref(sc->last_event)};
    return 1;
}

void scene_end_step(scene *sc, const char *interrupted_by)
{
    step_job *j = &sc->job;
    scene_cmd *c = j->cmd;
    if (!c) return;
    j->cmd = NULL;
    sc->frame_sub = 0; /* a frame stepped part way counts in the step, not as a frame */
    cs_info info;
    cs_sim_info(sc->engine, &info);
    if (!scene_healthy(sc)) {
        c->failed = 1;
        problem_set(&c->pr, 503, "unavailable", NULL, "the backend failed while stepping; the daemon is saving and exiting");
    } else {
        char hex[17];
        cs_hash_hex(cs_state_hash(sc->engine), hex);
        const uint64_t ran = info.step >= j->step0 ? info.step - j->step0 : 0; /* a rollback goes back */
        c->result = json_pack("{s:I, s:I, s:f, s:s, s:I, s:I, s:b}", "step", (json_int_t)info.step, "frame",
                              (json_int_t)sc->frame, "sim_time", info.time, "state_hash", hex, "frames_run",
                              (json_int_t)j->frames_run, "substeps_run", (json_int_t)ran, "interrupted",
                              interrupted_by != NULL);
        if (interrupted_by) json_object_set_new(c->result, "interrupted_by", json_string(interrupted_by));
        if (sc->last_event && sc->last_event != j->before_event) json_object_set(c->result, "event", sc->last_event);
        scene_emit(sc, json_pack("{s:s, s:I, s:I}", "event", "stepped", "step", (json_int_t)info.step, "frame",
                                 (json_int_t)sc->frame),
                   c->request_id);
    }
    json_decref(j->before_event);
    j->before_event = NULL;
    scene_publish(sc, 1); /* before the answer: a read that follows it sees the step */
    c->done(c, c->done_arg);
}

/* ---- what a scene costs ---- */

/* Bytes GET /v1/cloth/state's JSON may take for n vertices: 2 n vectors of three %.9g numbers at
 * 18 characters each, brackets and commas included, and the object around them. */
static uint64_t cloth_json_cap(uint64_t n) { return 128 + n * 2 * 3 * 18; }

/* Bytes of the torn-spring list (ids of u32) and of its JSON ("4294967295," at most) when every
 * spring of n vertices is torn. */
static uint64_t torn_cap(uint64_t n) { return (uint64_t)CS_SPRING_TYPES_PER_VERTEX * n * (sizeof(uint32_t) + 11) + 16; }

cs_status scene_cost(const cs_scene *fields, const cs_params *params, int32_t rocks, void *ctx, uint64_t *bytes)
{
    const frame_sink_ops *sink = ctx;
    uint64_t engine, snap;
    cs_status st = cs_scene_memory(fields, params, rocks, &engine);
    if (st == CS_OK) st = cs_snapshot_bytes(fields, rocks, &snap);
    if (st != CS_OK) return st;
    const uint64_t n = (uint64_t)fields->nx * (uint64_t)fields->ny; /* no overflow: cs_scene_memory took it */
    if (n > INT32_MAX) return CS_E_LIMIT;
    /* cloth_state's JSON and the positions and velocities it is made from, or a snapshot */
    const uint64_t cloth = cloth_json_cap(n) + 2 * 3 * sizeof(float) * n, answer = cloth > snap ? cloth : snap;
    const uint64_t scalars = sizeof(float) * 3 * n; /* fill_scalars' scratch (velocities, or strains) */
    const uint64_t held = sink && sink->bytes ? sink->bytes((int32_t)n, rocks) : 0;
    *bytes = engine + 2 * snap + answer + held + scalars + 2 * torn_cap(n);
    return CS_OK;
}

uint64_t scene_cloth_json_cap(uint64_t n) { return cloth_json_cap(n); }

cs_sim *scene_engine_new(const scene_config *cfg, const clothd_settings *set, const char *backend, void *cost_ctx,
                         cs_status *st, char *err, size_t err_len)
{
    cs_sim *sim = NULL;
    const uint64_t limit = (uint64_t)set->max_state_mb << 20;
    uint64_t bytes;
    if (scene_cost(&cfg->fields, &cfg->params, set->max_rocks, cost_ctx, &bytes) != CS_OK || bytes > limit) {
        snprintf(err, err_len, "a %d x %d cloth needs more than max_state_mb (%d MiB)", (int)cfg->fields.nx,
                 (int)cfg->fields.ny, (int)set->max_state_mb);
        *st = CS_E_LIMIT;
        return NULL;
    }
    *st = cs_sim_create(&cfg->fields, &cfg->params, backend, &sim, err, err_len);
    if (*st != CS_OK) return NULL;
    cs_sim_set_threads(sim, set->threads);
    cs_sim_set_rock_limit(sim, set->max_rocks);
    cs_sim_set_memory_limit(sim, limit, scene_cost, cost_ctx);
    return sim;
}

/* ---- for the state file ---- */

cs_sim *scene_engine(scene *sc) { return sc->engine; }

const loop_settings *scene_loop(const scene *sc) { return &sc->loop; }

int scene_paused_for_save(scene *sc) { return scene_healthy(sc) ? sc->paused : sc->paused_before_failure; }

const unsigned char *scene_last_checkpoint(const scene *sc, size_t *len)
{
    *len = sc->checkpoint_len;
    return sc->checkpoint;
}
