/* test_surface_motion.c - surface contact in motion: a curtain pushed, energy, overlaps.
 *
 * 1. A kinematic rock (infinite mass) driven at 5 m/s into a curtain pinned along its top edge
 *    pushes it ahead and never through: at every frame the cloth's surface on the rock's line of
 *    motion lies ahead of the rock's centre (the layer it pushes; cloth folding round behind it
 *    may cross that line too), and by the end the rock has carried it forward 1.4 m.
 * 2. With every damping and friction off, a stone dropped on the cloth gains no energy beyond
 *    velocity Verlet's error: for an oscillation of angular frequency w that error is at most
 *    (w dt)^2 / 8 of its energy; the contact's w is sqrt(N k_contact / M) (N the vertices the
 *    guard counts), the bound takes 10 times that of the drop's energy M g h.
 * 3. An overlap (allowed in here by placement_overlap) releases no more than the separation cap
 *    lets through: two stones sunk 5 cm into each other in free fall leave at a relative speed of
 *    at most max_depenetration_speed plus one substep's acceleration a dt (the push stops once they
 *    separate faster than the cap; it may overshoot by one substep), so their kinetic energy is at
 *    most 1/2 mu (v_cap + a dt)^2, mu the reduced mass; without the cap the 6.5 kJ of the overlap
 *    throws them apart at 37 m/s (c_rock takes the rest). The same rock sunk into the cloth: the total energy
 *    (counting the contacts' elastic energy) never rises. */
#include "testkit.h"

static void test_curtain_pushed_never_through(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = sc.ny = 32;
    sc.orientation = CS_VERTICAL;
    sc.pins = CS_PINS_TOP_EDGE;
    p.ground = 0;
    assert_true(p.contact_model == CS_CONTACT_SURFACE && p.tear_strain == 0.0f);
    cs_sim *sim = tk_sim(&sc, &p);
    /* The curtain hangs in the plane y = 0; the rock starts 0.3 m in front, at mid-height, off
     * the grid's lines, and moves along +y. */
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.radius = 0.1f;
    d.kinematic = true;
    d.position[0] = 0.013f, d.position[1] = -0.3f, d.position[2] = sc.height + 0.021f;
    d.velocity[1] = 5.0f;
    uint32_t id;
    assert_int_equal(cs_rock_add(sim, &d, &id), CS_OK);
    cs_info info;
    cs_sim_info(sim, &info);
    const cs_rock_state *r = &sim->state.rocks[0];
    double ahead_min = 1e9;
    int met = 0;
    for (int f = 1; f <= 21; f++) { /* 0.35 s: 1.75 m, 1.45 m past the curtain's plane */
        tk_step(sim, info.substeps);
        double lo = 0, hi = 0;
        if (!tk_surface_on_line(sim, 1, r->x.x, r->x.z, &lo, &hi)) continue; /* slid off to the side */
        /* The layer ahead is the one pushed (others may fold round behind the rock). */
        if (!(hi > r->x.y))
            fail_msg("at %.3f s the curtain is only behind the rock's centre (surface at y %.4f, centre at %.4f)",
                     f / 60.0, hi, (double)r->x.y);
        if (r->x.y > -0.1) {
            met++;
            if (hi - r->x.y < ahead_min) ahead_min = hi - r->x.y;
        }
    }
    print_message("curtain: %d frames pushed, surface at least %.2f mm ahead of the centre (R + offset = %.0f mm), "
                  "rock at y %.3f m, %d substeps\n",
                  met, 1e3 * ahead_min, 1e3 * (d.radius + p.contact_offset), (double)r->x.y, (int)info.substeps);
    assert_true(met >= 10);         /* it did push the curtain for most of the run */
    assert_true(r->x.y > 1.4f);     /* and is far past where the curtain hung */
    assert_true(ahead_min > 0.05);  /* never deeper than half the rock's radius into its layer */
    cs_sim_destroy(sim);
}

