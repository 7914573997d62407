/* fuzz_snapshot.c - the snapshot loader (cs_snapshot_load: PUT /v1/snapshot, the state file,
 * a journal bundle's base) into a small simulation.
 *
 * Each input is loaded as it is (the header's checks), and, when it starts like a snapshot, once
 * more with its header made right (this build's version and parameter table, the length, the
 * checksum), so that the fuzzer reaches the payload's checks instead of stopping at the
 * checksum, and seeds of an older parameter table still reach them.
 *
 * Besides what ASan and UBSan catch, it checks what clothsim.h promises: a refused snapshot
 * leaves the simulation as it was; an accepted one holds nothing a command would refuse (at most
 * the rock limit of rocks, ids below a next id of at least 1, a step count within 2^63 - 1), is a
 * state the engine can read and save, add a rock to or refuse one clearly, then save (or, where
 * the rock's new accelerations overflowed, refuse to save as not finite - and the next step finds
 * it), load again (the same bytes) and step, and the daemon's reading of it after
 * PUT /v1/snapshot works.
 *
 * The same input is also read as a state file (statefile.c: snapshots and their trailer), as the
 * daemon does at start: a layout it accepts names its scenes' snapshots one after another within
 * the input (the first few are loaded), with valid ids none of which comes twice, and the trailers
 * it writes - every scene (format 4), the first alone (format 3) - read back the same. */
#include <stdint.h>

#include "core/json_read.h"
#include "core/statefile.h"
#include "fuzz_common.h"

/* A small rock limit (the daemon's max_rocks), so that snapshots past it are found. */
#define FUZZ_ROCK_LIMIT 4

static cs_sim *sim_a, *sim_b;   /* the load's, and the reload's */
static unsigned char *pristine; /* the state of a fresh fuzz_sim() */
static size_t pristine_len;

int LLVMFuzzerInitialize(int *argc, char ***argv)
{
    (void)argc, (void)argv;
    sim_a = fuzz_sim();
    sim_b = fuzz_sim();
    cs_sim_set_rock_limit(sim_a, FUZZ_ROCK_LIMIT);
    cs_sim_set_rock_limit(sim_b, FUZZ_ROCK_LIMIT);
    pristine = fuzz_state(sim_a, &pristine_len);
    return 0;
}

static uint64_t fnv1a(const unsigned char *p, size_t n)
{
    uint64_t h = 0xcbf29ce484222325ull;
    for (size_t i = 0; i < n; i++) h = (h ^ p[i]) * 0x100000001b3ull;
    return h;
}

static void put_u64(unsigned char *p, uint64_t v)
{
    for (int i = 0; i < 8; i++) p[i] = (unsigned char)(v >> (8 * i));
}

/* What the daemon reads of the simulation after a load (simloop.c's snapshot_put). */
static void read_back(cs_sim *sim)
{
    cs_info info;
    cs_sim_info(sim, &info);
    if (info.substeps < 1) fuzz_fail("a loaded snapshot runs %d substeps a frame", (int)info.substeps);
    (void)(info.step / (uint64_t)info.substeps);
    cs_scene sc;
    cs_params p;
    cs_sim_scene(sim, &sc);
    cs_sim_params(sim, &p);
    for (int32_t r = 0; r < cs_rock_count(sim); r++) {
        cs_rock k;
        if (cs_rock_at(sim, r, &k) != CS_OK) fuzz_fail("rock %d of %d cannot be read", (int)r, (int)cs_rock_count(sim));
    }
    const int64_t n_torn = cs_read_torn(sim, NULL, 0);
    if (n_torn < 0) fuzz_fail("cs_read_torn: %lld", (long long)n_torn);
    uint32_t *ids = malloc(sizeof *ids * (size_t)(n_torn ? n_torn : 1));
    if (!ids) fuzz_fail("out of memory");
    if (cs_read_torn(sim, ids, (size_t)n_torn) != n_torn) fuzz_fail("cs_read_torn gives another count");
    free(ids);
    float target[3];
    const int32_t grabbed = cs_grabbed(sim, target);
    if (grabbed < -1 || grabbed >= info.n_vertices) fuzz_fail("grabbed vertex %d of %d", (int)grabbed, (int)info.n_vertices);
    /* What the API shows of it: what a command would let in. */
    if (info.step > CS_STEP_MAX) fuzz_fail("step %llu, past 2^63 - 1", (unsigned long long)info.step);
    if (cs_rock_count(sim) > cs_sim_rock_limit(sim)) fuzz_fail("%d rocks, past the limit", (int)cs_rock_count(sim));
}

