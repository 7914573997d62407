/* simloop.c - the sim thread (see simloop.h). */
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "core/clock.h"
#include "sim/autodrop.h"
#include "sim/autothreads.h"
#include "sim/commands.h"
#include "sim/rectap.h"
#include "sim/simloop.h"

#define PUBLISH_EVERY 0.016 /* s of wall time between publications while running */
#define HELD_WAIT 0.001     /* s the thread waits when a frame waits for a recording's writer */
#define RTF_WINDOW 0.5      /* s of wall time over which the real-time factor is measured */
#define MAX_LAG 0.25        /* s of wall time a scene may fall behind before it stops catching up */
#define COST_PRIOR 2e-8     /* s per vertex and substep assumed before the first measurement */
#define WHOLE_WORK 1e6      /* vertex-substeps run in one call whatever the clock says (a few ms) */
#define BEAT_EVERY 0.25     /* s the thread waits at most, however idle: each turn is a heartbeat, a
                             * quarter of the least liveness_timeout (1 s), so that a turn that comes
                             * late does not turn an idle daemon's /livez 503 */

struct simloop {
    scenes *table;
    metrics *m;
    int cap;             /* scenes in one turn: the table's most */
    scene **turn;        /* the scenes of a turn */
    scene **batch;       /* those whose frames are stepped together */
    cs_sim **engines;
    int64_t *substeps;
    cs_status *each;
    pthread_t thread;
    int started;
    pthread_mutex_t lock;
    pthread_cond_t cond;
    int kicked;          /* a command came since the thread last looked */
    int stop;
    atomic_int stopping; /* stop, readable without the lock between slices */
    int held;            /* this turn, a frame waited for a recording's writer (held()) */
    atomic_llong last_turn_ns; /* clock_mono of the last turn, in ns (0: none yet): the heartbeat */
    double beat_every;   /* s between two calls of beat (and the longest wait) */
    double beat_last;
    void (*beat)(void *ctx);
    void *beat_ctx;
    int auto_threads;    /* the threads setting is 0: `at` counts them (autothreads.h) */
    autothreads at;
};

/* The heartbeat: a turn of the loop (any thread reads it: simloop_last_turn), and the beat hook
 * at most every beat_every seconds. */
static void heartbeat(simloop *sl)
{
    const double now = clock_mono();
    atomic_store(&sl->last_turn_ns, (long long)(now * 1e9));
    if (sl->beat && now - sl->beat_last >= sl->beat_every) {
        sl->beat_last = now;
        sl->beat(sl->beat_ctx);
    }
}

double simloop_last_turn(simloop *sl) { return 1e-9 * (double)atomic_load(&sl->last_turn_ns); }

void simloop_set_threads(simloop *sl, int threads)
{
    sl->auto_threads = threads == 0;
    if (sl->auto_threads) autothreads_init(&sl->at, cs_cpu_threads());
    metrics_threads(sl->m, threads == 0 ? 1 : threads);
}

void simloop_set_beat(simloop *sl, void (*beat)(void *ctx), void *ctx, double every)
{
    sl->beat = beat;
    sl->beat_ctx = ctx;
    if (every > 0 && every < sl->beat_every) sl->beat_every = every;
}

static void wake(void *ctx)
{
    simloop *sl = ctx;
    pthread_mutex_lock(&sl->lock);
    sl->kicked = 1;
    pthread_cond_signal(&sl->cond);
    pthread_mutex_unlock(&sl->lock);
}

/* ---- stepping one scene ---- */

/* Compute the engine spent on work (vertex-substeps), for the count of threads. */
static void ran(simloop *sl, double seconds, double work)
{
    if (sl->auto_threads) autothreads_ran(&sl->at, seconds, work);
}

