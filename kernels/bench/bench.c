/* clothd-bench - how many vertex-substeps per second a backend sustains, and what its cost model
 * says it should.
 *
 * Cases: square cloths (--sizes), each with the rock counts of --rocks resting on it, their
 * contact by each model of --contact (surface, vertex; without rocks the first only); velocity
 * Verlet with every force on (springs with damping, drag, gravity, ground, plasticity and tearing
 * checks, and contact with the rocks). Each case settles briefly, then runs for --seconds of wall
 * time. --self-collision turns self_collision on in every case and reports what it did (its
 * passes, broad phases, pairs, contacts, cuts); --crumple makes each cloth a
 * free one that a side wind blows onto the ground, and measures it after a simulated second of
 * folding. Prints one line per case (JSON with --json), with the backend's cost model: the bytes each
 * kernel (or CPU pass) reads and writes per vertex per substep and its launches per frame; for CUDA
 * the bandwidth roofline on an H100 (3.35 TB/s) and an H200 (4.8 TB/s), the launch floor at
 * LAUNCH_US per dependent kernel of a graph, WAIT_US per wait of the host for the device, and
 * what this device's memory bandwidth allows.
 * --model prints the cost models without running anything (no device needed), and for CUDA how
 * many default scenes one batch runs in real time (print_batch).
 *
 * --batch N,...: for each size and each count N, N scenes of the default scene and parameters
 * (cs_scene_default, cs_params_default with the backend's integrator, cs_params_default_integrator,
 * or --integrator's; the effective substeps per frame from cs_sim_info),
 * stepped frame by frame for --seconds each way: all N in one cs_sims_step call a frame (batch),
 * and each by its own cs_sim_step (alone). Prints the aggregate vertex-substeps/s of both, their
 * ratio, the batch's against one scene stepped alone (the single-scene figure), and how many such
 * scenes the batch's throughput keeps in real time (each needs substeps x frame_rate substeps a
 * second). --frames F --only batch|alone runs one way for F frames and prints nothing else: a
 * fixed amount of work, for timing the two ways as whole processes (without --batch, --frames F
 * runs each case for F frames from its start instead of --seconds: the same work every run,
 * for comparing two builds). --read reads every scene's
 * positions after each frame (what a daemon streaming them all does). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "clothsim/backend.h"
#include "clothsim/clothsim.h"

/* What the predictions assume: HBM3 peak bandwidths, and the device time of a kernel node that
 * depends on the previous one inside a CUDA graph (an assumption until measured). */
#define H100_BW 3.35e12
#define H200_BW 4.8e12
#define LAUNCH_US 2.0
/* The host time of one CUDA runtime call a batch makes per scene (an event, a wait, an async
 * copy; an assumption until measured). */
#define HOST_CALL_US 1.5
/* A wait of the host for the device mid-step (a few bytes copied back, the stream synchronized,
 * the device idle until the host queues more; an assumption until measured). */
#define WAIT_US 10.0

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* What self_collision did while a case was measured: its broad phases and pairs (the lists they
 * built, on average), the contacts that pushed and the vertices the bound cut, per pass. */
static void print_self(const cs_self_stats *st, int json)
{
    const double passes = st->passes > 0 ? (double)st->passes : 1.0, broad = st->broad > 0 ? (double)st->broad : 1.0;
    if (json)
        printf(",\"self_passes\":%d,\"self_broad_phases\":%d,\"self_pairs_per_broad_phase\":%.0f,"
               "\"self_contacts_per_pass\":%.1f,\"self_cut_per_pass\":%.2f,\"self_lost\":%lld",
               st->passes, st->broad, (double)st->pairs / broad, (double)st->contacts / passes,
               (double)st->cut / passes, (long long)st->lost);
    else
        printf("        self_collision: %d passes, %d broad phases (%.2f a pass), %.0f repelling pairs in the lists a broad "
               "phase, %.1f contacts and %.2f vertices cut a pass, %lld vertices without a list\n",
               st->passes, st->broad, st->broad / passes, (double)st->pairs / broad,
               (double)st->contacts / passes, (double)st->cut / passes, (long long)st->lost);
}

static void usage(FILE *f)
{
    fprintf(f,
            "usage: clothd-bench [--backend cpu|cuda|auto] [--json] [--threads N] [--seconds S]\n"
            "                    [--sizes 64,128,256,512] [--rocks 0,16] [--contact surface,vertex]\n"
            "                    [--integrator velocity_verlet|symplectic_euler|implicit_euler] [--model]\n"
            "                    [--self-collision] [--crumple] [--frames F] [--set NAME=VALUE ...]\n"
            "       clothd-bench --batch 1,4,16,64 [--backend B] [--sizes 32,64] [--threads N] [--seconds S]\n"
            "                    [--frames F --only batch|alone] [--read] [--json]\n");
}

