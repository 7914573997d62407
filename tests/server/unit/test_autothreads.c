/* test_autothreads.c - the automatic count of CPU threads (sim/autothreads.c) on windows of busy
 * time the test writes: one thread while one keeps up, one more while the scenes barely keep up,
 * one back once the measured cost says the others suffice for a few windows in a row, every
 * thread for a step. */
#include "sim/autothreads.h"
#include "unitkit.h"

/* A window of 1 s of wall time from t in which `busy` s went to stepping `work` vertex-substeps;
 * the count for the next one. */
static int window(autothreads *a, double *t, double busy, double work, int greedy)
{
    autothreads_ran(a, busy, work);
    *t += AUTOTHREADS_WINDOW;
    return autothreads_turn(a, *t, greedy);
}

/* A count of at most `most` threads, started (its first turn) at time 0; returns that time. */
static double begin(autothreads *a, int most)
{
    autothreads_init(a, most);
    autothreads_turn(a, 0, 0);
    return 0;
}

/* Quiet windows (busy, work) in a row while the count stays `was`: AUTOTHREADS_CALM - 1 of them,
 * then the last one's count. */
static int calm_windows(autothreads *a, double *t, double busy, double work, int was)
{
    for (int k = 1; k < AUTOTHREADS_CALM; k++) assert_int_equal(window(a, t, busy, work, 0), was);
    return window(a, t, busy, work, 0);
}

static void test_one_thread_while_it_keeps_up(void **unused)
{
    (void)unused;
    autothreads a;
    autothreads_init(&a, 4);
    double t = 100;
    assert_int_equal(autothreads_turn(&a, t, 0), 1);
    for (int k = 0; k < 5; k++) assert_int_equal(window(&a, &t, 0.6, 1e6, 0), 1); /* 60 % busy */
    assert_int_equal(autothreads_turn(&a, t + 0.5, 0), 1); /* mid-window: no decision */
}

static void test_more_while_behind_then_back(void **unused)
{
    (void)unused;
    autothreads a;
    double t = begin(&a, 4);
    assert_int_equal(window(&a, &t, 0.95, 1e6, 0), 2); /* 95 % busy on one: a second */
    /* Two threads take 0.92 s for the work one thread did in 0.95 s: a poor machine. Still busy:
     * a third. */
    assert_int_equal(window(&a, &t, 0.92, 1e6, 0), 3);
    /* On three, 0.5 s for the same work: on two it would take 0.92 (measured): stay. */
    assert_int_equal(window(&a, &t, 0.5, 1e6, 0), 3);
    /* The scene quietens: half the work. On two it was 0.92 s per 1e6, so 0.46: below 0.75, one
     * back once AUTOTHREADS_CALM windows in a row say so (a lull between stones does not). */
    assert_int_equal(calm_windows(&a, &t, 0.25, 5e5, 3), 2);
    /* On two, 0.45 s for 5e5: with its first window two cost 0.91 us a unit against 0.95 on one,
     * short of AUTOTHREADS_GAIN while one keeps up (0.47 busy): one back at once. */
    assert_int_equal(window(&a, &t, 0.45, 5e5, 0), 1);
    assert_int_equal(window(&a, &t, 0.5, 5e5, 0), 1);
}

static void test_unmeasured_count_assumed_full_speedup(void **unused)
{
    (void)unused;
    autothreads a;
    autothreads_init(&a, 2);
    double t = 0;
    autothreads_turn(&a, t, 1); /* a step: every thread at once, nothing measured on one */
    assert_int_equal(a.now, 2);
    /* On two, 40 % busy: on one it could be 80 % (two threads twice as fast), over 75 %: keep two. */
    assert_int_equal(window(&a, &t, 0.4, 1e6, 0), 2);
    /* 25 %: 50 % on one at worst: one back. */
    assert_int_equal(calm_windows(&a, &t, 0.25, 1e6, 2), 1);
}

/* A thread that buys nothing is given back, though the scenes stay behind: on two threads a unit
 * of work costs more than on one (the barriers of a small cloth on a busy machine). The count is
 * tried again after AUTOTHREADS_PROBE windows, and kept when it then pays. */
static void test_a_thread_that_buys_nothing_goes_back(void **unused)
{
    (void)unused;
    autothreads a;
    double t = begin(&a, 2);
    assert_int_equal(window(&a, &t, 0.98, 1e6, 0), 2);  /* behind on one (0.98 us a unit): a second */
    assert_int_equal(window(&a, &t, 1.0, 8.2e5, 0), 1); /* 1.22 us a unit on two: back to one */
    /* still behind on one, but two was measured slower: stay, until the count is tried again */
    int k = 0;
    while (window(&a, &t, 0.98, 1e6, 0) == 1) {
        k++;
        assert_true(k < AUTOTHREADS_PROBE);
    }
    assert_int_equal(k, AUTOTHREADS_PROBE - 2);
    /* now two pays (0.6 us a unit, averaged with the old 1.22: 0.91, under 0.95 x 0.98): kept */
    assert_int_equal(window(&a, &t, 0.96, 1.6e6, 0), 2);
    assert_int_equal(window(&a, &t, 0.96, 1.6e6, 0), 2);
}

