/* test_statefile.c - the state file's layout (core/statefile.c), as PROTOCOL.md gives it: format
 * 3's trailer with the run state and the daemon-loop settings; formats 2 and 1 still read; a file
 * clothd 0.1.0 wrote (tests/data) read with the settings its snapshot holds; the refusals. */
#include "core/statefile.h"
#include "unitkit.h"

static unsigned char *snapshot(size_t *len)
{
    cs_sim *sim = uk_engine(4, 3);
    *len = cs_snapshot_size(sim);
    unsigned char *b = malloc(*len + 512);
    assert_int_equal(cs_snapshot_save(sim, b, *len, len), CS_OK);
    cs_sim_destroy(sim);
    return b;
}

static statefile_error parse(unsigned char *snap, size_t len, const char *trailer, statefile *out, loop_settings *loop,
                             char *why)
{
    memcpy(snap + len, trailer, strlen(trailer));
    return statefile_parse(snap, len + strlen(trailer), out, loop, why, 300);
}

static void test_trailer(void **unused)
{
    (void)unused;
    loop_settings loop = uk_defaults().scene.loop;
    loop.time_scale = 0.5f, loop.seed = 9;
    size_t len;
    char *t = statefile_trailer(1, &loop, &len);
    assert_int_equal(len, strlen(t));
    uk_assert_json(t, "{\"clothd_state\":3,\"run\":\"paused\",\"params\":{\"time_scale\":0.5,\"max_speed\":false,"
                      "\"auto_drop_interval\":3.0,\"auto_drop_max\":8,\"seed\":9,\"checkpoint_interval\":60}}");
    free(t);
    size_t sl;
    unsigned char *snap = snapshot(&sl);
    statefile out;
    char why[300];
    loop_settings back = uk_defaults().scene.loop;
    t = statefile_trailer(0, &loop, &len);
    assert_int_equal(parse(snap, sl, t, &out, &back, why), STATEFILE_OK);
    assert_int_equal(out.format, 3);
    assert_false(out.paused);
    assert_int_equal(out.snapshot_len, sl);
    assert_int_equal(out.loop_given, 6);
    assert_memory_equal(&back, &loop, sizeof loop);
    statefile_free(&out);
    free(t);
    free(snap);
}

static void test_older_formats(void **unused)
{
    (void)unused;
    size_t sl;
    unsigned char *snap = snapshot(&sl);
    statefile out;
    char why[300];
    loop_settings loop = uk_defaults().scene.loop, before = loop;
    assert_int_equal(statefile_parse(snap, sl, &out, &loop, why, sizeof why), STATEFILE_OK);
    assert_int_equal(out.format, 1);
    assert_false(out.paused); /* format 1 kept no run state: it resumes running */
    assert_int_equal(out.loop_given, 0); /* a snapshot of this table holds no daemon-loop settings */
    assert_int_equal(out.n_scenes, 1);
    assert_string_equal(out.scenes[0].id, "default");
    statefile_free(&out);
    assert_int_equal(parse(snap, sl, "{\"clothd_state\":2,\"run\":\"paused\"}", &out, &loop, why), STATEFILE_OK);
    assert_int_equal(out.format, 2);
    assert_true(out.paused);
    assert_memory_equal(&loop, &before, sizeof loop);
    statefile_free(&out);
    free(snap);
    /* clothd 0.1.0's file: format 2, its snapshot written with the daemon-loop settings in the
     * engine's table (--time-scale 2.5 --seed 7 --auto-drop-interval 0.75 --auto-drop-max 3
     * --checkpoint-interval 17 --max-speed true). */
    unsigned char file[8192];
    const size_t n = uk_data_file("clothd-0.1.0.state", file, sizeof file);
    assert_int_equal(statefile_parse(file, n, &out, &loop, why, sizeof why), STATEFILE_OK);
    assert_int_equal(out.format, 2);
    assert_true(out.paused);
    assert_int_equal(out.loop_given, 6);
    assert_true(loop.time_scale == 2.5f && loop.seed == 7 && loop.auto_drop_interval == 0.75f && loop.auto_drop_max == 3 &&
                loop.checkpoint_interval == 17 && loop.max_speed == 1);
    statefile_free(&out);
}

/* Format 4: every scene's snapshot, then a trailer naming them in order; what it writes reads
 * back; a trailer that names a bad id, one twice, or more or fewer scenes than there are
 * snapshots is refused. */
