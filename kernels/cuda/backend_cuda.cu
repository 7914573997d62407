/* backend_cuda.cu - the CUDA backend: the SIM_HD functions of physics.h in kernels, running the
 * substep sequence of backend.h so that its state equals the CPU backend's bit for bit (both built
 * without contraction: -fmad=false here, -ffp-contract=off there).
 *
 * Layout (structure of arrays, as the host keeps it): the state read and the state written are
 * two buffers of x, y, z, vx, vy, vz (6 n floats each), swapped every substep, so one kernel per
 * substep reads every neighbour's current state and writes its own vertex's next one; a byte mask
 * (1 free, 0 pinned or grabbed); accelerations (3 n), written where a step call or a refresh ends;
 * rest lengths in two buffers read and written alternately, with a byte per vertex saying whether
 * its springs changed in the last update: a vertex writes its six rest lengths into the other
 * buffer only when they changed now or then, so a cloth at rest writes 2 bytes a vertex per
 * substep for its strain, not 24.
 *
 * One translation unit (static functions, no relocatable device code), in the layout of
 * cuda-samples' particles: this file the backend's entry points (upload, download, refresh, step,
 * step_batch: the table of backend.h), the files it includes one job each -
 *   cloth_kernel.cuh         what the kernels and the host share: memory accessors, sizes, the
 *                            scene struct, a launch's buffers, the modes
 *   cloth_kernel_impl.cuh    the cloth kernel, Verlet's first drift, Euler's strain pass (device)
 *   rocks_kernel_impl.cuh    the rocks' forces and moves (device)
 *   batch_kernel_impl.cuh    a batch's kernels and its frames' device copy (device)
 *   implicit_kernel_impl.cuh integrator implicit_euler's kernels, over a batch of scenes (device)
 *   memory_cuda.cuh          a scene's context and buffers, the device's errors (host)
 *   graphs_cuda.cuh          the explicit substeps' launches and the CUDA graphs of a frame (host)
 *   selfcontact_cuda.cuh     self_collision: its kernels and the host's sequence of a pass
 *   implicit_cuda.cuh        integrator implicit_euler: the host sequence of its kernels
 *   batch_cuda.cuh           a batch's tables, its run and its frames' copies (host)
 *   cost_cuda.cuh            the cost model
 *
 * Integrator implicit_euler has a sequence of its own (implicit_cuda.cuh): launches of per-vertex
 * and per-chunk kernels around the functions of clothsim/implicit.h over a batch of scenes (a lone
 * step is a batch of one), the host deciding each scene's Newton iterations and line search from
 * what it reads back; a batch steps such scenes together after its explicit ones. */
#include <cuda_runtime.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <mutex>

#include "clothsim/backend.h"
#include "clothsim/implicit.h"
#include "clothsim/physics.h"

#include "cloth_kernel.cuh"
#include "cloth_kernel_impl.cuh"
#include "rocks_kernel_impl.cuh"
#include "batch_kernel_impl.cuh"
#include "implicit_kernel_impl.cuh"
#include "memory_cuda.cuh"
#include "graphs_cuda.cuh"
#include "selfcontact_cuda.cuh"
#include "implicit_cuda.cuh"
#include "batch_cuda.cuh"
#include "cost_cuda.cuh"

