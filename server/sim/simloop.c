/* simloop.c - the sim thread (see simloop.h). */
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "core/json_write.h"
#include "core/params_json.h"
#include "core/rock_json.h"
#include "sim/commands.h"
#include "core/log.h"
#include "sim/simloop.h"
#include "stream/stream.h"

#define PUBLISH_EVERY 0.016  /* s of wall time between publications while running */
#define ENERGY_EVERY 0.1     /* s of wall time between energy evaluations while running */
#define RTF_WINDOW 0.5       /* s of wall time over which the real-time factor is measured */
#define MAX_LAG 0.25         /* s of wall time the loop may fall behind before it stops catching up */
#define COST_PRIOR 2e-8      /* s per vertex and substep assumed before the first measurement */
#define WHOLE_WORK 1e6       /* vertex-substeps run in one call whatever the clock says (a few ms) */

/* A step in progress (POST /v1/sim/step): run in slices between which the queue is drained. */
typedef struct step_job {
    sim_cmd *cmd;            /* NULL when none */
    int frames;              /* 1: frames were asked; 0: substeps */
    long long want;          /* how many */
    long long frames_run;    /* complete frames run */
    uint64_t step0;          /* the step it started at */
    json_t *before_event;    /* last_event when it started */
} step_job;

struct simloop {
    cs_sim *sim;
    void (*before_frame)(cs_sim *sim, uint64_t frame); /* the test daemon's hook (testhooks.h), or NULL */
    loop_settings loop; /* the daemon-loop settings (PATCH /v1/params changes them) */
    metrics *m;
    journal *j;
    pthread_t thread;
    int started;

    pthread_mutex_t qlock;
    pthread_cond_t qcond;
    sim_cmd *head, *tail;
    int queued, queue_max; /* commands in the queue, and the most it takes */
    int stop;
    atomic_int stopping;   /* stop, readable without the lock between slices */

    /* the sim thread's own */
    int paused, paused_before_failure;
    uint64_t frame;
    int32_t frame_sub;     /* substeps run of the frame in progress (a frame stepped in parts) */
    double frame_wall;     /* compute time of the frame in progress */
    double cost;           /* measured s per vertex and substep, for sizing slices */
    const char *failed_as; /* how the last failed run_substeps ended: instability, step_limit, NULL (backend) */
    step_job job;
    double due, last_publish, last_energy, rtf, rtf_wall, rtf_sim;
    cs_energy energy;
    unsigned char *checkpoint;
    size_t checkpoint_len, checkpoint_cap;
    uint64_t checkpoint_frame, frames_since_checkpoint;
    uint64_t rng;
    int32_t seed;
    double next_drop;
    uint32_t autos[CS_MAX_ROCKS];
    int n_autos;
    json_t *last_event;
    struct stream *stream;
    /* Every step and every state-changing command counts a change; the stream is handed a frame
     * only when there is one since the last it was handed, or a scalar it lacks is wanted:
     * commands that change nothing (reads, pauses, a client joining) publish no duplicate frame. */
    uint64_t changes, framed_changes;
    unsigned framed_scalars;
    uint32_t *torn;      /* ids of the torn springs, ascending */
    int64_t n_torn, torn_cap;
    float *scratch;      /* velocities or rest lengths for the stream's scalars */
    size_t scratch_cap;