static void test_many_scenes(void **unused)
{
    (void)unused;
    size_t sl;
    unsigned char *one = snapshot(&sl);
    unsigned char *file = malloc(2 * sl + 1024);
    memcpy(file, one, sl);
    memcpy(file + sl, one, sl);
    loop_settings a = uk_defaults().scene.loop, b = a;
    b.seed = 42;
    const char *ids[] = {"default", "b-2"};
    const int paused[] = {0, 1};
    const loop_settings *loops[] = {&a, &b};
    size_t tlen;
    char *t = statefile_trailer_scenes(2, ids, paused, loops, &tlen);
    memcpy(file + 2 * sl, t, tlen);
    statefile out;
    char why[300];
    loop_settings loop = uk_defaults().scene.loop;
    assert_int_equal(statefile_parse(file, 2 * sl + tlen, &out, &loop, why, sizeof why), STATEFILE_OK);
    assert_int_equal(out.format, 4);
    assert_int_equal(out.n_scenes, 2);
    assert_string_equal(out.scenes[1].id, "b-2");
    assert_int_equal(out.scenes[1].offset, sl);
    assert_int_equal(out.scenes[1].snapshot_len, sl);
    assert_true(out.scenes[1].paused && !out.scenes[0].paused);
    assert_int_equal(out.scenes[1].loop.seed, 42);
    statefile_free(&out);
    free(t);
    static const char *const bad[][2] = {
        {"{\"clothd_state\":4,\"scenes\":[{\"id\":\"a\",\"run\":\"paused\",\"params\":{}},{\"id\":\"a\",\"run\":\"paused\",\"params\":{}}]}", "twice"},
        {"{\"clothd_state\":4,\"scenes\":[{\"id\":\"A\",\"run\":\"paused\",\"params\":{}},{\"id\":\"a\",\"run\":\"paused\",\"params\":{}}]}", "no valid id"},
        {"{\"clothd_state\":4,\"scenes\":[{\"id\":\"a\",\"run\":\"paused\",\"params\":{}}]}", "holds 2 snapshots"},
        {"{\"clothd_state\":4,\"scenes\":[{\"id\":\"a\",\"run\":\"paused\",\"params\":{}},{\"id\":\"b\",\"run\":\"paused\",\"params\":{\"k_bend\":1}}]}", "'b' is refused"},
        {"{\"clothd_state\":3,\"run\":\"paused\",\"params\":{}}", "holds 2 snapshots, but a state file of format 3 holds one"},
    };
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
        const size_t n = strlen(bad[k][0]);
        memcpy(file + 2 * sl, bad[k][0], n);
        assert_int_equal(statefile_parse(file, 2 * sl + n, &out, &loop, why, sizeof why), STATEFILE_DAMAGED);
        if (!strstr(why, bad[k][1])) fail_msg("'%s' refused as '%s', not '%s'", bad[k][0], why, bad[k][1]);
    }
    /* No scene at all: the trailer alone. */
    t = statefile_trailer_scenes(0, NULL, NULL, NULL, &tlen);
    assert_int_equal(statefile_parse((const unsigned char *)t, tlen, &out, &loop, why, sizeof why), STATEFILE_OK);
    assert_int_equal(out.n_scenes, 0);
    statefile_free(&out);
    free(t);
    free(file);
    free(one);
}

static void refused(const char *trailer, statefile_error e, const char *reason)
{
    size_t sl;
    unsigned char *snap = snapshot(&sl);
    statefile out;
    char why[300];
    loop_settings loop = uk_defaults().scene.loop, before = loop;
    assert_int_equal(parse(snap, sl, trailer, &out, &loop, why), e);
    if (!strstr(why, reason)) fail_msg("%s: the reason '%s' does not say '%s'", trailer, why, reason);
    assert_memory_equal(&loop, &before, sizeof loop); /* nothing taken from a refused file */
    free(snap);
}

static void test_refusals(void **unused)
{
    (void)unused;
    refused("{\"clothd_state\":5,\"run\":\"paused\",\"params\":{}}", STATEFILE_NEWER, "this build reads formats 1 to 4");
    refused("{\"clothd_state\":3,\"run\":\"paused\"}", STATEFILE_DAMAGED, "has a trailer that is not");
    refused("{\"clothd_state\":3,\"run\":\"asleep\",\"params\":{}}", STATEFILE_DAMAGED, "has a trailer that is not");
    refused("{\"clothd_state\":3,\"run\":\"paused\",\"params\":{\"seed\":2,\"k_bend\":1}}", STATEFILE_DAMAGED,
            "'k_bend' is not a daemon-loop setting");
    refused("{\"clothd_state\":3,\"run\":\"paused\",\"params\":{\"seed\":-1}}", STATEFILE_DAMAGED, "seed must be between");
    refused("{\"clothd_state\":2,\"run\":\"paused\",\"x\":1}", STATEFILE_DAMAGED, "has a trailer that is not");
    refused("{\"clothd_state\":1,\"run\":\"paused\"}", STATEFILE_DAMAGED, "a bad clothd_state");
    refused("{\"base_step\":0,\"entries\":[]}", STATEFILE_FOREIGN, "a journal bundle?");
    refused("{\"clothd_sta", STATEFILE_DAMAGED, "not a state file's trailer");
    statefile out;
    char why[300];
    loop_settings loop;
    assert_int_equal(statefile_parse((const unsigned char *)"hello", 5, &out, &loop, why, sizeof why), STATEFILE_FOREIGN);
    assert_int_equal(statefile_parse((const unsigned char *)"CSNP\1\0\0\0", 8, &out, &loop, why, sizeof why), STATEFILE_DAMAGED);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_trailer),
        cmocka_unit_test(test_older_formats),
        cmocka_unit_test(test_refusals),
        cmocka_unit_test(test_many_scenes),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
