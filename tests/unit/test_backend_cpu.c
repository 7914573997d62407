/* test_backend_cpu.c - the CPU backend against a plain transcription of backend.h's sequence.
 *
 * The reference below evaluates every spring from both of its ends, tests every rock against
 * every vertex and sums each chunk's reactions with the full cs_tree_sum - the way a GPU kernel
 * does it. The CPU backend evaluates each spring once, skips chunks no rock can reach and sums
 * sparsely. Both must give the same state bit for bit, on grids from 2 x 2 up to rows split into
 * several chunks, with rocks, ground, pins, a grab, torn springs, plasticity and tearing, both
 * integrators and both friction models. Thread counts must not matter either. */
#include "testkit.h"

/* ---- a copy of the state, stepped by the reference ---- */

static void state_copy(cs_state *dst, const cs_state *src)
{
    assert_int_equal(cs_state_alloc(dst, src->n), CS_OK);
    const size_t n = (size_t)src->n;
    float *const d[] = {dst->x, dst->y, dst->z, dst->vx, dst->vy, dst->vz, dst->ax, dst->ay, dst->az, dst->w};
    const float *const s[] = {src->x, src->y, src->z, src->vx, src->vy, src->vz, src->ax, src->ay, src->az, src->w};
    for (int a = 0; a < 10; a++) memcpy(d[a], s[a], n * sizeof(float));
    memcpy(dst->L0, src->L0, n * CS_NTYPES * sizeof(float));
    memcpy(dst->pinned, src->pinned, n);
    dst->n_rocks = src->n_rocks;
    if (src->n_rocks) {
        dst->rocks = malloc(sizeof *dst->rocks * (size_t)src->n_rocks);
        memcpy(dst->rocks, src->rocks, sizeof *dst->rocks * (size_t)src->n_rocks);
    }
    dst->grab = src->grab;
    dst->grab_target = src->grab_target;
}

static cs_vec3 at(const float *X, const float *Y, const float *Z, int32_t v) { return cs_v3(X[v], Y[v], Z[v]); }

/* How often the reference saw each kind of event, so the tests can check they were exercised. */
static long seen_rock_contacts, seen_ground_contacts, seen_torn;

/* The 1-ring of vertex (i, j) as physics.h defines it: off-grid slots repeat the vertex. */
static void ref_ring(const cs_phys *p, const cs_state *s, const cs_vec3 *ro, int32_t i, int32_t j, cs_ring *g)
{
    const int32_t nx = p->nx, ny = p->ny;
    for (int k = 0; k < CS_RING; k++) {
        int32_t ii = i + cs_ring_di(k), jj = j + cs_ring_dj(k);
        if (ii < 0 || ii >= nx || jj < 0 || jj >= ny) ii = i, jj = j;
        const int32_t o = jj * nx + ii;
        g->x[k] = at(s->x, s->y, s->z, o);
    }
    const int32_t v = j * nx + i;
    g->v = at(s->vx, s->vy, s->vz, v);
    g->ro = p->friction == CS_FRICTION_RESULTANT ? ro[v] : cs_v3(0, 0, 0);
    g->faces = cs_ring_faces(s->L0, nx, ny, i, j);
}

/* a for every vertex (and, with strain, the new rest lengths); partials per chunk and rock.
 * First every vertex's non-contact resultant (springs, air, gravity), then its contacts. */
