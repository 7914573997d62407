/* test_snapshot.c - snapshots (snapshot.c): the whole state as a versioned, checksummed buffer.
 *
 * Round trip mid-run (rocks, torn and plastically grown springs, a grab, pins): the loaded state
 * has the same hash, info, parameters, rocks, pins and grab, and continuing from it gives the
 * same hash as the run that was never interrupted. A snapshot of another scene size switches the
 * scene. Refusals - truncated, corrupted, another version, another magic, and buffers whose
 * checksum is fixed up but which hold a NaN, a bad rest length or an out-of-range parameter -
 * return CS_E_FORMAT or CS_E_VERSION and leave the simulation exactly as it was. Whatever a command
 * would refuse is refused too (test_api_rules), rock ids and the step count stop at their limits
 * with a clear refusal and every state on the way saves and loads again.
 *
 * The layout is rebuilt here from the format's documentation (snapshot.c's header comment):
 * header "CSNP", u32 version, u64 layout id, u64 payload bytes, u64 FNV-1a 64 of the payload;
 * payload: every table row as f64 per component, u64 step, f64 time, i32 grab, 3 f32 target,
 * u32 rocks, u32 next id, 9 vertex arrays of n f32, 6 n f32 rest lengths, n u8 pins padded to 4,
 * per rock u32 id, u32 kinematic, 21 f32. The checksum is this file's own FNV-1a. */
#include "testkit.h"

#define HEADER 32u

/* ---- the format, independently ---- */

static uint64_t fnv1a64(const unsigned char *p, size_t n)
{
    uint64_t h = 0xcbf29ce484222325ull;
    for (size_t i = 0; i < n; i++) {
        h ^= p[i];
        h *= 0x100000001b3ull;
    }
    return h;
}

static uint64_t get_u64(const unsigned char *p)
{
    uint64_t u = 0;
    for (int i = 0; i < 8; i++) u |= (uint64_t)p[i] << (8 * i);
    return u;
}

static void put_u32(unsigned char *p, uint32_t u)
{
    for (int i = 0; i < 4; i++) p[i] = (unsigned char)(u >> (8 * i));
}

static void put_u64(unsigned char *p, uint64_t u)
{
    for (int i = 0; i < 8; i++) p[i] = (unsigned char)(u >> (8 * i));
}

static void put_f32(unsigned char *p, float f)
{
    uint32_t u;
    memcpy(&u, &f, 4);
    put_u32(p, u);
}

static float get_f32(const unsigned char *p)
{
    uint32_t u = 0;
    for (int i = 0; i < 4; i++) u |= (uint32_t)p[i] << (8 * i);
    float f;
    memcpy(&f, &u, 4);
    return f;
}

static void put_f64(unsigned char *p, double f)
{
    uint64_t u;
    memcpy(&u, &f, 8);
    put_u64(p, u);
}

static int components(const cs_param_info *p) { return p->type == CS_T_VEC3 ? 3 : 1; }

/* Bytes of the parameter table in the payload; with name, the offset of that row instead. */
static size_t table_offset(const char *name)
{
    size_t off = 0;
    for (size_t i = 0; i < cs_param_count(); i++) {
        const cs_param_info *p = cs_param_at(i);
        if (name && strcmp(p->name, name) == 0) return off;
        off += 8u * (size_t)components(p);
    }
    if (name) fail_msg("no parameter %s", name);
    return off;
}

/* Offsets in the whole buffer (header included). */
static size_t off_arrays(void) { return HEADER + table_offset(NULL) + 8 + 8 + 4 + 12 + 4 + 4; }
static size_t off_x(size_t v) { return off_arrays() + 4 * v; }
static size_t off_vz(size_t n, size_t v) { return off_arrays() + 4 * (5 * n + v); }
static size_t off_rest(size_t n, size_t li) { return off_arrays() + 4 * (9 * n + li); }
static size_t off_pins(size_t n) { return off_arrays() + 4 * (15 * n); }
static size_t off_rock(size_t n, int r) { return off_pins(n) + (n + 3) / 4 * 4 + (size_t)r * (8 + 4 * 21); }

/* The clock, the grab and the rock counters, and the accelerations, the grab and the rock counters in the whole buffer. */
static size_t off_step(void) { return HEADER + table_offset(NULL); }
static size_t off_time(void) { return off_step() + 8; }
static size_t off_target(void) { return off_step() + 20; }
static size_t off_next_id(void) { return off_step() + 36; }
static size_t off_ax(size_t n, size_t v) { return off_arrays() + 4 * (6 * n + v); }

static size_t expected_size(size_t n, size_t rocks)
{
    return off_pins(n) + (n + 3) / 4 * 4 + rocks * (8 + 4 * 21);
}

/* Recomputes the checksum after an edit of the payload. */
static void fix_checksum(unsigned char *b, size_t len)
{
    put_u64(b + 24, fnv1a64(b + HEADER, len - HEADER));
}

/* One field of a buffer set to a value, the checksum kept right. */
typedef enum { E_F32, E_F64, E_U32, E_U64 } edit_kind;
typedef struct edit {
    const char *what;
    size_t off;
    edit_kind kind;
    double value; /* E_F32, E_F64 */
    uint64_t u;   /* E_U32, E_U64 */
} edit;

/* t = buf (len bytes; may be t itself) with the edit. */
static void apply_edit(unsigned char *t, const unsigned char *buf, size_t len, const edit *e)
{
    if (t != buf) memcpy(t, buf, len);
    switch (e->kind) {
    case E_F32: put_f32(t + e->off, (float)e->value); break;
    case E_F64: put_f64(t + e->off, e->value); break;
    case E_U32: put_u32(t + e->off, (uint32_t)e->u); break;
    case E_U64: put_u64(t + e->off, e->u); break;
    }
    fix_checksum(t, len);
}