/* A rock added to an accepted state: taken with a fresh id, or refused with a reason. */
static void add_rock(cs_sim *sim)
{
    uint32_t highest = 0;
    for (int32_t r = 0; r < cs_rock_count(sim); r++) {
        cs_rock k;
        cs_rock_at(sim, r, &k);
        if (k.id == 0) fuzz_fail("a rock of id 0");
        if (k.id > highest) highest = k.id;
    }
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.position[2] = 3.0f;
    uint32_t id = 0;
    const cs_status st = cs_rock_add(sim, &d, &id);
    if (st == CS_OK && (id == 0 || id <= highest)) fuzz_fail("a new rock got id %u (the highest was %u)", id, highest);
    if (st != CS_OK && !cs_sim_error(sim)[0]) fuzz_fail("a rock refused (%s) without a reason", cs_status_name(st));
}

static void load(const unsigned char *buf, size_t len)
{
    cs_sim *sim = sim_a, *again = sim_b;
    fuzz_reset(sim, pristine, pristine_len);
    const cs_status st = cs_snapshot_load(sim, buf, len);
    if (st != CS_OK) {
        if (!cs_sim_error(sim)[0]) fuzz_fail("a refused snapshot (%s) has no reason", cs_status_name(st));
        if (!fuzz_state_is(sim, pristine, pristine_len)) fuzz_fail("a refused snapshot changed the simulation");
        return;
    }
    read_back(sim);
    free(fuzz_state(sim, &(size_t){0})); /* an accepted snapshot saves */
    add_rock(sim);
    /* The rock's command recomputes the accelerations; on an extreme state they may overflow. Such
     * a state is not saved, and the next step finds it (and the daemon rolls it back) - or, under
     * implicit_euler, which steps from positions and velocities alone, replaces them: then the
     * state saves again. */
    size_t l1 = cs_snapshot_size(sim);
    unsigned char *s1 = malloc(l1);
    if (!s1) fuzz_fail("out of memory");
    const cs_status saved = cs_snapshot_save(sim, s1, l1, &l1);
    if (saved == CS_E_NONFINITE) {
        const cs_status next = cs_sim_step(sim, 1);
        cs_params p;
        cs_sim_params(sim, &p);
        const int repaired = next == CS_OK && p.integrator == CS_IMPLICIT_EULER;
        if (next != CS_E_NONFINITE && !repaired)
            fuzz_fail("a state too big to save (not finite) steps with %s", cs_status_name(next));
        if (repaired) free(fuzz_state(sim, &(size_t){0})); /* and then it saves */
        free(s1);
        return;
    }
    if (saved != CS_OK) fuzz_fail("cs_snapshot_save: %s", cs_sim_error(sim));
    fuzz_reset(again, pristine, pristine_len);
    if (cs_snapshot_load(again, s1, l1) != CS_OK) fuzz_fail("a saved snapshot is refused: %s", cs_sim_error(again));
    if (!fuzz_state_is(again, s1, l1)) fuzz_fail("saving a loaded snapshot again gives other bytes");
    const cs_status a = cs_sim_step(sim, 1), b = cs_sim_step(again, 1);
    if (a != b) fuzz_fail("a substep: %s, after a save and load: %s", cs_status_name(a), cs_status_name(b));
    if (a == CS_OK && !fuzz_same_state(sim, again)) fuzz_fail("a substep after a save and load gives another state");
    free(s1);
}

/* The input as a state file. */
/* The layout written back - format 4 with every scene, or format 3 with the first one alone -
 * reads back as it was read. */
