/* accuracy.c - clothd-accuracy: how close implicit_euler's hanging column comes to its closed form
 * at each solver setting, and what it costs.
 *
 * A column of N vertices (a 2 x N vertical cloth, pinned along its top, shear and bending springs
 * off, no ground) hangs under gravity from rest at its rest length; after S simulated seconds its
 * extension is compared with sum (N - j) m g / k = m g N (N - 1) / (2 k), the value a stiff
 * implicit solver must reach and explicit or Gauss-Seidel-like sweeps approach slowly. Prints, per
 * size and solver_tolerance, the error, the Newton and conjugate-gradient iterations a frame, and
 * the wall time a frame.
 *   clothd-accuracy [--sizes 64,128,256] [--tolerances 1e-2,5e-3,1e-3,1e-4] [--seconds S] [--threads T]
 * With --curtain N it instead hangs an N x N curtain of the default fabric (air drag 5/s, so that
 * it settles) for S seconds under velocity_verlet and under implicit_euler and compares their
 * stretch (the options before it count: --seconds first); with --stone N it sets a 0.15 m stone
 * down on an N x N edge-pinned cloth (air drag 3/s) and compares how deep it rests; with --pile N
 * it drops eight stones of the daemon's sizes (0.05-0.12 m, 2,500 kg/m^3), one every half second,
 * onto the default N x N cloth and prints, every 2 s, their kinetic energy (the linear and the
 * spin's) and, under implicit_euler, Newton iterations and parts a frame: whether the pile settles,
 * and what it costs while it does not. --iterations K sets solver_iterations for every case (the
 * column's default is 100, the others' the table's). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "clothsim/clothsim.h"

/* --iterations: solver_iterations for every case (0: each case's own) */
static int iterations = 0;

/* The table's defaults, with --iterations. */
static void params_default(cs_params *p)
{
    cs_params_default(p);
    if (iterations > 0) p->solver_iterations = iterations;
}

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static int parse_list(const char *s, double *out, int most)
{
    int n = 0;
    while (s && *s && n < most) {
        char *end;
        out[n++] = strtod(s, &end);
        if (end == s) return -1;
        s = *end == ',' ? end + 1 : end;
    }
    return n;
}

/* The scene on the CPU backend (threads > 0: that many), NULL when refused. */
static cs_sim *cpu_sim(const cs_scene *sc, const cs_params *p, int threads)
{
    cs_sim *sim = NULL;
    char err[256];
    if (cs_sim_create(sc, p, "cpu", &sim, err, sizeof err) != CS_OK) return NULL;
    if (threads > 0) cs_sim_set_threads(sim, threads);
    return sim;
}

/* Steps sim `seconds` of frames (wall ms a frame into *ms), then its cloth's lowest z into *lo;
 * nonzero when a step or the read fails. */
static int settle_lowest(cs_sim *sim, const cs_scene *sc, const cs_params *p, double seconds, double *ms, double *lo)
{
    const int frames = (int)(seconds * p->frame_rate + 0.5);
    const size_t n = (size_t)sc->nx * (size_t)sc->ny;
    const double t0 = now();
    if (cs_sim_step_frames(sim, frames) != CS_OK) return -1;
    *ms = 1e3 * (now() - t0) / frames;
    float *x = malloc(sizeof(float) * 3 * n);
    if (!x || cs_read_positions(sim, x, 3 * n) != CS_OK) {
        free(x);
        return -1;
    }
    *lo = 1e30;
    for (size_t v = 0; v < n; v++) *lo = x[3 * v + 2] < *lo ? x[3 * v + 2] : *lo;
    free(x);
    return 0;
}

/* A curtain (N x N, vertical, pinned along its top, the default fabric, air drag 5/s so that it
 * settles) after S seconds under an integrator: its lowest point below the top (the stretch). */
static double curtain(int N, int integrator, double seconds, int threads, double *ms)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    params_default(&p);
    sc.nx = sc.ny = N;
    sc.orientation = CS_VERTICAL;
    sc.pins = CS_PINS_TOP_EDGE;
    sc.height = 2.0f;
    p.ground = 0, p.drag = 5.0f, p.auto_substeps = 1, p.max_substeps = 100000;
    p.integrator = integrator;
    cs_sim *sim = cpu_sim(&sc, &p, threads);
    double lo = 0.0;
    const int bad = !sim || settle_lowest(sim, &sc, &p, seconds, ms, &lo) != 0;
    cs_sim_destroy(sim);
    if (bad) return -1;
    return (sc.height + sc.size_y / 2.0) - lo - sc.size_y; /* the stretch past the rest length */
}

/* A stone (0.15 m, 2,500 kg/m^3: 35 kg) set down on an N x N edge-pinned cloth of the default
 * fabric (air drag 3/s, so that it settles) after S seconds under an integrator: how deep its
 * centre lies below the cloth's plane; into *sag how deep the cloth's lowest point lies. */
