/* test_status.c - status names and messages, and how a refusal is recorded. */
#include "testkit.h"

static const cs_status all[] = {CS_OK,         CS_E_INVALID, CS_E_RANGE,  CS_E_NOT_FOUND,
                                CS_E_UNSTABLE, CS_E_LIMIT,   CS_E_NOMEM,  CS_E_NONFINITE,
                                CS_E_FORMAT,   CS_E_VERSION, CS_E_BACKEND, CS_E_DEVICE};

static void test_every_status_has_a_distinct_name_and_a_message(void **unused)
{
    (void)unused;
    const size_t n = sizeof all / sizeof all[0];
    for (size_t i = 0; i < n; i++) {
        assert_string_not_equal(cs_status_name(all[i]), "unknown");
        assert_true(strlen(cs_status_message(all[i])) > 5);
        for (size_t k = 0; k < i; k++) assert_string_not_equal(cs_status_name(all[i]), cs_status_name(all[k]));
    }
    assert_string_equal(cs_status_name(CS_OK), "ok");
    assert_string_equal(cs_status_name(CS_E_UNSTABLE), "unstable");
    assert_string_equal(cs_status_name((cs_status)-99), "unknown");
    assert_string_equal(cs_status_message((cs_status)42), "unknown status");
}

static void test_refusal_is_explained_and_success_clears_it(void **unused)
{
    (void)unused;
    cs_sim *sim = tk_sim(NULL, NULL);
    assert_string_equal(cs_sim_error(sim), "");
    assert_string_equal(cs_sim_error_param(sim), "");
    assert_int_equal(cs_sim_step(sim, -1), CS_E_RANGE);
    assert_non_null(strstr(cs_sim_error(sim), "substeps"));
    assert_string_equal(cs_sim_error_param(sim), "substeps");
    assert_int_equal(cs_sim_step(sim, 1), CS_OK);
    assert_string_equal(cs_sim_error(sim), "");
    assert_string_equal(cs_sim_error_param(sim), "");
    cs_sim_destroy(sim);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_every_status_has_a_distinct_name_and_a_message),
        cmocka_unit_test(test_refusal_is_explained_and_success_clears_it),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