/* The work of the engine's last call, which ran n substeps, for the count of threads: its
 * vertex-substeps, and under implicit_euler its vertices times what its solver did - one unit a
 * conjugate-gradient iteration, two a Newton iteration (an assembly, a hierarchy, a line search),
 * two a part. Rough, but the windows the count compares then weigh alike: on 128 x 128 (one
 * thread, build machine, 2026-12-07) a calm substep (1.1 Newton, 4.7 CG iterations) took 5.1 ms
 * and one under stones (1.09 parts, 3.8 Newton, 19 CG) 25.6 ms, 5.0 times as much, which these
 * units count as 2.9 times and vertex-substeps as 1: a window at two threads while stones landed
 * then cost more per vertex-substep than a calm one at one, and the count gave back a thread that
 * bought 14 %. self_collision's passes weigh in alike: on the default scene with it on (64 x 64,
 * one thread, same machine, 2026-12-08) a find of its lists took 7.2 ms and a pass without one
 * (with its gather for the parts) about 3 ms, some 60 and 25 of these units, against 12 for the
 * substep's solve; uncounted, windows where stones landed (a find nearly every pass) cost more
 * per unit at two threads than calm ones at one, and the count went back to one thread - 0.39-0.61
 * of real time against 0.64-0.84 on two. */
static double work_of(const cs_info *after, int64_t n)
{
    const cs_solver_stats *st = &after->solver;
    const double units = st->substeps > 0 ? (double)st->cg + 2.0 * st->newton + 2.0 * st->substeps : (double)n;
    const double self = 25.0 * (double)after->self.passes + 60.0 * (double)after->self.broad;
    return (units + self) * (double)after->n_vertices;
}

/* Substeps run, and a backend failure told to the daemon: it saves and exits (serve.c, persist.c). */
static cs_status run_substeps(simloop *sl, scene *sc, int64_t n)
{
    const double before = sc->frame_wall; /* scene_run_substeps adds the call's compute to it */
    const cs_status st = scene_run_substeps(sc, n);
    cs_info info;
    cs_sim_info(sc->engine, &info);
    ran(sl, sc->frame_wall - before, work_of(&info, n));
    if (sc->lost) {
        sc->lost = 0;
        kill(getpid(), SIGUSR1);
    }
    return st;
}

/* Substeps that fit a budget of compute, from the measured cost (at least 1, at most `most`).
 * Little work is never cut: a small scene's frames are stepped whole, as they always were. */
static int64_t fitting(const scene *sc, double budget, int64_t most)
{
    cs_info info;
    cs_sim_info(sc->engine, &info);
    if ((double)most * (double)info.n_vertices <= WHOLE_WORK) return most;
    const double each = (sc->cost > 0 ? sc->cost : COST_PRIOR) * (double)info.n_vertices;
    const double fit = budget > 0 ? budget / each : 0;
    return fit >= (double)most ? most : (fit >= 1 ? (int64_t)fit : 1);
}

/* What follows a complete frame: the frame count, metrics, automatic drops, checkpoints. */
static void frame_done(simloop *sl, scene *sc, int32_t substeps)
{
    sc->frame_sub = 0;
    metrics_frame(sl->m, substeps, sc->frame_wall);
    sc->frame++;
    autodrop_after_frame(sc);
    if (++sc->frames_since_checkpoint >= (uint64_t)sc->loop.checkpoint_interval) scene_take_checkpoint(sc);
    /* A step or a scene at max_speed publishes now and then only; its recordings take every
     * frame (a scene in real time publishes each frame anyway: paced). */
    if ((sc->job.cmd || sc->loop.max_speed) && recordings_want(sc, 1)) scene_publish(sc, 0);
}

/* Whether a frame of a step, or of a scene at max_speed, waits for its recordings' writer to make
 * room (the turn notes it: sl->held); a scene in real time never waits. */
static int held(simloop *sl, scene *sc)
{
    if (!(sc->job.cmd || sc->loop.max_speed) || sc->frame_sub != 0 || recordings_room(sc)) return 0;
    sl->held = 1;
    return 1;
}

/* Steps the frame in progress on, by about `budget` seconds of compute at most (a whole frame
 * when it fits, else at least one substep), and when it is complete does what follows a frame:
 * the frame count, automatic drops, checkpoints. 1 when the frame completed, 0 when it is not
 * complete yet, -1 after a failure (dealt with: see scene_run_substeps). */
