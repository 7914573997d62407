/* snapshot_seeds.c - writes valid snapshots for fuzz_snapshot's corpus into a directory: small
 * cloths in the states a snapshot can hold (rocks, a grab, pins, torn and stretched springs, a
 * vertical cloth). scripts/fuzz.sh adds them to the corpus on every run, so the seeds follow the
 * parameter table (a snapshot of another table is refused at its header). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "clothsim/clothsim.h"

static int fail(const char *what, cs_sim *sim)
{
    fprintf(stderr, "snapshot_seeds: %s: %s\n", what, sim ? cs_sim_error(sim) : "");
    return 1;
}

static int save(cs_sim *sim, const char *dir, const char *name)
{
    const size_t cap = cs_snapshot_size(sim);
    unsigned char *buf = malloc(cap);
    size_t len = 0;
    if (!buf || cs_snapshot_save(sim, buf, cap, &len) != CS_OK) {
        free(buf);
        return fail(name, sim);
    }
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "wb");
    const int ok = f && fwrite(buf, 1, len, f) == len;
    if (f && fclose(f) != 0) return fail(path, NULL);
    free(buf);
    return ok ? 0 : fail(path, NULL);
}

static cs_sim *make(int nx, int ny, void (*tweak)(cs_scene *, cs_params *))
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = nx;
    sc.ny = ny;
    if (tweak) tweak(&sc, &p);
    cs_sim *sim = NULL;
    char err[300];
    if (cs_sim_create(&sc, &p, "cpu", &sim, err, sizeof err) != CS_OK) {
        fprintf(stderr, "snapshot_seeds: %s\n", err);
        return NULL;
    }
    cs_sim_set_threads(sim, 1);
    return sim;
}

static void tearing(cs_scene *sc, cs_params *p)
{
    sc->pins = CS_PINS_CORNERS;
    p->tear_strain = 0.02f;
    p->plastic_yield = 0.05f; /* above tear_strain: springs tear before they flow */
}

static void vertical(cs_scene *sc, cs_params *p)
{
    sc->orientation = CS_VERTICAL;
    sc->pins = CS_PINS_TOP_EDGE;
    p->integrator = CS_SYMPLECTIC_EULER;
    p->wind[0] = 3.0f;
    p->plastic_yield = 1e-4f; /* sagging stretches the rest lengths */
    p->plastic_rate = 1.0f;
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: snapshot_seeds DIR\n");
        return 2;
    }
    const char *dir = argv[1];
    int rc = 0;

    cs_sim *sim = make(2, 2, NULL); /* the smallest cloth, at rest */
    if (!sim) return 1;
    rc |= save(sim, dir, "plain-2x2");
    cs_sim_destroy(sim);

    sim = make(3, 3, NULL); /* two rocks (one kinematic), a grab, some steps */
    if (!sim) return 1;
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.position[2] = 1.2f;
    uint32_t id;
    if (cs_rock_add(sim, &d, &id) != CS_OK) return fail("rock", sim);
    d.kinematic = true;
    d.position[0] = 0.5f;
    d.velocity[2] = -1.0f;
    if (cs_rock_add(sim, &d, &id) != CS_OK) return fail("rock", sim);
    const float target[3] = {0.1f, 0.1f, 1.5f};
    if (cs_grab(sim, 4, target) != CS_OK || cs_sim_step(sim, 40) != CS_OK) return fail("grab", sim);
    rc |= save(sim, dir, "rocks-grab-3x3");
    cs_sim_destroy(sim);

    sim = make(4, 4, tearing); /* a vertex pulled up tears and stretches springs */
    if (!sim) return 1;
    const float up[3] = {0.0f, 0.0f, 4.0f};
    if (cs_grab(sim, 5, up) != CS_OK || cs_sim_step(sim, 3000) != CS_OK) return fail("tearing", sim);
    cs_info info;
    cs_sim_info(sim, &info);
    if (info.n_torn == 0) fprintf(stderr, "snapshot_seeds: note: no spring tore in torn-4x4\n");
    rc |= save(sim, dir, "torn-4x4");
    cs_sim_destroy(sim);

    sim = make(3, 2, vertical); /* vertical, top edge pinned, wind */
    if (!sim) return 1;
    if (cs_sim_step(sim, 10) != CS_OK) return fail("vertical", sim);
    rc |= save(sim, dir, "vertical-3x2");
    cs_sim_destroy(sim);
    return rc;
}