/* ---- the scene ---- */

static cs_sim *busy_sim(void)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    p.integrator = CS_VELOCITY_VERLET; /* its guard refuses a snapshot it cannot serve (test_fixed_up_checksum) */
    sc.nx = 13;
    sc.ny = 10; /* n = 130: the pins need padding to 4 bytes */
    sc.size_x = 1.2f;
    sc.size_y = 0.9f;
    sc.height = 0.5f;
    sc.pins = CS_PINS_CORNERS;
    p.tear_strain = 0.1f;
    p.plastic_yield = 0.03f;
    p.plastic_rate = 20.0f;
    p.friction_model = CS_FRICTION_RESULTANT;
    p.wind[1] = 0.5f;
    cs_sim *sim = tk_sim(&sc, &p);
    assert_int_equal(cs_sim_set_threads(sim, 1), CS_OK);
    tk_add_rock(sim, 0.1f, 0.0f, 0.8f, 0.12f, 400.0f);
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.position[0] = -0.3f, d.position[1] = 0.2f, d.position[2] = 0.425f; /* just clear of the cloth */
    d.velocity[0] = 0.3f;
    d.angular_velocity[2] = 1.5f;
    d.radius = 0.07f;
    d.kinematic = true;
    assert_int_equal(cs_rock_add(sim, &d, NULL), CS_OK);
    const int32_t pins[2] = {6, 5 * 13};
    assert_int_equal(cs_pin(sim, pins, 2, true), CS_OK);
    assert_int_equal(cs_sim_step_frames(sim, 10), CS_OK);
    const float target[3] = {0.4f, 0.3f, 1.5f};
    assert_int_equal(cs_grab(sim, 4 * 13 + 9, target), CS_OK);
    assert_int_equal(cs_sim_step_frames(sim, 15), CS_OK);
    return sim;
}

/* ---- what a refused load must leave alone ---- */

typedef struct view {
    uint64_t hash;
    cs_info info;
    cs_params params;
    cs_scene scene;
    int32_t n_rocks;
    cs_rock rocks[4];
    int32_t grab;
    float target[3];
    uint8_t pinned[512];
} view;

static void take_view(cs_sim *sim, view *v)
{
    memset(v, 0, sizeof *v);
    v->hash = cs_state_hash(sim);
    cs_sim_info(sim, &v->info);
    /* what the last step call did is not state: a snapshot carries none of it */
    memset(&v->info.solver, 0, sizeof v->info.solver);
    memset(&v->info.self, 0, sizeof v->info.self);
    cs_sim_params(sim, &v->params);
    cs_sim_scene(sim, &v->scene);
    v->n_rocks = cs_rock_count(sim);
    assert_true(v->n_rocks <= 4);
    for (int32_t r = 0; r < v->n_rocks; r++) assert_int_equal(cs_rock_at(sim, r, &v->rocks[r]), CS_OK);
    v->grab = cs_grabbed(sim, v->target);
    assert_true(v->info.n_vertices <= 512);
    for (int32_t k = 0; k < v->info.n_vertices; k++) v->pinned[k] = cs_is_pinned(sim, k);
}

static void assert_same_view(const view *a, const view *b, const char *what)
{
    if (a->hash != b->hash) fail_msg("%s: the hash changed", what);
    if (memcmp(&a->info, &b->info, sizeof a->info) != 0) fail_msg("%s: the info changed", what);
    if (memcmp(&a->params, &b->params, sizeof a->params) != 0) fail_msg("%s: the parameters changed", what);
    if (memcmp(&a->scene, &b->scene, sizeof a->scene) != 0) fail_msg("%s: the scene changed", what);
    if (a->n_rocks != b->n_rocks || memcmp(a->rocks, b->rocks, sizeof a->rocks) != 0)
        fail_msg("%s: the rocks changed", what);
    if (a->grab != b->grab || memcmp(a->target, b->target, sizeof a->target) != 0) fail_msg("%s: the grab changed", what);
    if (memcmp(a->pinned, b->pinned, sizeof a->pinned) != 0) fail_msg("%s: the pins changed", what);
}

static unsigned char *save(cs_sim *sim, size_t *len)
{
    const size_t size = cs_snapshot_size(sim);
    unsigned char *buf = malloc(size + 16);
    assert_non_null(buf);
    assert_int_equal(cs_snapshot_save(sim, buf, size, len), CS_OK);
    assert_int_equal(*len, size);
    return buf;
}

/* ---- tests ---- */