static void reads_back(const uint8_t *data, size_t at, const statefile *f, int one)
{
    const int n = one ? 1 : f->n_scenes;
    const char **ids = malloc(sizeof *ids * (size_t)(n ? n : 1));
    int *paused = malloc(sizeof *paused * (size_t)(n ? n : 1));
    const loop_settings **loops = malloc(sizeof *loops * (size_t)(n ? n : 1));
    if (!ids || !paused || !loops) fuzz_fail("out of memory");
    for (int k = 0; k < n; k++) {
        ids[k] = f->scenes[k].id;
        paused[k] = f->scenes[k].paused;
        loops[k] = &f->scenes[k].loop;
    }
    size_t tlen = 0;
    char *t = one ? statefile_trailer(paused[0], loops[0], &tlen) : statefile_trailer_scenes(n, ids, paused, loops, &tlen);
    const size_t body = one ? f->scenes[0].snapshot_len : at;
    unsigned char *file = t ? malloc(body + tlen) : NULL;
    if (!file) fuzz_fail("out of memory");
    memcpy(file, data, body);
    memcpy(file + body, t, tlen);
    statefile again;
    char why[300] = "";
    clothd_config defaults;
    settings_default(&defaults);
    loop_settings back = defaults.scene.loop;
    if (statefile_parse(file, body + tlen, &again, &back, why, sizeof why) != STATEFILE_OK)
        fuzz_fail("a state file written with its trailer (format %d) does not read back: %s", one ? 3 : 4, why);
    if (again.n_scenes != n || again.format != (one ? STATEFILE_FORMAT_ONE : STATEFILE_FORMAT))
        fuzz_fail("a state file of %d scenes reads back with %d (format %d)", n, again.n_scenes, again.format);
    for (int k = 0; k < n; k++) {
        const statefile_scene *x = &f->scenes[k], *y = &again.scenes[k];
        /* Format 3 names no scene: its one reads back as `default` (the daemon writes it only for a
         * daemon of `default` alone). */
        const char *id = one ? SCENE_DEFAULT : x->id;
        if (strcmp(id, y->id) != 0 || x->paused != y->paused || x->offset != y->offset ||
            x->snapshot_len != y->snapshot_len)
            fuzz_fail("the scene %d of a state file does not read back as written: id %s / %s, paused %d / %d, at %zu / %zu, "
                      "%zu / %zu bytes", k, id, y->id, x->paused, y->paused, x->offset, y->offset, x->snapshot_len,
                      y->snapshot_len);
#define FUZZ_SAME_LOOP(name, ...)                                                                             \
        if (memcmp(&x->loop.name, &y->loop.name, sizeof x->loop.name) != 0)                                   \
            fuzz_fail("the scene %d of a state file does not read back as written: its %s", k, #name);
        CLOTHD_LOOP_SETTINGS(FUZZ_SAME_LOOP)
#undef FUZZ_SAME_LOOP
    }
    statefile_free(&again);
    free(file);
    free(t);
    free(ids);
    free(paused);
    free(loops);
}

static void state_file(const uint8_t *data, size_t size)
{
    statefile layout;
    char why[300] = "";
    clothd_config defaults;
    settings_default(&defaults);
    loop_settings loop = defaults.scene.loop;
    if (statefile_parse(data, size, &layout, &loop, why, sizeof why) != STATEFILE_OK) {
        if (!why[0]) fuzz_fail("a state file refused without a reason");
        return;
    }
    /* Each scene's snapshot lies within the input, one after another from its start; each id is a
     * scene id, none twice; the first scene's settings are the ones handed back. */
    size_t at = 0;
    for (int k = 0; k < layout.n_scenes; k++) {
        const statefile_scene *e = &layout.scenes[k];
        if (e->offset != at || e->snapshot_len == 0 || e->snapshot_len > size - at)
            fuzz_fail("the scene %d's snapshot (%zu bytes at %zu) does not follow the one before in %zu", k,
                      e->snapshot_len, e->offset, size);
        at += e->snapshot_len;
        if (!scene_id_valid(e->id)) fuzz_fail("a scene id '%s' read from a state file", e->id);
        for (int j = 0; j < k; j++)
            if (strcmp(layout.scenes[j].id, e->id) == 0) fuzz_fail("the scene id '%s' read twice", e->id);
        if (k < 4 && e->snapshot_len < size) load(data + e->offset, e->snapshot_len);
    }
    if (layout.n_scenes && memcmp(&loop, &layout.scenes[0].loop, sizeof loop) != 0)
        fuzz_fail("the daemon-loop settings handed back are not the first scene's");
    if (layout.snapshot_len != (layout.n_scenes ? layout.scenes[0].snapshot_len : 0))
        fuzz_fail("snapshot_len is not the first scene's");
    reads_back(data, at, &layout, 0);
    if (layout.n_scenes) reads_back(data, at, &layout, 1);
    statefile_free(&layout);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    load(data, size);
    state_file(data, size);
    if (size >= 32 && memcmp(data, "CSNP", 4) == 0) {
        unsigned char *fixed = malloc(size);
        if (!fixed) fuzz_fail("out of memory");
        memcpy(fixed, data, size);
        memcpy(fixed + 4, pristine + 4, 12); /* version, layout id */
        put_u64(fixed + 16, size - 32);
        put_u64(fixed + 24, fnv1a(fixed + 32, size - 32));
        if (memcmp(fixed, data, size) != 0) load(fixed, size);
        free(fixed);
    }
    return 0;
}