static cs_status cuda_upload(void *ctx, const cs_model *m, cs_state *s)
{
    cuda_ctx *c = (cuda_ctx *)ctx;
    c->pending = 1;
    cs_status st = join_batch(c);
    if (st == CS_OK) st = reserve(c, m, s);
    if (st != CS_OK) return st;
    const size_t n = (size_t)s->n, f = sizeof(float) * n;
    cuda_scene k;
    memset(&k, 0, sizeof k);
    k.p = m->phys;
    k.nr = s->n_rocks;
    k.grab = s->grab;
    k.grab_target = s->grab_target;
    k.tile_rows = tile_rows_for(&m->phys, c->sms);
    k.ngroups = (m->phys.nchunks + CS_CHUNK_GROUP - 1) / CS_CHUNK_GROUP;
    c->host_sc = k;
    /* From pageable memory: each copy is done when it returns (after the work queued before it). */
    CUDA_CHECK(cudaMemcpyAsync(c->sc, &k, sizeof k, cudaMemcpyHostToDevice, c->stream));
    const float *parts[] = {s->x, s->y, s->z, s->vx, s->vy, s->vz};
    float *st_dev = c->vb.state[c->cur];
    for (int q = 0; q < 6; q++)
        CUDA_CHECK(cudaMemcpyAsync(st_dev + (size_t)q * n, parts[q], f, cudaMemcpyHostToDevice, c->stream));
    const float *acc[] = {s->ax, s->ay, s->az};
    for (int q = 0; q < 3; q++)
        CUDA_CHECK(cudaMemcpyAsync(c->vb.acc + (size_t)q * n, acc[q], f, cudaMemcpyHostToDevice, c->stream));
    for (size_t v = 0; v < n; v++) c->vb.mask_stage[v] = s->w[v] != 0.0f;
    CUDA_CHECK(cudaMemcpyAsync(c->vb.mask, c->vb.mask_stage, n, cudaMemcpyHostToDevice, c->stream));
    CUDA_CHECK(cudaMemcpyAsync(c->vb.rest[c->rest_cur], s->L0, CS_NTYPES * f, cudaMemcpyHostToDevice, c->stream));
    /* The other rest-length buffer is not a copy of this one: every vertex writes it once. */
    CUDA_CHECK(cudaMemsetAsync(c->vb.chg, 1, n, c->stream));
    if (s->n_rocks)
        CUDA_CHECK(cudaMemcpyAsync(c->rb.rocks, s->rocks, sizeof(cs_rock_state) * (size_t)s->n_rocks,
                                   cudaMemcpyHostToDevice, c->stream));
    c->frame_call = -1; /* a frame copied before this is no longer the state */
    return CS_OK;
}


/* Accelerations of cloth and rocks from the current state, on the device; nothing waits. */
static cs_status cuda_refresh(void *ctx, const cs_model *m, cs_state *s)
{
    cuda_ctx *c = (cuda_ctx *)ctx;
    (void)m, (void)s;
    c->pending = 1;
    const cs_status st = join_batch(c);
    if (st != CS_OK) return st;
    if (m->phys.integrator == CS_IMPLICIT_EULER) {
        const cs_status is = im_refresh(c, m);
        c->frame_call = -1;
        return is;
    }
    cloth(c, MODE_ACCEL, false, c->cur, c->rest_cur);
    CUDA_CHECK(cudaGetLastError());
    rocks(c, ROCKS_ACCEL, c->cur, c->rest_cur);
    CUDA_CHECK(cudaGetLastError());
    c->frame_call = -1;
    return CS_OK;
}

/* After a step call: the parts of the state the host read of the last frame, copied on the device
 * (the next call overwrites the state) and then, on the copy stream, into pinned memory. */
static cs_status copy_frame(cuda_ctx *c)
{
    const unsigned parts = c->wanted & (CS_SYNC_POSITIONS | CS_SYNC_VELOCITIES | CS_SYNC_ROCKS);
    c->wanted = 0;
    c->frame_call = -1;
    if (!parts) return CS_OK;
    c->pending = 1;
    const int k = c->slot ^= 1;
    const size_t n = (size_t)c->vb.n, f3 = 3 * sizeof(float) * n;
    const size_t rocks = sizeof(cs_rock_state) * (size_t)c->host_sc.nr;
    /* The copy made two calls ago from this slot must be done before the slot is rewritten. */
    CUDA_CHECK(cudaStreamWaitEvent(c->stream, c->copied[k], 0));
    const float *st = c->vb.state[c->cur];
    if (parts & CS_SYNC_POSITIONS)
        CUDA_CHECK(cudaMemcpyAsync(c->vb.frame_dev[k], st, f3, cudaMemcpyDeviceToDevice, c->stream));
    if (parts & CS_SYNC_VELOCITIES)
        CUDA_CHECK(cudaMemcpyAsync(c->vb.frame_dev[k] + 3 * n, st + 3 * n, f3, cudaMemcpyDeviceToDevice, c->stream));
    if ((parts & CS_SYNC_ROCKS) && rocks)
        CUDA_CHECK(cudaMemcpyAsync(c->rb.frame_rocks_dev[k], c->rb.rocks, rocks, cudaMemcpyDeviceToDevice, c->stream));
    CUDA_CHECK(cudaEventRecord(c->ready[k], c->stream));
    CUDA_CHECK(cudaStreamWaitEvent(c->copy, c->ready[k], 0));
    if (parts & CS_SYNC_POSITIONS)
        CUDA_CHECK(cudaMemcpyAsync(c->vb.frame_host[k], c->vb.frame_dev[k], f3, cudaMemcpyDeviceToHost, c->copy));
    if (parts & CS_SYNC_VELOCITIES)
        CUDA_CHECK(cudaMemcpyAsync(c->vb.frame_host[k] + 3 * n, c->vb.frame_dev[k] + 3 * n, f3, cudaMemcpyDeviceToHost,
                                   c->copy));
    if ((parts & CS_SYNC_ROCKS) && rocks)
        CUDA_CHECK(cudaMemcpyAsync(c->rb.frame_rocks_host[k], c->rb.frame_rocks_dev[k], rocks, cudaMemcpyDeviceToHost,
                                   c->copy));
    CUDA_CHECK(cudaEventRecord(c->copied[k], c->copy));
    c->frame_call = c->calls;
    c->frame_parts = parts;
    c->frame_waited = 0;
    return CS_OK;
}