static void test_round_trip_mid_run(void **unused)
{
    (void)unused;
    cs_sim *a = busy_sim();
    view mid;
    take_view(a, &mid);
    /* The run has what the snapshot must carry. */
    assert_true(mid.info.n_torn > 0);
    assert_int_equal(mid.n_rocks, 2);
    assert_true(mid.grab == 4 * 13 + 9);
    assert_true(mid.pinned[6] && mid.pinned[65] && mid.pinned[0] && !mid.pinned[1]);
    size_t len;
    unsigned char *buf = save(a, &len);
    assert_int_equal(len, expected_size(130, 2));
    assert_memory_equal(buf, "CSNP", 4);
    assert_true(get_u64(buf + 16) == len - HEADER);
    assert_true(get_u64(buf + 24) == fnv1a64(buf + HEADER, len - HEADER));
    /* The documented offsets do point at the state: x[7] and the second rock's radius. */
    assert_true(get_f32(buf + off_x(7)) == a->state.x[7]);
    assert_true(get_f32(buf + off_rock(130, 1) + 8 + 4 * 19) == 0.07f);
    print_message("snapshot of 13 x 10 with 2 rocks: %zu bytes, %lld torn, step %llu\n", len,
                  (long long)mid.info.n_torn, (unsigned long long)mid.info.step);

    /* The uninterrupted run. */
    tk_step(a, 400);
    const uint64_t h_end = cs_state_hash(a);
    assert_true(h_end != mid.hash);

    /* Loaded into a simulation of another (smaller) scene: switches to the saved one. */
    cs_scene small;
    cs_scene_default(&small);
    small.nx = 5;
    small.ny = 7;
    cs_sim *b = tk_sim(&small, NULL);
    assert_int_equal(cs_sim_set_threads(b, 1), CS_OK);
    assert_int_equal(cs_snapshot_load(b, buf, len), CS_OK);
    view got;
    take_view(b, &got);
    assert_same_view(&mid, &got, "after load");
    assert_int_equal(got.scene.nx, 13);
    assert_int_equal(got.info.n_vertices, 130);
    /* Saving again gives the same bytes. */
    size_t len2;
    unsigned char *buf2 = save(b, &len2);
    assert_int_equal(len2, len);
    assert_memory_equal(buf, buf2, len);
    free(buf2);
    /* Continuing gives the uninterrupted run's state. */
    tk_step(b, 400);
    assert_true(cs_state_hash(b) == h_end);

    /* Loaded back into the run that went on: it returns to the snapshot and goes the same way. */
    assert_int_equal(cs_snapshot_load(a, buf, len), CS_OK);
    take_view(a, &got);
    assert_same_view(&mid, &got, "reloaded");
    tk_step(a, 400);
    assert_true(cs_state_hash(a) == h_end);

    /* And a snapshot of the small scene switches a back to 5 x 7. */
    cs_sim *c = tk_sim(&small, NULL);
    tk_step(c, 10);
    view cv;
    take_view(c, &cv);
    size_t len3;
    unsigned char *buf3 = save(c, &len3);
    assert_int_equal(len3, expected_size(35, 0));
    assert_int_equal(cs_snapshot_load(a, buf3, len3), CS_OK);
    take_view(a, &got);
    assert_same_view(&cv, &got, "small scene loaded");
    assert_int_equal(got.info.n_vertices, 35);
    assert_int_equal(cs_rock_count(a), 0);
    free(buf3);
    free(buf);
    cs_sim_destroy(c);
    cs_sim_destroy(b);
    cs_sim_destroy(a);
}

/* Loads buf and expects the refusal want, with the simulation unchanged. */
static void refuse(cs_sim *sim, const view *before, const unsigned char *buf, size_t len, cs_status want,
                   const char *what)
{
    const cs_status st = cs_snapshot_load(sim, buf, len);
    if (st != want)
        fail_msg("%s: %s (%s), expected %s", what, cs_status_name(st), cs_sim_error(sim), cs_status_name(want));
    assert_true(strlen(cs_sim_error(sim)) > 0);
    view after;
    take_view(sim, &after);
    assert_same_view(before, &after, what);
}

static uint32_t rng = 4242;
static size_t rnd(size_t below)
{
    rng = rng * 1664525u + 1013904223u;
    return (size_t)(rng >> 8) % below;
}

static void test_truncated(void **unused)
{
    (void)unused;
    cs_sim *src = busy_sim();
    size_t len;
    unsigned char *buf = save(src, &len);
    /* The target is another simulation in a state of its own. */
    cs_sim *sim = busy_sim();
    tk_step(sim, 7);
    view before;
    take_view(sim, &before);
    char what[64];
    size_t lens[64];
    int nl = 0;
    const size_t fixed[] = {0, 1, 4, HEADER - 1, HEADER, HEADER + 1, HEADER + 8, HEADER + table_offset(NULL),
                            off_arrays(), off_pins(130), off_rock(130, 1), len / 2, len - 84, len - 4, len - 1};
    for (size_t k = 0; k < sizeof fixed / sizeof fixed[0]; k++) lens[nl++] = fixed[k];
    while (nl < 45) lens[nl++] = 1 + rnd(len - 1);
    for (int k = 0; k < nl; k++) {
        snprintf(what, sizeof what, "truncated to %zu of %zu bytes", lens[k], len);
        refuse(sim, &before, buf, lens[k], CS_E_FORMAT, what);
    }
    /* A truncated copy whose header is made to agree (payload length and checksum): still
     * refused, since the arrays do not fit. */
    for (size_t cut = 4; cut <= 64; cut *= 2) {
        unsigned char *t = malloc(len);
        memcpy(t, buf, len - cut);
        put_u64(t + 16, len - cut - HEADER);
        fix_checksum(t, len - cut);
        snprintf(what, sizeof what, "cut by %zu with a consistent header", cut);
        refuse(sim, &before, t, len - cut, CS_E_FORMAT, what);
        free(t);
    }
    /* One byte too many. */
    buf[len] = 0;
    refuse(sim, &before, buf, len + 1, CS_E_FORMAT, "one byte too many");
    refuse(sim, &before, NULL, 0, CS_E_FORMAT, "NULL");
    /* The untouched buffer still loads. */
    assert_int_equal(cs_snapshot_load(sim, buf, len), CS_OK);
    free(buf);
    cs_sim_destroy(sim);
    cs_sim_destroy(src);
}

