/* snapshot.c - the whole state as a versioned, checksummed byte buffer (snapshots, checkpoints).
 *
 * Layout, all little-endian:
 *   header (32 bytes): "CSNP", u32 version, u64 layout id (a hash of the parameter table's names,
 *   types and kinds, so a build with other parameters knows the buffer is not its own), u64
 *   payload bytes, u64 FNV-1a 64 of the payload;
 *   payload: every table row (scene then live) as f64 per component; u64 step; f64 time;
 *   i32 grab vertex, 3 f32 grab target; u32 rocks, u32 next rock id; x, y, z, vx, vy, vz, ax, ay,
 *   az (n f32 each); rest lengths (6 n f32); pins (n u8, zero-padded to 4 bytes); per rock: u32 id,
 *   u32 kinematic, 21 f32 (x, v, w, a, alpha, q, radius, density).
 * A snapshot is written with the table as it is. One written with an earlier table that this file
 * keeps (past_tables) loads too: its rows are matched by name, those the table has lost are
 * skipped (cs_snapshot_value still reads them) and those it has gained keep their defaults.
 * Everything derived (masses, the mask, the guard's substeps, torn count) is recomputed on load,
 * and nothing is adopted until the whole buffer has been checked: against the format, and against
 * what the commands and steps that make a state allow (clothsim.h, cs_snapshot_load). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sim_internal.h"

#define SNAP_MAGIC "CSNP"
#define SNAP_VERSION 1u
#define SNAP_HEADER 32u
#define ROCK_FLOATS 21u

typedef struct wbuf {
    unsigned char *p;
    size_t len;
} wbuf;

static void put_u32(wbuf *b, uint32_t u)
{
    for (int i = 0; i < 4; i++) b->p[b->len++] = (unsigned char)(u >> (8 * i));
}
static void put_u64(wbuf *b, uint64_t u)
{
    for (int i = 0; i < 8; i++) b->p[b->len++] = (unsigned char)(u >> (8 * i));
}
static void put_f32(wbuf *b, float f)
{
    uint32_t u;
    memcpy(&u, &f, 4);
    put_u32(b, u);
}
static void put_f64(wbuf *b, double f)
{
    uint64_t u;
    memcpy(&u, &f, 8);
    put_u64(b, u);
}
static void put_floats(wbuf *b, const float *f, size_t n)
{
    for (size_t i = 0; i < n; i++) put_f32(b, f[i]);
}

typedef struct rbuf {
    const unsigned char *p;
    size_t len, at;
    int bad; /* ran past the end */
} rbuf;

static int take(rbuf *b, size_t n)
{
    if (b->bad || b->len - b->at < n) {
        b->bad = 1;
        return 0;
    }
    return 1;
}
static uint32_t get_u32(rbuf *b)
{
    if (!take(b, 4)) return 0;
    uint32_t u = 0;
    for (int i = 0; i < 4; i++) u |= (uint32_t)b->p[b->at++] << (8 * i);
    return u;
}
static uint64_t get_u64(rbuf *b)
{
    if (!take(b, 8)) return 0;
    uint64_t u = 0;
    for (int i = 0; i < 8; i++) u |= (uint64_t)b->p[b->at++] << (8 * i);
    return u;
}
static float get_f32(rbuf *b)
{
    const uint32_t u = get_u32(b);
    float f;
    memcpy(&f, &u, 4);
    return f;
}
static double get_f64(rbuf *b)
{
    const uint64_t u = get_u64(b);
    double f;
    memcpy(&f, &u, 8);
    return f;
}
static void get_floats(rbuf *b, float *f, size_t n)
{
    for (size_t i = 0; i < n; i++) f[i] = get_f32(b);
}

/* A row of a parameter table as a snapshot's layout sees it. */
typedef struct table_row {
    const char *name;
    cs_param_type type;
    cs_param_kind kind;
} table_row;

/* The table until the daemon's own settings (time_scale, max_speed, auto_drop_interval,
 * auto_drop_max, seed, checkpoint_interval) left it for the daemon: snapshots and state files
 * of clothd 0.1.0 as first released. Frozen: never edited. */