static int advance_frame(simloop *sl, scene *sc, double budget)
{
    cs_info info;
    heartbeat(sl); /* a long frame in parts turns too */
    if (sc->frame_sub == 0) {
        if (sc->before_frame) sc->before_frame(sc->engine, sc->frame);
        sc->frame_wall = 0;
    }
    cs_sim_info(sc->engine, &info);
    const int32_t left = info.substeps - sc->frame_sub;
    const int64_t n = left > 0 ? fitting(sc, budget, left) : 0;
    if (n > 0 && run_substeps(sl, sc, n) != CS_OK) {
        sc->frame_sub = 0;
        return -1;
    }
    sc->frame_sub += (int32_t)n;
    if (sc->frame_sub < info.substeps) return 0;
    frame_done(sl, sc, info.substeps);
    return 1;
}

/* One frame while running, in parts when it is long; only a stop cuts it short (commands apply
 * at frame boundaries). 1 done, 0 stopped part way, -1 a failure (dealt with). */
static int run_frame(simloop *sl, scene *sc)
{
    for (;;) {
        const int r = advance_frame(sl, sc, SIMLOOP_RUN_SLICE);
        if (r != 0) return r;
        if (atomic_load(&sl->stopping)) return 0;
    }
}

/* Runs the step in progress for about one slice of compute (whole frames when they fit); ends
 * it when it is done or failed. Publishes its progress (without the state hash) now and then. */
static void step_slice(simloop *sl, scene *sc)
{
    step_job *j = &sc->job;
    const double t0 = clock_mono();
    do {
        const double budget = SIMLOOP_SLICE - (clock_mono() - t0);
        cs_info info;
        cs_sim_info(sc->engine, &info);
        if (j->frames) {
            if (held(sl, sc)) break;
            const int r = advance_frame(sl, sc, budget);
            if (r < 0) {
                scene_end_step(sc, sc->failed_as);
                return;
            }
            if (r == 1 && ++j->frames_run == j->want) {
                scene_end_step(sc, NULL);
                return;
            }
        } else {
            const long long done = (long long)(info.step - j->step0);
            if (run_substeps(sl, sc, fitting(sc, budget, j->want - done)) != CS_OK) {
                scene_end_step(sc, sc->failed_as);
                return;
            }
            cs_sim_info(sc->engine, &info);
            if ((long long)(info.step - j->step0) >= j->want) {
                scene_end_step(sc, NULL);
                return;
            }
        }
    } while (clock_mono() - t0 < SIMLOOP_SLICE);
    if (clock_mono() - sc->last_publish >= PUBLISH_EVERY) scene_publish(sc, 0);
}

static void update_rtf(scene *sc, double t)
{
    if (t - sc->rtf_wall < RTF_WINDOW) return;
    cs_info info;
    cs_sim_info(sc->engine, &info);
    sc->rtf = (info.time - sc->rtf_sim) / (t - sc->rtf_wall);
    sc->rtf_wall = t;
    sc->rtf_sim = info.time;
}

/* Wall seconds between a scene's frames. */
static double period_of(const scene *sc)
{
    cs_params p;
    cs_sim_params(sc->engine, &p);
    return 1.0 / ((double)p.frame_rate * (double)sc->loop.time_scale);
}

/* Whether a running scene's frame is due (or it runs at max_speed). */
static int frame_due(simloop *sl, scene *sc, double now)
{
    return !sc->job.cmd && !sc->paused && (sc->loop.max_speed || now >= sc->due) && !held(sl, sc);
}

/* After a frame of a running scene (r: run_frame's): its pacing, and what it publishes. */
static void paced(scene *sc, int r)
{
    if (r == 0) return; /* stopping part way through a long frame: the next look says so */
    if (r < 0) {
        scene_publish(sc, 1);
        return;
    }
    const double after = clock_mono();
    sc->due += period_of(sc);
    if (after - sc->due > MAX_LAG) sc->due = after; /* too slow to keep up: do not try to catch up */
    update_rtf(sc, after);
    if (!sc->loop.max_speed || after - sc->last_publish >= PUBLISH_EVERY) scene_publish(sc, 0);
}

/* Whether a scene's whole frame is little work: such frames are stepped together in one call. */
static int steps_whole(const scene *sc)
{
    cs_info info;
    cs_sim_info(sc->engine, &info);
    return sc->frame_sub == 0 && (double)info.substeps * (double)info.n_vertices <= WHOLE_WORK;
}