static int64_t ref_accel(const cs_phys *p, cs_state *s, float *partials, int strain)
{
    const int32_t nx = p->nx, ny = p->ny, n = p->n, nr = s->n_rocks;
    float *buf = calloc((size_t)p->nchunks * (size_t)(nr ? nr : 1) * 6 * CS_CHUNK, sizeof(float));
    cs_vec3 *ros = malloc(sizeof *ros * (size_t)n);
    int64_t torn = 0;
    for (int32_t j = 0; j < ny; j++) {
        for (int32_t i = 0; i < nx; i++) {
            const int32_t v = j * nx + i;
            const cs_vec3 xi = at(s->x, s->y, s->z, v), vi = at(s->vx, s->vy, s->vz, v);
            cs_vec3 f = cs_v3(0, 0, 0);
            float len;
#define REF_SLOT(t, di, dj, fwd)                                                                       \
    {                                                                                                  \
        const int32_t o = v + (di) + (dj) * nx;                                                        \
        const size_t li = (size_t)(t) * n + ((fwd) ? v : o);                                           \
        if (i + (di) >= 0 && i + (di) < nx && j + (dj) >= 0 && j + (dj) < ny) {                        \
            f = cs_add(f, cs_spring_force(xi, vi, at(s->x, s->y, s->z, o), at(s->vx, s->vy, s->vz, o),  \
                                          s->L0[li], p->k[t], p->c_spring, &len));                     \
            if ((fwd) && strain) {                                                                     \
                s->L0_next[li] = cs_strain_update(len, s->L0[li], p);                                  \
                torn += s->L0[li] > 0.0f && s->L0_next[li] <= 0.0f;                                    \
            }                                                                                          \
        } else if ((fwd) && strain) {                                                                  \
            s->L0_next[li] = s->L0[li];                                                                \
        }                                                                                              \
    }
            CS_SPRING_SLOTS(REF_SLOT)
#undef REF_SLOT
            ros[v] = cs_add(f, cs_air_gravity(vi, p));
        }
    }
    for (int32_t j = 0; j < ny; j++) {
        for (int32_t i = 0; i < nx; i++) {
            const int32_t v = j * nx + i;
            const cs_vec3 xi = at(s->x, s->y, s->z, v), vi = at(s->vx, s->vy, s->vz, v);
            const cs_vec3 ro = ros[v];
            cs_vec3 f = ro;
            const int32_t chunk = j * p->nseg + i / CS_CHUNK, lane = i % CS_CHUNK;
            for (int32_t r = 0; r < nr; r++) {
                float *b = buf + (((size_t)chunk * nr + r) * 6) * CS_CHUNK;
                if (p->contact_model == CS_CONTACT_SURFACE) {
                    cs_ring g;
                    cs_surface_out o;
                    ref_ring(p, s, ros, i, j, &g);
                    cs_surface_gather(&g, &s->rocks[r], p, f, s->w[v], &o);
                    if (o.touches) {
                        seen_rock_contacts++;
                        f = cs_add(f, o.share);
                    }
                    if (o.owns) {
                        const float q[6] = {o.force.x, o.force.y, o.force.z, o.torque.x, o.torque.y, o.torque.z};
                        for (int k = 0; k < 6; k++) b[k * CS_CHUNK + lane] = q[k];
                    }
                    continue;
                }
                cs_vec3 F, arm;
                if (cs_vertex_rock_contact(xi, vi, ro, &s->rocks[r], p, &F, &arm)) {
                    seen_rock_contacts++;
                    f = cs_add(f, F);
                    const cs_vec3 R = cs_neg(F), T = cs_cross(arm, R);
                    const float q[6] = {R.x, R.y, R.z, T.x, T.y, T.z};
                    for (int k = 0; k < 6; k++) b[k * CS_CHUNK + lane] = q[k];
                }
            }
            cs_vec3 F;
            if (cs_vertex_ground_contact(xi, vi, ro, p, &F)) {
                seen_ground_contacts++;
                f = cs_add(f, F);
            }
            const cs_vec3 a = cs_scale(f, p->inv_mass * s->w[v]);
            s->ax[v] = a.x, s->ay[v] = a.y, s->az[v] = a.z;
        }
    }
    for (int32_t c = 0; c < p->nchunks; c++)
        for (int32_t r = 0; r < nr; r++)
            for (int k = 0; k < 6; k++)
                partials[((size_t)c * nr + r) * 6 + k] = cs_tree_sum(buf + (((size_t)c * nr + r) * 6 + k) * CS_CHUNK);
    free(buf);
    free(ros);
    return torn;
}