static cs_status cuda_step(void *ctx, const cs_model *m, cs_state *s, int32_t substeps, cs_step_report *rep)
{
    cuda_ctx *c = (cuda_ctx *)ctx;
    (void)s;
    rep->torn = 0;
    rep->finite = 1;
    if (substeps <= 0) return CS_OK;
    const cs_status js = join_batch(c);
    if (js != CS_OK) return js;
    CUDA_CHECK(cudaMemsetAsync(c->flags, 0, FLAG_COUNT * sizeof(int), c->stream));
    const int strain = m->phys.strain_on != 0;
    const int implicit = m->phys.integrator == CS_IMPLICIT_EULER;
    if (implicit) {
        /* implicit_euler: its own launches, which swap the buffers as they go (no advance) */
        const cs_status is = im_step(c, m, substeps, rep);
        if (is != CS_OK) return is;
        c->calls++;
    }
    /* self_collision: one substep at a time, each followed by its pass (as the CPU backend) */
    const int self = !implicit && m->phys.self_on;
    for (int32_t left = implicit ? 0 : substeps; left > 0;) {
        if (self) {
            const cs_status ss = sc_begin(c, m->phys.n);
            if (ss != CS_OK) return ss;
        }
        graph_key k;
        memset(&k, 0, sizeof k);
        k.len = self ? 1 : left < graph_len(m) ? left : graph_len(m);
        k.integrator = m->phys.integrator;
        k.strain = strain;
        k.rocks = rock_path(c->host_sc.nr);
        /* The buffers this graph starts from: each substep before it swapped them. */
        const int32_t done = self ? 0 : substeps - left;
        k.pos = c->cur ^ (done & 1);
        k.rest = c->rest_cur ^ (strain ? done & 1 : 0);
        cudaGraphExec_t exec = NULL;
        const cs_status st = graph_for(c, &k, &exec);
        if (st != CS_OK) return st;
        CUDA_CHECK(cudaGraphLaunch(exec, c->stream));
        left -= k.len;
        if (self) { /* the substep's buffers swapped: the pass works on the new state */
            c->cur ^= 1;
            if (strain) c->rest_cur ^= 1;
            const cs_status ss = sc_end(c, &m->phys, &rep->self);
            if (ss != CS_OK) return ss;
        }
    }
    if (self) c->calls++;
    else if (!implicit) advance(c, substeps, strain);
    const cs_status fs = copy_frame(c);
    if (fs != CS_OK) return fs;
    CUDA_CHECK(cudaMemcpyAsync(c->host_flags, c->flags, FLAG_COUNT * sizeof(int), cudaMemcpyDeviceToHost, c->stream));
    CUDA_CHECK(cudaStreamSynchronize(c->stream));
    c->pending = 0;
    rep->torn = c->host_flags[FLAG_TORN];
    rep->finite = c->host_flags[FLAG_NONFINITE] == 0;
    return CS_OK;
}

/* Every scene of the batch advanced by one launch per kernel and substep (step_batch of
 * backend.h); scenes created on another device than the first's step alone. */
static cs_status cuda_step_batch(cs_batch_item *items, int n)
{
    if (n <= 0) return CS_OK;
    cuda_ctx *c = (cuda_ctx *)items[0].ctx;
    for (int k = 1; k < n; k++)
        if (((cuda_ctx *)items[k].ctx)->dev != c->dev) {
            for (int j = 0; j < n; j++)
                items[j].status = cuda_step(items[j].ctx, items[j].m, items[j].s, items[j].substeps, &items[j].rep);
            return CS_OK;
        }
    /* self_collision's pass works on one scene: those scenes step alone, as the CPU backend's
     * cpu_step_batch does; batch_run leaves them out, and implicit_euler's scenes, which
     * im_batch_run steps together after the explicit ones. */
    for (int k = 0; k < n; k++)
        if (items[k].m->phys.self_on) {
            memset(&items[k].rep, 0, sizeof items[k].rep);
            items[k].status = cuda_step(items[k].ctx, items[k].m, items[k].s, items[k].substeps, &items[k].rep);
        }
    std::lock_guard<std::mutex> hold(batch_lock);
    cs_status st = batch_run(c, &batch, items, n);
    if (st == CS_OK) st = im_batch_run(c, &batch, items, n);
    if (st != CS_OK) {
        (void)cudaStreamSynchronize(batch.stream); /* nothing left running on the staging */
        (void)cudaGetLastError();
        for (int k = 1; k < n; k++) snprintf(((cuda_ctx *)items[k].ctx)->err, sizeof c->err, "%s", c->err);
    }
    return st;
}

