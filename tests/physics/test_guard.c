/* test_guard.c - the stability guard and the non-finite guard (kernels/MODEL.md, Time).
 *
 * The guard's limit is recomputed here by hand from MODEL.md's formula: per vertex
 * K = its spring stiffnesses + w k_contact, C = its spring dampings + w (c_contact + c_tangent)
 * + m drag / 2, where w counts the contacts a vertex can have (surface contact: 3, and half one
 * more with the ground; vertex contact: 1), dt_i = (sqrt(C^2 + 2 m K) - C) / K; per dynamic rock
 * the same with M, k_rock M, c_rock M (rock contacts scale with the mass) and, with surface
 * contact, k_contact and c_contact + c_tangent for each of the cloth triangles that fit on its
 * surface (4 pi (R + offset)^2 over a triangle's rest area, plus one);
 * dt_max = stability_safety x the smallest. The interior vertex of a grid of 5 x 5 or more has
 * the most springs (4 structural, 4 shear, 4 bend), and dt_i falls as K and C grow, so it gives
 * the vertex minimum. When dt = 1/(frame_rate substeps) exceeds dt_max, substeps becomes
 * ceil(1/(frame_rate dt_max)) (auto_substeps, up to max_substeps) or the change is refused. */
#include "testkit.h"

static double limit(double m, double K, double C) { return (sqrt(C * C + 2 * m * K) - C) / K; }

/* dt_max by hand for an nx x ny >= 5 x 5 scene and the given dynamic rocks (masses, radii). */
static double hand_dt_max_r(const cs_scene *sc, const cs_params *p, const double *rock_mass, const double *rock_radius,
                            int n_rocks)
{
    const int surface = p->contact_model == CS_CONTACT_SURFACE;
    const double w = surface ? (p->ground ? 3.5 : 3.0) : 1.0;
    const double m = (double)sc->areal_density * sc->size_x * sc->size_y / ((double)sc->nx * sc->ny);
    const double K = 4.0 * p->k_structural + 4.0 * p->k_shear + 4.0 * p->k_bend + w * p->k_contact;
    const double C = 12.0 * p->c_spring + w * (p->c_contact + p->c_tangent) + m * p->drag / 2;
    double lim = limit(m, K, C);
    const double tri = (double)sc->size_x / (sc->nx - 1) * sc->size_y / (sc->ny - 1) / 2;
    for (int r = 0; r < n_rocks; r++) {
        const double M = rock_mass[r], reach = rock_radius[r] + p->contact_offset;
        const double n = surface ? floor(4 * 3.14159265358979323846 * reach * reach / tri) + 3 : 0;
        const double l = limit(M, p->k_rock * M + n * p->k_contact, p->c_rock * M + n * (p->c_contact + p->c_tangent));
        if (l < lim) lim = l;
    }
    return p->stability_safety * lim;
}

static double hand_dt_max(const cs_scene *sc, const cs_params *p, const double *rock_mass, int n_rocks)
{
    const double radius[1] = {0.03};
    assert_true(n_rocks <= 1);
    return hand_dt_max_r(sc, p, rock_mass, radius, n_rocks);
}

/* The substeps the guard must choose, checking that the ceiling is not a near tie. */
static int hand_substeps(const cs_params *p, double dt_max)
{
    const double need = 1.0 / (p->frame_rate * dt_max);
    assert_true(fabs(need - floor(need + 0.5)) > 1e-6);
    const double dt = 1.0 / ((double)p->frame_rate * p->substeps);
    return dt > dt_max ? (int)ceil(need) : p->substeps;
}

static void small_scene(cs_scene *sc, cs_params *p)
{
    cs_scene_default(sc);
    cs_params_default(p);
    p->integrator = CS_VELOCITY_VERLET; /* the guard bounds the explicit integrators' substeps */
    sc->nx = 16;
    sc->ny = 14;
    sc->size_x = 1.0f;
    sc->size_y = 0.9f;
    sc->height = 0.6f;
    tk_v1_material(sc, p); /* the figures below were measured on it */
}

/* A simulation on one thread: results do not depend on the thread count (test_determinism), and
 * OpenMP barriers at every substep crawl when ctest runs tests side by side on two cores. */
static cs_sim *mk(const cs_scene *sc, const cs_params *p)
{
    cs_sim *sim = tk_sim(sc, p);
    assert_int_equal(cs_sim_set_threads(sim, 1), CS_OK);
    return sim;
}

static void assert_close_rel(double got, double want, double rel)
{
    if (!(fabs(got - want) <= rel * fabs(want))) fail_msg("%.12g, expected %.12g (relative %.1e)", got, want, rel);
}