static void test_corrupted_byte(void **unused)
{
    (void)unused;
    cs_sim *sim = busy_sim();
    size_t len;
    unsigned char *buf = save(sim, &len);
    tk_step(sim, 5);
    view before;
    take_view(sim, &before);
    unsigned char *t = malloc(len);
    assert_non_null(t);
    size_t offs[160];
    int no = 0;
    for (size_t k = 0; k < HEADER; k++) offs[no++] = k;
    const size_t fixed[] = {HEADER, HEADER + table_offset("k_structural"), off_arrays() - 1, off_x(0), off_vz(130, 3),
                            off_rest(130, 0), off_rest(130, 6 * 130 - 1), off_pins(130), off_pins(130) + 130,
                            off_rock(130, 0), off_rock(130, 1) + 8, len - 1};
    for (size_t k = 0; k < sizeof fixed / sizeof fixed[0]; k++) offs[no++] = fixed[k];
    while (no < 140) offs[no++] = HEADER + rnd(len - HEADER);
    const unsigned char flips[2] = {0x01, 0xa5};
    char what[80];
    for (int f = 0; f < 2; f++) {
        for (int k = 0; k < no; k++) {
            const size_t o = offs[k];
            memcpy(t, buf, len);
            t[o] ^= flips[f];
            snprintf(what, sizeof what, "byte %zu of %zu xor 0x%02x", o, len, flips[f]);
            const cs_status st = cs_snapshot_load(sim, t, len);
            /* The version field: CS_E_VERSION; the layout id (which parameter table wrote it):
             * either code; everything else, the magic, length, checksum and payload: CS_E_FORMAT. */
            if (o >= 4 && o < 8) {
                if (st != CS_E_VERSION) fail_msg("%s: %s, expected version", what, cs_status_name(st));
            } else if (o >= 8 && o < 16) {
                if (st != CS_E_VERSION && st != CS_E_FORMAT) fail_msg("%s: %s, expected version or format", what,
                                                                     cs_status_name(st));
            } else if (st != CS_E_FORMAT) {
                fail_msg("%s: %s (%s), expected format", what, cs_status_name(st), cs_sim_error(sim));
            }
            view after;
            take_view(sim, &after);
            assert_same_view(&before, &after, what);
        }
    }
    free(t);
    free(buf);
    cs_sim_destroy(sim);
}

static void test_version_and_magic(void **unused)
{
    (void)unused;
    cs_sim *sim = busy_sim();
    size_t len;
    unsigned char *buf = save(sim, &len);
    tk_step(sim, 3);
    view before;
    take_view(sim, &before);
    unsigned char *t = malloc(len);
    assert_non_null(t);
    const uint32_t versions[] = {0, 2, 3, 0x100, 0xffffffffu};
    char what[64];
    for (size_t k = 0; k < sizeof versions / sizeof versions[0]; k++) {
        memcpy(t, buf, len);
        put_u32(t + 4, versions[k]);
        snprintf(what, sizeof what, "version %u", versions[k]);
        refuse(sim, &before, t, len, CS_E_VERSION, what);
    }
    const char *magics[] = {"CSNQ", "csnp", "PNSC", "\0\0\0\0", "CSN"};
    for (size_t k = 0; k < sizeof magics / sizeof magics[0]; k++) {
        memcpy(t, buf, len);
        memcpy(t, magics[k], 4);
        snprintf(what, sizeof what, "magic %zu", k);
        refuse(sim, &before, t, len, CS_E_FORMAT, what);
    }
    /* Not a snapshot at all: zeros, and text. */
    memset(t, 0, len);
    refuse(sim, &before, t, len, CS_E_FORMAT, "zeros");
    const char *text = "{\"this\": \"is not a snapshot, only some JSON that is long enough\"}";
    refuse(sim, &before, (const unsigned char *)text, strlen(text), CS_E_FORMAT, "text");
    free(t);
    free(buf);
    cs_sim_destroy(sim);
}

/* cs_snapshot_peek reads the header without loading: its length and version, whether this build
 * reads it; what does not start with the magic is no snapshot at all, however long. */
static void test_peek(void **unused)
{
    (void)unused;
    cs_sim *sim = busy_sim();
    size_t len;
    unsigned char *buf = save(sim, &len);
    unsigned char *t = malloc(len + 7);
    assert_non_null(t);
    memcpy(t, buf, len);
    memcpy(t + len, "trailer", 7);
    cs_snapshot_info info;
    assert_int_equal(cs_snapshot_peek(t, len + 7, &info), CS_OK);
    assert_int_equal(info.length, len); /* what follows it is not part of it */
    assert_int_equal(info.version, 1);
    assert_true(info.readable);
    /* Cut short: still a snapshot's start, with no length (it is not all there). */
    assert_int_equal(cs_snapshot_peek(t, len - 1, &info), CS_OK);
    assert_int_equal(info.length, 0);
    assert_int_equal(cs_snapshot_peek(t, 6, &info), CS_OK);
    assert_int_equal(info.length, 0);
    assert_int_equal(info.version, 0);
    /* Another version, or another parameter table: a snapshot this build does not read. */
    put_u32(t + 4, 7);
    assert_int_equal(cs_snapshot_peek(t, len, &info), CS_OK);
    assert_int_equal(info.version, 7);
    assert_false(info.readable);
    put_u32(t + 4, 1);
    t[8] ^= 1; /* the layout id */
    assert_int_equal(cs_snapshot_peek(t, len, &info), CS_OK);
    assert_false(info.readable);
    assert_int_equal(info.length, len);
    /* No magic: not a snapshot. */
    memcpy(t, "CSNQ", 4);
    assert_int_equal(cs_snapshot_peek(t, len, &info), CS_E_FORMAT);
    assert_int_equal(info.length, 0);
    assert_int_equal(cs_snapshot_peek("CSN", 3, &info), CS_E_FORMAT);
    assert_int_equal(cs_snapshot_peek(NULL, 0, &info), CS_E_FORMAT);
    assert_int_equal(cs_snapshot_peek(buf, len, NULL), CS_E_INVALID);
    free(t);
    free(buf);
    cs_sim_destroy(sim);
}

