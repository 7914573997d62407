/* test_physics.c - the SIM_HD force functions of physics.h on hand-computed cases, and the
 * exact symmetries the backends rely on. */
#include "testkit.h"

static cs_phys base(void)
{
    cs_phys p;
    memset(&p, 0, sizeof p);
    p.mass = 0.5f, p.inv_mass = 2.0f;
    p.k_contact = 100, p.c_contact = 1, p.c_tangent = 1, p.mu = 0.5f, p.contact_offset = 0.1f;
    p.k_rock = 1000, p.c_rock = 2, p.mu_rock = 0.4f;
    p.dt = 0.1f, p.hdt = 0.05f;
    p.plastic_f = 1;
    p.max_sep = 3.0e38f;
    return p;
}

#define assert_v3(v, X, Y, Z, tol)                                                                     \
    do {                                                                                               \
        tk_assert_near((v).x, X, tol);                                                                 \
        tk_assert_near((v).y, Y, tol);                                                                 \
        tk_assert_near((v).z, Z, tol);                                                                 \
    } while (0)

static int same_bits(cs_vec3 a, cs_vec3 b) { return memcmp(&a, &b, sizeof a) == 0; }

static void test_spring_force(void **unused)
{
    (void)unused;
    float len;
    const cs_vec3 o = cs_v3(0, 0, 0);
    /* Stretched by 1 m at k = 10: 10 N toward the other end. */
    cs_vec3 f = cs_spring_force(o, o, cs_v3(2, 0, 0), o, 1, 10, 0, &len);
    assert_v3(f, 10, 0, 0, 1e-6);
    tk_assert_near(len, 2, 0);
    /* Compressed: pushes away. */
    f = cs_spring_force(o, o, cs_v3(0, 0.5f, 0), o, 1, 10, 0, &len);
    assert_v3(f, 0, -5, 0, 1e-6);
    /* Damping sees only the velocity along the spring: (3, 4, 0) . x = 3, c = 0.5. */
    f = cs_spring_force(o, o, cs_v3(2, 0, 0), cs_v3(3, 4, 0), 1, 10, 0.5f, &len);
    assert_v3(f, 11.5, 0, 0, 1e-6);
    /* Torn, or shorter than 1e-9 m: nothing. */
    f = cs_spring_force(o, o, cs_v3(2, 0, 0), cs_v3(3, 4, 0), CS_TORN, 10, 0.5f, &len);
    assert_true(f.x == 0 && f.y == 0 && f.z == 0);
    f = cs_spring_force(o, o, cs_v3(1e-10f, 0, 0), cs_v3(3, 4, 0), 1, 10, 0.5f, &len);
    assert_true(f.x == 0 && f.y == 0 && f.z == 0);
}

static uint32_t seed = 99;
static float rnd(void)
{
    seed = seed * 1664525u + 1013904223u;
    return (float)(seed >> 8) / 16777216.0f * 2.0f - 1.0f;
}
static cs_vec3 rnd3(float s) { return cs_v3(s * rnd(), s * rnd(), s * rnd()); }

/* Evaluated from either end, a spring's force is exactly negated - bit for bit, signed zeros
 * included - which lets a backend evaluate each spring once and match one that evaluates it from
 * both ends. Rock-rock contact is exactly opposite in value (a zero force may come out as +0 from
 * both sides, since (+0) + (-0) = +0; nothing relies on its bits, each side being computed in its
 * own rock's sum). */
static void test_exact_antisymmetry(void **unused)
{
    (void)unused;
    const cs_phys p = base();
    for (int k = 0; k < 10000; k++) {
        const cs_vec3 xi = rnd3(1), xj = rnd3(1), vi = rnd3(3), vj = rnd3(3);
        const float L0 = 0.5f + rnd(), kk = 100 * (1 + rnd()), c = 1 + rnd();
        float l1, l2;
        const cs_vec3 a = cs_spring_force(xi, vi, xj, vj, L0, kk, c, &l1);
        const cs_vec3 b = cs_spring_force(xj, vj, xi, vi, L0, kk, c, &l2);
        assert_true(same_bits(a, cs_neg(b)));
        assert_true(l1 == l2);

        cs_rock_state ra, rb;
        memset(&ra, 0, sizeof ra);
        memset(&rb, 0, sizeof rb);
        ra.x = rnd3(0.5f), rb.x = rnd3(0.5f), ra.v = rnd3(2), rb.v = rnd3(2), ra.w = rnd3(5), rb.w = rnd3(5);
        ra.radius = 0.3f + 0.2f * rnd(), rb.radius = 0.3f + 0.2f * rnd();
        cs_vec3 Fa = {0, 0, 0}, Ta, Fb = {0, 0, 0}, Tb;
        const int ca = cs_rock_pair_contact(&ra, &rb, &p, &Fa, &Ta), cb = cs_rock_pair_contact(&rb, &ra, &p, &Fb, &Tb);
        assert_int_equal(ca, cb);
        if (ca) assert_true(Fa.x == -Fb.x && Fa.y == -Fb.y && Fa.z == -Fb.z);
    }
}

