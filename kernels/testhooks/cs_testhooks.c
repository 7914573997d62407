/* cs_testhooks.c - fault injection for test builds (see cs_testhooks.h). */
#include <math.h>
#include <stdio.h>

#include "cs_testhooks.h"
#include "sim_internal.h"

cs_status cs_test_poison(cs_sim *sim, int32_t vertex)
{
    if (!sim) return CS_E_INVALID;
    if (vertex < 0 || vertex >= sim->state.n)
        return cs_fail(sim, CS_E_RANGE, "vertex", "vertex %d is not in 0..%d", (int)vertex, (int)sim->state.n - 1);
    cs_status st = cs_sim_sync(sim, CS_SYNC_ALL);
    if (st != CS_OK) return st;
    sim->state.x[vertex] = NAN;
    if ((st = cs_sim_commit(sim)) != CS_OK) return st;
    cs_ok(sim);
    return CS_OK;
}

/* The broken backend: the real one's table with every call that reaches the device failing.
 * One per process, which is all a test daemon needs. */
static const cs_backend *real;
static cs_backend broken;

static cs_status lost_state(void *ctx, const cs_model *m, cs_state *s)
{
    (void)ctx;
    (void)m;
    (void)s;
    return CS_E_DEVICE;
}
static cs_status lost_download(void *ctx, const cs_model *m, cs_state *s, unsigned what)
{
    (void)what;
    return lost_state(ctx, m, s);
}
static cs_status lost_step(void *ctx, const cs_model *m, cs_state *s, int32_t substeps, cs_step_report *rep)
{
    (void)substeps;
    (void)rep;
    return lost_state(ctx, m, s);
}
static const char *lost_error(void *ctx)
{
    (void)ctx;
    return "device state lost (simulated by a test hook)";
}

cs_status cs_test_break_backend(cs_sim *sim)
{
    if (!sim) return CS_E_INVALID;
    if (sim->backend == &broken) return CS_OK;
    if (real && real != sim->backend)
        return cs_fail(sim, CS_E_INVALID, NULL, "a backend of another kind was broken in this process already");
    real = sim->backend;
    broken = *real;
    broken.upload = lost_state;
    broken.download = lost_download;
    broken.refresh = lost_state;
    broken.step = lost_step;
    broken.step_batch = NULL; /* a batch falls back to lost_step */
    broken.error = lost_error;
    sim->backend = &broken;
    sim->host_stale = CS_SYNC_ALL;
    cs_ok(sim);
    return CS_OK;
}