    /* published */
    pthread_mutex_t plock;
    char *sim_json, *params_json, *scene_json, *torn_json;
    size_t sim_len, params_len, scene_len, torn_len;
    cs_rock *rocks;
    int n_rocks;
    metrics_gauges gauges;
    int healthy;
};

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* splitmix64: the auto drops' random numbers, from `seed`. */
static uint64_t next_u64(uint64_t *s)
{
    uint64_t z = (*s += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}
static double uniform(uint64_t *s) { return (double)(next_u64(s) >> 11) * (1.0 / 9007199254740992.0); }

static cs_params params_of(const simloop *sl)
{
    cs_params p;
    cs_sim_params(sl->sim, &p);
    return p;
}

/* Restart the automatic drops: seeded afresh, the first one within a second. */
static void reseed(simloop *sl)
{
    const loop_settings *p = &sl->loop;
    cs_info info;
    cs_sim_info(sl->sim, &info);
    sl->seed = p->seed;
    sl->rng = (uint64_t)p->seed;
    sl->n_autos = 0;
    sl->next_drop = info.time + (p->auto_drop_interval < 1.0f ? p->auto_drop_interval : 1.0);
}

static void take_checkpoint(simloop *sl)
{
    const size_t need = cs_snapshot_size(sl->sim);
    if (need > sl->checkpoint_cap) {
        unsigned char *b = realloc(sl->checkpoint, need);
        if (!b) {
            log_msg("checkpoint: out of memory (%zu bytes); keeping the previous one", need);
            return;
        }
        sl->checkpoint = b;
        sl->checkpoint_cap = need;
    }
    if (cs_snapshot_save(sl->sim, sl->checkpoint, sl->checkpoint_cap, &sl->checkpoint_len) == CS_OK)
        sl->checkpoint_frame = sl->frame;
    else
        log_msg("checkpoint failed: %s; keeping the previous one", cs_sim_error(sl->sim));
    sl->frames_since_checkpoint = 0;
}

/* The journal starts afresh from the current state (which is also the new checkpoint). */
static void rebase(simloop *sl)
{
    take_checkpoint(sl);
    cs_info info;
    cs_sim_info(sl->sim, &info);
    if (journal_rebase(sl->j, sl->checkpoint, sl->checkpoint_len, info.step) != 0)
        log_msg("journal: out of memory while starting afresh");
}

static void set_event(simloop *sl, json_t *event)
{
    json_decref(sl->last_event);
    sl->last_event = event;
}

/* ---- the stream: events and frames ---- */

/* Sends an event to every stream client (steals ev). */
static void emit(simloop *sl, json_t *ev, const char *request_id)
{
    if (!sl->stream) {
        json_decref(ev);
        return;
    }
    json_object_set_new(ev, "type", json_string("event"));
    json_object_set_new(ev, "request_id", request_id && request_id[0] ? json_string(request_id) : json_null());
    char *text = json_dumps(ev, JSON_DUMP_FLAGS);
    json_decref(ev);
    if (text) stream_event(sl->stream, text);
    free(text);
}

/* Keeps the list of torn springs; returns the newly torn ones as a JSON array (NULL when none are
 * new: a rebuild or restore only replaces the list). */
static json_t *update_torn(simloop *sl)
{
    cs_info info;
    cs_sim_info(sl->sim, &info);
    if (info.n_torn == sl->n_torn) return NULL;
    uint32_t *now = malloc(sizeof *now * (size_t)(info.n_torn ? info.n_torn : 1));
    if (!now) return NULL;
    const int64_t n = cs_read_torn(sl->sim, now, (size_t)info.n_torn);
    json_t *fresh = n > sl->n_torn ? json_array() : NULL;
    for (int64_t a = 0, b = 0; fresh && a < n; a++) {
        while (b < sl->n_torn && sl->torn[b] < now[a]) b++;
        if (b >= sl->n_torn || sl->torn[b] != now[a]) json_array_append_new(fresh, json_integer(now[a]));
    }
    free(sl->torn);
    sl->torn = now;
    sl->n_torn = n;
    json_t *all = json_array();
    for (int64_t k = 0; k < n; k++) json_array_append_new(all, json_integer(now[k]));
    char *text = json_dumps(all, JSON_DUMP_FLAGS);
    json_decref(all);
    pthread_mutex_lock(&sl->plock);
    char *old = sl->torn_json;
    sl->torn_json = text;
    sl->torn_len = text ? strlen(text) : 0;
    pthread_mutex_unlock(&sl->plock);
    free(old);
    return fresh;
}

static float *scratch(simloop *sl, size_t floats)
{
    if (floats > sl->scratch_cap) {
        float *g = realloc(sl->scratch, sizeof(float) * floats);
        if (!g) return NULL;
        sl->scratch = g;
        sl->scratch_cap = floats;
    }
    return sl->scratch;
}

/* The stream's scalars: speed (255 at SCALAR_SPEED_FULL) and strain, the largest stretch of a
 * vertex's intact structural springs (255 at SCALAR_STRAIN_FULL). */
static void fill_scalars(simloop *sl, pose *f, unsigned want)
{
    const int32_t n = f->n;
    float *buf;
    f->has[SCALAR_SPEED] = f->has[SCALAR_STRAIN] = 0;
    if ((want & (1u << SCALAR_SPEED)) && (buf = scratch(sl, 3 * (size_t)n)) &&
        cs_read_velocities(sl->sim, buf, 3 * (size_t)n) == CS_OK) {
        for (int32_t v = 0; v < n; v++) {
            const float s = sqrtf(buf[3 * v] * buf[3 * v] + buf[3 * v + 1] * buf[3 * v + 1] + buf[3 * v + 2] * buf[3 * v + 2]);
            const float q = s / SCALAR_SPEED_FULL * 255.0f;
            f->scalar[SCALAR_SPEED][v] = (uint8_t)(q < 255.0f ? q : 255.0f);
        }
        f->has[SCALAR_SPEED] = 1;
    }
    if ((want & (1u << SCALAR_STRAIN)) && (buf = scratch(sl, (size_t)n)) && cs_read_strain(sl->sim, buf, (size_t)n) == CS_OK) {
        for (int32_t v = 0; v < n; v++) {
            const float q = buf[v] / SCALAR_STRAIN_FULL * 255.0f;
            f->scalar[SCALAR_STRAIN][v] = (uint8_t)(q < 255.0f ? q : 255.0f);
        }
        f->has[SCALAR_STRAIN] = 1;
    }
}

/* Hands the current positions, rocks and scalars to the stream (when a client listens). */
static void publish_frame(simloop *sl, const cs_info *info, const cs_rock *rocks, int n_rocks)
{
    unsigned want = 0;
    pose *f = sl->stream ? stream_frame_begin(sl->stream, &want) : NULL;
    if (!f) return;
    if (sl->changes == sl->framed_changes && (want & ~sl->framed_scalars) == 0) {
        stream_frame_discard(sl->stream, f);
        return;
    }
    if (pose_reserve(f, info->n_vertices, n_rocks) != 0 ||
        cs_read_positions(sl->sim, f->xyz, 3 * (size_t)info->n_vertices) != CS_OK) {
        stream_frame_discard(sl->stream, f); /* clients keep the frame they have */
        return;
    }
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    f->wall_ns = (uint64_t)ts.tv_sec * 1000000000ull + (uint64_t)ts.tv_nsec;
    f->frame = sl->frame;
    f->step = info->step;
    f->sim_time = info->time;
    f->n = info->n_vertices;
    f->n_rocks = n_rocks;
    for (int r = 0; r < n_rocks; r++) {
        pose_rock *k = &f->rocks[r];
        k->id = rocks[r].id;
        memcpy(k->position, rocks[r].def.position, sizeof k->position);
        k->radius = rocks[r].def.radius;
        memcpy(k->orientation, rocks[r].def.orientation, sizeof k->orientation);
    }
    pose_bbox(f);
    fill_scalars(sl, f, want);
    sl->framed_changes = sl->changes;
    sl->framed_scalars = want;
    stream_frame_publish(sl->stream, f);
}

/* ---- publishing ---- */

static void publish(simloop *sl, int with_hash)
{
    cs_info info;
    cs_sim_info(sl->sim, &info);
    const double t = now_s();
    if ((sl->paused && !sl->job.cmd) || t - sl->last_energy >= ENERGY_EVERY) {
        cs_energy_get(sl->sim, &sl->energy);
        sl->last_energy = t;
    }
    char hex[17];
    json_t *hash = json_null();
    if (with_hash && sl->healthy) { /* a lost backend has no state to hash */
        cs_hash_hex(cs_state_hash(sl->sim), hex);
        hash = json_string(hex);
    }
    json_t *o = json_pack(
        "{s:s, s:I, s:I, s:f, s:f, s:f, s:i, s:f, s:s, s:i, s:i, s:I, s:i,"
        " s:{s:f, s:f, s:f, s:f}, s:o, s:O}",
        "state", sl->paused ? "paused" : "running", "step", (json_int_t)info.step, "frame", (json_int_t)sl->frame,
        "sim_time", info.time, "dt", info.dt, "dt_max", info.dt_max, "substeps", (int)info.substeps,
        "realtime_factor", sl->paused ? 0.0 : sl->rtf, "backend", cs_sim_backend(sl->sim), "n_vertices",
        (int)info.n_vertices, "n_springs", (int)info.n_springs, "n_torn", (json_int_t)info.n_torn, "n_rocks",
        (int)info.n_rocks, "energy", "kinetic", sl->energy.kinetic, "spring", sl->energy.spring, "gravity",
        sl->energy.gravity, "total", sl->energy.total, "state_hash", hash, "last_event",
        sl->last_event ? sl->last_event : json_null());
    size_t sim_len = 0, params_len = 0, scene_len = 0;
    char *sim_json = json_dumps(o, JSON_DUMP_FLAGS);
    json_decref(o);
    if (sim_json) sim_len = strlen(sim_json);

    scene_config sc;
    cs_sim_scene(sl->sim, &sc.fields);
    cs_sim_params(sl->sim, &sc.params);
    sc.loop = sl->loop;
    json_t *pj = params_to_json(SET_LIVE, &sc), *sj = params_to_json(SET_SCENE, &sc);
    char *params_json = json_dumps(pj, JSON_DUMP_FLAGS), *scene_json = json_dumps(sj, JSON_DUMP_FLAGS);
    json_decref(pj);
    json_decref(sj);
    if (params_json) params_len = strlen(params_json);
    if (scene_json) scene_len = strlen(scene_json);

    const int n_rocks = cs_rock_count(sl->sim);
    cs_rock *rocks = n_rocks ? malloc(sizeof *rocks * (size_t)n_rocks) : NULL;
    for (int r = 0; rocks && r < n_rocks; r++) cs_rock_at(sl->sim, r, &rocks[r]);
    json_t *torn = update_torn(sl);
    if (torn) emit(sl, json_pack("{s:s, s:I, s:o}", "event", "torn", "step", (json_int_t)info.step, "springs", torn), NULL);
    publish_frame(sl, &info, rocks, rocks ? n_rocks : 0);

    pthread_mutex_lock(&sl->plock);
    char *old[3] = {sl->sim_json, sl->params_json, sl->scene_json};
    cs_rock *old_rocks = sl->rocks;
    if (sim_json) sl->sim_json = sim_json, sl->sim_len = sim_len;
    else old[0] = NULL;
    if (params_json) sl->params_json = params_json, sl->params_len = params_len;
    else old[1] = NULL;
    if (scene_json) sl->scene_json = scene_json, sl->scene_len = scene_len;
    else old[2] = NULL;
    if (rocks || n_rocks == 0) sl->rocks = rocks, sl->n_rocks = n_rocks;
    else old_rocks = NULL;
    sl->gauges.realtime_factor = sl->paused ? 0.0 : sl->rtf;
    sl->gauges.rocks = n_rocks;
    sl->gauges.vertices = info.n_vertices;
    sl->gauges.torn = info.n_torn;
    sl->gauges.paused = sl->paused;
    pthread_mutex_unlock(&sl->plock);
    for (int k = 0; k < 3; k++) free(old[k]);
    free(old_rocks);
    sl->last_publish = t;
}

static char *copy_text(simloop *sl, char *const *src, const size_t *src_len, size_t *len)
{
    pthread_mutex_lock(&sl->plock);
    char *s = *src ? malloc(*src_len + 1) : NULL;
    if (s) {
        memcpy(s, *src, *src_len + 1);
        *len = *src_len;
    }
    pthread_mutex_unlock(&sl->plock);
    return s;
}

char *simloop_sim_json(simloop *sl, size_t *len) { return copy_text(sl, &sl->sim_json, &sl->sim_len, len); }
char *simloop_params_json(simloop *sl, size_t *len) { return copy_text(sl, &sl->params_json, &sl->params_len, len); }
char *simloop_scene_json(simloop *sl, size_t *len) { return copy_text(sl, &sl->scene_json, &sl->scene_len, len); }
char *simloop_torn_json(simloop *sl, size_t *len) { return copy_text(sl, &sl->torn_json, &sl->torn_len, len); }

int simloop_rocks(simloop *sl, cs_rock **out)
{
    pthread_mutex_lock(&sl->plock);
    const int n = sl->n_rocks;
    *out = n ? malloc(sizeof **out * (size_t)n) : NULL;
    if (*out) memcpy(*out, sl->rocks, sizeof **out * (size_t)n);
    pthread_mutex_unlock(&sl->plock);
    return *out || n == 0 ? n : 0;
}

void simloop_gauges(simloop *sl, metrics_gauges *g)
{
    pthread_mutex_lock(&sl->plock);
    *g = sl->gauges;
    g->healthy = sl->healthy;
    pthread_mutex_unlock(&sl->plock);
}

int simloop_healthy(simloop *sl)
{
    pthread_mutex_lock(&sl->plock);
    const int h = sl->healthy;
    pthread_mutex_unlock(&sl->plock);
    return h;
}

journal *simloop_journal(simloop *sl) { return sl->j; }

const unsigned char *simloop_checkpoint(simloop *sl, size_t *len)
{
    *len = sl->checkpoint_len;
    return sl->checkpoint;
}
cs_sim *simloop_engine(simloop *sl) { return sl->sim; }
const loop_settings *simloop_loop(simloop *sl) { return &sl->loop; }

int simloop_paused(simloop *sl) { return simloop_healthy(sl) ? sl->paused : sl->paused_before_failure; }

/* ---- commands ---- */

/* Applies a state-changing command, journals it and tells the stream. */
static int apply(simloop *sl, const json_t *cmd, const char *request_id, json_t **result, problem *pr)
{
    cs_info info;
    cs_sim_info(sl->sim, &info);
    json_t *entry = NULL;
    const int32_t seed_before = sl->loop.seed;
    if (command_apply(sl->sim, &sl->loop, cmd, &entry, result, pr) != 0) return -1;
    const char *op = json_string_value(json_object_get(entry, "op"));
    if (command_rebuilds(op)) {
        sl->frame = 0;
        reseed(sl);
        rebase(sl);
    } else {
        journal_append(sl->j, info.step, entry);
        if (journal_full(sl->j)) rebase(sl);
        if (sl->loop.seed != seed_before) reseed(sl);
        const loop_settings *p = &sl->loop;
        if (p->auto_drop_interval > 0 && sl->next_drop > info.time + p->auto_drop_interval)
            sl->next_drop = info.time + p->auto_drop_interval;
    }
    if (*result) json_object_set_new(*result, "applied_step", json_integer((json_int_t)info.step));
    emit(sl, json_pack("{s:s, s:I, s:O, s:O}", "event", op, "applied_step", (json_int_t)info.step, "command", entry,
                       "result", *result ? *result : json_null()),
         request_id);
    json_decref(entry);
    return 0;
}

static void fail_cmd(sim_cmd *c, int status, const char *slug, const char *fmt, const char *arg)
{
    c->failed = 1;
    problem_set(&c->pr, status, slug, NULL, fmt, arg);
}

/* The non-finite state guard: back to the last checkpoint, paused, event published. */
static void roll_back(simloop *sl)
{
    cs_info bad;
    cs_sim_info(sl->sim, &bad);
    const cs_status st = cs_snapshot_load(sl->sim, sl->checkpoint, sl->checkpoint_len);
    if (st == CS_OK) sl->frame = sl->checkpoint_frame;
    cs_info now;
    cs_sim_info(sl->sim, &now);
    sl->paused = 1;
    set_event(sl, json_pack("{s:s, s:I, s:I, s:s}", "type", "instability", "step", (json_int_t)bad.step,
                            "restored_step", (json_int_t)now.step, "detail",
                            st == CS_OK ? "the state stopped being finite; rolled back to the last checkpoint and paused"
                                        : "the state stopped being finite and the checkpoint could not be restored"));
    emit(sl, json_pack("{s:s, s:O}", "event", "instability", "detail", sl->last_event), NULL);
    if (st != CS_OK) {
        /* The good checkpoint is kept (no rebase, which would replace it with this state). */
        log_msg("instability at step %llu: the checkpoint could not be restored (%s); paused",
                (unsigned long long)bad.step, cs_sim_error(sl->sim));
        return;
    }
    log_msg("instability at step %llu: rolled back to step %llu and paused", (unsigned long long)bad.step,
            (unsigned long long)now.step);
    rebase(sl);
}

/* A failure that loses the backend: unhealthy, and main is asked to save and exit. */
static void backend_lost(simloop *sl)
{
    cs_info info;
    cs_sim_info(sl->sim, &info);
    log_msg("backend failure at step %llu: %s", (unsigned long long)info.step, cs_sim_error(sl->sim));
    pthread_mutex_lock(&sl->plock);
    sl->healthy = 0;
    pthread_mutex_unlock(&sl->plock);
    sl->paused_before_failure = sl->paused;
    sl->paused = 1;
    set_event(sl, json_pack("{s:s, s:I, s:s}", "type", "backend_failure", "step", (json_int_t)info.step, "detail",
                            cs_sim_error(sl->sim)));
    emit(sl, json_pack("{s:s, s:O}", "event", "backend_failure", "detail", sl->last_event), NULL);
    kill(getpid(), SIGUSR1);
}

static void auto_drop(simloop *sl);

/* The step count has reached CS_STEP_MAX: paused, with the event (a snapshot brought it there). */
static void step_limit(simloop *sl)
{
    cs_info info;
    cs_sim_info(sl->sim, &info);
    sl->paused = 1;
    set_event(sl, json_pack("{s:s, s:I, s:s}", "type", "step_limit", "step", (json_int_t)info.step, "detail",
                            cs_sim_error(sl->sim)));
    emit(sl, json_pack("{s:s, s:O}", "event", "step_limit", "detail", sl->last_event), NULL);
    log_msg("step %llu: %s; paused", (unsigned long long)info.step, cs_sim_error(sl->sim));
}

/* Substeps that fit a budget of compute, from the measured cost (at least 1, at most `most`).
 * Little work is never cut: a small scene's frames are stepped whole, as they always were. */
static int64_t fitting(const simloop *sl, double budget, int64_t most)
{
    cs_info info;
    cs_sim_info(sl->sim, &info);
    if ((double)most * (double)info.n_vertices <= WHOLE_WORK) return most;
    const double each = (sl->cost > 0 ? sl->cost : COST_PRIOR) * (double)info.n_vertices;
    const double fit = budget > 0 ? budget / each : 0;
    return fit >= (double)most ? most : (fit >= 1 ? (int64_t)fit : 1);
}

/* Runs n substeps and measures them; the engine's status, with a failure dealt with (rolled back
 * and paused, paused at the step limit, or the backend lost). */
static cs_status run_substeps(simloop *sl, int64_t n)
{
    sl->changes++;
    const double t0 = now_s();
    const cs_status st = cs_sim_step(sl->sim, n);
    const double took = now_s() - t0;
    cs_info info;
    cs_sim_info(sl->sim, &info);
    if (st == CS_OK && info.n_vertices > 0) {
        /* Down at once, up by half at most: a call the scheduler held up (a loaded machine) says
         * little about the next one. */
        const double c = took / ((double)n * (double)info.n_vertices);
        sl->cost = sl->cost <= 0 || c < sl->cost ? c : (c < 1.5 * sl->cost ? c : 1.5 * sl->cost);
    }
    sl->frame_wall += took;
    sl->failed_as = st == CS_E_NONFINITE ? "instability" : st == CS_E_LIMIT ? "step_limit" : NULL;
    if (st == CS_E_NONFINITE) roll_back(sl);
    else if (st == CS_E_LIMIT) step_limit(sl);
    else if (st != CS_OK) backend_lost(sl);
    return st;
}

/* Steps the frame in progress on, by about `budget` seconds of compute at most (a whole frame
 * when it fits, else at least one substep), and when it is complete does what follows a frame:
 * the frame count, automatic drops, checkpoints. 1 when the frame completed, 0 when it is not
 * complete yet, -1 after a failure (dealt with: see run_substeps). */
static int advance_frame(simloop *sl, double budget)
{
    cs_info info;
    if (sl->frame_sub == 0) {
        if (sl->before_frame) sl->before_frame(sl->sim, sl->frame);
        sl->frame_wall = 0;
    }
    cs_sim_info(sl->sim, &info);
    const int32_t left = info.substeps - sl->frame_sub;
    const int64_t n = left > 0 ? fitting(sl, budget, left) : 0;
    if (n > 0 && run_substeps(sl, n) != CS_OK) {
        sl->frame_sub = 0;
        return -1;
    }
    sl->frame_sub += (int32_t)n;
    if (sl->frame_sub < info.substeps) return 0;
    sl->frame_sub = 0;
    metrics_frame(sl->m, info.substeps, sl->frame_wall);
    sl->frame++;
    auto_drop(sl);
    if (++sl->frames_since_checkpoint >= (uint64_t)sl->loop.checkpoint_interval) take_checkpoint(sl);
    return 1;
}

/* One frame while running, in parts when it is long; only a stop cuts it short (commands apply
 * at frame boundaries). 1 done, 0 stopped part way, -1 a failure (dealt with). */
static int run_frame(simloop *sl)
{
    for (;;) {
        const int r = advance_frame(sl, SIMLOOP_RUN_SLICE);
        if (r != 0) return r;
        if (atomic_load(&sl->stopping)) return 0;
    }
}

/* Ends the step in progress and answers it: how far it got, and why it stopped early
 * (interrupted_by: pause, cancel, step, command, shutdown, instability, step_limit), or 503 when
 * the backend failed meanwhile. */
static void end_step(simloop *sl, const char *interrupted_by)
{
    step_job *j = &sl->job;
    sim_cmd *c = j->cmd;
    if (!c) return;
    j->cmd = NULL;
    sl->frame_sub = 0; /* a frame stepped part way counts in the step, not as a frame */
    cs_info info;
    cs_sim_info(sl->sim, &info);
    if (!simloop_healthy(sl)) {
        fail_cmd(c, 503, "unavailable", "%s", "the backend failed while stepping; the daemon is saving and exiting");
    } else {
        char hex[17];
        cs_hash_hex(cs_state_hash(sl->sim), hex);
        const uint64_t ran = info.step >= j->step0 ? info.step - j->step0 : 0; /* a rollback goes back */
        c->result = json_pack("{s:I, s:I, s:f, s:s, s:I, s:I, s:b}", "step", (json_int_t)info.step, "frame",
                              (json_int_t)sl->frame, "sim_time", info.time, "state_hash", hex, "frames_run",
                              (json_int_t)j->frames_run, "substeps_run", (json_int_t)ran, "interrupted",
                              interrupted_by != NULL);
        if (interrupted_by) json_object_set_new(c->result, "interrupted_by", json_string(interrupted_by));
        if (sl->last_event && sl->last_event != j->before_event) json_object_set(c->result, "event", sl->last_event);
        emit(sl, json_pack("{s:s, s:I, s:I}", "event", "stepped", "step", (json_int_t)info.step, "frame",
                           (json_int_t)sl->frame),
             c->request_id);
    }
    json_decref(j->before_event);
    j->before_event = NULL;
    publish(sl, 1); /* before the answer: a read that follows it sees the step */
    c->done(c, c->done_arg);
}

/* Starts a step: checks it (409 while running, the body, the step limit) and makes it the step in
 * progress. 1 when it is kept (answered by end_step), 0 when refused (c failed). */
static int step_start(simloop *sl, sim_cmd *c)
{
    long long n = 0;
    int frames = 0;
    if (!sl->paused) {
        fail_cmd(c, 409, "wrong-state", "%s", "step only while paused: POST /v1/sim/pause first");
        return 0;
    }
    if (step_from_json(c->body, &frames, &n, &c->pr) != 0) {
        c->failed = 1;
        return 0;
    }
    cs_info info;
    cs_sim_info(sl->sim, &info);
    const uint64_t substeps = (uint64_t)n * (frames ? (uint64_t)info.substeps : 1);
    if (substeps > CS_STEP_MAX - info.step) {
        c->failed = 1;
        problem_set(&c->pr, 422, "limit", frames ? "frames" : "substeps",
                    "%llu more substeps would take the step count (%llu) past 2^63 - 1", (unsigned long long)substeps,
                    (unsigned long long)info.step);
        return 0;
    }
    sl->job = (step_job){c, frames, n, 0, info.step, json_incref(sl->last_event)};
    return 1;
}

/* Runs the step in progress for about one slice of compute (whole frames when they fit); ends
 * it when it is done or failed. Publishes its progress (without the state hash) now and then. */
static void step_slice(simloop *sl)
{
    step_job *j = &sl->job;
    const double t0 = now_s();
    do {
        const double budget = SIMLOOP_SLICE - (now_s() - t0);
        cs_info info;
        cs_sim_info(sl->sim, &info);
        if (j->frames) {
            const int r = advance_frame(sl, budget);
            if (r < 0) {
                end_step(sl, sl->failed_as);
                return;
            }
            if (r == 1 && ++j->frames_run == j->want) {
                end_step(sl, NULL);
                return;
            }
        } else {
            const long long done = (long long)(info.step - j->step0);
            if (run_substeps(sl, fitting(sl, budget, j->want - done)) != CS_OK) {
                end_step(sl, sl->failed_as);
                return;
            }
            cs_sim_info(sl->sim, &info);
            if ((long long)(info.step - j->step0) >= j->want) {
                end_step(sl, NULL);
                return;
            }
        }
    } while (now_s() - t0 < SIMLOOP_SLICE);
    if (now_s() - sl->last_publish >= PUBLISH_EVERY) publish(sl, 0);
}

/* Bytes GET /v1/cloth/state's JSON may take for n vertices: 2 n vectors of three %.9g numbers at
 * 18 characters each, brackets and commas included, and the object around them. */
static uint64_t cloth_json_cap(uint64_t n) { return 128 + n * 2 * 3 * 18; }

/* Bytes of the torn-spring list (ids of u32) and of its JSON ("4294967295," at most) when every
 * spring of n vertices is torn. */
static uint64_t torn_cap(uint64_t n) { return (uint64_t)CS_SPRING_TYPES_PER_VERTEX * n * (sizeof(uint32_t) + 11) + 16; }

cs_status simloop_scene_cost(const cs_scene *scene, int32_t rocks, void *ctx, uint64_t *bytes)
{
    (void)ctx;
    uint64_t engine, snap;
    cs_status st = cs_scene_memory(scene, rocks, &engine);
    if (st == CS_OK) st = cs_snapshot_bytes(scene, rocks, &snap);
    if (st != CS_OK) return st;
    const uint64_t n = (uint64_t)scene->nx * (uint64_t)scene->ny; /* no overflow: cs_scene_memory took it */
    if (n > INT32_MAX) return CS_E_LIMIT;
    /* cloth_state's JSON and the positions and velocities it is made from, or a snapshot */
    const uint64_t cloth = cloth_json_cap(n) + 2 * 3 * sizeof(float) * n, answer = cloth > snap ? cloth : snap;
    const uint64_t scalars = sizeof(float) * 3 * n; /* fill_scalars' scratch (velocities, or strains) */
    *bytes = engine + 2 * snap + answer + stream_memory((int32_t)n, rocks) + scalars + 2 * torn_cap(n);
    return CS_OK;
}

static void cloth_state(simloop *sl, sim_cmd *c)
{
    cs_info info;
    cs_sim_info(sl->sim, &info);
    cs_scene sc;
    cs_sim_scene(sl->sim, &sc);
    const size_t n = (size_t)info.n_vertices;
    float *pos = malloc(sizeof(float) * 3 * n), *vel = malloc(sizeof(float) * 3 * n);
    if (!pos || !vel || cs_read_positions(sl->sim, pos, 3 * n) != CS_OK || cs_read_velocities(sl->sim, vel, 3 * n) != CS_OK) {
        free(pos);
        free(vel);
        fail_cmd(c, 500, "internal", "%s", "could not read the cloth's state");
        return;
    }
    if (json_is_true(json_object_get(c->body, "binary"))) {
        c->blob_len = sizeof(float) * 6 * n;
        c->blob = malloc(c->blob_len);
        if (c->blob) {
            memcpy(c->blob, pos, sizeof(float) * 3 * n);
            memcpy(c->blob + sizeof(float) * 3 * n, vel, sizeof(float) * 3 * n);
        }
    } else {
        /* Formatted by hand: jansson would build n small arrays twice over. */
        const size_t cap = (size_t)cloth_json_cap(n);
        char *s = malloc(cap);
        if (s) {
            size_t at = (size_t)snprintf(s, cap, "{\"step\":%llu,\"nx\":%d,\"ny\":%d,\"positions\":[",
                                         (unsigned long long)info.step, (int)sc.nx, (int)sc.ny);
            for (int part = 0; part < 2; part++) {
                const float *a = part ? vel : pos;
                if (part) at += (size_t)snprintf(s + at, cap - at, "],\"velocities\":[");
                for (size_t v = 0; v < n; v++)
                    at += (size_t)snprintf(s + at, cap - at, "%s[%.9g,%.9g,%.9g]", v ? "," : "", a[3 * v], a[3 * v + 1],
                                           a[3 * v + 2]);
            }
            at += (size_t)snprintf(s + at, cap - at, "]}");
            c->blob = (unsigned char *)s;
            c->blob_len = at;
        }
    }
    if (!c->blob) fail_cmd(c, 500, "internal", "%s", "out of memory");
    free(pos);
    free(vel);
}

static void snapshot_put(simloop *sl, sim_cmd *c)
{
    const cs_status st = cs_snapshot_load(sl->sim, c->blob_in, c->blob_in_len);
    if (st != CS_OK) {
        c->failed = 1;
        problem_from_engine(&c->pr, st, cs_sim_error(sl->sim), cs_sim_error_param(sl->sim));
        return;
    }
    loop_from_snapshot(&sl->loop, c->blob_in, c->blob_in_len); /* one written before they left its table */
    cs_info info;
    cs_sim_info(sl->sim, &info);
    sl->frame = info.step / (uint64_t)info.substeps;
    reseed(sl);
    rebase(sl);
    char hex[17];
    cs_hash_hex(cs_state_hash(sl->sim), hex);
    c->result = json_pack("{s:I, s:I, s:s}", "applied_step", (json_int_t)info.step, "step", (json_int_t)info.step,
                          "state_hash", hex);
    /* Everything may have changed: the event carries what a viewer needs to redraw, like hello. */
    scene_config sc;
    cs_sim_scene(sl->sim, &sc.fields);
    cs_sim_params(sl->sim, &sc.params);
    sc.loop = sl->loop;
    json_t *rocks = json_array();
    for (int32_t r = 0; r < cs_rock_count(sl->sim); r++) {
        cs_rock k;
        if (cs_rock_at(sl->sim, r, &k) == CS_OK) json_array_append_new(rocks, rock_to_json(&k));
    }
    const int64_t n_torn = cs_read_torn(sl->sim, NULL, 0);
    uint32_t *ids = malloc(sizeof *ids * (size_t)(n_torn ? n_torn : 1));
    json_t *torn = json_array();
    if (ids) {
        cs_read_torn(sl->sim, ids, (size_t)n_torn);
        for (int64_t k = 0; k < n_torn; k++) json_array_append_new(torn, json_integer(ids[k]));
        free(ids);
    }
    emit(sl, json_pack("{s:s, s:I, s:o, s:o, s:o, s:o}", "event", "snapshot_restored", "applied_step",
                       (json_int_t)info.step, "scene", params_to_json(SET_SCENE, &sc), "params",
                       params_to_json(SET_LIVE, &sc), "rocks", rocks, "torn", torn),
         c->request_id);
}

/* What a command does to a step in progress: the reason it ends it, or NULL (reads go on
 * beside it). */
static const char *interrupts(sim_cmd_kind kind)
{
    switch (kind) {
    case CMD_PAUSE: return "pause";
    case CMD_STEP_CANCEL: return "cancel";
    case CMD_STEP: return "step";
    case CMD_APPLY:
    case CMD_RESUME:
    case CMD_SNAPSHOT_PUT: return "command";
    default: return NULL;
    }
}

/* Runs one command; returns 1 when the sim thread keeps it to answer later (a step now in
 * progress), else 0. PAUSE, RESUME and HASH answer with GET /v1/sim's JSON, filled after the
 * publication that follows. */
static int handle(simloop *sl, sim_cmd *c)
{
    cs_info info;
    /* After a backend failure, until main has stopped this thread: nothing touches the lost
     * engine. Pauses, publications and the journal (kept in memory) still answer. */
    if (!sl->healthy && c->kind != CMD_PAUSE && c->kind != CMD_PUBLISH && c->kind != CMD_HASH && c->kind != CMD_BUNDLE) {
        fail_cmd(c, 503, "unavailable", "%s", "the backend has failed; the daemon is saving the state and exiting");
        return 0;
    }
    const int stepping = sl->job.cmd != NULL;
    if (stepping && interrupts(c->kind)) end_step(sl, interrupts(c->kind));
    if (c->kind == CMD_APPLY || c->kind == CMD_SNAPSHOT_PUT) sl->changes++;
    switch (c->kind) {
    case CMD_APPLY:
        if (apply(sl, c->body, c->request_id, &c->result, &c->pr) != 0) c->failed = 1;
        break;
    case CMD_PAUSE:
        sl->paused = 1;
        cs_sim_info(sl->sim, &info);
        emit(sl, json_pack("{s:s, s:I}", "event", "paused", "step", (json_int_t)info.step), c->request_id);
        break;
    case CMD_RESUME:
        if (!simloop_healthy(sl)) {
            fail_cmd(c, 503, "unavailable", "%s", "the backend has failed; the daemon is shutting down");
            break;
        }
        sl->paused = 0;
        sl->due = now_s();
        sl->rtf_wall = sl->due;
        cs_sim_info(sl->sim, &info);
        sl->rtf_sim = info.time;
        emit(sl, json_pack("{s:s, s:I}", "event", "resumed", "step", (json_int_t)info.step), c->request_id);
        break;
    case CMD_STEP: return step_start(sl, c);
    case CMD_STEP_CANCEL:
        cs_sim_info(sl->sim, &info);
        c->result = json_pack("{s:b, s:I, s:I}", "cancelled", stepping, "step", (json_int_t)info.step, "frame",
                              (json_int_t)sl->frame);
        break;
    case CMD_HASH:
    case CMD_PUBLISH: break;
    case CMD_SNAPSHOT_GET: {
        const size_t need = cs_snapshot_size(sl->sim);
        c->blob = malloc(need);
        const cs_status st = c->blob ? cs_snapshot_save(sl->sim, c->blob, need, &c->blob_len) : CS_E_NOMEM;
        if (st == CS_E_NONFINITE)
            fail_cmd(c, 409, "wrong-state", "%s",
                     "the state is not finite (a command made its accelerations overflow): the next step rolls it "
                     "back to the last checkpoint");
        else if (st != CS_OK)
            fail_cmd(c, 500, "internal", "%s", "could not write the snapshot");
        break;
    }
    case CMD_SNAPSHOT_PUT: snapshot_put(sl, c); break;
    case CMD_CLOTH_STATE: cloth_state(sl, c); break;
    case CMD_BUNDLE:
        cs_sim_info(sl->sim, &info);
        c->blob = journal_bundle(sl->j, info.step, &c->blob_len);
        if (!c->blob) fail_cmd(c, 500, "internal", "%s", "out of memory");
        break;
    }
    return 0;
}

/* Waits (while paused: for a command; while running: until `until` on the monotonic clock, or a
 * command), then runs the queued commands, publishes and answers them. Returns 1 when stopping. */
static int drain(simloop *sl, int wait, double until)
{
    pthread_mutex_lock(&sl->qlock);
    if (wait && !sl->head && !sl->stop) {
        if (until <= 0) {
            pthread_cond_wait(&sl->qcond, &sl->qlock);
        } else {
            struct timespec ts;
            ts.tv_sec = (time_t)until;
            ts.tv_nsec = (long)((until - (double)ts.tv_sec) * 1e9);
            pthread_cond_timedwait(&sl->qcond, &sl->qlock, &ts);
        }
    }
    sim_cmd *list = sl->head;
    sl->head = sl->tail = NULL;
    sl->queued = 0;
    const int stop = sl->stop;
    pthread_mutex_unlock(&sl->qlock);
    if (!list) return stop;
    int want_hash = 0;
    sim_cmd *answer = NULL, **tail = &answer;
    for (sim_cmd *c = list, *next; c; c = next) {
        next = c->next; /* c may be answered (and gone) before the loop ends: a step is ended */
        c->failed = 0;
        c->result = NULL;
        c->blob = NULL;
        c->blob_len = 0;
        memset(&c->pr, 0, sizeof c->pr);
        want_hash |= c->kind == CMD_HASH;
        if (handle(sl, c)) continue; /* the step in progress: end_step answers it */
        c->next = NULL;
        *tail = c;
        tail = &c->next;
    }
    /* Publish (with the hash while paused, or when asked), then answer: reads that follow the
     * answers see the commands. A step in progress publishes its progress without the hash. */
    publish(sl, want_hash || (sl->paused && !sl->job.cmd));
    for (sim_cmd *c = answer, *next; c; c = next) {
        next = c->next;
        if (!c->failed && (c->kind == CMD_PAUSE || c->kind == CMD_RESUME || c->kind == CMD_HASH))
            c->blob = (unsigned char *)simloop_sim_json(sl, &c->blob_len);
        c->done(c, c->done_arg);
    }
    return stop;
}

static void update_rtf(simloop *sl, double t)
{
    if (t - sl->rtf_wall < RTF_WINDOW) return;
    cs_info info;
    cs_sim_info(sl->sim, &info);
    sl->rtf = (info.time - sl->rtf_sim) / (t - sl->rtf_wall);
    sl->rtf_wall = t;
    sl->rtf_sim = info.time;
}

static void *run(void *arg)
{
    simloop *sl = arg;
    sigset_t all;
    sigfillset(&all);
    pthread_sigmask(SIG_BLOCK, &all, NULL);
    sl->due = now_s();
    sl->rtf_wall = sl->due;
    for (;;) {
        if (sl->job.cmd) {
            /* A step in progress: a slice, then the queue (without waiting). */
            if (drain(sl, 0, 0)) break;
            if (sl->job.cmd) step_slice(sl);
            continue;
        }
        const double t = now_s();
        const cs_params p = params_of(sl);
        const loop_settings *loop = &sl->loop;
        const int running = !sl->paused;
        /* Wait for commands while paused, or until the next frame is due. */
        const int wait = !running || (!loop->max_speed && t < sl->due);
        if (drain(sl, wait, running ? sl->due : 0)) break;
        if (sl->job.cmd || sl->paused || (!loop->max_speed && now_s() < sl->due)) continue;
        const int r = run_frame(sl);
        if (r == 0) continue; /* stopping part way through a long frame: the next drain says so */
        if (r < 0) {
            publish(sl, 1);
            continue;
        }
        const double after = now_s();
        const double frame_wall = 1.0 / ((double)p.frame_rate * (double)loop->time_scale);
        sl->due += frame_wall;
        if (after - sl->due > MAX_LAG) sl->due = after; /* too slow to keep up: do not try to catch up */
        update_rtf(sl, after);
        if (!loop->max_speed || after - sl->last_publish >= PUBLISH_EVERY) publish(sl, 0);
    }
    end_step(sl, "shutdown"); /* a step in progress (or one that came with the stop) */
    return NULL;
}

/* ---- automatic drops ---- */

static void auto_drop(simloop *sl)
{
    const loop_settings *p = &sl->loop;
    if (p->seed != sl->seed) reseed(sl);
    if (p->auto_drop_interval <= 0 || p->auto_drop_max <= 0) return;
    cs_info info;
    cs_sim_info(sl->sim, &info);
    if (info.time < sl->next_drop) return;
    sl->next_drop = info.time + p->auto_drop_interval;
    json_t *result = NULL;
    problem pr;
    /* The oldest automatic rocks go first. */
    while (sl->n_autos > 0 && sl->n_autos >= p->auto_drop_max) {
        json_t *cmd = json_pack("{s:s, s:I, s:s}", "op", "rock_remove", "id", (json_int_t)sl->autos[0], "by", "auto");
        if (apply(sl, cmd, NULL, &result, &pr) == 0) json_decref(result);
        json_decref(cmd);
        memmove(sl->autos, sl->autos + 1, sizeof sl->autos[0] * (size_t)(sl->n_autos - 1));
        sl->n_autos--;
    }
    if (cs_rock_count(sl->sim) >= cs_sim_rock_limit(sl->sim)) return;
    cs_scene sc;
    cs_sim_scene(sl->sim, &sc);
    const double size = sc.size_x < sc.size_y ? sc.size_x : sc.size_y;
    const double u = uniform(&sl->rng), v = uniform(&sl->rng), w = uniform(&sl->rng);
    const double radius = (0.025 + 0.035 * w) * size;
    json_t *rock;
    if (sc.orientation == CS_HORIZONTAL) {
        /* Dropped from above, anywhere over the middle 70% of the net. */
        const double z = sc.height + 0.4 * (sc.size_x > sc.size_y ? sc.size_x : sc.size_y);
        rock = json_pack("{s:[f,f,f], s:f, s:[f,f,f]}", "position", (u - 0.5) * 0.7 * sc.size_x,
                         (v - 0.5) * 0.7 * sc.size_y, z, "radius", radius, "angular_velocity", 4.0 * (u - 0.5),
                         4.0 * (v - 0.5), 0.0);
    } else {
        /* Thrown at the hanging curtain from in front of it. */
        rock = json_pack("{s:[f,f,f], s:f, s:[f,f,f]}", "position", (u - 0.5) * 0.7 * sc.size_x, -0.5 * sc.size_y,
                         sc.height + (v - 0.5) * 0.6 * sc.size_y, "radius", radius, "velocity", 0.0, 4.0, 1.0);
    }
    json_t *cmd = json_pack("{s:s, s:o, s:s}", "op", "rock_add", "rock", rock, "by", "auto");
    if (apply(sl, cmd, NULL, &result, &pr) == 0) {
        sl->autos[sl->n_autos++] = (uint32_t)json_integer_value(json_object_get(result, "id"));
        json_decref(result);
    } else {
        log_msg("automatic drop refused: %s", pr.detail);
    }
    json_decref(cmd);
}

/* ---- lifecycle ---- */

simloop *simloop_new(cs_sim *sim, const clothd_config *cfg, metrics *m)
{
    simloop *sl = calloc(1, sizeof *sl);
    if (!sl) return NULL;
    sl->sim = sim;
    sl->loop = cfg->scene.loop;
    sl->queue_max = cfg->set.queue_max;
    sl->m = m;
    sl->healthy = 1;
    sl->changes = 1; /* the first frame a client asks for is new */
    sl->paused = cfg->set.paused;
    sl->j = journal_new((size_t)cfg->set.journal_max, (size_t)cfg->set.journal_max_mb << 20);
    pthread_mutex_init(&sl->qlock, NULL);
    pthread_condattr_t ca;
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC); /* waits are until a monotonic deadline */
    pthread_cond_init(&sl->qcond, &ca);
    pthread_condattr_destroy(&ca);
    pthread_mutex_init(&sl->plock, NULL);
    if (!sl->j) {
        simloop_free(sl);
        return NULL;
    }
    cs_info info;
    cs_sim_info(sim, &info);
    sl->frame = info.step / (uint64_t)info.substeps;
    reseed(sl);
    rebase(sl);
    publish(sl, sl->paused);
    return sl;
}

