/* test_backend.c - choosing a backend by name. */
#include "testkit.h"

static void test_pick_by_name(void **unused)
{
    (void)unused;
    const cs_backend *b = NULL;
    char note[160];
    assert_int_equal(cs_backend_pick("cpu", &b, note, sizeof note), CS_OK);
    assert_ptr_equal(b, &cs_backend_cpu);
    assert_int_equal(cs_backend_pick("bogus", &b, note, sizeof note), CS_E_INVALID);
    assert_non_null(strstr(note, "bogus"));
    /* auto takes CUDA only when this build has it and a device answers; else the CPU, saying why. */
    assert_int_equal(cs_backend_pick("auto", &b, note, sizeof note), CS_OK);
    char why[128];
    const cs_backend *cuda = cs_backend_cuda();
    if (cuda && cuda->available(why, sizeof why)) {
        assert_ptr_equal(b, cuda);
    } else {
        assert_ptr_equal(b, &cs_backend_cpu);
        assert_true(strlen(note) > strlen("auto: "));
        assert_int_equal(cs_backend_pick("cuda", &b, note, sizeof note), CS_E_BACKEND);
        assert_true(strlen(note) > strlen("cuda: "));
    }
    assert_int_equal(cs_backend_pick(NULL, &b, note, sizeof note), CS_OK);
}

static void test_sim_reports_its_backend(void **unused)
{
    (void)unused;
    cs_sim *sim = NULL;
    char err[200];
    assert_int_equal(cs_sim_create(NULL, NULL, "auto", &sim, err, sizeof err), CS_OK);
    assert_true(strlen(cs_sim_backend_note(sim)) > 0);
    assert_true(strcmp(cs_sim_backend(sim), "cpu") == 0 || strcmp(cs_sim_backend(sim), "cuda") == 0);
    assert_true(strlen(cs_sim_device(sim)) > 0);
    cs_sim_destroy(sim);
    if (!cs_backend_cuda()) {
        assert_int_equal(cs_sim_create(NULL, NULL, "cuda", &sim, err, sizeof err), CS_E_BACKEND);
        assert_null(sim);
        assert_non_null(strstr(err, "CUDA"));
    }
}

/* A backend without CS_CAP_SURFACE_CONTACT (the CUDA backend until surface contact is ported to
 * it) does not cover contact_model surface; the CPU backend covers both models. */
static void test_capabilities(void **unused)
{
    (void)unused;
    cs_params p;
    cs_params_default(&p);
    p.integrator = CS_VELOCITY_VERLET; /* the contact capability alone (implicit_euler is CS_CAP_IMPLICIT) */
    char why[200];
    cs_backend bare = cs_backend_cpu;
    bare.name = "bare";
    bare.caps = 0;
    assert_int_equal(p.contact_model, CS_CONTACT_SURFACE);
    assert_false(cs_backend_covers(&bare, &p, why, sizeof why));
    assert_non_null(strstr(why, "contact_model surface"));
    assert_true(cs_backend_covers(&cs_backend_cpu, &p, why, sizeof why));
    p.contact_model = CS_CONTACT_VERTEX;
    assert_true(cs_backend_covers(&bare, &p, why, sizeof why));
    const cs_backend *cuda = cs_backend_cuda();
    if (cuda && !(cuda->caps & CS_CAP_SURFACE_CONTACT) && cuda->available(why, sizeof why)) {
        /* auto then runs the defaults on the CPU, and says why; cuda refuses them */
        cs_sim *sim = NULL;
        char err[200];
        assert_int_equal(cs_sim_create(NULL, NULL, "auto", &sim, err, sizeof err), CS_OK);
        assert_string_equal(cs_sim_backend(sim), "cpu");
        assert_non_null(strstr(cs_sim_backend_note(sim), "surface"));
        cs_sim_destroy(sim);
        assert_int_equal(cs_sim_create(NULL, NULL, "cuda", &sim, err, sizeof err), CS_E_BACKEND);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_pick_by_name),
        cmocka_unit_test(test_sim_reports_its_backend),
        cmocka_unit_test(test_capabilities),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