/* Rocks on a square grid over the middle of the cloth, just touching it (light ones: the case
 * measures contact, not a cloth sagging to the ground). */
static int add_rocks(cs_sim *sim, const cs_scene *sc, const cs_params *p, int count)
{
    const int cols = (int)ceil(sqrt((double)count));
    for (int k = 0; k < count; k++) {
        cs_rock_def d;
        cs_rock_def_default(&d);
        d.radius = 0.08f;
        d.density = 200.0f;
        const double f = cols > 1 ? 0.6 / (cols - 1) : 0.0;
        d.position[0] = (float)((k % cols * f - (cols > 1 ? 0.3 : 0.0)) * sc->size_x);
        d.position[1] = (float)((k / cols * f - (cols > 1 ? 0.3 : 0.0)) * sc->size_y);
        d.position[2] = sc->height + d.radius + p->contact_offset;
        if (cs_rock_add(sim, &d, NULL) != CS_OK) return -1;
    }
    return 0;
}

/* Substeps per second that n vertices allow at this bandwidth, by the model's bytes. */
static double roofline(const cs_cost_model *m, double n, double bw)
{
    return bw / (m->bytes_per_vertex_substep * n + m->fixed_per_substep);
}

/* The bandwidth time, the dependent kernels' time and the host's waits one after the other: a
 * substep's kernels each wait for the one before, so their launch gaps are not hidden behind the
 * traffic, and while the host waits the device has nothing queued. */
static double predicted(const cs_cost_model *m, double n, double bw)
{
    return 1.0 / (1.0 / roofline(m, n, bw) + m->nodes_per_substep * LAUNCH_US * 1e-6 +
                  m->waits_per_substep * WAIT_US * 1e-6);
}

/* The model's rows and totals (and for CUDA its predictions) as JSON members or text lines. */
static void print_model(const char *backend, const cs_cost_model *m, double n, int json, double measured_bw)
{
    const int cuda = strcmp(backend, "cuda") == 0;
    const double launch = m->nodes_per_substep > 0 ? 1e6 / (LAUNCH_US * m->nodes_per_substep) : 0;
    const double rh100 = roofline(m, n, H100_BW), rh200 = roofline(m, n, H200_BW);
    const double ph100 = predicted(m, n, H100_BW), ph200 = predicted(m, n, H200_BW);
    if (!json) {
        printf("  %-46s %9s %9s %11s %9s\n", "kernel / pass", "read B/v", "write B/v", "fixed B", "per frame");
        for (int i = 0; i < m->n; i++)
            printf("  %-46s %9.2f %9.2f %11.0f %9.1f\n", m->k[i].name, m->k[i].read, m->k[i].written, m->k[i].fixed,
                   m->k[i].per_frame);
        printf("  %.2f bytes per vertex-substep (+ %.0f per substep), %.1f launches per frame\n",
               m->bytes_per_vertex_substep, m->fixed_per_substep, m->launches_per_frame);
        if (cuda)
            printf("  %.1f graphs per frame; roofline %.0f substeps/s on an H100, %.0f on an H200; launch floor %.0f at "
                   "%.1f us a kernel;\n  %.1f host waits a substep at %.0f us; predicted (roofline time plus kernel gaps "
                   "plus waits) %.0f on an H100, %.0f on an H200\n",
                   m->graphs_per_frame, rh100, rh200, launch, LAUNCH_US, m->waits_per_substep, WAIT_US, ph100, ph200);
        return;
    }
    printf(",\"model\":{\"kernels\":[");
    for (int i = 0; i < m->n; i++)
        printf("%s{\"name\":\"%s\",\"read_per_vertex\":%.2f,\"written_per_vertex\":%.2f,\"fixed_bytes\":%.0f,"
               "\"per_substep\":%.4f,\"per_frame\":%.2f}",
               i ? "," : "", m->k[i].name, m->k[i].read, m->k[i].written, m->k[i].fixed, m->k[i].per_substep,
               m->k[i].per_frame);
    printf("],\"bytes_per_vertex_substep\":%.2f,\"fixed_bytes_per_substep\":%.0f,\"launches_per_frame\":%.1f",
           m->bytes_per_vertex_substep, m->fixed_per_substep, m->launches_per_frame);
    if (cuda)
        printf(",\"graphs_per_frame\":%.1f,\"roofline_h100_substeps_per_s\":%.0f,\"roofline_h200_substeps_per_s\":%.0f,"
               "\"launch_floor_substeps_per_s\":%.0f,\"launch_us_assumed\":%.1f,\"host_waits_per_substep\":%.2f,"
               "\"wait_us_assumed\":%.1f,\"predicted_h100_substeps_per_s\":%.0f,\"predicted_h200_substeps_per_s\":%.0f",
               m->graphs_per_frame, rh100, rh200, launch, LAUNCH_US, m->waits_per_substep, WAIT_US, ph100, ph200);
    if (cuda && measured_bw > 0) printf(",\"roofline_this_device_substeps_per_s\":%.0f", roofline(m, n, measured_bw));
    printf("}");
}