static double stone(int N, int integrator, double seconds, int threads, double *ms, double *sag)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    params_default(&p);
    sc.nx = sc.ny = N;
    sc.pins = CS_PINS_EDGES;
    p.drag = 3.0f, p.auto_substeps = 1, p.max_substeps = 100000;
    p.integrator = integrator;
    cs_sim *sim = cpu_sim(&sc, &p, threads);
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.radius = 0.15f, d.density = 2500.0f;
    d.position[2] = sc.height + p.contact_offset + d.radius;
    uint32_t id;
    cs_rock r;
    double lo = 0.0;
    const int bad = !sim || cs_rock_add(sim, &d, &id) != CS_OK || settle_lowest(sim, &sc, &p, seconds, ms, &lo) != 0 ||
                    cs_rock_get(sim, id, &r) != CS_OK;
    cs_sim_destroy(sim);
    if (bad) return -1;
    *sag = sc.height - lo;
    return sc.height - r.def.position[2];
}

/* The kinetic energy of sim's rocks, linear and spin (J). */
static double rocks_energy(cs_sim *sim)
{
    double e = 0.0;
    for (int32_t r = 0; r < cs_rock_count(sim); r++) {
        cs_rock k;
        if (cs_rock_at(sim, r, &k) != CS_OK) continue;
        double v2 = 0.0, w2 = 0.0;
        for (int c = 0; c < 3; c++)
            v2 += (double)k.def.velocity[c] * k.def.velocity[c],
                w2 += (double)k.def.angular_velocity[c] * k.def.angular_velocity[c];
        e += 0.5 * k.mass * v2 + 0.5 * k.inertia * w2;
    }
    return e;
}

/* Eight stones dropped onto the default N x N cloth, one every 0.5 s from 0.8 m above it, at
 * places and sizes of a fixed draw over the middle 70 % (the daemon's automatic drops, without the
 * removals), for S seconds under an integrator: a line every 2 s. */
static int pile(int N, int integrator, double seconds, int threads)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    params_default(&p);
    sc.nx = sc.ny = N;
    p.integrator = integrator;
    cs_sim *sim = cpu_sim(&sc, &p, threads);
    if (!sim) return -1;
    uint64_t draw = 12345;
    int dropped = 0;
    long newton = 0, parts = 0, frames = 0;
    const int total = (int)(seconds * p.frame_rate + 0.5), every = (int)(0.5 * p.frame_rate + 0.5);
    for (int f = 0; f < total; f++) {
        if (f % every == 0 && dropped < 8) {
            double u[3];
            for (int k = 0; k < 3; k++) {
                draw = draw * 6364136223846793005ull + 1442695040888963407ull;
                u[k] = (double)(draw >> 40) / (double)(1 << 24);
            }
            cs_rock_def d;
            cs_rock_def_default(&d);
            d.position[0] = (float)((u[0] - 0.5) * 0.7 * sc.size_x);
            d.position[1] = (float)((u[1] - 0.5) * 0.7 * sc.size_y);
            d.position[2] = sc.height + 0.8f;
            d.radius = (float)((0.025 + 0.035 * u[2]) * sc.size_x);
            uint32_t id;
            if (cs_rock_add(sim, &d, &id) == CS_OK) dropped++;
        }
        if (cs_sim_step_frames(sim, 1) != CS_OK) {
            cs_sim_destroy(sim);
            return -1;
        }
        cs_info info;
        cs_sim_info(sim, &info);
        newton += info.solver.newton, parts += info.solver.substeps, frames++;
        if ((f + 1) % (int)(2 * p.frame_rate + 0.5) == 0) {
            printf("  %-16s t %5.1f s  %d rocks  kinetic energy %8.4f J", integrator == CS_IMPLICIT_EULER ? "implicit_euler" : "velocity_verlet",
                   info.time, cs_rock_count(sim), rocks_energy(sim));
            if (integrator == CS_IMPLICIT_EULER)
                printf("  %.2f Newton iterations and %.2f parts a frame", (double)newton / frames, (double)parts / frames);
            printf("\n");
            newton = parts = frames = 0;
        }
    }
    cs_sim_destroy(sim);
    return 0;
}