/* Everything a refused call must leave alone. */
typedef struct snapshot_view {
    uint64_t hash;
    cs_info info;
    cs_params params;
} snapshot_view;

static snapshot_view view(cs_sim *sim)
{
    snapshot_view v;
    memset(&v, 0, sizeof v);
    v.hash = cs_state_hash(sim);
    cs_sim_info(sim, &v.info);
    cs_sim_params(sim, &v.params);
    return v;
}

static void assert_same_view(const snapshot_view *a, const snapshot_view *b)
{
    assert_true(a->hash == b->hash);
    assert_memory_equal(&a->info, &b->info, sizeof a->info);
    assert_memory_equal(&a->params, &b->params, sizeof a->params);
}

static void test_dt_max_matches_formula(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    small_scene(&sc, &p);
    p.c_spring = 0.3f; /* make every term of C count */
    p.drag = 2.0f;
    cs_sim *sim = mk(&sc, &p);
    cs_info info;
    cs_sim_info(sim, &info);
    double want = hand_dt_max(&sc, &p, NULL, 0);
    print_message("16 x 14 cloth, c_spring 0.3, drag 2: dt_max %.6e s (hand %.6e), substeps %d, dt %.6e\n", info.dt_max, want,
                  (int)info.substeps, info.dt);
    assert_close_rel(info.dt_max, want, 1e-9);
    assert_int_equal(info.substeps, hand_substeps(&p, want));
    assert_close_rel(info.dt, 1.0 / (p.frame_rate * info.substeps), 1e-12);

    /* A dynamic rock of 0.0339 kg (R 0.03 m, 300 kg/m^3) on k_rock = 1e8/s^2 (c_rock 500/s)
     * limits harder than the vertices: 0.7 x 2/(sqrt(c^2 + 2 k) + c) = 9.9e-5 s, whatever its
     * mass. */
    p.k_rock = 1e8f;
    assert_int_equal(cs_sim_set_params(sim, &p), CS_OK);
    const double M = 300.0 * 4.0 / 3.0 * 3.14159265358979323846 * 0.03 * 0.03 * 0.03;
    const uint32_t id = tk_add_rock(sim, 0.0f, 0.0f, 2.0f, 0.03f, 300.0f);
    assert_close_rel(tk_rock(sim, id).mass, M, 1e-6);
    cs_sim_info(sim, &info);
    want = hand_dt_max(&sc, &p, &M, 1);
    assert_true(want < hand_dt_max(&sc, &p, NULL, 0)); /* the rock is the limit */
    assert_close_rel(info.dt_max, want, 1e-6);
    assert_int_equal(info.substeps, hand_substeps(&p, want));
    print_message("with a 0.0339 kg rock: dt_max %.6e s (hand %.6e), substeps %d\n", info.dt_max, want,
                  (int)info.substeps);
    /* A light kinematic rock does not count (it ignores forces). */
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.radius = 0.01f;
    d.density = 1.0f;
    d.kinematic = true;
    d.position[2] = 3.0f;
    assert_int_equal(cs_rock_add(sim, &d, NULL), CS_OK);
    cs_info info2;
    cs_sim_info(sim, &info2);
    assert_true(info2.dt_max == info.dt_max);
    /* Removing the dynamic rock gives the vertex limit and its substeps back. */
    assert_int_equal(cs_rock_remove(sim, id), CS_OK);
    cs_sim_info(sim, &info);
    assert_close_rel(info.dt_max, hand_dt_max(&sc, &p, NULL, 0), 1e-9);
    assert_int_equal(info.substeps, hand_substeps(&p, hand_dt_max(&sc, &p, NULL, 0)));
    cs_sim_destroy(sim);
}

/* k_structural x 100 through cs_sim_set_params: the guard raises substeps to exactly the hand
 * value, the run stays finite and its energy bounded while a rock drops onto the cloth. */