/* ---- batch mode ---- */

/* How a batch runs: its backend, and whether every scene's positions are read after each frame
 * (into buf, of len floats: the largest scene's). */
typedef struct batch_how {
    const char *backend;
    int read;
    float *buf;
    size_t len;
    int integrator; /* -1: its backend's default (cs_params_default_integrator) */
} batch_how;

/* n default scenes of size x size, under --integrator or else the default of the backend each runs
 * on. */
static cs_sim **batch_make(const batch_how *how, int size, int n, int threads)
{
    cs_sim **sims = calloc((size_t)n, sizeof *sims);
    if (!sims) return NULL;
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = sc.ny = size;
    for (int k = 0; k < n; k++) {
        char err[256];
        if (how->integrator >= 0) p.integrator = (cs_integrator)how->integrator;
        cs_status st = cs_sim_create(&sc, &p, how->backend, &sims[k], err, sizeof err);
        if (st == CS_OK && how->integrator < 0) { /* the backend's default, now that it is known */
            p.integrator = cs_params_default_integrator(cs_sim_backend(sims[k]));
            if ((st = cs_sim_set_params(sims[k], &p)) != CS_OK) {
                snprintf(err, sizeof err, "%s", cs_sim_error(sims[k]));
                cs_sim_destroy(sims[k]);
            }
        }
        if (st != CS_OK) {
            fprintf(stderr, "clothd-bench: %dx%d: %s\n", size, size, err);
            for (int j = 0; j < k; j++) cs_sim_destroy(sims[j]);
            free(sims);
            return NULL;
        }
        cs_sim_set_threads(sims[k], threads);
    }
    return sims;
}

/* Steps every scene one frame, in one batch or each alone; 0 when every one stepped. */
static int batch_frame(const batch_how *how, cs_sim **sims, int n, const int64_t *sub, cs_status *each, int alone)
{
    if (!alone) {
        if (cs_sims_step(sims, (size_t)n, sub, each) != CS_OK) return -1;
    } else {
        for (int k = 0; k < n; k++) each[k] = cs_sim_step(sims[k], sub[k]);
    }
    for (int k = 0; k < n; k++)
        if (each[k] != CS_OK) {
            fprintf(stderr, "clothd-bench: scene %d: %s\n", k, cs_sim_error(sims[k]));
            return -1;
        }
    for (int k = 0; how->read && k < n; k++) {
        cs_info info;
        cs_sim_info(sims[k], &info);
        if (cs_read_positions(sims[k], how->buf, 3 * (size_t)info.n_vertices) != CS_OK) {
            fprintf(stderr, "clothd-bench: scene %d: %s\n", k, cs_sim_error(sims[k]));
            return -1;
        }
    }
    return 0;
}

/* Frames a second (of all scenes together) over `seconds` of wall time, after one frame that
 * settles; or over `frames` frames when that is > 0. Negative on a failure. */
static double batch_rate(const batch_how *how, cs_sim **sims, int n, const int64_t *sub, cs_status *each, int alone, double seconds,
                         int64_t frames)
{
    if (frames > 0) {
        for (int64_t f = 0; f < frames; f++)
            if (batch_frame(how, sims, n, sub, each, alone) != 0) return -1;
        return 0;
    }
    if (batch_frame(how, sims, n, sub, each, alone) != 0) return -1;
    int64_t done = 0;
    const double t0 = now();
    double t = t0;
    while (t - t0 < seconds) {
        if (batch_frame(how, sims, n, sub, each, alone) != 0) return -1;
        done++;
        t = now();
    }
    return (double)done * n / (t - t0);
}

/* One count's figures, each way. */
typedef struct batch_row {
    int size, n, substeps;
    double frame_rate, batch, alone; /* frames a second of all scenes together */
} batch_row;