int main(int argc, char **argv)
{
    double sizes[8] = {64, 128, 256}, tols[8] = {1e-2, 5e-3, 1e-3, 1e-4};
    int n_sizes = 3, n_tols = 4, threads = 0;
    double seconds = 3.0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--sizes") == 0 && v) n_sizes = parse_list(v, sizes, 8), i++;
        else if (strcmp(a, "--tolerances") == 0 && v) n_tols = parse_list(v, tols, 8), i++;
        else if (strcmp(a, "--seconds") == 0 && v) seconds = atof(v), i++;
        else if (strcmp(a, "--threads") == 0 && v) threads = atoi(v), i++;
        else if (strcmp(a, "--iterations") == 0 && v) iterations = atoi(v), i++;
        else if (strcmp(a, "--curtain") == 0 && v) {
            /* the curtain's stretch under velocity_verlet and implicit_euler */
            const int N = atoi(v);
            double ms_v = 0, ms_i = 0;
            const double sv = curtain(N, CS_VELOCITY_VERLET, seconds, threads, &ms_v);
            const double si = curtain(N, CS_IMPLICIT_EULER, seconds, threads, &ms_i);
            printf("curtain %d x %d after %.1f s: stretch velocity_verlet %.6f m (%.1f ms a frame), implicit_euler "
                   "%.6f m (%.1f ms a frame): %+.2f %%\n",
                   N, N, seconds, sv, ms_v, si, ms_i, 100 * (si - sv) / sv);
            return 0;
        }
        else if (strcmp(a, "--stone") == 0 && v) {
            /* the stone's depth under velocity_verlet and implicit_euler */
            const int N = atoi(v);
            double ms_v = 0, ms_i = 0, sv = 0, si = 0;
            const double dv = stone(N, CS_VELOCITY_VERLET, seconds, threads, &ms_v, &sv);
            const double di = stone(N, CS_IMPLICIT_EULER, seconds, threads, &ms_i, &si);
            printf("stone on %d x %d after %.1f s: the stone's centre %.4f m deep under velocity_verlet (%.1f ms a "
                   "frame), %.4f m under implicit_euler (%.1f ms a frame): %+.2f %%; the cloth's lowest point %.4f "
                   "and %.4f m: %+.2f %%\n",
                   N, N, seconds, dv, ms_v, di, ms_i, 100 * (di - dv) / dv, sv, si, 100 * (si - sv) / sv);
            return 0;
        }
        else if (strcmp(a, "--pile") == 0 && v) {
            /* a pile of stones under velocity_verlet and implicit_euler */
            const int N = atoi(v);
            return pile(N, CS_VELOCITY_VERLET, seconds, threads) || pile(N, CS_IMPLICIT_EULER, seconds, threads);
        }
        else {
            fprintf(stderr, "usage: clothd-accuracy [--sizes 64,128,256] [--tolerances 1e-2,1e-3] [--seconds S] "
                            "[--threads T] [--iterations K] [--curtain N | --stone N | --pile N]\n");
            return 2;
        }
    }
    if (n_sizes <= 0 || n_tols <= 0 || !(seconds > 0)) return 2;
    printf("%6s %10s %12s %12s %10s %10s %10s\n", "N", "tolerance", "extension", "closed form", "error %",
           "newton/fr", "cg/fr");
    for (int si = 0; si < n_sizes; si++)
        for (int ti = 0; ti < n_tols; ti++) {
            const int N = (int)sizes[si];
            cs_scene sc;
            cs_params p;
            cs_scene_default(&sc);
            params_default(&p);
            sc.nx = 2, sc.ny = N;
            sc.orientation = CS_VERTICAL;
            sc.pins = CS_PINS_TOP_EDGE;
            sc.size_x = 0.02f, sc.size_y = 2.0f, sc.height = 2.0f;
            p.k_shear = 0.0f, p.k_bend = 0.0f, p.ground = 0;
            p.integrator = CS_IMPLICIT_EULER;
            p.solver_tolerance = (float)tols[ti];
            p.solver_iterations = iterations > 0 ? iterations : 100, p.cg_iterations = 1000;
            cs_sim *sim = NULL;
            char err[256];
            if (cs_sim_create(&sc, &p, "cpu", &sim, err, sizeof err) != CS_OK) {
                fprintf(stderr, "clothd-accuracy: %s\n", err);
                return 1;
            }
            if (threads > 0) cs_sim_set_threads(sim, threads);
            const int frames = (int)(seconds * p.frame_rate + 0.5);
            long newton = 0, cg = 0;
            const double t0 = now();
            for (int f = 0; f < frames; f++) {
                if (cs_sim_step_frames(sim, 1) != CS_OK) {
                    fprintf(stderr, "clothd-accuracy: %s\n", cs_sim_error(sim));
                    return 1;
                }
                cs_info info;
                cs_sim_info(sim, &info);
                newton += info.solver.newton, cg += info.solver.cg;
            }
            const double wall = now() - t0;
            float *z = malloc(sizeof(float) * 6 * (size_t)N);
            if (!z || cs_read_positions(sim, z, 6 * (size_t)N) != CS_OK) return 1; /* vertex 0: the bottom */
            const double m = (double)sc.areal_density * sc.size_x * sc.size_y / (2.0 * N), g = 9.81;
            const double want = m * g * N * (N - 1) / (2.0 * p.k_structural);
            const double got = (sc.height + sc.size_y / 2.0 - z[2]) - sc.size_y;
            printf("%6d %10.0e %12.6f %12.6f %10.2f %10.1f %10.1f   %.2f ms/frame\n", N, tols[ti], got, want,
                   100 * (got - want) / want, (double)newton / frames, (double)cg / frames, 1e3 * wall / frames);
            free(z);
            cs_sim_destroy(sim);
        }
    return 0;
}