/* A snapshot written with the table before the daemon's own settings left it: the state file
 * tests/data/clothd-0.1.0.state, which clothd 0.1.0 wrote (tests/server/statefile.test.mjs says
 * how), starts with one. It loads, to the state it was saved at; the rows the table has lost stay
 * readable by name; saved again, it is in this table's layout, without them. */
static void test_past_table(void **unused)
{
    (void)unused;
    FILE *f = fopen(CLOTHD_TEST_DATA "/clothd-0.1.0.state", "rb");
    assert_non_null(f);
    unsigned char file[8192];
    const size_t len = fread(file, 1, sizeof file, f);
    fclose(f);
    cs_snapshot_info info;
    assert_int_equal(cs_snapshot_peek(file, len, &info), CS_OK);
    assert_true(info.readable);
    assert_true(info.length > 0 && info.length < len); /* a trailer follows */
    cs_sim *sim = tk_sim_serial(NULL, NULL);
    assert_int_equal(cs_snapshot_load(sim, file, info.length), CS_OK);
    char hex[17];
    cs_hash_hex(cs_state_hash(sim), hex);
    assert_string_equal(hex, "aaf84cac7b29ecbf");
    cs_info ci;
    cs_sim_info(sim, &ci);
    assert_int_equal(ci.step, 90);
    assert_int_equal(ci.n_vertices, 30);
    cs_params p;
    cs_sim_params(sim, &p);
    tk_assert_near(p.k_bend, 33, 0);
    /* It ran on contact per vertex, uncapped, with absolute rock stiffnesses: it resumes on vertex
     * contact, uncapped, rock contact at the defaults (per kg now). */
    cs_params def;
    cs_params_default(&def);
    assert_int_equal(p.contact_model, CS_CONTACT_VERTEX);
    assert_true(p.max_depenetration_speed == 0.0f);
    assert_true(p.k_rock == def.k_rock && p.c_rock == def.c_rock);
    double v[3];
    assert_int_equal(cs_snapshot_value(file, info.length, "time_scale", v), CS_OK);
    tk_assert_near(v[0], 2.5, 0);
    assert_int_equal(cs_snapshot_value(file, info.length, "seed", v), CS_OK);
    tk_assert_near(v[0], 7, 0);
    assert_int_equal(cs_snapshot_value(file, info.length, "checkpoint_interval", v), CS_OK);
    tk_assert_near(v[0], 17, 0);
    assert_int_equal(cs_snapshot_value(file, info.length, "k_bend", v), CS_OK);
    tk_assert_near(v[0], 33, 0);
    assert_int_equal(cs_snapshot_value(file, info.length, "gravity", v), CS_OK);
    tk_assert_near(v[2], -9.81, 1e-6);
    assert_int_equal(cs_snapshot_value(file, info.length, "no_such_row", v), CS_E_NOT_FOUND);
    assert_int_equal(cs_snapshot_value(file, 100, "seed", v), CS_E_FORMAT);
    size_t now_len;
    unsigned char *now = save(sim, &now_len);
    /* six rows of one component fewer, nine more (contact_model, max_depenetration_speed,
     * placement_overlap; implicit_substeps, solver_iterations, solver_tolerance, cg_iterations;
     * self_collision, self_thickness) */
    assert_true(now_len == info.length - 6 * 8 + 9 * 8);
    assert_int_equal(cs_snapshot_value(now, now_len, "time_scale", v), CS_E_NOT_FOUND);
    assert_int_equal(cs_snapshot_value(now, now_len, "k_bend", v), CS_OK);
    tk_assert_near(v[0], 33, 0);
    cs_sim *again = tk_sim_serial(NULL, NULL);
    assert_int_equal(cs_snapshot_load(again, now, now_len), CS_OK);
    cs_hash_hex(cs_state_hash(again), hex);
    assert_string_equal(hex, "aaf84cac7b29ecbf");
    free(now);
    cs_sim_destroy(again);
    cs_sim_destroy(sim);
}

/* Edits with the checksum fixed up: a benign edit loads (so the fix-up is right), a NaN, an
 * infinity, a bad rest length or rock, or an out-of-range parameter is refused. */