static const table_row table_until_daemon_settings[] = {
    {"nx", CS_T_INT, CS_KIND_SCENE}, {"ny", CS_T_INT, CS_KIND_SCENE}, {"size_x", CS_T_FLOAT, CS_KIND_SCENE},
    {"size_y", CS_T_FLOAT, CS_KIND_SCENE}, {"height", CS_T_FLOAT, CS_KIND_SCENE},
    {"orientation", CS_T_ENUM, CS_KIND_SCENE}, {"pins", CS_T_ENUM, CS_KIND_SCENE},
    {"areal_density", CS_T_FLOAT, CS_KIND_SCENE}, {"gravity", CS_T_VEC3, CS_KIND_LIVE},
    {"wind", CS_T_VEC3, CS_KIND_LIVE}, {"k_structural", CS_T_FLOAT, CS_KIND_LIVE},
    {"k_shear", CS_T_FLOAT, CS_KIND_LIVE}, {"k_bend", CS_T_FLOAT, CS_KIND_LIVE},
    {"c_spring", CS_T_FLOAT, CS_KIND_LIVE}, {"drag", CS_T_FLOAT, CS_KIND_LIVE},
    {"plastic_yield", CS_T_FLOAT, CS_KIND_LIVE}, {"tear_strain", CS_T_FLOAT, CS_KIND_LIVE},
    {"plastic_rate", CS_T_FLOAT, CS_KIND_LIVE}, {"k_contact", CS_T_FLOAT, CS_KIND_LIVE},
    {"c_contact", CS_T_FLOAT, CS_KIND_LIVE}, {"c_tangent", CS_T_FLOAT, CS_KIND_LIVE},
    {"mu", CS_T_FLOAT, CS_KIND_LIVE}, {"contact_offset", CS_T_FLOAT, CS_KIND_LIVE},
    {"friction_model", CS_T_ENUM, CS_KIND_LIVE}, {"k_rock", CS_T_FLOAT, CS_KIND_LIVE},
    {"c_rock", CS_T_FLOAT, CS_KIND_LIVE}, {"mu_rock", CS_T_FLOAT, CS_KIND_LIVE},
    {"ground", CS_T_BOOL, CS_KIND_LIVE}, {"ground_z", CS_T_FLOAT, CS_KIND_LIVE},
    {"frame_rate", CS_T_FLOAT, CS_KIND_LIVE}, {"substeps", CS_T_INT, CS_KIND_LIVE},
    {"max_substeps", CS_T_INT, CS_KIND_LIVE}, {"auto_substeps", CS_T_BOOL, CS_KIND_LIVE},
    {"stability_safety", CS_T_FLOAT, CS_KIND_LIVE}, {"integrator", CS_T_ENUM, CS_KIND_LIVE},
    {"time_scale", CS_T_FLOAT, CS_KIND_LIVE}, {"max_speed", CS_T_BOOL, CS_KIND_LIVE},
    {"grab_speed", CS_T_FLOAT, CS_KIND_LIVE}, {"auto_drop_interval", CS_T_FLOAT, CS_KIND_LIVE},
    {"auto_drop_max", CS_T_INT, CS_KIND_LIVE}, {"seed", CS_T_INT, CS_KIND_LIVE},
    {"checkpoint_interval", CS_T_INT, CS_KIND_LIVE},
};

/* The table until the contact model's rows (contact_model, max_depenetration_speed,
 * placement_overlap) came, with k_rock and c_rock still absolute (N/m, N s/m): snapshots and
 * state files of the build that took the daemon's settings out. Frozen: never edited. */
static const table_row table_until_surface_contact[] = {
    {"nx", CS_T_INT, CS_KIND_SCENE}, {"ny", CS_T_INT, CS_KIND_SCENE}, {"size_x", CS_T_FLOAT, CS_KIND_SCENE},
    {"size_y", CS_T_FLOAT, CS_KIND_SCENE}, {"height", CS_T_FLOAT, CS_KIND_SCENE},
    {"orientation", CS_T_ENUM, CS_KIND_SCENE}, {"pins", CS_T_ENUM, CS_KIND_SCENE},
    {"areal_density", CS_T_FLOAT, CS_KIND_SCENE}, {"gravity", CS_T_VEC3, CS_KIND_LIVE},
    {"wind", CS_T_VEC3, CS_KIND_LIVE}, {"k_structural", CS_T_FLOAT, CS_KIND_LIVE},
    {"k_shear", CS_T_FLOAT, CS_KIND_LIVE}, {"k_bend", CS_T_FLOAT, CS_KIND_LIVE},
    {"c_spring", CS_T_FLOAT, CS_KIND_LIVE}, {"drag", CS_T_FLOAT, CS_KIND_LIVE},
    {"plastic_yield", CS_T_FLOAT, CS_KIND_LIVE}, {"tear_strain", CS_T_FLOAT, CS_KIND_LIVE},
    {"plastic_rate", CS_T_FLOAT, CS_KIND_LIVE}, {"k_contact", CS_T_FLOAT, CS_KIND_LIVE},
    {"c_contact", CS_T_FLOAT, CS_KIND_LIVE}, {"c_tangent", CS_T_FLOAT, CS_KIND_LIVE},
    {"mu", CS_T_FLOAT, CS_KIND_LIVE}, {"contact_offset", CS_T_FLOAT, CS_KIND_LIVE},
    {"friction_model", CS_T_ENUM, CS_KIND_LIVE}, {"k_rock", CS_T_FLOAT, CS_KIND_LIVE},
    {"c_rock", CS_T_FLOAT, CS_KIND_LIVE}, {"mu_rock", CS_T_FLOAT, CS_KIND_LIVE},
    {"ground", CS_T_BOOL, CS_KIND_LIVE}, {"ground_z", CS_T_FLOAT, CS_KIND_LIVE},
    {"frame_rate", CS_T_FLOAT, CS_KIND_LIVE}, {"substeps", CS_T_INT, CS_KIND_LIVE},
    {"max_substeps", CS_T_INT, CS_KIND_LIVE}, {"auto_substeps", CS_T_BOOL, CS_KIND_LIVE},
    {"stability_safety", CS_T_FLOAT, CS_KIND_LIVE}, {"integrator", CS_T_ENUM, CS_KIND_LIVE},
    {"grab_speed", CS_T_FLOAT, CS_KIND_LIVE},
};