/* Puts a scene's next whole frame in the batch, at slot nb. */
static void batch_add(simloop *sl, int nb, scene *sc)
{
    cs_info info;
    cs_sim_info(sc->engine, &info);
    if (sc->before_frame) sc->before_frame(sc->engine, sc->frame);
    sc->frame_wall = 0;
    sl->batch[nb] = sc;
    sl->engines[nb] = sc->engine;
    sl->substeps[nb] = info.substeps;
}

/* Steps the batch's nb frames in one call (each ends bitwise as alone: cs_sims_step). The call's
 * compute time is shared among the scenes by their work; a failure is dealt with as
 * scene_run_substeps does, and a complete frame as advance_frame does. sl->each[k]: how each fared. */
static void batch_run(simloop *sl, int nb)
{
    double work = 0;
    for (int k = 0; k < nb; k++) {
        cs_info info;
        cs_sim_info(sl->batch[k]->engine, &info);
        work += (double)sl->substeps[k] * (double)info.n_vertices;
    }
    const double t0 = clock_mono();
    const cs_status st = cs_sims_step(sl->engines, (size_t)nb, sl->substeps, sl->each);
    const double took = clock_mono() - t0;
    double solved = 0; /* the work the count of threads weighs (work_of) */
    for (int k = 0; k < nb; k++) {
        scene *sc = sl->batch[k];
        cs_info info;
        cs_sim_info(sc->engine, &info);
        solved += work_of(&info, sl->substeps[k]);
        const double share = work > 0 ? (double)sl->substeps[k] * (double)info.n_vertices / work : 0;
        if (st != CS_OK) sl->each[k] = st;
        scene_ran_substeps(sc, sl->substeps[k], sl->each[k], took * share);
        if (sc->lost) {
            sc->lost = 0;
            kill(getpid(), SIGUSR1);
        }
        if (sl->each[k] == CS_OK) frame_done(sl, sc, (int32_t)sl->substeps[k]);
    }
    ran(sl, took, solved);
}

/* Whether a step in progress goes by whole frames stepped together with other scenes'. */
static int batched_step(const scene *sc) { return sc->job.cmd && sc->job.frames && steps_whole(sc); }

/* The steps in progress, for about one slice of compute: those of frames of small scenes frame by
 * frame together in batched calls, the others one by one (step_slice). */
static void step_slices(simloop *sl, int n)
{
    const double t0 = clock_mono();
    for (int nb = -1; nb != 0 && clock_mono() - t0 < SIMLOOP_SLICE;) {
        nb = 0;
        for (int k = 0; k < n; k++)
            if (batched_step(sl->turn[k]) && !held(sl, sl->turn[k])) batch_add(sl, nb++, sl->turn[k]);
        if (nb == 0) break;
        batch_run(sl, nb);
        for (int k = 0; k < nb; k++) {
            scene *sc = sl->batch[k];
            if (sl->each[k] != CS_OK) scene_end_step(sc, sc->failed_as);
            else if (++sc->job.frames_run == sc->job.want) scene_end_step(sc, NULL);
        }
    }
    for (int k = 0; k < n; k++) {
        scene *sc = sl->turn[k];
        if (sc->job.cmd && !batched_step(sc)) step_slice(sl, sc);
        else if (sc->job.cmd && clock_mono() - sc->last_publish >= PUBLISH_EVERY) scene_publish(sc, 0);
    }
}

/* The due frames of the running scenes: the small ones together, in one batched call, the large
 * ones one by one, in parts when they are long. */
static void run_due_frames(simloop *sl, int n)
{
    const double now = clock_mono();
    int nb = 0;
    for (int k = 0; k < n; k++)
        if (steps_whole(sl->turn[k]) && frame_due(sl, sl->turn[k], now)) batch_add(sl, nb++, sl->turn[k]);
    if (nb > 0) batch_run(sl, nb);
    for (int k = 0; k < nb; k++) paced(sl->batch[k], sl->each[k] == CS_OK ? 1 : -1);
    for (int k = 0; k < n && !atomic_load(&sl->stopping); k++) {
        scene *sc = sl->turn[k];
        int in_batch = 0;
        for (int b = 0; b < nb && !in_batch; b++) in_batch = sl->batch[b] == sc;
        if (in_batch || !frame_due(sl, sc, clock_mono())) continue;
        paced(sc, run_frame(sl, sc));
    }
}