static void test_strain_update(void **unused)
{
    (void)unused;
    cs_phys p = base();
    p.plastic_yield = 0.1f, p.tear_strain = 0.5f;
    tk_assert_near(cs_strain_update(1.2f, 1.0f, &p), 1.2, 1e-7);   /* yields: L0 <- |d| */
    assert_true(cs_strain_update(1.6f, 1.0f, &p) == CS_TORN);        /* tears */
    assert_true(cs_strain_update(1.05f, 1.0f, &p) == 1.0f);          /* elastic */
    assert_true(cs_strain_update(0.5f, 1.0f, &p) == 1.0f);           /* compression never yields */
    assert_true(cs_strain_update(3.0f, CS_TORN, &p) == CS_TORN);     /* torn stays torn */
    p.plastic_f = 0.25f;                                             /* finite rate: a quarter */
    tk_assert_near(cs_strain_update(1.2f, 1.0f, &p), 1.05, 1e-7);
    p.plastic_yield = 0, p.tear_strain = 0;                          /* both off */
    assert_true(cs_strain_update(5.0f, 1.0f, &p) == 1.0f);
}

static void test_air_and_gravity(void **unused)
{
    (void)unused;
    cs_phys p = base();
    p.gravity = cs_v3(0, 0, -10), p.drag = 2, p.wind = cs_v3(0, 1, 0);
    /* m (g - drag (v - wind)) with v = (1, 1, 0): 0.5 ((0, 0, -10) - 2 (1, 0, 0)). */
    assert_v3(cs_air_gravity(cs_v3(1, 1, 0), &p), -1, 0, -5, 1e-6);
}

static void test_contact_law(void **unused)
{
    (void)unused;
    const cs_vec3 up = cs_v3(0, 0, 1), o = cs_v3(0, 0, 0);
    /* At rest, 1 cm in, k = 100: 1 N along the normal. */
    assert_v3(cs_contact_law(up, 0.01f, o, 100, 1, 0.5f, 1, CS_FRICTION_COULOMB_VISCOUS, o, 1e30f), 0, 0, 1, 1e-6);
    /* Separating fast: k delta - c vn < 0, and contact never pulls. */
    cs_vec3 F = cs_contact_law(up, 0.01f, cs_v3(0, 0, 10), 100, 1, 0.5f, 1, CS_FRICTION_COULOMB_VISCOUS, o, 1e30f);
    assert_true(F.x == 0 && F.y == 0 && F.z == 0);
    /* Sliding at 3 m/s with fn = 10: viscous 1 x 3 = 3 N is below mu fn = 5 N... */
    F = cs_contact_law(up, 0.1f, cs_v3(3, 0, 0), 100, 1, 0.5f, 1, CS_FRICTION_COULOMB_VISCOUS, o, 1e30f);
    assert_v3(F, -3, 0, 10, 1e-5);
    /* ...and capped at mu fn when c_tangent is large. */
    F = cs_contact_law(up, 0.1f, cs_v3(0, -3, 0), 100, 1, 0.5f, 10, CS_FRICTION_COULOMB_VISCOUS, o, 1e30f);
    assert_v3(F, 0, 5, 10, 1e-5);
    /* Resultant (seed 003): Ro = (4, 0, -10) pressed in, mu |Ron| = 5 cancels all 4 N of Rot. */
    F = cs_contact_law(up, 0.1f, o, 100, 0, 0.5f, 1, CS_FRICTION_RESULTANT, cs_v3(4, 0, -10), 1e30f);
    assert_v3(F, -4, 0, 10, 1e-5);
    /* Rot = 8 N is more than mu |Ron|: only 5 N cancelled. */
    F = cs_contact_law(up, 0.1f, o, 100, 0, 0.5f, 1, CS_FRICTION_RESULTANT, cs_v3(8, 0, -10), 1e30f);
    assert_v3(F, -5, 0, 10, 1e-5);
    /* Ro pulling away from the surface: no friction. */
    F = cs_contact_law(up, 0.1f, o, 100, 0, 0.5f, 1, CS_FRICTION_RESULTANT, cs_v3(4, 0, 10), 1e30f);
    assert_v3(F, 0, 0, 10, 1e-5);
    /* max_depenetration_speed: separating at 2 m/s, a cap of 2 still pushes (k delta - c vn =
     * 10 - 2), a cap just below it does not push at all, nor does friction act. */
    F = cs_contact_law(up, 0.1f, cs_v3(1, 0, 2), 100, 1, 0.5f, 1, CS_FRICTION_COULOMB_VISCOUS, o, 2.0f);
    assert_v3(F, -1, 0, 8, 1e-5);
    F = cs_contact_law(up, 0.1f, cs_v3(1, 0, 2), 100, 1, 0.5f, 1, CS_FRICTION_COULOMB_VISCOUS, o, 1.999f);
    assert_true(F.x == 0 && F.y == 0 && F.z == 0);
    /* Approaching is never capped. */
    F = cs_contact_law(up, 0.1f, cs_v3(0, 0, -2), 100, 1, 0.5f, 1, CS_FRICTION_COULOMB_VISCOUS, o, 0.5f);
    assert_v3(F, 0, 0, 12, 1e-5);
}