/* The table until implicit_euler's rows (implicit_substeps, solver_iterations, solver_tolerance,
 * cg_iterations) came: snapshots and state files of the builds with surface contact. Frozen: never
 * edited. */
static const table_row table_until_implicit[] = {
    {"nx", CS_T_INT, CS_KIND_SCENE}, {"ny", CS_T_INT, CS_KIND_SCENE}, {"size_x", CS_T_FLOAT, CS_KIND_SCENE},
    {"size_y", CS_T_FLOAT, CS_KIND_SCENE}, {"height", CS_T_FLOAT, CS_KIND_SCENE},
    {"orientation", CS_T_ENUM, CS_KIND_SCENE}, {"pins", CS_T_ENUM, CS_KIND_SCENE},
    {"areal_density", CS_T_FLOAT, CS_KIND_SCENE}, {"gravity", CS_T_VEC3, CS_KIND_LIVE},
    {"wind", CS_T_VEC3, CS_KIND_LIVE}, {"k_structural", CS_T_FLOAT, CS_KIND_LIVE},
    {"k_shear", CS_T_FLOAT, CS_KIND_LIVE}, {"k_bend", CS_T_FLOAT, CS_KIND_LIVE},
    {"c_spring", CS_T_FLOAT, CS_KIND_LIVE}, {"drag", CS_T_FLOAT, CS_KIND_LIVE},
    {"plastic_yield", CS_T_FLOAT, CS_KIND_LIVE}, {"tear_strain", CS_T_FLOAT, CS_KIND_LIVE},
    {"plastic_rate", CS_T_FLOAT, CS_KIND_LIVE}, {"k_contact", CS_T_FLOAT, CS_KIND_LIVE},
    {"c_contact", CS_T_FLOAT, CS_KIND_LIVE}, {"c_tangent", CS_T_FLOAT, CS_KIND_LIVE},
    {"mu", CS_T_FLOAT, CS_KIND_LIVE}, {"contact_offset", CS_T_FLOAT, CS_KIND_LIVE},
    {"friction_model", CS_T_ENUM, CS_KIND_LIVE}, {"contact_model", CS_T_ENUM, CS_KIND_LIVE},
    {"max_depenetration_speed", CS_T_FLOAT, CS_KIND_LIVE}, {"placement_overlap", CS_T_FLOAT, CS_KIND_LIVE},
    {"k_rock", CS_T_FLOAT, CS_KIND_LIVE}, {"c_rock", CS_T_FLOAT, CS_KIND_LIVE},
    {"mu_rock", CS_T_FLOAT, CS_KIND_LIVE}, {"ground", CS_T_BOOL, CS_KIND_LIVE},
    {"ground_z", CS_T_FLOAT, CS_KIND_LIVE}, {"frame_rate", CS_T_FLOAT, CS_KIND_LIVE},
    {"substeps", CS_T_INT, CS_KIND_LIVE}, {"max_substeps", CS_T_INT, CS_KIND_LIVE},
    {"auto_substeps", CS_T_BOOL, CS_KIND_LIVE}, {"stability_safety", CS_T_FLOAT, CS_KIND_LIVE},
    {"integrator", CS_T_ENUM, CS_KIND_LIVE}, {"grab_speed", CS_T_FLOAT, CS_KIND_LIVE},
};
/* The table before self_collision and self_thickness. */
static const table_row table_until_self_collision[] = {
    {"nx", CS_T_INT, CS_KIND_SCENE}, {"ny", CS_T_INT, CS_KIND_SCENE}, {"size_x", CS_T_FLOAT, CS_KIND_SCENE},
    {"size_y", CS_T_FLOAT, CS_KIND_SCENE}, {"height", CS_T_FLOAT, CS_KIND_SCENE},
    {"orientation", CS_T_ENUM, CS_KIND_SCENE}, {"pins", CS_T_ENUM, CS_KIND_SCENE},
    {"areal_density", CS_T_FLOAT, CS_KIND_SCENE}, {"gravity", CS_T_VEC3, CS_KIND_LIVE},
    {"wind", CS_T_VEC3, CS_KIND_LIVE}, {"k_structural", CS_T_FLOAT, CS_KIND_LIVE},
    {"k_shear", CS_T_FLOAT, CS_KIND_LIVE}, {"k_bend", CS_T_FLOAT, CS_KIND_LIVE},
    {"c_spring", CS_T_FLOAT, CS_KIND_LIVE}, {"drag", CS_T_FLOAT, CS_KIND_LIVE},
    {"plastic_yield", CS_T_FLOAT, CS_KIND_LIVE}, {"tear_strain", CS_T_FLOAT, CS_KIND_LIVE},
    {"plastic_rate", CS_T_FLOAT, CS_KIND_LIVE}, {"k_contact", CS_T_FLOAT, CS_KIND_LIVE},
    {"c_contact", CS_T_FLOAT, CS_KIND_LIVE}, {"c_tangent", CS_T_FLOAT, CS_KIND_LIVE},
    {"mu", CS_T_FLOAT, CS_KIND_LIVE}, {"contact_offset", CS_T_FLOAT, CS_KIND_LIVE},
    {"friction_model", CS_T_ENUM, CS_KIND_LIVE}, {"contact_model", CS_T_ENUM, CS_KIND_LIVE},
    {"max_depenetration_speed", CS_T_FLOAT, CS_KIND_LIVE}, {"placement_overlap", CS_T_FLOAT, CS_KIND_LIVE},
    {"k_rock", CS_T_FLOAT, CS_KIND_LIVE}, {"c_rock", CS_T_FLOAT, CS_KIND_LIVE},
    {"mu_rock", CS_T_FLOAT, CS_KIND_LIVE}, {"ground", CS_T_BOOL, CS_KIND_LIVE},
    {"ground_z", CS_T_FLOAT, CS_KIND_LIVE}, {"frame_rate", CS_T_FLOAT, CS_KIND_LIVE},
    {"substeps", CS_T_INT, CS_KIND_LIVE}, {"max_substeps", CS_T_INT, CS_KIND_LIVE},
    {"auto_substeps", CS_T_BOOL, CS_KIND_LIVE}, {"stability_safety", CS_T_FLOAT, CS_KIND_LIVE},
    {"integrator", CS_T_ENUM, CS_KIND_LIVE}, {"grab_speed", CS_T_FLOAT, CS_KIND_LIVE},
    {"implicit_substeps", CS_T_INT, CS_KIND_LIVE}, {"solver_iterations", CS_T_INT, CS_KIND_LIVE},
    {"solver_tolerance", CS_T_FLOAT, CS_KIND_LIVE}, {"cg_iterations", CS_T_INT, CS_KIND_LIVE},
};