static int run_batch(batch_how *how, const int *sizes, int n_sizes, const int *counts, int n_counts, int threads, double seconds,
                     int64_t frames, const char *only, int json)
{
    if (frames > 0) { /* one way, fixed work */
        for (int si = 0; si < n_sizes; si++)
            for (int ci = 0; ci < n_counts; ci++) {
                const int n = counts[ci];
                cs_sim **sims = batch_make(how, sizes[si], n, threads);
                int64_t *sub = malloc(sizeof *sub * (size_t)n);
                cs_status *each = malloc(sizeof *each * (size_t)n);
                if (!sims || !sub || !each) return 1;
                for (int k = 0; k < n; k++) {
                    cs_info info;
                    cs_sim_info(sims[k], &info);
                    sub[k] = info.substeps;
                }
                if (batch_rate(how, sims, n, sub, each, strcmp(only, "alone") == 0, 0, frames) < 0) return 1;
                for (int k = 0; k < n; k++) cs_sim_destroy(sims[k]);
                free(sims), free(sub), free(each);
            }
        return 0;
    }
    if (!json)
        printf("%-9s %6s %9s %19s %19s %8s %9s %9s\n", "grid", "scenes", "substeps", "batch vertex-sub/s",
               "alone vertex-sub/s", "b/alone", "b/single", "realtime");
    for (int si = 0; si < n_sizes; si++) {
        const int size = sizes[si];
        double single = 0; /* one scene alone: frames a second */
        for (int ci = 0; ci < n_counts; ci++) {
            const int n = counts[ci];
            cs_sim **sims = batch_make(how, size, n, threads);
            int64_t *sub = malloc(sizeof *sub * (size_t)n);
            cs_status *each = malloc(sizeof *each * (size_t)n);
            if (!sims || !sub || !each) return 1;
            cs_info info;
            cs_params p;
            cs_sim_info(sims[0], &info);
            cs_sim_params(sims[0], &p);
            for (int k = 0; k < n; k++) sub[k] = info.substeps;
            batch_row r = {size, n, info.substeps, p.frame_rate, 0, 0};
            if (single == 0) {
                single = batch_rate(how, sims, 1, sub, each, 1, seconds, 0);
                if (single < 0) return 1;
            }
            r.alone = n == 1 ? single : batch_rate(how, sims, n, sub, each, 1, seconds, 0);
            r.batch = batch_rate(how, sims, n, sub, each, 0, seconds, 0);
            if (r.alone < 0 || r.batch < 0) return 1;
            const double vs = (double)size * size * r.substeps; /* vertex-substeps a frame */
            const double realtime = r.batch / r.frame_rate;    /* scenes it keeps in real time */
            if (json)
                printf("{\"backend\":\"%s\",\"device\":\"%s\",\"read\":%s,\"nx\":%d,\"ny\":%d,\"scenes\":%d,"
                       "\"substeps_per_frame\":%d,\"frame_rate\":%.1f,\"batch_vertex_substeps_per_s\":%.0f,"
                       "\"alone_vertex_substeps_per_s\":%.0f,\"single_vertex_substeps_per_s\":%.0f,"
                       "\"batch_over_alone\":%.3f,\"batch_over_single\":%.3f,\"scenes_in_real_time\":%.1f}\n",
                       cs_sim_backend(sims[0]), cs_sim_device(sims[0]), how->read ? "true" : "false", size, size, n, r.substeps, r.frame_rate, r.batch * vs, r.alone * vs,
                       single * vs, r.batch / r.alone, r.batch / single, realtime);
            else
                printf("%4dx%-4d %6d %9d %19.0f %19.0f %8.2f %9.2f %9.1f\n", size, size, n, r.substeps, r.batch * vs,
                       r.alone * vs, r.batch / r.alone, r.batch / single, realtime);
            fflush(stdout);
            for (int k = 0; k < n; k++) cs_sim_destroy(sims[k]);
            free(sims), free(sub), free(each);
        }
    }
    return 0;
}

/* Scenes of one kind a batch runs in real time at this bandwidth: a frame's time is each scene's
 * traffic (its substeps at the model's bytes) and host calls, plus the batch's kernels and waits for
 * the device once (their launch gaps and round trips, shared by every scene), one after another. */
static double scenes_in_real_time(const cs_cost_model *m, double n, double substeps, double fps, double bw,
                                  double calls)
{
    const double traffic = substeps * (m->bytes_per_vertex_substep * n + m->fixed_per_substep) / bw;
    const double shared = m->launches_per_frame * LAUNCH_US * 1e-6 + substeps * m->waits_per_substep * WAIT_US * 1e-6;
    const double host = calls * HOST_CALL_US * 1e-6;
    const double left = 1.0 / fps - shared;
    return left > 0 ? floor(left / (traffic + host)) : 0;
}

/* The batch prediction: the default scene (scene and parameters as the engine's defaults, no rocks)
 * under integrator in one batch of many, on an H100 and an H200: by bandwidth, launches and waits
 * alone, with each scene's host calls when no frame is read, and with every scene's frame read each
 * frame. */