static void test_stiff_raises_substeps_and_stays_bounded(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    small_scene(&sc, &p);
    cs_sim *sim = mk(&sc, &p);
    cs_info before, after;
    cs_sim_info(sim, &before);
    assert_int_equal(before.substeps, p.substeps);

    p.k_structural *= 100.0f;
    assert_int_equal(cs_sim_set_params(sim, &p), CS_OK);
    cs_sim_info(sim, &after);
    const double want = hand_dt_max(&sc, &p, NULL, 0);
    const int want_sub = hand_substeps(&p, want);
    print_message("k_structural 40000: dt_max %.6e s (hand %.6e), substeps %d -> %d (hand %d)\n", after.dt_max, want,
                  (int)before.substeps, (int)after.substeps, want_sub);
    assert_close_rel(after.dt_max, want, 1e-9);
    assert_true(after.substeps > before.substeps);
    assert_int_equal(after.substeps, want_sub);
    assert_true(after.dt <= after.dt_max);
    cs_params got;
    cs_sim_params(sim, &got);
    assert_int_equal(got.substeps, p.substeps); /* the request is kept; the effective count is the guard's */

    /* Drop a 0.85 kg rock (R 0.15 m, 60 kg/m^3) from 0.24 m above the cloth onto its centre and
     * run 2 simulated seconds. */
    const uint32_t id = tk_add_rock(sim, 0.0f, 0.0f, sc.height + 0.4f, 0.15f, 60.0f);
    const double M = tk_rock(sim, id).mass;
    cs_energy e0;
    assert_int_equal(cs_energy_get(sim, &e0), CS_OK);
    double e_max = e0.total, ke_max = 0;
    for (int f = 0; f < 120; f++) {
        assert_int_equal(cs_sim_step_frames(sim, 1), CS_OK);
        cs_energy e;
        assert_int_equal(cs_energy_get(sim, &e), CS_OK);
        assert_true(isfinite(e.total));
        if (e.total > e_max) e_max = e.total;
        if (e.kinetic > ke_max) ke_max = e.kinetic;
    }
    cs_energy e1;
    assert_int_equal(cs_energy_get(sim, &e1), CS_OK);
    const cs_rock rock = tk_rock(sim, id);
    print_message("drop: M %.3f kg, E0 %.4f J, max E %.4f J, max KE %.4f J, E(2 s) %.4f J, rock at z %.4f\n", M,
                  e0.total, e_max, ke_max, e1.total, (double)rock.def.position[2]);
    /* Damping only removes energy; cs_energy leaves out the contact penalty's energy, which is at
     * most a few mJ here, so allow 0.05 J. The fall to the cloth releases M g 0.24 m = 2.0 J, and
     * the stiff cloth gives way by centimetres only: the kinetic energy stays below M g 0.4 m; an
     * unstable run would exceed it by orders of magnitude. */
    assert_true(e_max <= e0.total + 0.05);
    assert_true(ke_max < M * 9.81 * 0.4);
    assert_true(ke_max > M * 9.81 * 0.2); /* it did fall */
    assert_true(e1.total < e0.total);
    /* The cloth holds it (still bouncing lightly: contact damping is small): its centre stays
     * above the cloth's height, below where it started. */
    assert_true(rock.def.position[2] > sc.height && rock.def.position[2] < sc.height + 0.4f);
    float *x = tk_positions(sim);
    for (int32_t v = 0; v < sim->state.n; v++)
        assert_true(fabsf(x[3 * v]) <= 0.51f && fabsf(x[3 * v + 1]) <= 0.46f && x[3 * v + 2] > sc.height - 0.5f &&
                    x[3 * v + 2] < sc.height + 0.05f);
    free(x);
    cs_sim_destroy(sim);
}

/* The guard is not vacuous: the same stiff cloth forced (white-box) to run at the 30 substeps the
 * guard refused goes non-finite or explodes within a simulated second. */
static void test_unguarded_stiff_cloth_blows_up(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    small_scene(&sc, &p);
    p.k_structural *= 100.0f;
    cs_sim *sim = mk(&sc, &p);
    cs_info info;
    cs_sim_info(sim, &info);
    assert_true(info.substeps > 30);
    cs_model_derive(&sim->model, &sc, &p, 30, info.dt_max);
    assert_int_equal(cs_sim_commit(sim), CS_OK);
    cs_sim_info(sim, &info);
    assert_int_equal(info.substeps, 30);
    cs_energy e0;
    assert_int_equal(cs_energy_get(sim, &e0), CS_OK);
    int frames = 0;
    cs_status st = CS_OK;
    double e_max = e0.total;
    while (frames < 60 && st == CS_OK) {
        st = cs_sim_step_frames(sim, 1);
        frames++;
        cs_energy e;
        if (st == CS_OK && cs_energy_get(sim, &e) == CS_OK && e.total > e_max) e_max = e.total;
    }
    print_message("unguarded at 30 substeps: %s after %d frames, max energy %.3g J (start %.3g J)\n",
                  cs_status_name(st), frames, e_max, e0.total);
    assert_true(st == CS_E_NONFINITE || e_max > e0.total + 1e3);
    cs_sim_destroy(sim);
}

static int changed_param(const char *name, const char *const *allowed, int n)
{
    for (int k = 0; k < n; k++)
        if (strcmp(name, allowed[k]) == 0) return 1;
    return 0;
}

