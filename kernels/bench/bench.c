/* clothd-bench - how many vertex-substeps per second a backend sustains.
 *
 * Cases: cloths of 64, 128, 256 and 512 squared vertices, each without rocks and with 16 rocks
 * resting on it, the rocks' contact by each model asked for (surface, vertex); velocity Verlet
 * with every force on (springs with damping, drag, gravity, ground, plasticity and tearing checks,
 * and contact with the rocks). Each case settles briefly, then runs for --seconds of wall time.
 * Prints one line per case (JSON with --json). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "clothsim/clothsim.h"

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void usage(FILE *f)
{
    fprintf(f,
            "usage: clothd-bench [--backend cpu|cuda|auto] [--json] [--threads N] [--seconds S]\n"
            "                    [--sizes 64,128,256,512] [--rocks 0,16] [--contact surface,vertex]\n"
            "                    [--integrator velocity_verlet|symplectic_euler]\n");
}

/* Rocks on a 4-wide grid over the middle of the cloth, just touching it (light ones: the case
 * measures contact, not a cloth sagging to the ground). */
static int add_rocks(cs_sim *sim, const cs_scene *sc, const cs_params *p, int count)
{
    for (int k = 0; k < count; k++) {
        cs_rock_def d;
        cs_rock_def_default(&d);
        d.radius = 0.08f;
        d.density = 200.0f;
        d.position[0] = (float)((k % 4 - 1.5) * sc->size_x / 5);
        d.position[1] = (float)((k / 4 % 4 - 1.5) * sc->size_y / 5);
        d.position[2] = sc->height + d.radius + p->contact_offset;
        if (cs_rock_add(sim, &d, NULL) != CS_OK) return -1;
    }
    return 0;
}

int main(int argc, char **argv)
{
    const char *backend = "cpu", *sizes = "64,128,256,512", *integrator = "velocity_verlet", *rock_cases = "0,16";
    const char *contacts = "surface,vertex";
    int json = 0, threads = 0;
    double seconds = 1.5;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *val = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--json") == 0) json = 1;
        else if (strcmp(a, "--backend") == 0 && val) backend = val, i++;
        else if (strcmp(a, "--threads") == 0 && val) threads = atoi(val), i++;
        else if (strcmp(a, "--seconds") == 0 && val) seconds = atof(val), i++;
        else if (strcmp(a, "--sizes") == 0 && val) sizes = val, i++;
        else if (strcmp(a, "--rocks") == 0 && val) rock_cases = val, i++;
        else if (strcmp(a, "--contact") == 0 && val) contacts = val, i++;
        else if (strcmp(a, "--integrator") == 0 && val) integrator = val, i++;
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
    const int integ_index = cs_param_choice(integ, integrator);
    if (integ_index < 0) {
        fprintf(stderr, "clothd-bench: unknown integrator '%s'\n", integrator);
        return 2;
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
    if (!json)
        printf("%-7s %-9s %5s %-8s %14s %22s\n", "backend", "grid", "rocks", "contact", "substeps/s",
               "vertex-substeps/s");

    int rock_counts[8], n_counts = 0;
    char list[256];
    snprintf(list, sizeof list, "%s", rock_cases);
    for (char *tok = strtok(list, ","); tok && n_counts < 8; tok = strtok(NULL, ",")) rock_counts[n_counts++] = atoi(tok);
    snprintf(list, sizeof list, "%s", sizes);
    for (char *tok = strtok(list, ","); tok; tok = strtok(NULL, ",")) {
        const int size = atoi(tok);
        if (size < 2 || size > 4096) {
            fprintf(stderr, "clothd-bench: sizes must be 2..4096\n");
            return 2;
        }
        for (int rc = 0; rc < n_counts; rc++) for (int mi = 0; mi < n_models; mi++) {
            /* without rocks the model does not matter: the first one only */
            if (rock_counts[rc] == 0 && mi > 0) continue;
            cs_scene sc;
            cs_params p;
            cs_scene_default(&sc);
            cs_params_default(&p);
            sc.nx = sc.ny = size;
            p.integrator = integ_index;
            p.plastic_yield = 0.5f;  /* the strain pass runs; at rest nothing yields */
            p.tear_strain = 2.0f;
            p.max_substeps = 100000;
            p.contact_model = models[mi];
            cs_sim *sim = NULL;
            char err[256];
            if (cs_sim_create(&sc, &p, backend, &sim, err, sizeof err) != CS_OK) {
                fprintf(stderr, "clothd-bench: %dx%d: %s\n", size, size, err);
                return 1;
            }
            cs_sim_set_threads(sim, threads);
            if (add_rocks(sim, &sc, &p, rock_counts[rc]) != 0) {
                fprintf(stderr, "clothd-bench: adding rocks: %s\n", cs_sim_error(sim));
                return 1;
            }
            /* Settle, and size a batch to about 1/20 of the measuring time. */
            int64_t batch = 1;
            double t0 = now();
            while (now() - t0 < 0.05 * seconds) {
                cs_sim_step(sim, batch);
                batch *= 2;
            }
            const double rate_guess = (double)(batch - 1) / (now() - t0 + 1e-9);
            batch = (int64_t)(rate_guess * seconds / 20) + 1;
            int64_t done = 0;
            cs_status st = CS_OK;
            t0 = now();
            double t = t0;
            while (t - t0 < seconds && st == CS_OK) {
                st = cs_sim_step(sim, batch);
                done += batch;
                t = now();
            }
            if (st != CS_OK) {
                fprintf(stderr, "clothd-bench: %dx%d: %s\n", size, size, cs_sim_error(sim));
                return 1;
            }
            const double sps = (double)done / (t - t0);
            const double vsps = sps * size * size;
            cs_info info;
            cs_sim_info(sim, &info);
            cs_backend_stats bs;
            cs_sim_backend_stats(sim, &bs);
            /* Where the backend models its traffic: bytes per vertex-substep, and the share of the
             * measured copy bandwidth that this speed amounts to. */
            char traffic[160] = "";
            if (bs.bytes_per_vertex_substep > 0 && bs.copy_bandwidth > 0)
                snprintf(traffic, sizeof traffic, ",\"bytes_per_vertex_substep\":%.1f,\"copy_bandwidth_gb_s\":%.1f,"
                         "\"fraction_of_copy_bandwidth\":%.3f",
                         bs.bytes_per_vertex_substep, bs.copy_bandwidth / 1e9,
                         vsps * bs.bytes_per_vertex_substep / bs.copy_bandwidth);
            if (json)
                printf("{\"backend\":\"%s\",\"device\":\"%s\",\"nx\":%d,\"ny\":%d,\"rocks\":%d,\"contact_model\":\"%s\","
                       "\"integrator\":\"%s\",\"substeps_per_frame\":%d,\"substeps\":%lld,\"seconds\":%.3f,"
                       "\"substeps_per_s\":%.1f,\"vertex_substeps_per_s\":%.0f%s}\n",
                       cs_sim_backend(sim), cs_sim_device(sim), size, size, info.n_rocks, cm->choices[models[mi]],
                       integrator, info.substeps, (long long)done, t - t0, sps, vsps, traffic);
            else
                printf("%-7s %4dx%-4d %5d %-8s %14.0f %22.0f\n", cs_sim_backend(sim), size, size, info.n_rocks,
                       cm->choices[models[mi]], sps, vsps);
            fflush(stdout);
            cs_sim_destroy(sim);
        }
    }
    return 0;
}