static void print_batch_of(int json, cs_integrator integrator)
{
    const cs_backend *cuda = cs_backend_cuda();
    cs_sim *sim = NULL;
    char err[256];
    cs_params dp;
    cs_params_default(&dp);
    dp.integrator = integrator;
    static const char *const names[] = {CS_CHOICES_INTEGRATOR};
    const char *name = names[integrator];
    if (!cuda || cs_sim_create(NULL, &dp, "cpu", &sim, err, sizeof err) != CS_OK) return;
    cs_info info;
    cs_params p;
    cs_cost_model m;
    cs_sim_info(sim, &info);
    cs_sim_params(sim, &p);
    cs_sim_cost(sim, cuda, &m);
    cs_scene sc;
    cs_sim_scene(sim, &sc);
    cs_sim_destroy(sim);
    const double n = info.n_vertices, F = info.substeps, fps = p.frame_rate;
    const double bws[2] = {H100_BW, H200_BW};
    double k[2][3];
    for (int d = 0; d < 2; d++) {
        k[d][0] = scenes_in_real_time(&m, n, F, fps, bws[d], 0);
        k[d][1] = scenes_in_real_time(&m, n, F, fps, bws[d], m.batch_calls_per_scene);
        k[d][2] = scenes_in_real_time(&m, n, F, fps, bws[d], m.batch_calls_per_read_scene);
    }
    const double mb = F * (m.bytes_per_vertex_substep * n + m.fixed_per_substep) / 1e6;
    if (json) {
        printf("{\"backend\":\"cuda\",\"batch\":\"default scene\",\"integrator\":\"%s\",\"nx\":%d,\"ny\":%d,"
               "\"substeps_per_frame\":%d,\"frame_rate\":%.0f,\"bytes_per_vertex_substep\":%.2f,\"mb_per_scene_frame\":%.2f,"
               "\"launches_per_frame\":%.1f,\"launch_us_assumed\":%.1f,\"host_call_us_assumed\":%.1f,"
               "\"host_calls_per_scene\":%.0f,\"host_calls_per_read_scene\":%.0f",
               name, (int)sc.nx, (int)sc.ny, info.substeps, fps, m.bytes_per_vertex_substep, mb, m.launches_per_frame,
               LAUNCH_US, HOST_CALL_US, m.batch_calls_per_scene, m.batch_calls_per_read_scene);
        const char *dev[2] = {"h100", "h200"};
        for (int d = 0; d < 2; d++)
            printf(",\"real_time_scenes_%s_device_only\":%.0f,\"real_time_scenes_%s\":%.0f,"
                   "\"real_time_scenes_%s_frames_read\":%.0f",
                   dev[d], k[d][0], dev[d], k[d][1], dev[d], k[d][2]);
        printf("}\n");
        return;
    }
    printf("cuda, a batch of default scenes under %s (%d x %d, %d substeps a frame at %.0f fps, no rocks):\n", name,
           (int)sc.nx, (int)sc.ny, info.substeps, fps);
    printf("  %.2f bytes per vertex-substep: %.1f MB a scene-frame; %.0f launches and %.1f waits a frame for the "
           "whole batch (%.1f, %.1f us each);\n  %.0f host calls a scene per frame, %.0f with its frame read (%.1f us "
           "each)\n",
           m.bytes_per_vertex_substep, mb, m.launches_per_frame, m.waits_per_substep * F, LAUNCH_US, WAIT_US,
           m.batch_calls_per_scene, m.batch_calls_per_read_scene, HOST_CALL_US);
    printf("  scenes in real time: H100 %.0f by bandwidth, launches and waits, %.0f with host calls, %.0f with every "
           "frame read;\n                       H200 %.0f, %.0f, %.0f\n",
           k[0][0], k[0][1], k[0][2], k[1][0], k[1][1], k[1][2]);
}

/* The batch predictions: the CUDA backend's default integrator, then implicit_euler. */
static void print_batch(int json)
{
    const cs_integrator def = cs_params_default_integrator("cuda");
    print_batch_of(json, def);
    if (def != CS_IMPLICIT_EULER) print_batch_of(json, CS_IMPLICIT_EULER);
}

static int parse_list(const char *s, int *out, int cap)
{
    char list[256];
    int n = 0;
    snprintf(list, sizeof list, "%s", s);
    for (char *tok = strtok(list, ","); tok && n < cap; tok = strtok(NULL, ",")) out[n++] = atoi(tok);
    return n;
}

/* The --set options: live parameters, each NAME=VALUE (a number, or an enum's name). */
#define MAX_SETS 16
static const char *sets[MAX_SETS];
static int n_sets;

/* Applies the --set options to p; prints why and returns -1 when one is not a live parameter or is
 * out of its range. */