/* While the scenes would fall behind without it, a thread that buys a little is kept: on one
 * thread 0.99 us a unit and busy, on two 0.971 us (2 % less, short of AUTOTHREADS_GAIN) and still
 * busy. While one thread would keep up, the same small gain does not hold a core. */
static void test_a_small_gain_counts_only_while_behind(void **unused)
{
    (void)unused;
    autothreads a;
    double t = begin(&a, 2);
    assert_int_equal(window(&a, &t, 0.99, 1e6, 0), 2); /* behind on one */
    for (int k = 0; k < 5; k++) assert_int_equal(window(&a, &t, 1.0, 1.03e6, 0), 2);
    t = begin(&a, 2);
    assert_int_equal(window(&a, &t, 0.93, 1e6, 0), 2); /* 93 % busy on one: a second */
    /* on two 0.911 us a unit (2 % less), 80 % busy: on one 82 %, keeping up: back to one */
    assert_int_equal(window(&a, &t, 0.8, 8.78e5, 0), 1);
}

/* A lull of two windows keeps the thread: stones dropped every 3 s onto a cloth that needs two
 * threads while they land (the daemon's 128 x 128 scene on the build machine). */
static void test_a_lull_keeps_the_thread(void **unused)
{
    (void)unused;
    autothreads a;
    double t = begin(&a, 2);
    assert_int_equal(window(&a, &t, 0.95, 1e6, 0), 2);
    for (int k = 0; k < 4; k++) {
        for (int q = 0; q < 2; q++) assert_int_equal(window(&a, &t, 0.3, 6e5, 0), 2); /* a lull */
        assert_int_equal(window(&a, &t, 0.95, 1.9e6, 0), 2); /* a stone lands */
    }
}

/* A count's cost is its windows summed, the older ones fading: one window that cost far more a
 * unit (a stone's landing does work its units do not count) does not send back a thread that
 * paid in the windows before it, where the last window alone, or half of it, would. */
static void test_one_costly_window_does_not_decide(void **unused)
{
    (void)unused;
    autothreads a;
    double t = begin(&a, 2);
    assert_int_equal(window(&a, &t, 0.98, 1e6, 0), 2); /* behind on one, 0.98 us a unit */
    for (int k = 0; k < 5; k++) assert_int_equal(window(&a, &t, 0.95, 1.3e6, 0), 2); /* 0.73 us on two */
    /* 2.5 us a unit for one window: (0.73 + 2.5) / 2 would pass 0.95 x 0.98; the sums give 0.87 */
    assert_int_equal(window(&a, &t, 0.99, 4e5, 0), 2);
    assert_true(autothreads_cost(&a, 2) < AUTOTHREADS_GAIN * autothreads_cost(&a, 1));
    /* two that cost more a unit than one, window after window, still send it back */
    int k = 0;
    while (window(&a, &t, 0.99, 8e5, 0) == 2) {
        k++;
        assert_true(k < 10);
    }
}

static void test_greedy_takes_every_thread(void **unused)
{
    (void)unused;
    autothreads a;
    double t = begin(&a, 8);
    assert_int_equal(autothreads_turn(&a, 0.125, 1), 8); /* at once, not at the window's end */
    t = 0.125;
    assert_int_equal(window(&a, &t, 1.0, 1e6, 1), 8);
    /* no more steps: down one at a time, never below what keeps up */
    assert_int_equal(calm_windows(&a, &t, 0.05, 1e6, 8), 7);
}

static void test_idle_and_bounds(void **unused)
{
    (void)unused;
    autothreads a;
    double t = begin(&a, 1);
    assert_int_equal(window(&a, &t, 1.0, 1e6, 0), 1); /* one core: nowhere to go */
    autothreads_init(&a, 100000);
    assert_int_equal(a.most, AUTOTHREADS_MOST);
    autothreads_init(&a, 0);
    assert_int_equal(a.most, 1);
    autothreads_init(&a, 3);
    t = 0;
    autothreads_turn(&a, t, 1);
    assert_int_equal(window(&a, &t, 0, 0, 0), 3); /* paused: no work, no decision */
    assert_int_equal(autothreads_turn(&a, t - 5, 0), 3); /* a clock that went back restarts the window */
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_one_thread_while_it_keeps_up),
        cmocka_unit_test(test_more_while_behind_then_back),
        cmocka_unit_test(test_unmeasured_count_assumed_full_speedup),
        cmocka_unit_test(test_a_thread_that_buys_nothing_goes_back),
        cmocka_unit_test(test_a_small_gain_counts_only_while_behind),
        cmocka_unit_test(test_a_lull_keeps_the_thread),
        cmocka_unit_test(test_one_costly_window_does_not_decide),
        cmocka_unit_test(test_greedy_takes_every_thread),
        cmocka_unit_test(test_idle_and_bounds),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