static void test_vertex_rock_and_ground_contact(void **unused)
{
    (void)unused;
    const cs_phys p = base();
    cs_rock_state r;
    memset(&r, 0, sizeof r);
    r.radius = 1;
    cs_vec3 F, arm;
    /* 1.05 m from the centre: 5 cm into the 10 cm offset, 100 N/m -> 5 N outward. */
    assert_true(cs_vertex_rock_contact(cs_v3(0, 0, 1.05f), cs_v3(0, 0, 0), cs_v3(0, 0, 0), &r, &p, &F, &arm));
    assert_v3(F, 0, 0, 5, 1e-4);
    assert_v3(arm, 0, 0, 1.05, 1e-6);
    assert_false(cs_vertex_rock_contact(cs_v3(0, 0, 1.2f), cs_v3(0, 0, 0), cs_v3(0, 0, 0), &r, &p, &F, &arm));
    assert_false(cs_vertex_rock_contact(cs_v3(0, 0, 0), cs_v3(0, 0, 0), cs_v3(0, 0, 0), &r, &p, &F, &arm));
    /* A rock spinning about +z drags a resting vertex on its +x side toward +y. */
    r.w = cs_v3(0, 0, 2);
    assert_true(cs_vertex_rock_contact(cs_v3(1.05f, 0, 0), cs_v3(0, 0, 0), cs_v3(0, 0, 0), &r, &p, &F, &arm));
    assert_true(F.y > 0);
    tk_assert_near(F.x, 5, 1e-4);
    tk_assert_near(F.y, 2.1, 1e-4); /* viscous: c_tangent |vt| = 2.1 < mu fn = 2.5 */
    /* The ground (on, at z = 0) pushes a vertex 4 cm into the 10 cm offset up by 6 N... */
    cs_phys g = p;
    g.ground = 1;
    assert_true(cs_vertex_ground_contact(cs_v3(0, 0, 0.04f), cs_v3(0, 0, 0), cs_v3(0, 0, 0), &g, &F));
    assert_v3(F, 0, 0, 6, 1e-4);
    g.ground = 0; /* ...and nothing when off. */
    assert_false(cs_vertex_ground_contact(cs_v3(0, 0, 0.04f), cs_v3(0, 0, 0), cs_v3(0, 0, 0), &g, &F));
}

/* A rock rolling without slipping on the ground (v = w x R up... contact point at rest) feels no
 * friction; one sliding without spin is slowed and spun up in the rolling direction. */
static void test_rock_ground_torque_sign(void **unused)
{
    (void)unused;
    cs_phys p = base();
    p.ground = 1;
    cs_rock_state r;
    memset(&r, 0, sizeof r);
    r.radius = 0.5f;
    r.mass = 1.0f, r.inv_mass = 1.0f; /* rock contacts scale with the reduced mass: 1 kg */
    r.x = cs_v3(0, 0, 0.49f);
    r.v = cs_v3(1, 0, 0);
    cs_vec3 F, T;
    assert_true(cs_rock_ground_contact(&r, &p, &F, &T));
    assert_true(F.x < 0 && F.z > 0);
    assert_true(T.y > 0); /* spins up w_y > 0: rolling along +x */
    r.w = cs_v3(0, 2, 0);  /* v = w R: the contact point is at rest */
    assert_true(cs_rock_ground_contact(&r, &p, &F, &T));
    tk_assert_near(F.x, 0, 1e-6);
}