/* The tables a snapshot may have been written with: [0] is the engine's table as it is. */
static const struct {
    const table_row *rows;
    size_t n;
} past_tables[] = {
    {NULL, 0},
    {table_until_daemon_settings, sizeof table_until_daemon_settings / sizeof table_until_daemon_settings[0]},
    {table_until_surface_contact, sizeof table_until_surface_contact / sizeof table_until_surface_contact[0]},
    {table_until_implicit, sizeof table_until_implicit / sizeof table_until_implicit[0]},
    {table_until_self_collision, sizeof table_until_self_collision / sizeof table_until_self_collision[0]},
};
#define N_TABLES (sizeof past_tables / sizeof past_tables[0])

static size_t table_len(size_t t) { return t == 0 ? cs_param_count() : past_tables[t].n; }

static table_row table_at(size_t t, size_t i)
{
    if (t != 0) return past_tables[t].rows[i];
    const cs_param_info *p = cs_param_at(i);
    return (table_row){p->name, p->type, p->kind};
}

static uint64_t table_id(size_t t)
{
    uint64_t h = CS_FNV_OFFSET;
    for (size_t i = 0; i < table_len(t); i++) {
        const table_row r = table_at(t, i);
        const unsigned char tk[2] = {(unsigned char)r.type, (unsigned char)r.kind};
        h = cs_fnv1a(h, r.name, strlen(r.name) + 1);
        h = cs_fnv1a(h, tk, 2);
    }
    return h;
}

static uint64_t layout_id(void) { return table_id(0); }

/* The table a layout id names, or -1 when none this build knows. */
static int table_of(uint64_t layout)
{
    for (size_t t = 0; t < N_TABLES; t++)
        if (table_id(t) == layout) return (int)t;
    return -1;
}