/* A scene that starts running (created, resumed, restarted from the state file) joins the frame
 * clock: its first frame is due with the next frame of a running scene of the same frame period,
 * so that scenes of one period are stepped together, or now when there is none. */
static void join_clock(simloop *sl, int n, scene *sc)
{
    const double now = clock_mono(), period = period_of(sc);
    sc->due = now;
    for (int k = 0; k < n; k++) {
        const scene *o = sl->turn[k];
        if (o == sc || !o->was_running || o->paused || o->due > now + period || period_of(o) != period) continue;
        sc->due = o->due;
        break;
    }
    cs_info info;
    cs_sim_info(sc->engine, &info);
    sc->rtf_wall = now;
    sc->rtf_sim = info.time;
}

/* ---- commands ---- */

/* Runs a scene's queued commands, publishes (with the hash while paused, or when asked), then
 * answers them: reads that follow the answers see the commands. A step in progress publishes its
 * progress without the hash. */
static void run_commands(scene *sc)
{
    scene_cmd *list = scene_take_queue(sc);
    if (!list) return;
    int want_hash = 0;
    scene_cmd *answer = NULL, **tail = &answer;
    for (scene_cmd *c = list, *next; c; c = next) {
        next = c->next; /* c may be answered (and gone) before the loop ends: a step is ended */
        c->failed = 0;
        c->result = NULL;
        c->blob = NULL;
        c->blob_len = 0;
        memset(&c->pr, 0, sizeof c->pr);
        want_hash |= command_wants_hash(c);
        if (command_run(sc, c)) continue; /* the step in progress: scene_end_step answers it */
        c->next = NULL;
        *tail = c;
        tail = &c->next;
    }
    scene_publish(sc, want_hash || (sc->paused && !sc->job.cmd));
    for (scene_cmd *c = answer, *next; c; c = next) {
        next = c->next;
        command_finish(sc, c);
    }
}

/* ---- the thread ---- */

/* Waits for a command while every scene is paused, or until `until` on the monotonic clock (0: no
 * wait), unless a command came meanwhile; BEAT_EVERY (or the beat's period) at most. Returns 1
 * when stopping. */
static int wait_for_work(simloop *sl, int wait, double until)
{
    const double beat = clock_mono() + sl->beat_every; /* the next heartbeat comes whatever happens */
    if (until <= 0 || until > beat) until = beat;
    pthread_mutex_lock(&sl->lock);
    if (wait && !sl->kicked && !sl->stop) {
        struct timespec ts;
        ts.tv_sec = (time_t)until;
        ts.tv_nsec = (long)((until - (double)ts.tv_sec) * 1e9);
        pthread_cond_timedwait(&sl->cond, &sl->lock, &ts);
    }
    sl->kicked = 0;
    const int stop = sl->stop;
    pthread_mutex_unlock(&sl->lock);
    return stop;
}

/* With threads 0 (auto), the count the scenes step on from now (autothreads.h), given to each
 * engine (a new scene's too) and shown in /metrics. greedy: a step or a max_speed scene. */
static void count_threads(simloop *sl, int n, int greedy)
{
    if (!sl->auto_threads) return;
    const int t = autothreads_turn(&sl->at, clock_mono(), greedy);
    for (int k = 0; k < n; k++) cs_sim_set_threads(sl->turn[k]->engine, t);
    metrics_threads(sl->m, t);
}

/* A scene that stopped running leaves the frame clock; one that started joins it. */
static void clock_in(simloop *sl, int n, scene *sc)
{
    if (sc->paused) sc->was_running = 0;
    else if (!sc->was_running) {
        join_clock(sl, n, sc);
        sc->was_running = 1;
    }
}

