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
#include "sim/commands.h"
#include "sim/simloop.h"

#define PUBLISH_EVERY 0.016 /* s of wall time between publications while running */
#define RTF_WINDOW 0.5      /* s of wall time over which the real-time factor is measured */
#define MAX_LAG 0.25        /* s of wall time a scene may fall behind before it stops catching up */
#define COST_PRIOR 2e-8     /* s per vertex and substep assumed before the first measurement */
#define WHOLE_WORK 1e6      /* vertex-substeps run in one call whatever the clock says (a few ms) */
#define MAX_TURN 64         /* scenes stepped in one turn of the loop */

struct simloop {
    scenes *table;
    metrics *m;
    pthread_t thread;
    int started;
    pthread_mutex_t lock;
    pthread_cond_t cond;
    int kicked;          /* a command came since the thread last looked */
    int stop;
    atomic_int stopping; /* stop, readable without the lock between slices */
};

static void wake(void *ctx)
{
    simloop *sl = ctx;
    pthread_mutex_lock(&sl->lock);
    sl->kicked = 1;
    pthread_cond_signal(&sl->cond);
    pthread_mutex_unlock(&sl->lock);
}

/* ---- stepping one scene ---- */

/* Substeps run, and a backend failure told to the daemon: it saves and exits (main.c). */
static cs_status run_substeps(scene *sc, int64_t n)
{
    const cs_status st = scene_run_substeps(sc, n);
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

/* Steps the frame in progress on, by about `budget` seconds of compute at most (a whole frame
 * when it fits, else at least one substep), and when it is complete does what follows a frame:
 * the frame count, automatic drops, checkpoints. 1 when the frame completed, 0 when it is not
 * complete yet, -1 after a failure (dealt with: see scene_run_substeps). */
static int advance_frame(simloop *sl, scene *sc, double budget)
{
    cs_info info;
    if (sc->frame_sub == 0) {
        if (sc->before_frame) sc->before_frame(sc->engine, sc->frame);
        sc->frame_wall = 0;
    }
    cs_sim_info(sc->engine, &info);
    const int32_t left = info.substeps - sc->frame_sub;
    const int64_t n = left > 0 ? fitting(sc, budget, left) : 0;
    if (n > 0 && run_substeps(sc, n) != CS_OK) {
        sc->frame_sub = 0;
        return -1;
    }
    sc->frame_sub += (int32_t)n;
    if (sc->frame_sub < info.substeps) return 0;
    sc->frame_sub = 0;
    metrics_frame(sl->m, info.substeps, sc->frame_wall);
    sc->frame++;
    autodrop_after_frame(sc);
    if (++sc->frames_since_checkpoint >= (uint64_t)sc->loop.checkpoint_interval) scene_take_checkpoint(sc);
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
            if (run_substeps(sc, fitting(sc, budget, j->want - done)) != CS_OK) {
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

/* A frame of a running scene whose frame is due (or that runs at max_speed), and its pacing. */
static void run_due_frame(simloop *sl, scene *sc)
{
    cs_params p;
    cs_sim_params(sc->engine, &p);
    const loop_settings *loop = &sc->loop;
    if (sc->job.cmd || sc->paused || (!loop->max_speed && clock_mono() < sc->due)) return;
    const int r = run_frame(sl, sc);
    if (r == 0) return; /* stopping part way through a long frame: the next look says so */
    if (r < 0) {
        scene_publish(sc, 1);
        return;
    }
    const double after = clock_mono();
    sc->due += 1.0 / ((double)p.frame_rate * (double)loop->time_scale);
    if (after - sc->due > MAX_LAG) sc->due = after; /* too slow to keep up: do not try to catch up */
    update_rtf(sc, after);
    if (!loop->max_speed || after - sc->last_publish >= PUBLISH_EVERY) scene_publish(sc, 0);
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
 * wait), unless a command came meanwhile. Returns 1 when stopping. */
static int wait_for_work(simloop *sl, int wait, double until)
{
    pthread_mutex_lock(&sl->lock);
    if (wait && !sl->kicked && !sl->stop) {
        if (until <= 0) {
            pthread_cond_wait(&sl->cond, &sl->lock);
        } else {
            struct timespec ts;
            ts.tv_sec = (time_t)until;
            ts.tv_nsec = (long)((until - (double)ts.tv_sec) * 1e9);
            pthread_cond_timedwait(&sl->cond, &sl->lock, &ts);
        }
    }
    sl->kicked = 0;
    const int stop = sl->stop;
    pthread_mutex_unlock(&sl->lock);
    return stop;
}

static void *run(void *arg)
{
    simloop *sl = arg;
    sigset_t all;
    sigfillset(&all);
    pthread_sigmask(SIG_BLOCK, &all, NULL);
    scene *turn[MAX_TURN];
    int n = scenes_list(sl->table, turn, MAX_TURN);
    for (int k = 0; k < n; k++) {
        turn[k]->due = turn[k]->rtf_wall = clock_mono();
        scene_release(turn[k]);
    }
    for (int stop = 0; !stop;) {
        n = scenes_list(sl->table, turn, MAX_TURN);
        int stepping = 0, running = 0, fast = 0;
        double due = 0;
        for (int k = 0; k < n; k++) {
            scene *sc = turn[k];
            stepping |= sc->job.cmd != NULL;
            if (sc->paused) continue;
            running = 1;
            fast |= sc->loop.max_speed;
            if (due == 0 || sc->due < due) due = sc->due;
        }
        /* A step in progress: a slice, then the queues (without waiting). Else wait for commands
         * while paused, or until the next frame is due. */
        const int wait = !stepping && (!running || (!fast && clock_mono() < due));
        stop = wait_for_work(sl, wait, running ? due : 0);
        for (int k = 0; k < n; k++) run_commands(turn[k]);
        for (int k = 0; k < n && !stop; k++) {
            if (turn[k]->job.cmd) step_slice(sl, turn[k]);
            else run_due_frame(sl, turn[k]);
        }
        for (int k = 0; k < n; k++) {
            if (stop) scene_end_step(turn[k], "shutdown"); /* a step in progress (or one that came with the stop) */
            scene_release(turn[k]);
        }
    }
    return NULL;
}

/* ---- lifecycle ---- */

simloop *simloop_new(scenes *table, metrics *m)
{
    simloop *sl = calloc(1, sizeof *sl);
    if (!sl) return NULL;
    sl->table = table;
    sl->m = m;
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
    scene *all[MAX_TURN];
    const int n = scenes_list(sl->table, all, MAX_TURN);
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
}

void simloop_free(simloop *sl)
{
    if (!sl) return;
    if (sl->started) simloop_stop(sl);
    scenes_set_wake(sl->table, NULL, NULL);
    pthread_mutex_destroy(&sl->lock);
    pthread_cond_destroy(&sl->cond);
    free(sl);
}