/* Refusals: max_substeps below what the guard needs, and auto_substeps off. */
static void test_refusals_change_nothing(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    small_scene(&sc, &p);
    cs_sim *sim = mk(&sc, &p);
    tk_add_rock(sim, 0.1f, 0.0f, sc.height + 0.2f, 0.1f, 300.0f);
    tk_step(sim, 45);
    const snapshot_view v0 = view(sim);

    cs_params q = p;
    q.k_structural *= 100.0f;
    const int need = hand_substeps(&q, hand_dt_max(&sc, &q, NULL, 0));
    assert_true(need > 50);
    q.max_substeps = 50;
    assert_int_equal(cs_sim_set_params(sim, &q), CS_E_UNSTABLE);
    const char *blame = cs_sim_error_param(sim);
    print_message("max_substeps 50 (hand: %d needed): refused, param \"%s\": %s\n", need, blame, cs_sim_error(sim));
    const char *const changed1[] = {"k_structural", "max_substeps"};
    assert_true(changed_param(blame, changed1, 2));
    assert_non_null(cs_param_find(blame));
    assert_true(strlen(cs_sim_error(sim)) > 0);
    snapshot_view v1 = view(sim);
    assert_same_view(&v0, &v1);

    /* Just enough max_substeps is accepted, with exactly that many substeps. */
    q.max_substeps = need;
    assert_int_equal(cs_sim_set_params(sim, &q), CS_OK);
    cs_info info;
    cs_sim_info(sim, &info);
    assert_int_equal(info.substeps, need);
    q.max_substeps = need - 1;
    assert_int_equal(cs_sim_set_params(sim, &q), CS_E_UNSTABLE);
    cs_info info2;
    cs_sim_info(sim, &info2);
    assert_int_equal(info2.substeps, need);
    assert_int_equal(cs_sim_set_params(sim, &p), CS_OK); /* back to the defaults */
    cs_sim_info(sim, &info);
    assert_int_equal(info.substeps, p.substeps);
    tk_step(sim, 0);
    const snapshot_view v2 = view(sim);

    /* auto_substeps off: refused even with room in max_substeps. */
    q = p;
    q.k_structural *= 100.0f;
    q.auto_substeps = 0;
    assert_int_equal(cs_sim_set_params(sim, &q), CS_E_UNSTABLE);
    blame = cs_sim_error_param(sim);
    print_message("auto_substeps off: refused, param \"%s\": %s\n", blame, cs_sim_error(sim));
    const char *const changed2[] = {"k_structural", "auto_substeps", "substeps"};
    assert_true(changed_param(blame, changed2, 3));
    v1 = view(sim);
    assert_same_view(&v2, &v1);
    /* With auto_substeps off the caller may ask for enough substeps itself. */
    q.substeps = need;
    assert_int_equal(cs_sim_set_params(sim, &q), CS_OK);
    cs_sim_info(sim, &info);
    assert_int_equal(info.substeps, need);
    q.substeps = need - 1;
    assert_int_equal(cs_sim_set_params(sim, &q), CS_E_UNSTABLE);
    cs_sim_destroy(sim);
}

/* A NaN or an infinity put into the state is caught within one frame. */
static void test_nonfinite_detected(void **unused)
{
    (void)unused;
    const float bad[3] = {NAN, INFINITY, -INFINITY};
    for (int which = 0; which < 3; which++) {
        for (int where = 0; where < 3; where++) {
            cs_scene sc;
            cs_params p;
            small_scene(&sc, &p);
            cs_sim *sim = mk(&sc, &p);
            tk_add_rock(sim, 0.0f, 0.0f, sc.height + 0.3f, 0.1f, 300.0f);
            assert_int_equal(cs_sim_step_frames(sim, 2), CS_OK);
            assert_int_equal(cs_sim_sync(sim, CS_SYNC_ALL), CS_OK);
            cs_state *s = &sim->state;
            const int32_t v = 5 * sc.nx + 7; /* a free interior vertex */
            if (where == 0) s->x[v] = bad[which];
            else if (where == 1) s->vz[v] = bad[which];
            else s->rocks[0].x.z = bad[which];
            assert_int_equal(cs_sim_commit(sim), CS_OK);
            cs_info info0;
            cs_sim_info(sim, &info0);
            assert_int_equal(cs_sim_step_frames(sim, 1), CS_E_NONFINITE);
            cs_info info;
            cs_sim_info(sim, &info);
            assert_true(info.step <= info0.step + (uint64_t)info0.substeps);
            assert_true(strlen(cs_sim_error(sim)) > 0);
            cs_sim_destroy(sim);
        }
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_dt_max_matches_formula),
        cmocka_unit_test(test_stiff_raises_substeps_and_stays_bounded),
        cmocka_unit_test(test_unguarded_stiff_cloth_blows_up),
        cmocka_unit_test(test_refusals_change_nothing),
        cmocka_unit_test(test_nonfinite_detected),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