static void test_fixed_up_checksum(void **unused)
{
    (void)unused;
    cs_sim *src = busy_sim();
    size_t len;
    unsigned char *buf = save(src, &len);
    const size_t n = 130;
    unsigned char *t = malloc(len);
    assert_non_null(t);

    /* The control: x[7] moved by 1 cm and the checksum fixed: accepted, and x[7] reads back. */
    const float x7 = get_f32(buf + off_x(7)) + 0.01f;
    memcpy(t, buf, len);
    put_f32(t + off_x(7), x7);
    fix_checksum(t, len);
    cs_sim *scratch = tk_sim(NULL, NULL);
    assert_int_equal(cs_snapshot_load(scratch, t, len), CS_OK);
    float *x = tk_positions(scratch);
    assert_true(x[3 * 7] == x7);
    free(x);
    /* The same for a parameter: k_structural 500 loads and reads back. */
    memcpy(t, buf, len);
    put_f64(t + HEADER + table_offset("k_structural"), 500.0);
    fix_checksum(t, len);
    assert_int_equal(cs_snapshot_load(scratch, t, len), CS_OK);
    cs_params got;
    cs_sim_params(scratch, &got);
    assert_true(got.k_structural == 500.0f);
    cs_sim_destroy(scratch);

    cs_sim *sim = busy_sim();
    tk_step(sim, 11);
    view before;
    take_view(sim, &before);

    const edit edits[] = {
        {"NaN x[0]", off_x(0), E_F32, NAN, 0},
        {"NaN x[129]", off_x(129), E_F32, NAN, 0},
        {"infinite vz[3]", off_vz(n, 3), E_F32, INFINITY, 0},
        {"NaN rest length", off_rest(n, 2), E_F32, NAN, 0},
        {"negative rest length", off_rest(n, 2), E_F32, -0.5, 0},
        {"zero rest length", off_rest(n, 2), E_F32, 0.0, 0},
        {"rest length where the grid has no spring", off_rest(n, 12), E_F32, 0.1, 0}, /* SX owned by (12, 0), the last column */
        {"NaN rock position", off_rock(n, 0) + 8, E_F32, NAN, 0},
        {"zero rock radius", off_rock(n, 0) + 8 + 4 * 19, E_F32, 0.0, 0},
        /* The fuzzer's find: an orientation of (0, 0, 0, 7.3e-40) turned into NaN once normalized. */
        {"rock orientation w a denormal", off_rock(n, 0) + 8 + 4 * 18, E_F32, 7.34684e-40, 0},
        {"rock orientation w 2 (not a unit quaternion)", off_rock(n, 0) + 8 + 4 * 18, E_F32, 2.0, 0},
        {"k_structural -1", HEADER + table_offset("k_structural"), E_F64, -1.0, 0},
        {"k_structural NaN", HEADER + table_offset("k_structural"), E_F64, NAN, 0},
        {"stability_safety 2", HEADER + table_offset("stability_safety"), E_F64, 2.0, 0},
        {"substeps 2.5", HEADER + table_offset("substeps"), E_F64, 2.5, 0},
        {"substeps above max_substeps", HEADER + table_offset("substeps"), E_F64, 5000.0, 0},
        {"integrator 7", HEADER + table_offset("integrator"), E_F64, 7.0, 0},
        {"ground 0.5", HEADER + table_offset("ground"), E_F64, 0.5, 0},
        {"gravity z -1e4", HEADER + table_offset("gravity") + 16, E_F64, -1e4, 0},
        {"nx 1", HEADER + table_offset("nx"), E_F64, 1.0, 0},
        {"areal_density 0", HEADER + table_offset("areal_density"), E_F64, 0.0, 0},
        /* What no command or step makes (the source has rocks 1 and 2, next id 3; vertex 6 pinned
         * and at rest, 61 grabbed). */
        {"next rock id 0", off_next_id(), E_U32, 0, 0},
        {"next rock id 2, not above rock 2", off_next_id(), E_U32, 0, 2},
        {"step 2^63", off_step(), E_U64, 0, CS_STEP_MAX + 1},
        {"step 2^64 - 1", off_step(), E_U64, 0, UINT64_MAX},
        {"time -1 s", off_time(), E_F64, -1.0, 0},
        {"grab target x 2e6 m", off_target(), E_F32, 2e6, 0},
        {"pinned vertex 6 moving", off_vz(n, 6), E_F32, 0.25, 0},
        {"pinned vertex 6 accelerating", off_ax(n, 6), E_F32, 1.0, 0},
        {"grabbed vertex 61 accelerating", off_ax(n, 61), E_F32, -3.0, 0},
    };
    assert_true(get_u64(buf + off_next_id()) % (1ull << 32) == 3);
    assert_true(cs_is_pinned(src, 6) && cs_grabbed(src, NULL) == 61);
    assert_true(get_f32(buf + off_vz(n, 6)) == 0.0f && get_f32(buf + off_ax(n, 61)) == 0.0f);
    /* A rest length where the grid has no spring must be CS_TORN: check the chosen one is absent. */
    assert_true(get_f32(buf + off_rest(n, 12)) == CS_TORN);
    for (size_t k = 0; k < sizeof edits / sizeof edits[0]; k++) {
        apply_edit(t, buf, len, &edits[k]);
        refuse(sim, &before, t, len, CS_E_FORMAT, edits[k].what);
    }
    /* The controls of those rules: at the edges they allow, the same edits load. */
    const edit fine[] = {
        {"next rock id 4294967295 (every id used)", off_next_id(), E_U32, 0, 4294967295u},
        {"step 2^63 - 1", off_step(), E_U64, 0, CS_STEP_MAX},
        {"grab target x 1e6 m", off_target(), E_F32, 1e6, 0},
        {"free vertex 7 accelerating", off_ax(n, 7), E_F32, 1.0, 0},
    };
    cs_sim *edge = busy_sim();
    for (size_t k = 0; k < sizeof fine / sizeof fine[0]; k++) {
        apply_edit(t, buf, len, &fine[k]);
        const cs_status st = cs_snapshot_load(edge, t, len);
        if (st != CS_OK) fail_msg("%s: refused (%s)", fine[k].what, cs_sim_error(edge));
    }
    cs_sim_destroy(edge);
    /* A grab of a vertex that does not exist, and a rock id past the next id. */
    const size_t clock = HEADER + table_offset(NULL);
    memcpy(t, buf, len);
    put_u32(t + clock + 16, 130);
    fix_checksum(t, len);
    refuse(sim, &before, t, len, CS_E_FORMAT, "grab of vertex 130 of 130");
    memcpy(t, buf, len);
    put_u32(t + off_rock(n, 1), 99);
    fix_checksum(t, len);
    refuse(sim, &before, t, len, CS_E_FORMAT, "rock id 99 past the next id 3");
    memcpy(t, buf, len);
    t[off_pins(n) + 10] = 2;
    fix_checksum(t, len);
    refuse(sim, &before, t, len, CS_E_FORMAT, "a pin byte of 2");

    /* Parameters in range that the stability guard cannot serve (k_structural 1e8 needs far more
     * than max_substeps 1000): refused too, as a parameter change would be. */
    memcpy(t, buf, len);
    put_f64(t + HEADER + table_offset("k_structural"), 1e8);
    fix_checksum(t, len);
    {
        const cs_status st = cs_snapshot_load(sim, t, len);
        if (st != CS_E_UNSTABLE && st != CS_E_FORMAT) fail_msg("unstable snapshot: %s", cs_status_name(st));
        view after;
        take_view(sim, &after);
        assert_same_view(&before, &after, "unstable snapshot");
    }

    /* Still the original loads into it. */
    assert_int_equal(cs_snapshot_load(sim, buf, len), CS_OK);
    free(t);
    free(buf);
    cs_sim_destroy(sim);
    cs_sim_destroy(src);
}