/* The chunk tree's shape is part of the contract (GPU block reductions use it): pairs 128 apart
 * first. 1e8 + 1 rounds to 1e8 in float, so the tree gives 0 where a running sum gives 1. */
static void test_tree_sum_shape(void **unused)
{
    (void)unused;
    float buf[CS_CHUNK];
    for (int i = 0; i < CS_CHUNK; i++) buf[i] = (float)(i + 1);
    tk_assert_near(cs_tree_sum(buf), 32896, 0);
    memset(buf, 0, sizeof buf);
    buf[0] = 1e8f, buf[128] = 1, buf[1] = -1e8f;
    assert_true(cs_tree_sum(buf) == 0.0f);
}

static void test_rock_force_sums_partials_then_gravity(void **unused)
{
    (void)unused;
    cs_phys p = base();
    p.gravity = cs_v3(0, 0, -10);
    cs_rock_state r;
    memset(&r, 0, sizeof r);
    r.radius = 0.1f, r.mass = 2, r.x = cs_v3(0, 0, 5);
    const float partials[12] = {1, 2, 3, 4, 5, 6, 10, 20, 30, 40, 50, 60};
    cs_vec3 F, T;
    cs_rock_force(&r, 1, 0, partials, 2, &p, &F, &T);
    assert_v3(F, 11, 22, 33 - 20, 1e-6);
    assert_v3(T, 44, 55, 66, 1e-6);
}

/* The chunk partials are summed in groups of CS_CHUNK_GROUP, then the groups: with 1 in chunk 0
 * and +-1e8 in the next group, the groups give 1 + (1e8 - 1e8) = 1 where one running sum would
 * give (1 + 1e8) - 1e8 = 0 (1e8 + 1 rounds to 1e8 in float). */
static void test_rock_force_groups_chunks(void **unused)
{
    (void)unused;
    cs_phys p = base();
    cs_rock_state r;
    memset(&r, 0, sizeof r);
    r.radius = 0.1f, r.x = cs_v3(0, 0, 5);
    enum { NCH = CS_CHUNK_GROUP + 2 };
    float partials[NCH * 6];
    memset(partials, 0, sizeof partials);
    partials[0] = 1.0f;
    partials[CS_CHUNK_GROUP * 6] = 1e8f;
    partials[(CS_CHUNK_GROUP + 1) * 6] = -1e8f;
    cs_vec3 F, T;
    cs_rock_force(&r, 1, 0, partials, NCH, &p, &F, &T);
    assert_true(F.x == 1.0f);
}

static void test_quaternion_and_grab(void **unused)
{
    (void)unused;
    float q[4] = {0, 0, 0, 1};
    for (int i = 0; i < 1000; i++) cs_quat_integrate(q, cs_v3(0, 0, 1), 1e-3f);
    /* 1 rad about z. */
    tk_assert_near(q[2], sin(0.5), 1e-3);
    tk_assert_near(q[3], cos(0.5), 1e-3);
    tk_assert_near(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3], 1, 1e-6);
    cs_phys p = base();
    p.grab_speed = 2; /* at most 0.2 m per 0.1 s step */
    assert_v3(cs_grab_velocity(cs_v3(0, 0, 0), cs_v3(0, 3, 4), &p), 0, 1.2, 1.6, 1e-6);
    assert_v3(cs_grab_velocity(cs_v3(0, 0, 0), cs_v3(0.05f, 0, 0), &p), 0.5, 0, 0, 1e-6);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_spring_force),
        cmocka_unit_test(test_exact_antisymmetry),
        cmocka_unit_test(test_strain_update),
        cmocka_unit_test(test_air_and_gravity),
        cmocka_unit_test(test_contact_law),
        cmocka_unit_test(test_vertex_rock_and_ground_contact),
        cmocka_unit_test(test_rock_ground_torque_sign),
        cmocka_unit_test(test_tree_sum_shape),
        cmocka_unit_test(test_rock_force_sums_partials_then_gravity),
        cmocka_unit_test(test_rock_force_groups_chunks),
        cmocka_unit_test(test_quaternion_and_grab),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