void simloop_attach_stream(simloop *sl, struct stream *st) { sl->stream = st; }

void simloop_set_frame_hook(simloop *sl, void (*hook)(cs_sim *sim, uint64_t frame)) { sl->before_frame = hook; }

int simloop_start(simloop *sl)
{
    if (pthread_create(&sl->thread, NULL, run, sl) != 0) return -1;
    sl->started = 1;
    return 0;
}

void simloop_submit(simloop *sl, sim_cmd *cmd)
{
    cmd->next = NULL;
    pthread_mutex_lock(&sl->qlock);
    const int stop = sl->stop, full = sl->queued >= sl->queue_max;
    if (!stop && !full) {
        if (sl->tail) sl->tail->next = cmd;
        else sl->head = cmd;
        sl->tail = cmd;
        sl->queued++;
        pthread_cond_signal(&sl->qcond);
    }
    pthread_mutex_unlock(&sl->qlock);
    if (!stop && !full) return;
    cmd->failed = 1;
    cmd->result = NULL;
    cmd->blob = NULL;
    if (stop) problem_set(&cmd->pr, 503, "unavailable", NULL, "clothd is shutting down");
    else
        problem_set(&cmd->pr, 503, "busy", NULL,
                    "the simulation has queue_max (%d) commands waiting already; retry in a second", sl->queue_max);
    cmd->done(cmd, cmd->done_arg);
}