/* A snapshot of sim with one edit (the checksum kept right). */
static unsigned char *save_edited(cs_sim *sim, size_t off, edit_kind kind, uint64_t u, size_t *len)
{
    unsigned char *buf = save(sim, len);
    const edit e = {"", off, kind, 0, u};
    apply_edit(buf, buf, *len, &e);
    return buf;
}

/* What a command would refuse, a snapshot is refused too (the edits of test_fixed_up_checksum):
 * here what needs a scene of its own, a next rock id of 0 with no rock and a rock limit. */
static void test_api_rules(void **unused)
{
    (void)unused;
    cs_sim *src = busy_sim();
    size_t len;
    unsigned char *buf = save(src, &len);
    /* Without rocks, a next id of 0 has no rock to contradict it: refused all the same (the next
     * rock would be id 0, which no route can address). */
    cs_scene small;
    cs_scene_default(&small);
    small.nx = small.ny = 6;
    cs_sim *bare = tk_sim(&small, NULL);
    size_t blen;
    unsigned char *b0 = save_edited(bare, off_next_id(), E_U32, 0, &blen);
    view bare_before;
    take_view(bare, &bare_before);
    refuse(bare, &bare_before, b0, blen, CS_E_FORMAT, "no rocks, next rock id 0");
    free(b0);
    cs_sim_destroy(bare);

    /* More rocks than the rock limit (max_rocks): CS_E_LIMIT naming it, as cs_rock_add does. */
    cs_sim *one = tk_sim(&small, NULL);
    assert_int_equal(cs_sim_set_rock_limit(one, 1), CS_OK);
    assert_int_equal(cs_sim_rock_limit(one), 1);
    assert_int_equal(cs_sim_set_rock_limit(one, 0), CS_E_RANGE);
    assert_int_equal(cs_sim_set_rock_limit(one, CS_MAX_ROCKS + 1), CS_E_RANGE);
    tk_add_rock(one, 0.0f, 0.0f, 2.0f, 0.1f, 300.0f);
    cs_rock_def d;
    cs_rock_def_default(&d);
    assert_int_equal(cs_rock_add(one, &d, NULL), CS_E_LIMIT);
    assert_string_equal(cs_sim_error_param(one), "max_rocks");
    view one_before;
    take_view(one, &one_before);
    assert_int_equal(cs_snapshot_load(one, buf, len), CS_E_LIMIT);
    assert_string_equal(cs_sim_error_param(one), "max_rocks");
    refuse(one, &one_before, buf, len, CS_E_LIMIT, "2 rocks past a limit of 1");
    assert_int_equal(cs_sim_set_rock_limit(one, 2), CS_OK);
    assert_int_equal(cs_snapshot_load(one, buf, len), CS_OK);
    cs_sim_destroy(one);
    free(buf);
    cs_sim_destroy(src);
}

/* Snapshot and reload: the same bytes. */
static void assert_reloads(cs_sim *sim, const char *what)
{
    size_t len, len2;
    unsigned char *a = save(sim, &len);
    cs_sim *other = tk_sim(NULL, NULL);
    const cs_status st = cs_snapshot_load(other, a, len);
    if (st != CS_OK) fail_msg("%s: its own snapshot is refused: %s", what, cs_sim_error(other));
    unsigned char *b = save(other, &len2);
    assert_int_equal(len, len2);
    assert_memory_equal(a, b, len);
    free(a);
    free(b);
    cs_sim_destroy(other);
}

/* Rock ids run out at CS_ROCK_ID_MAX: the last one is given, then cs_rock_add refuses (a clear
 * CS_E_LIMIT) instead of wrapping the next id to 0, and every state on the way saves and loads. A
 * rebuild starts again from 1. */