static int apply_sets(cs_params *p)
{
    for (int k = 0; k < n_sets; k++) {
        char name[64];
        const char *eq = strchr(sets[k], '=');
        const size_t len = eq ? (size_t)(eq - sets[k]) : 0;
        const cs_param_info *pi = NULL;
        if (eq && len < sizeof name) {
            memcpy(name, sets[k], len);
            name[len] = 0;
            pi = cs_param_find(name);
        }
        if (!pi || pi->kind != CS_KIND_LIVE || pi->type == CS_T_VEC3) {
            fprintf(stderr, "clothd-bench: --set %s: not NAME=VALUE of a live parameter with one value\n", sets[k]);
            return -1;
        }
        double v[3] = {0.0, 0.0, 0.0};
        char *end = NULL;
        const int choice = pi->choices ? cs_param_choice(pi, eq + 1) : -1;
        v[0] = choice >= 0 ? (double)choice : strtod(eq + 1, &end);
        char why[256] = "not a number";
        if ((choice < 0 && (end == eq + 1 || *end)) || cs_param_set(pi, p, v, why, sizeof why) != 0) {
            fprintf(stderr, "clothd-bench: --set %s: %s\n", sets[k], why);
            return -1;
        }
    }
    return 0;
}

int main(int argc, char **argv)
{
    const char *backend = "cpu", *sizes_arg = "64,128,256,512", *integrator = NULL, *rocks_arg = "0,16";
    const char *contacts = "surface,vertex";
    const char *batch_arg = NULL, *only = NULL;
    int json = 0, threads = 0, model_only = 0, sizes_given = 0, read_frames = 0, self_collision = 0, crumple = 0;
    double seconds = 1.5;
    long long frames = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *val = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--json") == 0) json = 1;
        else if (strcmp(a, "--model") == 0) model_only = 1;
        else if (strcmp(a, "--read") == 0) read_frames = 1;
        else if (strcmp(a, "--backend") == 0 && val) backend = val, i++;
        else if (strcmp(a, "--threads") == 0 && val) threads = atoi(val), i++;
        else if (strcmp(a, "--seconds") == 0 && val) seconds = atof(val), i++;
        else if (strcmp(a, "--sizes") == 0 && val) sizes_arg = val, sizes_given = 1, i++;
        else if (strcmp(a, "--batch") == 0 && val) batch_arg = val, i++;
        else if (strcmp(a, "--frames") == 0 && val) frames = atoll(val), i++;
        else if (strcmp(a, "--only") == 0 && val) only = val, i++;
        else if (strcmp(a, "--rocks") == 0 && val) rocks_arg = val, i++;
        else if (strcmp(a, "--contact") == 0 && val) contacts = val, i++;
        else if (strcmp(a, "--integrator") == 0 && val) integrator = val, i++;
        else if (strcmp(a, "--self-collision") == 0) self_collision = 1;
        else if (strcmp(a, "--crumple") == 0) crumple = 1;
        else if (strcmp(a, "--set") == 0 && val && n_sets < MAX_SETS) sets[n_sets++] = val, i++;
        else if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            usage(stdout);
            return 0;
        } else {
            usage(stderr);
            return 2;
        }
    }
    if (!(seconds > 0 && seconds < 3600)) {
        fprintf(stderr, "clothd-bench: --seconds must be in (0, 3600)\n");
        return 2;
    }
    const cs_param_info *integ = cs_param_find("integrator");
    const char *integ_name = integrator ? integrator : "velocity_verlet"; /* the sizes' default */
    const int integ_index = cs_param_choice(integ, integ_name);
    if (integ_index < 0) {
        fprintf(stderr, "clothd-bench: unknown integrator '%s'\n", integrator);
        return 2;
    }
    int sizes[16], rock_counts[8];
    const int n_sizes = parse_list(sizes_arg, sizes, 16), n_counts = parse_list(rocks_arg, rock_counts, 8);
    for (int s = 0; s < n_sizes; s++)
        if (sizes[s] < 2 || sizes[s] > 4096) {
            fprintf(stderr, "clothd-bench: sizes must be 2..4096\n");
            return 2;
        }
    if (!batch_arg && (only || frames < 0 || frames > 1000000)) {
        fprintf(stderr, "clothd-bench: --only belongs to --batch; --frames is 1..1e6\n");
        return 2;
    }
    if (batch_arg) {
        int counts[16], bsizes[16];
        const int n_counts = parse_list(batch_arg, counts, 16);
        const int n_bsizes = sizes_given ? parse_list(sizes_arg, bsizes, 16) : parse_list("32,64", bsizes, 16);
        for (int c = 0; c < n_counts; c++)
            if (counts[c] < 1 || counts[c] > CS_BATCH_MAX) {
                fprintf(stderr, "clothd-bench: --batch counts must be 1..%d\n", CS_BATCH_MAX);
                return 2;
            }
        if (n_counts == 0 || (frames > 0) != (only != NULL) || frames < 0 || frames > 1000000 ||
            (only && strcmp(only, "batch") != 0 && strcmp(only, "alone") != 0)) {
            fprintf(stderr, "clothd-bench: --batch takes counts; --frames (1..1e6) and --only batch|alone go "
                            "together\n");
            return 2;
        }
        for (int s = 0; s < n_bsizes; s++)
            if (bsizes[s] < 2 || bsizes[s] > 4096) {
                fprintf(stderr, "clothd-bench: sizes must be 2..4096\n");
                return 2;
            }
        int widest = 0;
        for (int k = 0; k < n_bsizes; k++) widest = bsizes[k] > widest ? bsizes[k] : widest;
        batch_how how = {backend, read_frames, NULL, 3 * (size_t)widest * (size_t)widest, integrator ? integ_index : -1};
        if (read_frames && !(how.buf = malloc(sizeof(float) * how.len))) return 1;
        const int rc = run_batch(&how, bsizes, n_bsizes, counts, n_counts, threads, seconds, frames, only ? only : "", json);
        free(how.buf);
        return rc;
    }
    const cs_param_info *cm = cs_param_find("contact_model");
    int models[4], n_models = 0;
    char mlist[64];
    snprintf(mlist, sizeof mlist, "%s", contacts);
    for (char *tok = strtok(mlist, ","); tok && n_models < 4; tok = strtok(NULL, ",")) {
        models[n_models] = cs_param_choice(cm, tok);
        if (models[n_models] < 0) {
            fprintf(stderr, "clothd-bench: unknown contact model '%s'\n", tok);
            return 2;
        }
        n_models++;
    }
    if (n_models == 0) {
        fprintf(stderr, "clothd-bench: --contact names no model\n");
        return 2;
    }
    if (!json && !model_only)
        printf("%-7s %-9s %5s %-8s %14s %22s %10s %12s\n", "backend", "grid", "rocks", "contact", "substeps/s",
               "vertex-substeps/s", "x realtime", "us/vertex-s");

    for (int si = 0; si < n_sizes; si++) {
        const int size = sizes[si];
        for (int rc = 0; rc < n_counts; rc++) for (int mi = 0; mi < n_models; mi++) {
            /* without rocks the model does not matter: the first one only */
            if (rock_counts[rc] == 0 && mi > 0) continue;
            cs_scene sc;
            cs_params p;
            cs_scene_default(&sc);
            cs_params_default(&p);
            sc.nx = sc.ny = size;
            p.integrator = integ_index;
            p.plastic_yield = 0.5f; /* the strain pass runs; at rest nothing yields */
            p.tear_strain = 2.0f;
            p.max_substeps = 100000;
            p.contact_model = models[mi];
            p.self_collision = self_collision;
            if (crumple) { /* crumple_scene: the cloth falls and folds onto the ground first */
                sc.orientation = CS_VERTICAL;
                sc.pins = CS_PINS_NONE;
                sc.height = 0.1f + 0.5f * sc.size_y;
                p.wind[1] = 2.0f;
            }
            if (apply_sets(&p) != 0) return 2;
            cs_sim *sim = NULL;
            char err[256];
            /* The model needs the scene and rocks only: a CPU simulation holds them. */
            if (cs_sim_create(&sc, &p, model_only ? "cpu" : backend, &sim, err, sizeof err) != CS_OK) {
                fprintf(stderr, "clothd-bench: %dx%d: %s\n", size, size, err);
                return 1;
            }
            cs_sim_set_threads(sim, threads);
            if (add_rocks(sim, &sc, &p, rock_counts[rc]) != 0) {
                fprintf(stderr, "clothd-bench: adding rocks: %s\n", cs_sim_error(sim));
                return 1;
            }
            cs_info info;
            cs_sim_info(sim, &info);
            if (model_only) {
                const cs_backend *kinds[2] = {&cs_backend_cpu, cs_backend_cuda()};
                for (int k = 0; k < 2; k++) {
                    if (!kinds[k]) continue;
                    cs_cost_model m;
                    cs_sim_cost(sim, kinds[k], &m);
                    if (json) {
                        printf("{\"backend\":\"%s\",\"nx\":%d,\"ny\":%d,\"rocks\":%d,\"contact_model\":\"%s\","
                               "\"integrator\":\"%s\",\"substeps_per_frame\":%d",
                               kinds[k]->name, size, size, info.n_rocks, cm->choices[models[mi]], integ_name,
                               info.substeps);
                        print_model(kinds[k]->name, &m, (double)size * size, 1, 0);
                        printf("}\n");
                    } else {
                        printf("%s, %d x %d, %d rocks (%s contact), %d substeps a frame:\n", kinds[k]->name, size,
                               size, info.n_rocks, cm->choices[models[mi]], info.substeps);
                        print_model(kinds[k]->name, &m, (double)size * size, 0, 0);
                    }
                }
                cs_sim_destroy(sim);
                continue;
            }
            /* --crumple: one simulated second of falling and folding first */
            if (crumple && cs_sim_step_frames(sim, p.frame_rate) != CS_OK) {
                fprintf(stderr, "clothd-bench: %dx%d: %s\n", size, size, cs_sim_error(sim));
                return 1;
            }
            /* Settle, and size a batch to about 1/20 of the measuring time; with --frames, the
             * same work every run instead: those frames from the start, a frame a batch. */
            int64_t batch = 1;
            double t0 = now();
            while (!frames && now() - t0 < 0.05 * seconds) {
                cs_sim_step(sim, batch);
                batch *= 2;
            }
            const double rate_guess = (double)(batch - 1) / (now() - t0 + 1e-9);
            batch = frames ? info.substeps : (int64_t)(rate_guess * seconds / 20) + 1;
            int64_t done = 0;
            cs_status st = CS_OK;
            t0 = now();
            double t = t0;
            cs_self_stats self_sum = {0};
            int64_t solved = 0, newton = 0, cg = 0;
            while ((frames ? done < frames * info.substeps : t - t0 < seconds) && st == CS_OK) {
                st = cs_sim_step(sim, batch);
                done += batch;
                t = now();
                cs_sim_info(sim, &info);
                self_sum.passes += info.self.passes, self_sum.broad += info.self.broad;
                self_sum.pairs += info.self.pairs, self_sum.contacts += info.self.contacts;
                self_sum.cut += info.self.cut, self_sum.lost += info.self.lost;
                solved += info.solver.substeps, newton += info.solver.newton, cg += info.solver.cg;
            }
            if (st != CS_OK) {
                fprintf(stderr, "clothd-bench: %dx%d: %s\n", size, size, cs_sim_error(sim));
                return 1;
            }
            const double sps = (double)done / (t - t0);
            const double vsps = sps * size * size;
            cs_sim_info(sim, &info);
            cs_backend_stats bs;
            cs_sim_backend_stats(sim, &bs);
            const cs_backend *self = strcmp(cs_sim_backend(sim), "cuda") == 0 ? cs_backend_cuda() : &cs_backend_cpu;
            cs_cost_model m;
            cs_sim_cost(sim, self, &m);
            const double traffic = vsps * m.bytes_per_vertex_substep + sps * m.fixed_per_substep;
            if (json) {
                printf("{\"backend\":\"%s\",\"device\":\"%s\",\"nx\":%d,\"ny\":%d,\"rocks\":%d,\"contact_model\":\"%s\","
                       "\"integrator\":\"%s\",\"substeps_per_frame\":%d,\"substeps\":%lld,\"seconds\":%.3f,\"substeps_per_s\":%.1f,"
                       "\"vertex_substeps_per_s\":%.0f,\"modelled_traffic_gb_s\":%.1f",
                       cs_sim_backend(sim), cs_sim_device(sim), size, size, info.n_rocks, cm->choices[models[mi]],
                       integ_name, info.substeps,
                       (long long)done, t - t0, sps, vsps, traffic / 1e9);
                if (bs.peak_bandwidth > 0)
                    printf(",\"peak_bandwidth_gb_s\":%.1f,\"fraction_of_peak\":%.3f", bs.peak_bandwidth / 1e9,
                           traffic / bs.peak_bandwidth);
                print_model(self->name, &m, (double)size * size, 1, bs.peak_bandwidth);
                if (self_collision) print_self(&self_sum, 1);
                if (solved > 0)
                    printf(",\"solver_parts_per_substep\":%.2f,\"newton_per_part\":%.2f,\"cg_per_newton\":%.2f",
                           (double)solved / (double)done, (double)newton / (double)solved,
                           newton > 0 ? (double)cg / (double)newton : 0.0);
                printf("}\n");
            } else {
                /* the real-time factor, and the wall time a simulated second costs per vertex (us) */
                const double rtf = sps / ((double)p.frame_rate * info.substeps);
                printf("%-7s %4dx%-4d %5d %-8s %14.0f %22.0f %10.3f %12.1f\n", cs_sim_backend(sim), size, size,
                       info.n_rocks, cm->choices[models[mi]], sps, vsps, rtf, 1e6 / (rtf * size * size));
                if (self_collision) print_self(&self_sum, 0);
                if (solved > 0)
                    printf("        solver: %.2f parts a substep, %.2f Newton iterations a part, %.2f CG a Newton\n",
                           (double)solved / (double)done, (double)newton / (double)solved,
                           newton > 0 ? (double)cg / (double)newton : 0.0);
            }
            fflush(stdout);
            cs_sim_destroy(sim);
        }
    }
    if (model_only) print_batch(json);
    return 0;
}