void simloop_stop(simloop *sl)
{
    pthread_mutex_lock(&sl->qlock);
    sl->stop = 1;
    atomic_store(&sl->stopping, 1);
    pthread_cond_signal(&sl->qcond);
    pthread_mutex_unlock(&sl->qlock);
    if (sl->started) pthread_join(sl->thread, NULL);
    sl->started = 0;
    /* Whatever arrived meanwhile: refused. */
    pthread_mutex_lock(&sl->qlock);
    sim_cmd *list = sl->head;
    sl->head = sl->tail = NULL;
    sl->queued = 0;
    pthread_mutex_unlock(&sl->qlock);
    for (sim_cmd *c = list, *next; c; c = next) {
        next = c->next;
        c->failed = 1;
        c->result = NULL;
        c->blob = NULL;
        problem_set(&c->pr, 503, "unavailable", NULL, "clothd is shutting down");
        c->done(c, c->done_arg);
    }
}

void simloop_free(simloop *sl)
{
    if (!sl) return;
    if (sl->started) simloop_stop(sl);
    cs_sim_destroy(sl->sim);
    journal_free(sl->j);
    free(sl->checkpoint);
    json_decref(sl->last_event);
    json_decref(sl->job.before_event);
    free(sl->sim_json);
    free(sl->params_json);
    free(sl->scene_json);
    free(sl->torn_json);
    free(sl->torn);
    free(sl->scratch);
    free(sl->rocks);
    pthread_mutex_destroy(&sl->qlock);
    pthread_cond_destroy(&sl->qcond);
    pthread_mutex_destroy(&sl->plock);
    free(sl);
}