static void test_no_energy_gained_without_damping(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = sc.ny = 32;
    p.c_spring = p.drag = p.c_contact = p.c_tangent = p.mu = 0.0f;
    p.ground = 0;
    cs_sim *sim = tk_sim(&sc, &p);
    const float R = 0.1f, h = 0.3f;
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.radius = R;
    d.position[0] = 0.01f, d.position[1] = -0.02f;
    d.position[2] = sc.height + R + p.contact_offset + h;
    assert_int_equal(cs_rock_add(sim, &d, NULL), CS_OK);
    cs_info info;
    cs_sim_info(sim, &info);
    const cs_rock_state *r = &sim->state.rocks[0];
    const double M = r->mass, drop = M * 9.81 * h;
    const double face = (double)sc.size_x / (sc.nx - 1) * sc.size_y / (sc.ny - 1) / 2;
    const double reach = R + p.contact_offset, N = floor(4 * 3.14159265358979323846 * reach * reach / face) + 3;
    const double w = sqrt(N * p.k_contact / M), bound = 10 * (w * info.dt) * (w * info.dt) / 8 * drop;
    cs_energy e;
    assert_int_equal(cs_energy_get(sim, &e), CS_OK);
    const double e0 = e.total;
    double e_max = e0, z_min = r->x.z;
    for (int f = 1; f <= 90; f++) {
        tk_step(sim, info.substeps);
        assert_int_equal(cs_energy_get(sim, &e), CS_OK);
        if (e.total > e_max) e_max = e.total;
        if (r->x.z < z_min) z_min = r->x.z;
    }
    print_message("no damping: %.1f kg from %.1f m (%.2f J), %d substeps, total energy %.4f J -> at most %+.6f J "
                  "(bound %.6f J); the rock came down to %.3f m\n",
                  M, (double)h, drop, (int)info.substeps, e0, e_max - e0, bound, z_min);
    assert_true(z_min < sc.height + R); /* it did press into the cloth */
    assert_true(e_max - e0 <= bound + 1e-6 * fabs(e0));
    cs_sim_destroy(sim);
}

static void test_overlap_released_at_the_cap(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    p.integrator = CS_VELOCITY_VERLET; /* max_depenetration_speed is the contact law's */
    sc.nx = sc.ny = 16;
    p.placement_overlap = 0.2f;
    p.gravity[2] = 0.0f;
    p.ground = 0;
    p.substeps = 400; /* w dt = 0.04 for the rocks' contact (w = sqrt(k_rock) = 1000 rad/s): the
                         one-substep overshoot a dt is small beside the uncapped release */
    const float R = 0.1f, overlap = 0.05f;
    for (int capped = 1; capped >= 0; capped--) {
        p.max_depenetration_speed = capped ? 3.0f : 0.0f;
        cs_sim *sim = tk_sim(&sc, &p);
        /* Two stones 2 m above the cloth, sunk 5 cm into each other. */
        uint32_t a = tk_add_rock(sim, -(R - overlap / 2), 0, sc.height + 2, R, 2500);
        uint32_t b = tk_add_rock(sim, R - overlap / 2, 0, sc.height + 2, R, 2500);
        (void)a, (void)b;
        cs_info info;
        cs_sim_info(sim, &info);
        const cs_rock_state *ra = &sim->state.rocks[0], *rb = &sim->state.rocks[1];
        const double mu = 1 / (ra->inv_mass + rb->inv_mass);
        const double a_max = p.k_rock * overlap; /* K overlap / mu, K = k_rock mu */
        const double U0 = 0.5 * p.k_rock * mu * overlap * overlap;
        tk_step(sim, 30 * info.substeps);
        const double v_rel = rb->v.x - ra->v.x, ke = 0.5 * mu * v_rel * v_rel;
        const double v_bound = p.max_depenetration_speed + a_max * info.dt;
        print_message("overlap of %.0f mm (%.0f J), cap %.0f m/s: apart at %.2f m/s (%.1f J); bound %.2f m/s "
                      "(%.1f J)\n",
                      1e3 * overlap, U0, (double)p.max_depenetration_speed, v_rel, ke, v_bound,
                      0.5 * mu * v_bound * v_bound);
        assert_true(rb->x.x - ra->x.x > 2 * R); /* apart */
        if (capped) assert_true(v_rel > 0 && v_rel <= v_bound);
        else assert_true(v_rel > 5 * (3.0 + v_bound)); /* what the cap (3 m/s) prevents */
        cs_sim_destroy(sim);
    }
    /* A stone sunk 8 cm into the flat cloth (its centre 2 cm above it): the total energy, which
     * counts the overlap's elastic energy, never rises while the cloth is pushed out. */
    p.gravity[2] = -9.81f;
    p.max_depenetration_speed = 3.0f;
    cs_sim *sim = tk_sim(&sc, &p);
    tk_add_rock(sim, 0.01f, 0.02f, sc.height + 0.02f, R, 2500);
    cs_info info;
    cs_sim_info(sim, &info);
    cs_energy e;
    assert_int_equal(cs_energy_get(sim, &e), CS_OK);
    const double e0 = e.total, contact0 = e.contact;
    double e_max = e0;
    for (int f = 1; f <= 30; f++) {
        tk_step(sim, info.substeps);
        assert_int_equal(cs_energy_get(sim, &e), CS_OK);
        if (e.total > e_max) e_max = e.total;
    }
    print_message("stone 8 cm into the cloth: contact energy %.3f J at the start, total %.3f J -> at most %+.6f J\n",
                  contact0, e0, e_max - e0);
    assert_true(contact0 > 0);
    assert_true(e_max <= e0 + 1e-5 * fabs(e0) + 1e-6);
    cs_sim_destroy(sim);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_curtain_pushed_never_through),
        cmocka_unit_test(test_no_energy_gained_without_damping),
        cmocka_unit_test(test_overlap_released_at_the_cap),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