static int row_components(cs_param_type type) { return type == CS_T_VEC3 ? 3 : 1; }

/* Payload bytes for n vertices and r rocks; 0 when it would not fit 64 bits. */
static uint64_t payload_bytes(uint64_t n, uint64_t r)
{
    uint64_t table = 0, arrays, pins, rocks, total;
    for (size_t i = 0; i < cs_param_count(); i++) table += 8u * (uint64_t)row_components(cs_param_at(i)->type);
    if (!cs_mul_ok(n, 4 * (9 + CS_NTYPES), &arrays) || !cs_add_ok(n, 3, &pins) ||
        !cs_mul_ok(r, 8 + 4 * ROCK_FLOATS, &rocks) || !cs_add_ok(table + 8 + 8 + 4 + 12 + 4 + 4, arrays, &total) ||
        !cs_add_ok(total, pins / 4 * 4, &total) || !cs_add_ok(total, rocks, &total))
        return 0;
    return total;
}

static size_t payload_size(const cs_state *s) { return (size_t)payload_bytes((uint64_t)s->n, (uint64_t)s->n_rocks); }

size_t cs_snapshot_size(cs_sim *sim) { return sim ? SNAP_HEADER + payload_size(&sim->state) : 0; }

cs_status cs_snapshot_bytes(const cs_scene *scene, int32_t rocks, uint64_t *bytes)
{
    if (!scene || !bytes || rocks < 0 || scene->nx < 1 || scene->ny < 1) return CS_E_INVALID;
    const uint64_t p = payload_bytes((uint64_t)scene->nx * (uint64_t)scene->ny, (uint64_t)rocks);
    if (p == 0 || !cs_add_ok(p, SNAP_HEADER, bytes)) return CS_E_LIMIT;
    return CS_OK;
}

/* Within 1e6 m of the origin on each axis (what a grab command takes). */
static int in_reach(cs_vec3 t) { return fabsf(t.x) <= 1e6f && fabsf(t.y) <= 1e6f && fabsf(t.z) <= 1e6f; }

static int all_finite(const float *f, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (!isfinite(f[i])) return 0;
    return 1;
}

/* Whether everything a load checks for finiteness is finite: the clock, the vertices, the rocks. */
static int state_finite(const cs_state *s)
{
    const size_t n = (size_t)s->n;
    const float *arrays[] = {s->x, s->y, s->z, s->vx, s->vy, s->vz, s->ax, s->ay, s->az};
    for (int a = 0; a < 9; a++)
        if (!all_finite(arrays[a], n)) return 0;
    for (int32_t r = 0; r < s->n_rocks; r++)
        if (!cs_rock_finite(&s->rocks[r], 1)) return 0;
    return isfinite(s->time);
}

cs_status cs_snapshot_save(cs_sim *sim, void *buf, size_t cap, size_t *len)
{
    if (!sim) return CS_E_INVALID;
    const size_t need = cs_snapshot_size(sim);
    if (!buf || cap < need) return cs_fail(sim, CS_E_INVALID, NULL, "snapshot buffer must hold %zu bytes", need);
    cs_status st = cs_sim_sync(sim, CS_SYNC_ALL);
    if (st != CS_OK) return st;
    const cs_state *s = &sim->state;
    /* What a load would refuse is not written (a command on an extreme state can make its
     * accelerations overflow; the next step finds that and rolls back). */
    if (!state_finite(s)) return cs_fail(sim, CS_E_NONFINITE, NULL, "the state is not finite: it is not saved");
    const size_t n = (size_t)s->n;
    wbuf b = {(unsigned char *)buf + SNAP_HEADER, 0};
    for (size_t i = 0; i < cs_param_count(); i++) {
        const cs_param_info *p = cs_param_at(i);
        const void *base = CS_PARAM_BASE(p, &sim->model.scene, &sim->model.params);
        for (int c = 0; c < row_components(p->type); c++) put_f64(&b, cs_param_get(p, base, c));
    }
    put_u64(&b, s->step);
    put_f64(&b, s->time);
    put_u32(&b, (uint32_t)s->grab);
    put_f32(&b, s->grab_target.x);
    put_f32(&b, s->grab_target.y);
    put_f32(&b, s->grab_target.z);
    put_u32(&b, (uint32_t)s->n_rocks);
    put_u32(&b, s->next_rock_id);
    const float *arrays[] = {s->x, s->y, s->z, s->vx, s->vy, s->vz, s->ax, s->ay, s->az};
    for (int a = 0; a < 9; a++) put_floats(&b, arrays[a], n);
    put_floats(&b, s->L0, n * CS_NTYPES);
    memcpy(b.p + b.len, s->pinned, n);
    b.len += n;
    while (b.len % 4) b.p[b.len++] = 0;
    for (int32_t r = 0; r < s->n_rocks; r++) {
        const cs_rock_state *k = &s->rocks[r];
        put_u32(&b, k->id);
        put_u32(&b, (uint32_t)k->kinematic);
        const float f[ROCK_FLOATS] = {k->x.x, k->x.y, k->x.z, k->v.x, k->v.y, k->v.z, k->w.x, k->w.y, k->w.z,
                                      k->a.x, k->a.y, k->a.z, k->alpha.x, k->alpha.y, k->alpha.z, k->q[0], k->q[1],
                                      k->q[2], k->q[3], k->radius, k->density};
        put_floats(&b, f, ROCK_FLOATS);
    }
    wbuf h = {buf, 0};
    memcpy(h.p, SNAP_MAGIC, 4);
    h.len = 4;
    put_u32(&h, SNAP_VERSION);
    put_u64(&h, layout_id());
    put_u64(&h, b.len);
    put_u64(&h, cs_fnv1a(CS_FNV_OFFSET, b.p, b.len));
    if (len) *len = SNAP_HEADER + b.len;
    cs_ok(sim);
    return CS_OK;
}