static void ref_rocks(const cs_phys *p, cs_state *s, const float *partials)
{
    for (int32_t r = 0; r < s->n_rocks; r++) {
        cs_vec3 F, T;
        cs_rock_force(s->rocks, s->n_rocks, r, partials, p->nchunks, p, &F, &T);
        cs_rock_accel(&s->rocks[r], F, T);
    }
}

static void ref_grab(const cs_phys *p, cs_state *s)
{
    if (s->grab < 0) return;
    const cs_vec3 v = cs_grab_velocity(at(s->x, s->y, s->z, s->grab), s->grab_target, p);
    s->vx[s->grab] = v.x, s->vy[s->grab] = v.y, s->vz[s->grab] = v.z;
}

static void ref_kick(cs_state *s, int32_t v, float h)
{
    s->vx[v] = s->vx[v] + h * s->ax[v];
    s->vy[v] = s->vy[v] + h * s->ay[v];
    s->vz[v] = s->vz[v] + h * s->az[v];
}

static void ref_drift(cs_state *s, int32_t v, float dt)
{
    s->x[v] = s->x[v] + dt * s->vx[v];
    s->y[v] = s->y[v] + dt * s->vy[v];
    s->z[v] = s->z[v] + dt * s->vz[v];
}

static void swap_rest(cs_state *s)
{
    float *t = s->L0;
    s->L0 = s->L0_next;
    s->L0_next = t;
}

static int64_t ref_step(const cs_phys *p, cs_state *s, int32_t substeps)
{
    const int32_t n = p->n;
    float *partials = calloc((size_t)p->nchunks * (size_t)(s->n_rocks ? s->n_rocks : 1) * 6, sizeof(float));
    int64_t torn = 0;
    for (int32_t it = 0; it < substeps; it++) {
        if (p->integrator == CS_VELOCITY_VERLET) {
            ref_grab(p, s);
            for (int32_t r = 0; r < s->n_rocks; r++) {
                cs_rock_kick(&s->rocks[r], p->hdt);
                cs_rock_drift(&s->rocks[r], p->dt);
            }
            for (int32_t v = 0; v < n; v++) {
                if (it > 0) ref_kick(s, v, p->hdt);
                ref_kick(s, v, p->hdt);
                ref_drift(s, v, p->dt);
            }
            torn += ref_accel(p, s, partials, p->strain_on);
            ref_rocks(p, s, partials);
            for (int32_t r = 0; r < s->n_rocks; r++) cs_rock_kick(&s->rocks[r], p->hdt);
            if (p->strain_on) swap_rest(s);
        } else {
            ref_accel(p, s, partials, 0);
            ref_rocks(p, s, partials);
            for (int32_t r = 0; r < s->n_rocks; r++) {
                cs_rock_kick(&s->rocks[r], p->dt);
                cs_rock_drift(&s->rocks[r], p->dt);
            }
            ref_grab(p, s);
            for (int32_t v = 0; v < n; v++) {
                ref_kick(s, v, p->dt);
                ref_drift(s, v, p->dt);
            }
            if (p->strain_on) {
                for (int t = 0; t < CS_NTYPES; t++) {
                    for (int32_t v = 0; v < n; v++) {
                        const size_t li = (size_t)t * n + v;
                        s->L0_next[li] = s->L0[li];
                        const int32_t o = cs_spring_far_end(p->nx, p->ny, t, v);
                        if (o < 0) continue;
                        const float len = cs_len(cs_sub(at(s->x, s->y, s->z, o), at(s->x, s->y, s->z, v)));
                        s->L0_next[li] = cs_strain_update(len, s->L0[li], p);
                        torn += s->L0[li] > 0.0f && s->L0_next[li] <= 0.0f;
                    }
                }
                swap_rest(s);
            }
        }
    }
    if (p->integrator == CS_VELOCITY_VERLET && substeps > 0)
        for (int32_t v = 0; v < n; v++) ref_kick(s, v, p->hdt);
    free(partials);
    seen_torn += torn;
    return torn;
}

/* ---- comparing ---- */

