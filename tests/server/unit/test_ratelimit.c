/* test_ratelimit.c - token buckets (core/ratelimit.c) on a clock the test sets: a burst, then
 * the rate; the wait a refused request is told; clients apart; no limit at rate 0. */
#include "core/ratelimit.h"
#include "unitkit.h"

static void test_burst_then_rate(void **unused)
{
    (void)unused;
    ratelimit *rl = ratelimit_new(2, 3); /* 2 a second after a burst of 3 */
    const unsigned char a[4] = {127, 0, 0, 1};
    for (int k = 0; k < 3; k++) assert_int_equal(ratelimit_take(rl, a, 4, 100.0), 0);
    assert_int_equal(ratelimit_take(rl, a, 4, 100.0), 1);  /* 1 token at 2/s: half a second, told as 1 s */
    assert_int_equal(ratelimit_take(rl, a, 4, 100.5), 0);  /* one back after 0.5 s */
    assert_int_equal(ratelimit_take(rl, a, 4, 100.5), 1);
    assert_int_equal(ratelimit_take(rl, a, 4, 110.0), 0);  /* a long rest refills to the burst, no more */
    assert_int_equal(ratelimit_take(rl, a, 4, 110.0), 0);
    assert_int_equal(ratelimit_take(rl, a, 4, 110.0), 0);
    assert_int_equal(ratelimit_take(rl, a, 4, 110.0), 1);
    ratelimit_free(rl);
}

static void test_slow_rate_wait(void **unused)
{
    (void)unused;
    ratelimit *rl = ratelimit_new(0.25, 1); /* one every 4 s */
    const unsigned char a[4] = {10, 0, 0, 1};
    assert_int_equal(ratelimit_take(rl, a, 4, 0.0), 0);
    assert_int_equal(ratelimit_take(rl, a, 4, 0.0), 4);
    assert_int_equal(ratelimit_take(rl, a, 4, 1.0), 3); /* 0.25 of a token back: 0.75 / 0.25 = 3 s */
    ratelimit_free(rl);
}

static void test_clients_apart(void **unused)
{
    (void)unused;
    ratelimit *rl = ratelimit_new(1, 1);
    const unsigned char a[4] = {192, 168, 0, 1}, b[4] = {192, 168, 0, 2}, v6[16] = {[15] = 1};
    assert_int_equal(ratelimit_take(rl, a, 4, 5.0), 0);
    assert_int_equal(ratelimit_take(rl, a, 4, 5.0), 1);
    assert_int_equal(ratelimit_take(rl, b, 4, 5.0), 0);
    assert_int_equal(ratelimit_take(rl, v6, 16, 5.0), 0);
    assert_int_equal(ratelimit_take(rl, v6, 16, 5.0), 1);
    ratelimit_free(rl);
}

static void test_no_limit(void **unused)
{
    (void)unused;
    ratelimit *rl = ratelimit_new(0, 1);
    const unsigned char a[4] = {1, 2, 3, 4};
    for (int k = 0; k < 1000; k++) assert_int_equal(ratelimit_take(rl, a, 4, 0.0), 0);
    ratelimit_free(rl);
    assert_int_equal(ratelimit_take(NULL, a, 4, 0.0), 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_burst_then_rate),
        cmocka_unit_test(test_slow_rate_wait),
        cmocka_unit_test(test_clients_apart),
        cmocka_unit_test(test_no_limit),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
