/* snapshot_seeds.c - writes snapshots for fuzz_snapshot's corpus into a directory: small cloths
 * in the states a snapshot can hold (rocks, a grab, pins, torn and stretched springs, a vertical
 * cloth), at the edges of what the API allows (the last rock id given, the last step count) and
 * just past them (a next rock id of 0, a step past 2^63 - 1, more rocks than the fuzz target's
 * rock limit), and a state file with its trailer. scripts/fuzz.sh adds them to the corpus on
 * every run, so the seeds follow the parameter table (a snapshot of another table is refused at
 * its header). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "clothsim/clothsim.h"

/* Offsets in a snapshot (kernels/src/snapshot.c): the 32-byte header, the table's rows (f64 per
 * component), then u64 step, f64 time, i32 grab, 3 f32 target, u32 rocks, u32 next rock id. */
static size_t clock_offset(void)
{
    size_t off = 32;
    for (size_t i = 0; i < cs_param_count(); i++) off += 8u * (cs_param_at(i)->type == CS_T_VEC3 ? 3u : 1u);
    return off;
}
#define OFF_STEP (clock_offset())
#define OFF_NEXT_ID (clock_offset() + 36)

static void put_le(unsigned char *p, uint64_t v, int bytes)
{
    for (int i = 0; i < bytes; i++) p[i] = (unsigned char)(v >> (8 * i));
}

/* The checksum after an edit: FNV-1a 64 of the payload, at offset 24. */
static void fix_checksum(unsigned char *b, size_t len)
{
    uint64_t h = 0xcbf29ce484222325ull;
    for (size_t i = 32; i < len; i++) h = (h ^ b[i]) * 0x100000001b3ull;
    put_le(b + 24, h, 8);
}

static int write_file(const char *dir, const char *name, const void *buf, size_t len);

static int fail(const char *what, cs_sim *sim)
{
    fprintf(stderr, "snapshot_seeds: %s: %s\n", what, sim ? cs_sim_error(sim) : "");
    return 1;
}

static int write_file(const char *dir, const char *name, const void *buf, size_t len)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "wb");
    const int ok = f && fwrite(buf, 1, len, f) == len;
    if (f && fclose(f) != 0) return fail(path, NULL);
    return ok ? 0 : fail(path, NULL);
}

/* Writes the snapshot with an edit at `off` (`bytes` little-endian bytes of v; none when bytes
 * is 0) and its checksum fixed, then `tail` after it (a state file's trailer) when not NULL. */
static int save_edited(cs_sim *sim, const char *dir, const char *name, size_t off, uint64_t v, int bytes,
                       const char *tail)
{
    const size_t cap = cs_snapshot_size(sim), tl = tail ? strlen(tail) : 0;
    unsigned char *buf = malloc(cap + tl);
    size_t len = 0;
    if (!buf || cs_snapshot_save(sim, buf, cap, &len) != CS_OK) {
        free(buf);
        return fail(name, sim);
    }
    if (bytes) {
        put_le(buf + off, v, bytes);
        fix_checksum(buf, len);
    }
    if (tl) memcpy(buf + len, tail, tl);
    const int rc = write_file(dir, name, buf, len + tl);
    free(buf);
    return rc;
}

static int save(cs_sim *sim, const char *dir, const char *name) { return save_edited(sim, dir, name, 0, 0, 0, NULL); }

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
    /* A state file as SIGTERM writes it: the snapshot and the trailer. */
    rc |= save_edited(sim, dir, "statefile-paused-3x2", 0, 0, 0, "{\"clothd_state\":2,\"run\":\"paused\"}");
    cs_sim_destroy(sim);

    /* At the edges of the API's rules, and just past them (the fuzz target's rock limit is 4). */
    sim = make(2, 3, NULL);
    if (!sim) return 1;
    if (cs_rock_add(sim, &d, &id) != CS_OK) return fail("rock", sim);
    rc |= save_edited(sim, dir, "next-id-last-2x3", OFF_NEXT_ID, CS_ROCK_ID_MAX, 4, NULL);
    rc |= save_edited(sim, dir, "next-id-used-up-2x3", OFF_NEXT_ID, (uint64_t)CS_ROCK_ID_MAX + 1, 4, NULL);
    rc |= save_edited(sim, dir, "next-id-0-2x3", OFF_NEXT_ID, 0, 4, NULL);
    rc |= save_edited(sim, dir, "step-last-2x3", OFF_STEP, CS_STEP_MAX - 2, 8, NULL);
    rc |= save_edited(sim, dir, "step-past-last-2x3", OFF_STEP, CS_STEP_MAX + 1, 8, NULL);
    for (int k = 0; k < 4; k++) {
        d.position[0] = 0.2f * (float)k;
        if (cs_rock_add(sim, &d, &id) != CS_OK) return fail("rock", sim);
    }
    rc |= save(sim, dir, "five-rocks-2x3");
    cs_sim_destroy(sim);
    return rc;
}