static void *run(void *arg)
{
    simloop *sl = arg;
    sigset_t all;
    sigfillset(&all);
    pthread_sigmask(SIG_BLOCK, &all, NULL);
    scene **turn = sl->turn;
    for (int stop = 0; !stop;) {
        heartbeat(sl);
        const int n = scenes_list(sl->table, turn, sl->cap);
        int stepping = 0, running = 0, fast = 0;
        double due = 0;
        for (int k = 0; k < n; k++) {
            scene *sc = turn[k];
            stepping |= sc->job.cmd != NULL;
            clock_in(sl, n, sc);
            if (sc->paused) continue;
            running = 1;
            fast |= sc->loop.max_speed;
            if (due == 0 || sc->due < due) due = sc->due;
        }
        /* A step in progress: a slice, then the queues (without waiting). Else wait for commands
         * while paused, or until the next frame is due. */
        const int wait = sl->held || (!stepping && (!running || (!fast && clock_mono() < due)));
        double until = running ? due : 0;
        if (sl->held) { /* a frame waits for a recording's writer: look again soon, not at once */
            const double soon = clock_mono() + HELD_WAIT;
            if (until <= 0 || until > soon) until = soon;
        }
        sl->held = 0;
        stop = wait_for_work(sl, wait, until);
        scenes_drop_gone(sl->table);
        for (int k = 0; k < n; k++) {
            run_commands(turn[k]);
            clock_in(sl, n, turn[k]);
        }
        if (!stop) {
            count_threads(sl, n, stepping || fast);
            step_slices(sl, n);
            run_due_frames(sl, n);
        }
        for (int k = 0; k < n; k++) {
            if (stop) scene_end_step(turn[k], "shutdown"); /* a step in progress (or one that came with the stop) */
            scene_release(turn[k]);
        }
    }
    return NULL;
}

/* ---- lifecycle ---- */

/* The turn's arrays, and the loop itself. */
static void free_turn(simloop *sl)
{
    free(sl->turn);
    free(sl->batch);
    free(sl->engines);
    free(sl->substeps);
    free(sl->each);
    free(sl);
}

simloop *simloop_new(scenes *table, metrics *m)
{
    simloop *sl = calloc(1, sizeof *sl);
    if (!sl) return NULL;
    sl->table = table;
    sl->m = m;
    sl->beat_every = BEAT_EVERY;
    sl->cap = scenes_max(table) > 0 ? scenes_max(table) : 1;
    const size_t c = (size_t)sl->cap;
    sl->turn = calloc(c, sizeof *sl->turn);
    sl->batch = calloc(c, sizeof *sl->batch);
    sl->engines = calloc(c, sizeof *sl->engines);
    sl->substeps = calloc(c, sizeof *sl->substeps);
    sl->each = calloc(c, sizeof *sl->each);
    if (!sl->turn || !sl->batch || !sl->engines || !sl->substeps || !sl->each) {
        free_turn(sl);
        return NULL;
    }
    pthread_mutex_init(&sl->lock, NULL);
    pthread_condattr_t ca;
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC); /* waits are until a monotonic deadline */
    pthread_cond_init(&sl->cond, &ca);
    pthread_condattr_destroy(&ca);
    scenes_set_wake(table, wake, sl);
    return sl;
}

int simloop_start(simloop *sl)
{
    if (pthread_create(&sl->thread, NULL, run, sl) != 0) return -1;
    sl->started = 1;
    return 0;
}

void simloop_stop(simloop *sl)
{
    /* Commands that come from now on are refused at once; the thread runs those queued before. */
    scenes_close(sl->table);
    scene **all = malloc(sizeof *all * (size_t)sl->cap);
    const int n = all ? scenes_list(sl->table, all, sl->cap) : 0;
    for (int k = 0; k < n; k++) scene_close(all[k]);
    pthread_mutex_lock(&sl->lock);
    sl->stop = 1;
    atomic_store(&sl->stopping, 1);
    pthread_cond_signal(&sl->cond);
    pthread_mutex_unlock(&sl->lock);
    if (sl->started) pthread_join(sl->thread, NULL);
    sl->started = 0;
    for (int k = 0; k < n; k++) {
        scene_refuse_queued(all[k]); /* what the thread did not take before it stopped */
        scene_release(all[k]);
    }
    free(all);
    scenes_drop_gone(sl->table);
}

void simloop_free(simloop *sl)
{
    if (!sl) return;
    if (sl->started) simloop_stop(sl);
    scenes_set_wake(sl->table, NULL, NULL);
    pthread_mutex_destroy(&sl->lock);
    pthread_cond_destroy(&sl->cond);
    free_turn(sl);
}