static void assert_same(const cs_state *a, const cs_state *b)
{
    const size_t n = (size_t)a->n;
    const float *const xa[] = {a->x, a->y, a->z, a->vx, a->vy, a->vz, a->ax, a->ay, a->az};
    const float *const xb[] = {b->x, b->y, b->z, b->vx, b->vy, b->vz, b->ax, b->ay, b->az};
    static const char *const names[] = {"x", "y", "z", "vx", "vy", "vz", "ax", "ay", "az"};
    for (int k = 0; k < 9; k++) {
        for (size_t v = 0; v < n; v++) {
            if (memcmp(&xa[k][v], &xb[k][v], sizeof(float)) != 0)
                fail_msg("%s[%zu] differs: %.9g vs %.9g (grid %d x ?)", names[k], v, (double)xa[k][v], (double)xb[k][v], 0);
        }
    }
    for (size_t i = 0; i < n * CS_NTYPES; i++)
        if (memcmp(&a->L0[i], &b->L0[i], sizeof(float)) != 0)
            fail_msg("L0[%zu] differs: %.9g vs %.9g", i, (double)a->L0[i], (double)b->L0[i]);
    assert_int_equal(a->n_rocks, b->n_rocks);
    for (int32_t r = 0; r < a->n_rocks; r++)
        if (memcmp(&a->rocks[r], &b->rocks[r], sizeof a->rocks[r]) != 0) fail_msg("rock %d differs", (int)r);
}

/* ---- scenes ---- */

static uint32_t rng = 12345;
static float frand(void) /* uniform in [0, 1) */
{
    rng = rng * 1664525u + 1013904223u;
    return (float)(rng >> 8) / 16777216.0f;
}

typedef struct variant {
    int nx, ny;
    int integrator, friction, strain, rocks;
    int model; /* cs_contact_model */
} variant;

/* A cloth shaken up: random velocities, displaced vertices, torn springs, a few pins, a grab,
 * rocks pressed into it and the ground just below its lowest vertices. */
static cs_sim *shaken(const variant *vr)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = vr->nx;
    sc.ny = vr->ny;
    sc.size_x = 0.04f * (float)(vr->nx - 1);
    sc.size_y = 0.04f * (float)(vr->ny - 1);
    sc.pins = CS_PINS_CORNERS;
    p.integrator = vr->integrator;
    p.friction_model = vr->friction;
    p.contact_model = vr->model;
    p.plastic_yield = vr->strain ? 0.01f : 0.0f;
    p.tear_strain = vr->strain ? 0.05f : 0.0f;
    p.plastic_rate = vr->strain ? 200.0f : 0.0f;
    p.ground_z = sc.height - 0.02f;
    p.wind[0] = 1.0f;
    p.max_substeps = 100000;
    cs_sim *sim = tk_sim(&sc, &p);
    cs_state *s = &sim->state;
    for (int32_t v = 0; v < s->n; v++) {
        s->x[v] += 0.01f * (frand() - 0.5f);
        s->y[v] += 0.01f * (frand() - 0.5f);
        s->z[v] += 0.03f * (frand() - 0.5f);
        s->vx[v] = 0.5f * (frand() - 0.5f);
        s->vy[v] = 0.5f * (frand() - 0.5f);
        s->vz[v] = 2.0f * (frand() - 0.5f);
    }
    for (size_t i = 0; i < (size_t)s->n * CS_NTYPES; i++)
        if (s->L0[i] > 0 && frand() < 0.03f) s->L0[i] = CS_TORN;
    s->n_torn = cs_torn_list(sc.nx, sc.ny, s->L0, NULL, 0);
    assert_int_equal(cs_sim_commit(sim), CS_OK);
    const int32_t mid = s->n / 2;
    const float target[3] = {s->x[mid] + 0.05f, s->y[mid], s->z[mid] + 0.1f};
    assert_int_equal(cs_grab(sim, mid, target), CS_OK);
    for (int r = 0; r < vr->rocks; r++) {
        cs_rock_def d;
        cs_rock_def_default(&d);
        const int32_t v = (int32_t)(frand() * (float)s->n);
        d.radius = 0.03f + 0.05f * frand();
        d.position[0] = s->x[v];
        d.position[1] = s->y[v];
        d.position[2] = s->z[v] + d.radius * 0.8f;
        d.velocity[2] = -1.0f;
        d.angular_velocity[0] = 3.0f * (frand() - 0.5f);
        d.angular_velocity[2] = 3.0f * (frand() - 0.5f);
        d.kinematic = r == 1;
        d.density = 200.0f;
        tk_place_rock(sim, &d); /* pressed in on purpose: past the overlap refusal */
    }
    return sim;
}