/* Reads the rows of table t into scene and params: by name, a row of the engine's table with its
 * type and kind; any other is skipped. CS_OK or the refusal. */
static cs_status load_table(cs_sim *sim, rbuf *b, size_t t, cs_scene *scene, cs_params *params)
{
    char why[200];
    for (size_t i = 0; i < table_len(t); i++) {
        const table_row r = table_at(t, i);
        double v[3] = {0, 0, 0};
        for (int c = 0; c < row_components(r.type); c++) v[c] = get_f64(b);
        if (b->bad) return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot is truncated");
        const cs_param_info *p = t == 0 ? cs_param_at(i) : cs_param_find(r.name);
        if (!p || p->type != r.type || p->kind != r.kind) continue;
        if (cs_param_set(p, CS_PARAM_BASE(p, scene, params), v, why, sizeof why) != 0)
            return cs_fail(sim, CS_E_FORMAT, p->name, "snapshot holds a bad parameter: %s", why);
    }
    const char *bad = NULL;
    if (cs_params_validate(params, &bad, why, sizeof why) != 0)
        return cs_fail(sim, CS_E_FORMAT, bad, "snapshot holds bad parameters: %s", why);
    return CS_OK;
}

static cs_status load_state(cs_sim *sim, rbuf *b, const cs_scene *scene, cs_state *s)
{
    const size_t n = (size_t)s->n;
    s->step = get_u64(b);
    s->time = get_f64(b);
    s->grab = (int32_t)get_u32(b);
    get_floats(b, &s->grab_target.x, 1);
    get_floats(b, &s->grab_target.y, 1);
    get_floats(b, &s->grab_target.z, 1);
    const uint32_t n_rocks = get_u32(b);
    s->next_rock_id = get_u32(b);
    if (b->bad) return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot is truncated");
    if (s->step > CS_STEP_MAX)
        return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot holds step %llu, past 2^63 - 1", (unsigned long long)s->step);
    if (!(isfinite(s->time) && s->time >= 0.0))
        return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot holds a bad clock (time %g s)", s->time);
    if (s->grab < -1 || s->grab >= s->n || !in_reach(s->grab_target))
        return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot holds a bad grab (vertex %d, or its target)", (int)s->grab);
    if (n_rocks > CS_MAX_ROCKS) return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot holds %u rocks, more than %d", n_rocks, CS_MAX_ROCKS);
    if (n_rocks > (uint32_t)sim->rock_limit)
        return cs_fail(sim, CS_E_LIMIT, "max_rocks", "snapshot holds %u rocks, more than max_rocks (%d)", n_rocks,
                       (int)sim->rock_limit);
    if (s->next_rock_id == 0) return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot holds a next rock id of 0 (ids start at 1)");
    float *arrays[] = {s->x, s->y, s->z, s->vx, s->vy, s->vz, s->ax, s->ay, s->az};
    for (int a = 0; a < 9; a++) get_floats(b, arrays[a], n);
    get_floats(b, s->L0, n * CS_NTYPES);
    if (!take(b, (n + 3) / 4 * 4)) return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot is truncated");
    memcpy(s->pinned, b->p + b->at, n);
    b->at += (n + 3) / 4 * 4;
    for (int a = 0; a < 9; a++)
        if (!all_finite(arrays[a], n)) return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot holds non-finite vertex state");
    for (int t = 0; t < CS_NTYPES; t++) {
        for (size_t v = 0; v < n; v++) {
            const float l = s->L0[(size_t)t * n + v];
            const int exists = cs_spring_exists(scene->nx, scene->ny, t, (int32_t)v);
            if (!(l == CS_TORN || (exists && isfinite(l) && l > 0.0f)))
                return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot holds a bad rest length");
        }
    }
    for (size_t v = 0; v < n; v++) {
        const int grabbed = (int32_t)v == s->grab;
        if (s->pinned[v] > 1) return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot holds bad pins");
        /* What pins and grabs leave: a pinned vertex at rest (unless grabbed), no acceleration on
         * a fixed one. */
        if ((s->pinned[v] && !grabbed && !(s->vx[v] == 0.0f && s->vy[v] == 0.0f && s->vz[v] == 0.0f)) ||
            ((s->pinned[v] || grabbed) && !(s->ax[v] == 0.0f && s->ay[v] == 0.0f && s->az[v] == 0.0f)))
            return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot holds a pinned or grabbed vertex (%zu) that moves", v);
    }
    if (n_rocks) {
        if (!(s->rocks = calloc(n_rocks, sizeof *s->rocks))) return cs_fail(sim, CS_E_NOMEM, NULL, "out of memory");
        s->rock_cap = (int32_t)n_rocks;
    }
    for (uint32_t r = 0; r < n_rocks; r++) {
        cs_rock_state *k = &s->rocks[r];
        k->id = get_u32(b);
        k->kinematic = (int32_t)get_u32(b);
        float f[ROCK_FLOATS];
        get_floats(b, f, ROCK_FLOATS);
        if (b->bad) return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot is truncated");
        if (!all_finite(f, ROCK_FLOATS) || (k->kinematic != 0 && k->kinematic != 1) || k->id == 0 || k->id >= s->next_rock_id ||
            !(f[19] >= 1e-3f && f[19] <= 1e3f) || !(f[20] >= 1e-3f && f[20] <= 1e6f))
            return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot holds a bad rock");
        /* A rock's orientation is a unit quaternion (the engine keeps it one every substep); a
         * zero, denormal or huge one would turn into a NaN the first time it is normalized. */
        const double qq = (double)f[15] * f[15] + (double)f[16] * f[16] + (double)f[17] * f[17] + (double)f[18] * f[18];
        if (!(fabs(qq - 1.0) <= 1e-3))
            return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot holds rock %u with an orientation that is not a unit quaternion", k->id);
        for (uint32_t o = 0; o < r; o++)
            if (s->rocks[o].id == k->id) return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot holds a rock id twice");
        k->x = cs_v3(f[0], f[1], f[2]);
        k->v = cs_v3(f[3], f[4], f[5]);
        k->w = cs_v3(f[6], f[7], f[8]);
        k->a = cs_v3(f[9], f[10], f[11]);
        k->alpha = cs_v3(f[12], f[13], f[14]);
        memcpy(k->q, &f[15], 4 * sizeof(float));
        k->radius = f[19];
        k->density = f[20];
        cs_rock_mass(k);
        s->n_rocks = (int32_t)r + 1;
    }
    if (b->at != b->len) return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot has %zu bytes too many", b->len - b->at);
    s->n_torn = cs_torn_list(scene->nx, scene->ny, s->L0, NULL, 0);
    /* The mask from pins and grab, without touching velocities (they are restored as saved). */
    for (size_t v = 0; v < n; v++) s->w[v] = (s->pinned[v] || (int32_t)v == s->grab) ? 0.0f : 1.0f;
    return CS_OK;
}

