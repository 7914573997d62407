/* testhooks.c - fault injection for the test daemon (see testhooks.h). */
#include <errno.h>
#include <stdlib.h>
#include <time.h>

#include "core/log.h"
#include "cs_testhooks.h"
#include "testhooks.h"

static long long nan_frame = -1, fail_frame = -1, save_pause_ms = -1, recording_write_ms = -1;
static long long wedge_frame = -1, wedge_ms = -1;

static void pause_ms(long long ms)
{
    struct timespec ts = {(time_t)(ms / 1000), (long)(ms % 1000) * 1000000L};
    while (nanosleep(&ts, &ts) != 0 && errno == EINTR) {
    }
}

static long long env_number(const char *name)
{
    const char *s = getenv(name);
    if (!s || !*s) return -1;
    char *end;
    errno = 0;
    const long long v = strtoll(s, &end, 10);
    if (errno || *end || v < 0) {
        log_msg("test hook %s=%s ignored: not a whole number >= 0", name, s);
        return -1;
    }
    log_msg("test hook armed: %s=%lld", name, v);
    return v;
}

void testhooks_init(void)
{
    nan_frame = env_number("CLOTHD_TEST_NAN_FRAME");
    fail_frame = env_number("CLOTHD_TEST_BACKEND_FAIL_FRAME");
    save_pause_ms = env_number("CLOTHD_TEST_SAVE_PAUSE_MS");
    recording_write_ms = env_number("CLOTHD_TEST_RECORDING_WRITE_MS");
    wedge_frame = env_number("CLOTHD_TEST_WEDGE_FRAME");
    wedge_ms = env_number("CLOTHD_TEST_WEDGE_MS");
    if (recording_write_ms >= 0) log_msg("test hook: the recordings' writer waits %lld ms before each frame", recording_write_ms);
}

int testhooks_recording_slow(void) { return recording_write_ms >= 0; }

void testhooks_before_recording_write(void) { pause_ms(recording_write_ms); }

void testhooks_before_frame(cs_sim *sim, uint64_t frame)
{
    if (nan_frame >= 0 && frame == (uint64_t)nan_frame) {
        nan_frame = -1;
        cs_info info;
        cs_sim_info(sim, &info);
        const int32_t v = info.n_vertices / 2;
        const cs_status st = cs_test_poison(sim, v);
        log_msg("test hook: NaN written into vertex %d after frame %llu (step %llu): %s", (int)v,
                (unsigned long long)frame, (unsigned long long)info.step, cs_status_name(st));
    }
    if (wedge_frame >= 0 && frame == (uint64_t)wedge_frame) {
        wedge_frame = -1;
        const long long ms = wedge_ms >= 0 ? wedge_ms : 0;
        log_msg("test hook: the sim thread wedged for %lld ms after frame %llu", ms, (unsigned long long)frame);
        pause_ms(ms);
        log_msg("test hook: the sim thread goes on");
    }
    if (fail_frame >= 0 && frame == (uint64_t)fail_frame) {
        fail_frame = -1;
        const cs_status st = cs_test_break_backend(sim);
        log_msg("test hook: backend broken after frame %llu: %s", (unsigned long long)frame, cs_status_name(st));
    }
}

void testhooks_before_rename(const char *tmp)
{
    if (save_pause_ms < 0) return;
    log_msg("test hook: %s written; pausing %lld ms before the rename", tmp, save_pause_ms);
    pause_ms(save_pause_ms);
}