static cs_status cuda_download(void *ctx, const cs_model *m, cs_state *s, unsigned what)
{
    cuda_ctx *c = (cuda_ctx *)ctx;
    (void)m;
    const size_t n = (size_t)s->n, f = sizeof(float) * n;
    c->wanted |= what;
    /* What the frame copied ahead holds: wait for that copy only. */
    unsigned from_frame = c->frame_call == c->calls ? what & c->frame_parts : 0;
    if (!(c->host_sc.nr)) from_frame &= ~(unsigned)CS_SYNC_ROCKS;
    if (from_frame) {
        const int k = c->slot;
        if (!c->frame_waited) CUDA_CHECK(cudaEventSynchronize(c->copied[k]));
        c->frame_waited = 1;
        const float *h = c->vb.frame_host[k];
        float *pos[] = {s->x, s->y, s->z}, *vel[] = {s->vx, s->vy, s->vz};
        if (from_frame & CS_SYNC_POSITIONS)
            for (int q = 0; q < 3; q++) memcpy(pos[q], h + (size_t)q * n, f);
        if (from_frame & CS_SYNC_VELOCITIES)
            for (int q = 0; q < 3; q++) memcpy(vel[q], h + (size_t)(3 + q) * n, f);
        if (from_frame & CS_SYNC_ROCKS)
            memcpy(s->rocks, c->rb.frame_rocks_host[k], sizeof(cs_rock_state) * (size_t)s->n_rocks);
        what &= ~from_frame;
    }
    /* The rest from the device's current buffers, into pageable memory: each copy is done when it
     * returns. (A batch's frame copy may still be reading the state too: nothing here writes it.) */
    if (what) c->pending = 1;
    const float *st = c->vb.state[c->cur];
    float *arrays[] = {s->x, s->y, s->z, s->vx, s->vy, s->vz};
    for (int q = 0; q < 6; q++)
        if (what & (q < 3 ? CS_SYNC_POSITIONS : CS_SYNC_VELOCITIES))
            CUDA_CHECK(cudaMemcpyAsync(arrays[q], st + (size_t)q * n, f, cudaMemcpyDeviceToHost, c->stream));
    float *acc[] = {s->ax, s->ay, s->az};
    if (what & CS_SYNC_ACCELERATIONS)
        for (int q = 0; q < 3; q++)
            CUDA_CHECK(cudaMemcpyAsync(acc[q], c->vb.acc + (size_t)q * n, f, cudaMemcpyDeviceToHost, c->stream));
    if (what & CS_SYNC_REST)
        CUDA_CHECK(cudaMemcpyAsync(s->L0, c->vb.rest[c->rest_cur], CS_NTYPES * f, cudaMemcpyDeviceToHost, c->stream));
    if ((what & CS_SYNC_ROCKS) && s->n_rocks)
        CUDA_CHECK(cudaMemcpyAsync(s->rocks, c->rb.rocks, sizeof(cs_rock_state) * (size_t)s->n_rocks,
                                   cudaMemcpyDeviceToHost, c->stream));
    return CS_OK;
}


static const char *cuda_device(void *ctx, const cs_model *) { return ((cuda_ctx *)ctx)->device; }
static const char *cuda_error(void *ctx) { return ((cuda_ctx *)ctx)->err; }

static const cs_backend cuda_backend = {
    "cuda", cuda_available, cuda_create, cuda_destroy, cuda_upload, cuda_download, cuda_refresh, cuda_step,
    cuda_device, cuda_error, cuda_stats, cuda_cost,
    CS_CAP_SURFACE_CONTACT | CS_CAP_IMPLICIT | CS_CAP_IMPLICIT_ROCKS | CS_CAP_SELF_COLLISION,
    cuda_step_batch,
};

extern "C" const cs_backend *cs_backend_cuda(void) { return &cuda_backend; }