size_t cs_snapshot_length(const void *buf, size_t len)
{
    if (!buf || len < SNAP_HEADER || memcmp(buf, SNAP_MAGIC, 4) != 0) return 0;
    rbuf h = {buf, SNAP_HEADER, 16, 0};
    const uint64_t plen = get_u64(&h);
    return plen <= len - SNAP_HEADER ? SNAP_HEADER + (size_t)plen : 0;
}

cs_status cs_snapshot_peek(const void *buf, size_t len, cs_snapshot_info *out)
{
    if (!out) return CS_E_INVALID;
    memset(out, 0, sizeof *out);
    if (!buf || len < 4 || memcmp(buf, SNAP_MAGIC, 4) != 0) return CS_E_FORMAT;
    rbuf h = {buf, len < SNAP_HEADER ? len : SNAP_HEADER, 4, 0};
    out->version = get_u32(&h);
    const uint64_t layout = get_u64(&h);
    out->length = cs_snapshot_length(buf, len);
    out->readable = !h.bad && out->version == SNAP_VERSION && table_of(layout) >= 0;
    return CS_OK;
}

cs_status cs_snapshot_load(cs_sim *sim, const void *buf, size_t len)
{
    if (!sim) return CS_E_INVALID;
    if (!buf || len < SNAP_HEADER) return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot is shorter than its header");
    rbuf h = {buf, SNAP_HEADER, 0, 0};
    if (memcmp(h.p, SNAP_MAGIC, 4) != 0) return cs_fail(sim, CS_E_FORMAT, NULL, "not a clothsim snapshot (bad magic)");
    h.at = 4;
    const uint32_t version = get_u32(&h);
    const uint64_t layout = get_u64(&h), plen = get_u64(&h), sum = get_u64(&h);
    if (version != SNAP_VERSION)
        return cs_fail(sim, CS_E_VERSION, NULL, "snapshot format version %u, this build reads %u", version, SNAP_VERSION);
    const int table = table_of(layout);
    if (table < 0) return cs_fail(sim, CS_E_VERSION, NULL, "snapshot was written with another parameter table");
    if (plen != len - SNAP_HEADER) return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot length does not match its header (truncated?)");
    rbuf b = {(const unsigned char *)buf + SNAP_HEADER, (size_t)plen, 0, 0};
    if (cs_fnv1a(CS_FNV_OFFSET, b.p, b.len) != sum) return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot checksum does not match (corrupted)");

    cs_scene scene;
    cs_params params;
    cs_scene_default(&scene);
    cs_params_default(&params);
    cs_status st = load_table(sim, &b, (size_t)table, &scene, &params);
    if (st != CS_OK) return st;
    if (table != 0) {
        /* Every past table predates the contact model: its state ran on contact per vertex with no
         * separation cap, and its k_rock, c_rock were absolute (N/m, N s/m), which have no per-kg
         * equivalent: it resumes on vertex contact, uncapped, with rock contact at the defaults. */
        cs_params def;
        cs_params_default(&def);
        params.contact_model = CS_CONTACT_VERTEX;
        params.max_depenetration_speed = 0.0f;
        params.k_rock = def.k_rock;
        params.c_rock = def.c_rock;
    }
    st = cs_check_memory(sim, &scene, &params);
    if (st != CS_OK) return st;
    /* Before allocating for the scene, make sure the buffer can hold its arrays at all. */
    const size_t n = (size_t)scene.nx * (size_t)scene.ny;
    if ((b.len - b.at) / (4 * (9 + CS_NTYPES) + 1) < n) return cs_fail(sim, CS_E_FORMAT, NULL, "snapshot is truncated");
    cs_state s;
    if (cs_state_alloc(&s, scene.nx * scene.ny) != CS_OK) return cs_fail(sim, CS_E_NOMEM, NULL, "out of memory");
    cs_combos combos;
    int32_t substeps;
    double dt_max;
    cs_guard_scene(&combos, &scene);
    st = load_state(sim, &b, &scene, &s);
    if (st == CS_OK)
        st = cs_guard_eval(sim, &combos, &scene, &params, s.rocks, s.n_rocks, NULL, &substeps, &dt_max);
    cs_model model = sim->model;
    if (st == CS_OK) {
        cs_model_derive(&model, &scene, &params, substeps, dt_max);
        st = sim->backend->upload(sim->ctx, &model, &s); /* on failure the backend is as it was */
        if (st != CS_OK) cs_backend_fail(sim, st, "could not take the snapshot");
    }
    if (st != CS_OK) {
        cs_state_free(&s);
        return st;
    }
    /* No refresh: the accelerations are part of the snapshot. */
    cs_state_free(&sim->state);
    sim->state = s;
    sim->model = model;
    sim->combos = combos;
    sim->host_stale = 0;
    cs_sim_no_step_yet(sim);
    cs_ok(sim);
    return CS_OK;
}

cs_status cs_snapshot_value(const void *buf, size_t len, const char *name, double out[3])
{
    if (!buf || !name || !out) return CS_E_INVALID;
    const size_t snap = cs_snapshot_length(buf, len);
    if (snap == 0) return CS_E_FORMAT;
    rbuf h = {buf, SNAP_HEADER, 4, 0};
    const uint32_t version = get_u32(&h);
    const int table = table_of(get_u64(&h));
    if (version != SNAP_VERSION || table < 0) return CS_E_VERSION;
    rbuf b = {(const unsigned char *)buf + SNAP_HEADER, snap - SNAP_HEADER, 0, 0};
    for (size_t i = 0; i < table_len((size_t)table); i++) {
        const table_row r = table_at((size_t)table, i);
        const int n = row_components(r.type), match = strcmp(r.name, name) == 0;
        for (int c = 0; c < n; c++) {
            const double v = get_f64(&b);
            if (match) out[c] = v;
        }
        if (b.bad) return CS_E_FORMAT;
        if (match) return CS_OK;
    }
    return CS_E_NOT_FOUND;
}