static void test_rock_ids_run_out(void **unused)
{
    (void)unused;
    cs_sim *sim = tk_sim(NULL, NULL);
    size_t len;
    unsigned char *buf = save_edited(sim, off_next_id(), E_U32, CS_ROCK_ID_MAX - 1, &len);
    assert_int_equal(cs_snapshot_load(sim, buf, len), CS_OK);
    free(buf);
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.position[2] = 2.0f;
    uint32_t id = 0;
    assert_int_equal(cs_rock_add(sim, &d, &id), CS_OK);
    assert_true(id == CS_ROCK_ID_MAX - 1);
    d.position[0] = 0.5f;
    assert_int_equal(cs_rock_add(sim, &d, &id), CS_OK);
    assert_true(id == CS_ROCK_ID_MAX);
    assert_true(id == 4294967294u);
    assert_reloads(sim, "the last id given");
    const uint64_t h = cs_state_hash(sim);
    d.position[0] = -0.5f;
    assert_int_equal(cs_rock_add(sim, &d, &id), CS_E_LIMIT);
    assert_true(strstr(cs_sim_error(sim), "used up") != NULL);
    assert_true(cs_state_hash(sim) == h);
    assert_int_equal(cs_rock_count(sim), 2);
    /* Removing one frees no id: ids are never reused within a scene. */
    assert_int_equal(cs_rock_remove(sim, CS_ROCK_ID_MAX), CS_OK);
    assert_int_equal(cs_rock_add(sim, &d, &id), CS_E_LIMIT);
    assert_reloads(sim, "ids used up");
    assert_int_equal(cs_sim_reset(sim), CS_OK);
    assert_int_equal(cs_rock_add(sim, &d, &id), CS_OK);
    assert_int_equal(id, 1);
    cs_sim_destroy(sim);
}

/* The step count stops at CS_STEP_MAX (2^63 - 1): a step past it is refused whole, one up to it
 * runs, and the state there saves and loads. */
static void test_step_limit(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_scene_default(&sc);
    sc.nx = sc.ny = 4;
    cs_sim *sim = tk_sim_serial(&sc, NULL);
    size_t len;
    unsigned char *buf = save_edited(sim, off_step(), E_U64, CS_STEP_MAX - 10, &len);
    assert_int_equal(cs_snapshot_load(sim, buf, len), CS_OK);
    free(buf);
    const uint64_t h = cs_state_hash(sim);
    assert_int_equal(cs_sim_step(sim, 11), CS_E_LIMIT);
    assert_string_equal(cs_sim_error_param(sim), "substeps");
    cs_info info;
    cs_sim_info(sim, &info);
    assert_true(info.step == CS_STEP_MAX - 10 && cs_state_hash(sim) == h);
    assert_int_equal(cs_sim_step(sim, 10), CS_OK);
    cs_sim_info(sim, &info);
    assert_true(info.step == CS_STEP_MAX);
    assert_reloads(sim, "the last step");
    assert_int_equal(cs_sim_step(sim, 1), CS_E_LIMIT);
    assert_int_equal(cs_sim_step(sim, 0), CS_OK);
    assert_int_equal(cs_sim_step_frames(sim, 1), CS_E_LIMIT);
    cs_sim_destroy(sim);
}

/* cs_snapshot_bytes tells a snapshot's size from the scene alone: what the layout above gives. */
static void test_snapshot_bytes(void **unused)
{
    (void)unused;
    cs_sim *sim = busy_sim();
    cs_scene sc;
    cs_sim_scene(sim, &sc);
    uint64_t bytes = 0;
    assert_int_equal(cs_snapshot_bytes(&sc, 2, &bytes), CS_OK);
    assert_true(bytes == expected_size(130, 2) && bytes == cs_snapshot_size(sim));
    assert_int_equal(cs_snapshot_bytes(&sc, 0, &bytes), CS_OK);
    assert_true(bytes == expected_size(130, 0));
    /* The length a buffer's header gives, with other bytes after it (a bundle, a state file). */
    size_t len;
    unsigned char *buf = save(sim, &len);
    unsigned char *more = malloc(len + 5);
    memcpy(more, buf, len);
    memcpy(more + len, "{...}", 5);
    assert_int_equal(cs_snapshot_length(more, len + 5), len);
    assert_int_equal(cs_snapshot_length(more, len - 1), 0);
    assert_int_equal(cs_snapshot_length("CSNQ", 4), 0);
    assert_int_equal(cs_snapshot_length(NULL, 0), 0);
    free(more);
    free(buf);
    cs_sim_destroy(sim);
}

static void test_save_needs_room(void **unused)
{
    (void)unused;
    cs_sim *sim = busy_sim();
    const size_t size = cs_snapshot_size(sim);
    unsigned char *buf = malloc(size);
    size_t len = 12345;
    assert_int_equal(cs_snapshot_save(sim, buf, size - 1, &len), CS_E_INVALID);
    assert_int_equal(cs_snapshot_save(sim, NULL, size, &len), CS_E_INVALID);
    assert_int_equal(cs_snapshot_save(sim, buf, size, &len), CS_OK);
    assert_int_equal(len, size);
    free(buf);
    cs_sim_destroy(sim);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_round_trip_mid_run),
        cmocka_unit_test(test_truncated),
        cmocka_unit_test(test_corrupted_byte),
        cmocka_unit_test(test_version_and_magic),
        cmocka_unit_test(test_peek),
        cmocka_unit_test(test_past_table),
        cmocka_unit_test(test_fixed_up_checksum),
        cmocka_unit_test(test_save_needs_room),
        cmocka_unit_test(test_api_rules),
        cmocka_unit_test(test_rock_ids_run_out),
        cmocka_unit_test(test_step_limit),
        cmocka_unit_test(test_snapshot_bytes),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