static void check_variant(const variant *vr, int32_t substeps)
{
    cs_sim *sim = shaken(vr);
    cs_state ref;
    state_copy(&ref, &sim->state);
    const int64_t torn_ref = ref_step(&sim->model.phys, &ref, substeps);
    const int64_t torn_before = sim->state.n_torn;
    tk_step(sim, substeps);
    assert_same(&sim->state, &ref);
    assert_int_equal(sim->state.n_torn - torn_before, torn_ref);
    cs_state_free(&ref);
    cs_sim_destroy(sim);
}

/* Accelerations after a command (refresh), before any step. */
static void test_refresh_matches_reference(void **unused)
{
    (void)unused;
    const int sizes[][2] = {{2, 2}, {3, 3}, {4, 5}, {5, 4}, {7, 6}, {16, 9}, {300, 4}};
    for (size_t k = 0; k < 2 * sizeof sizes / sizeof sizes[0]; k++) {
        const size_t z = k / 2;
        const variant vr = {sizes[z][0], sizes[z][1], CS_VELOCITY_VERLET, (int)(k & 1), 0, 3, (int)(k & 1)};
        cs_sim *sim = shaken(&vr);
        cs_state ref;
        state_copy(&ref, &sim->state);
        float *partials = calloc((size_t)sim->model.phys.nchunks * 6 * 3, sizeof(float));
        seen_rock_contacts = 0;
        ref_accel(&sim->model.phys, &ref, partials, 0);
        ref_rocks(&sim->model.phys, &ref, partials);
        assert_same(&sim->state, &ref);
        free(partials);
        cs_state_free(&ref);
        cs_sim_destroy(sim);
    }
}

static void test_steps_match_reference(void **unused)
{
    (void)unused;
    const int sizes[][2] = {{2, 2}, {3, 4}, {5, 5}, {9, 7}, {24, 20}, {270, 5}};
    for (size_t k = 0; k < sizeof sizes / sizeof sizes[0]; k++) {
        for (int integ = 0; integ < 2; integ++) {
            for (int fr = 0; fr < 2; fr++) {
                for (int model = 0; model < 2; model++) {
                    const variant vr = {sizes[k][0], sizes[k][1], integ, fr, 1, 4, model};
                    check_variant(&vr, 40);
                }
            }
        }
    }
    /* The scenes did exercise what they are meant to. */
    assert_true(seen_rock_contacts > 1000);
    assert_true(seen_ground_contacts > 1000);
    assert_true(seen_torn > 10);
}

static void test_threads_do_not_matter(void **unused)
{
    (void)unused;
    uint64_t h[3];
    for (int t = 1; t <= 3; t++) {
        rng = 777;
        const variant vr = {33, 31, CS_VELOCITY_VERLET, CS_FRICTION_RESULTANT, 1, 5, CS_CONTACT_SURFACE};
        cs_sim *sim = shaken(&vr);
        assert_int_equal(cs_sim_set_threads(sim, t), CS_OK);
        tk_step(sim, 200);
        h[t - 1] = cs_state_hash(sim);
        cs_sim_destroy(sim);
    }
    assert_true(h[0] == h[1]);
    assert_true(h[0] == h[2]);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_refresh_matches_reference),
        cmocka_unit_test(test_steps_match_reference),
        cmocka_unit_test(test_threads_do_not_matter),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
