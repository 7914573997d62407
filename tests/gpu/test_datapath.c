/* test_datapath.c - the CUDA backend's data path, on the CPU imitation of CUDA (tests/emu): for
 * each of the six defects its review found, that the new path is taken - counted by the
 * imitation (launches, threads, bytes copied and touched, graphs built and updated) - and that the
 * state stays bitwise equal to the CPU backend's.
 *   1. rock forces are summed by a warp per rock from the chunks that touched it, not by a
 *      thread per rock over every chunk;
 *   2. a frame copies positions and rocks only, asynchronously into pinned memory;
 *   3. grab moves, pin and parameter changes and new rocks reuse the frame's graph (updated in
 *      place where a launch size changes), and a long call is graphs of one frame;
 *   4. rocks are culled per tile: rocks that touch nothing cost the cloth kernel nothing;
 *   5. a failed upload (scene change, snapshot) leaves the state as it was;
 *   6. each spring's neighbours come from shared memory (loads per vertex), no 8-byte pad per
 *      vertex, and the stats allocate nothing;
 *   7. implicit_euler's conjugate gradients keep their scalars on the device: the host does not
 *      wait for each sum (three an iteration), only to learn whether a solve is done.
 * Plain C; exit 0 pass, 1 fail. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "clothsim/backend.h"
#include "clothsim/clothsim.h"
#include "emu.h"

static int failures;
/* Under ASan and UBSan (CLOTHD_SANITIZED) smaller cloths and fewer frames: the same paths. */
static int sanitized;
#define CHECK(cond, ...)                                                                               \
    do {                                                                                               \
        if (!(cond)) {                                                                                 \
            printf("  FAILED %s:%d: %s: ", __FILE__, __LINE__, #cond);                                 \
            printf(__VA_ARGS__);                                                                       \
            printf("\n");                                                                              \
            failures++;                                                                                \
        }                                                                                              \
    } while (0)

static cs_sim *make(const char *backend, int nx, int ny, int strain)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    p.integrator = CS_VELOCITY_VERLET; /* the explicit step's data path (implicit_euler reads back each sum) */
    sc.nx = nx, sc.ny = ny;
    sc.size_x = 0.03f * (float)(nx - 1);
    sc.size_y = 0.03f * (float)(ny - 1);
    p.plastic_yield = strain ? 0.5f : 0.0f;
    p.tear_strain = strain ? 2.0f : 0.0f;
    p.max_substeps = 100000;
    p.contact_model = CS_CONTACT_VERTEX; /* the cost model counts the vertex model's traffic */
    p.placement_overlap = 1.0f;          /* packed rocks on purpose */
    cs_sim *sim = NULL;
    char err[256];
    if (cs_sim_create(&sc, &p, backend, &sim, err, sizeof err) != CS_OK) {
        printf("creating a %s sim: %s\n", backend, err);
        exit(1);
    }
    cs_sim_set_threads(sim, 1);
    return sim;
}

/* Rocks of radius r on a grid over the cloth's middle, pressing into it (dz = 0), or dz above. */
static void rocks(cs_sim *sim, int count, float r, float dz)
{
    cs_scene sc;
    cs_params p;
    cs_sim_scene(sim, &sc);
    cs_sim_params(sim, &p);
    const int cols = (int)ceil(sqrt((double)count));
    for (int k = 0; k < count; k++) {
        cs_rock_def d;
        cs_rock_def_default(&d);
        d.radius = r;
        d.density = 200.0f;
        d.position[0] = ((float)(k % cols) / (float)(cols > 1 ? cols - 1 : 1) - 0.5f) * 0.6f * sc.size_x;
        d.position[1] = ((float)(k / cols) / (float)(cols > 1 ? cols - 1 : 1) - 0.5f) * 0.6f * sc.size_y;
        d.position[2] = sc.height + r + 0.5f * p.contact_offset + dz;
        if (cs_rock_add(sim, &d, NULL) != CS_OK) {
            printf("adding a rock: %s\n", cs_sim_error(sim));
            exit(1);
        }
    }
}

static const emu_kernel_stats *kernel(const char *prefix, emu_kernel_stats *all, int n)
{
    for (int i = 0; i < n; i++)
        if (strncmp(all[i].name, prefix, strlen(prefix)) == 0) return &all[i];
    return NULL;
}

static int32_t substeps_of(cs_sim *sim)
{
    cs_info info;
    cs_sim_info(sim, &info);
    return info.substeps;
}

/* Reads a frame as the daemon does: positions, then every rock. */
static void read_frame(cs_sim *sim, float *xyz, size_t n3)
{
    cs_read_positions(sim, xyz, n3);
    for (int32_t r = 0; r < cs_rock_count(sim); r++) {
        cs_rock k;
        cs_rock_at(sim, r, &k);
    }
}

static void same_as_cpu(cs_sim *gpu, cs_sim *cpu, const char *what)
{
    const uint64_t a = cs_state_hash(gpu), b = cs_state_hash(cpu);
    CHECK(a == b, "%s: state hash %016llx on the emulated CUDA backend, %016llx on the CPU backend", what,
          (unsigned long long)a, (unsigned long long)b);
}

/* 1 and 4: a warp per rock over the chunks that touched it; far rocks cost nothing. */
static void rock_sums(void)
{
    printf("1, 4: rock sums and culling\n");
    const int nx = sanitized ? 48 : 96, ny = nx;
    for (int many = 0; many < 2; many++) {
        const int nr = many ? 80 : sanitized ? 6 : 12;
        cs_sim *g = make("cuda", nx, ny, 1), *c = make("cpu", nx, ny, 1);
        rocks(g, nr, 0.04f, 0.0f);
        rocks(c, nr, 0.04f, 0.0f);
        cs_sim_step(g, 3);
        cs_sim_step(c, 3);
        emu_kernel_stats_reset();
        emu_count_bytes(1);
        cs_sim_step(g, 7);
        emu_count_bytes(0);
        cs_sim_step(c, 7);
        emu_kernel_stats ks[32];
        const int nk = emu_kernel_stats_get(ks, 32);
        const emu_kernel_stats *f = kernel(many ? "k_rock_force" : "k_rocks<ROCKS_VERLET>", ks, nk);
        CHECK(f != NULL, "no rock kernel ran");
        if (f) {
            const double threads = (double)f->threads / (double)f->launches;
            const double read = (double)f->read / (double)f->counted;
            /* A thread per rock over every chunk would read nchunks x rocks x 24 bytes. */
            const double dense = (double)ny * nr * 24.0;
            printf("  %d rocks: %s: %.0f threads a launch (%.0f a rock), %.0f bytes read a launch (%.0f%% of every "
                   "partial)\n",
                   nr, f->name, threads, threads / nr, read, 100.0 * read / dense);
            CHECK(threads >= 32.0 * nr, "%.0f threads for %d rocks: not a warp per rock", threads, nr);
            CHECK(read < 0.5 * dense + 100.0 * nr * (nr + 2),
                  "the rock kernel read %.0f bytes: it reads chunks that did not touch", read);
        }
        same_as_cpu(g, c, "rocks on the cloth");
        cs_sim_destroy(g);
        cs_sim_destroy(c);
    }
    /* 4: 200 rocks a metre above the cloth add nothing to what the cloth kernel touches. */
    const int ngroups = (ny + 63) / 64;
    uint64_t written[2] = {0, 0}, read[2] = {0, 0};
    for (int with = 0; with < 2; with++) {
        cs_sim *g = make("cuda", nx, ny, 0), *c = make("cpu", nx, ny, 0);
        if (with) {
            rocks(g, 200, 0.02f, 1.0f);
            rocks(c, 200, 0.02f, 1.0f);
        }
        cs_sim_step(g, 2);
        emu_kernel_stats_reset();
        emu_count_bytes(1);
        cs_sim_step(g, 5);
        emu_count_bytes(0);
        cs_sim_step(c, 7);
        emu_kernel_stats ks[32];
        const int nk = emu_kernel_stats_get(ks, 32);
        const emu_kernel_stats *k = kernel("k_cloth<MODE_VERLET,", ks, nk);
        if (k) written[with] = k->written / k->counted, read[with] = k->read / k->counted;
        if (with) same_as_cpu(g, c, "200 rocks above the cloth");
        cs_sim_destroy(g);
        cs_sim_destroy(c);
    }
    printf("  the cloth kernel per launch: %llu bytes written, %llu read without rocks; %llu, %llu with 200 far above\n",
           (unsigned long long)written[0], (unsigned long long)read[0], (unsigned long long)written[1],
           (unsigned long long)read[1]);
    CHECK(written[0] > 0 && written[1] == written[0], "far rocks changed what the cloth kernel writes");
    /* Each rock: its centre and radius for the culling, its word of each chunk group. */
    CHECK(read[1] <= (uint64_t)(read[0] + 200 * (16 + ngroups * 8)), "far rocks cost the cloth kernel more than culling them");
}

/* 2: a frame's copies. */
static void frames(void)
{
    printf("2: frames\n");
    const int nx = sanitized ? 64 : 128, ny = sanitized ? 32 : 64, nr = 4;
    const size_t n = (size_t)nx * ny;
    cs_sim *g = make("cuda", nx, ny, 1), *c = make("cpu", nx, ny, 1);
    rocks(g, nr, 0.05f, 0.0f);
    rocks(c, nr, 0.05f, 0.0f);
    float *xyz = malloc(sizeof(float) * 3 * n), *ref = malloc(sizeof(float) * 3 * n);
    const int32_t F = substeps_of(g);
    cs_sim_step(g, F);
    read_frame(g, xyz, 3 * n); /* the first read tells the backend what a frame needs */
    for (int k = 0; k < 3; k++) {
        emu_reset_counters();
        cs_sim_step(g, F);
        read_frame(g, xyz, 3 * n);
        emu_counters e;
        emu_get_counters(&e);
        const uint64_t expect = 12 * n + nr * sizeof(cs_rock_state) + 2 * sizeof(int);
        printf("  frame %d: %llu bytes to the host in %llu copies (%llu from pageable memory), %llu waits; a full "
               "state would be %zu bytes\n",
               k + 2, (unsigned long long)e.bytes_d2h, (unsigned long long)e.copies_d2h,
               (unsigned long long)e.pageable_async_copies, (unsigned long long)e.host_waits, 84 * n);
        CHECK(e.bytes_d2h == expect, "a frame copied %llu bytes, not the %llu of positions, rocks and the flags",
              (unsigned long long)e.bytes_d2h, (unsigned long long)expect);
        CHECK(e.pageable_async_copies == 0, "a frame copied into pageable memory (synchronously)");
        CHECK(e.host_waits == 2, "a frame waited %llu times (the step's end and the frame's copy: 2)",
              (unsigned long long)e.host_waits);
    }
    cs_sim_step(c, 4 * F);
    cs_read_positions(c, ref, 3 * n);
    CHECK(memcmp(xyz, ref, sizeof(float) * 3 * n) == 0, "the frame's positions are not the CPU backend's");
    emu_reset_counters();
    same_as_cpu(g, c, "after four frames");
    emu_counters e;
    emu_get_counters(&e);
    /* The frame brought the positions: a hash needs velocities, accelerations and rest lengths. */
    CHECK(e.bytes_d2h >= 48 * n, "a hash brought only %llu bytes: the rest of the state is velocities, "
                                 "accelerations and rest lengths", (unsigned long long)e.bytes_d2h);
    free(xyz);
    free(ref);
    cs_sim_destroy(g);
    cs_sim_destroy(c);
}

/* 3: graphs survive commands. */
static void graphs(void)
{
    printf("3: graphs\n");
    const int nx = 64, ny = 48;
    cs_sim *g = make("cuda", nx, ny, 1), *c = make("cpu", nx, ny, 1);
    cs_sim *sims[2] = {g, c};
    for (int s = 0; s < 2; s++) rocks(sims[s], 2, 0.05f, 0.0f);
    const int32_t F = substeps_of(g);
    for (int s = 0; s < 2; s++) cs_sim_step(sims[s], 2 * F); /* both parities of an odd frame */
    emu_counters e0, e1;
    emu_get_counters(&e0);
    const int frames = sanitized ? 6 : 12;
    for (int k = 0; k < frames; k++) {
        const float target[3] = {0.1f * (float)k, 0.05f, 1.2f};
        const int32_t v = (ny / 2) * nx + nx / 2 + (k % 3), pin = 5 * nx + 7;
        cs_params p;
        cs_sim_params(g, &p);
        p.wind[0] = 0.1f * (float)k;
        for (int s = 0; s < 2; s++) {
            cs_grab(sims[s], v, target);
            if (k % 4 == 1) cs_pin(sims[s], &pin, 1, k % 8 == 1);
            if (k % 4 == 2) cs_sim_set_params(sims[s], &p);
            if (k == 6) rocks(sims[s], 1, 0.04f, 0.0f);
            cs_sim_step(sims[s], F);
        }
    }
    emu_get_counters(&e1);
    printf("  %d frames of %d substeps with a grab move each, pin and parameter changes and a new rock: %llu graph "
           "launches, %llu built, %llu updated, %llu kernels\n",
           frames, F, (unsigned long long)(e1.graph_launches - e0.graph_launches),
           (unsigned long long)(e1.graph_instantiations - e0.graph_instantiations),
           (unsigned long long)(e1.graph_updates - e0.graph_updates),
           (unsigned long long)(e1.kernel_launches - e0.kernel_launches));
    CHECK(e1.graph_launches - e0.graph_launches == (uint64_t)frames, "not one graph launch a frame");
    CHECK(e1.graph_instantiations == e0.graph_instantiations, "commands rebuilt graphs");
    same_as_cpu(g, c, "grab moves, pins, parameters, a rock");

    /* More than ROCKS_FUSED rocks: a new rock changes a launch size - an update, not a rebuild. */
    for (int s = 0; s < 2; s++) rocks(sims[s], 70, 0.02f, 0.3f);
    for (int s = 0; s < 2; s++) cs_sim_step(sims[s], 2 * F);
    emu_get_counters(&e0);
    for (int s = 0; s < 2; s++) {
        rocks(sims[s], 9, 0.02f, 0.5f);
        cs_sim_step(sims[s], 2 * F);
    }
    emu_get_counters(&e1);
    printf("  past 64 rocks, 9 more: %llu built, %llu updated\n",
           (unsigned long long)(e1.graph_instantiations - e0.graph_instantiations),
           (unsigned long long)(e1.graph_updates - e0.graph_updates));
    CHECK(e1.graph_instantiations == e0.graph_instantiations, "a new rock rebuilt a graph");
    CHECK(e1.graph_updates > e0.graph_updates, "the rock kernels' launch sizes were not updated");
    same_as_cpu(g, c, "81 rocks");
    cs_sim_destroy(g);
    cs_sim_destroy(c);

    /* A long call: graphs of one frame, not one graph of the whole call (which for 100,000
     * substeps is 200,000 kernels). */
    cs_sim *small = make("cuda", 8, 8, 0);
    const int64_t long_call = sanitized ? 301 : 1001;
    emu_get_counters(&e0);
    cs_sim_step(small, long_call);
    emu_get_counters(&e1);
    const double nodes = (double)(e1.kernel_launches - e0.kernel_launches) /
                         (double)(e1.graph_launches - e0.graph_launches);
    printf("  a %lld-substep call: %llu graph launches of %.0f kernels, %llu built\n", (long long)long_call,
           (unsigned long long)(e1.graph_launches - e0.graph_launches), nodes,
           (unsigned long long)(e1.graph_instantiations - e0.graph_instantiations));
    CHECK(nodes <= 2 * 256 + 1, "graphs of %.0f kernels", nodes);
    CHECK(e1.graph_instantiations - e0.graph_instantiations <= 4, "%llu graphs built",
          (unsigned long long)(e1.graph_instantiations - e0.graph_instantiations));
    cs_sim_destroy(small);
}

/* 5: failed uploads. */
static void failed_uploads(void)
{
    printf("5: failed uploads\n");
    const int nx = 40, ny = 30;
    cs_sim *g = make("cuda", nx, ny, 1), *ref = make("cuda", nx, ny, 1), *c = make("cpu", nx, ny, 1);
    cs_sim *sims[3] = {g, ref, c};
    for (int s = 0; s < 3; s++) {
        rocks(sims[s], 3, 0.05f, 0.0f);
        cs_sim_step(sims[s], 77); /* the device is ahead of the host copy now */
    }
    /* A larger scene needs new buffers: the first allocation fails. */
    cs_scene big;
    cs_sim_scene(g, &big);
    big.nx = 60;
    emu_fail_alloc_after(0);
    const cs_status st = cs_sim_set_scene(g, &big);
    emu_fail_alloc_after(-1);
    CHECK(st == CS_E_NOMEM, "the failed scene change returned %d", (int)st);
    /* A snapshot of another size, the same way. */
    cs_sim *other = make("cpu", 50, 20, 0);
    const size_t cap = cs_snapshot_size(other);
    unsigned char *buf = malloc(cap);
    size_t len = 0;
    cs_snapshot_save(other, buf, cap, &len);
    emu_fail_alloc_after(0);
    const cs_status st2 = cs_snapshot_load(g, buf, len);
    emu_fail_alloc_after(-1);
    CHECK(st2 == CS_E_NOMEM, "the failed snapshot load returned %d", (int)st2);
    free(buf);
    cs_sim_destroy(other);
    for (int s = 0; s < 3; s++) CHECK(cs_sim_step(sims[s], 50) == CS_OK, "stepping after: %s", cs_sim_error(sims[s]));
    cs_info a, b;
    cs_sim_info(g, &a);
    cs_sim_info(ref, &b);
    CHECK(a.step == b.step && a.n_vertices == b.n_vertices, "the failed commands changed the scene or the step");
    const uint64_t hg = cs_state_hash(g), hr = cs_state_hash(ref), hc = cs_state_hash(c);
    printf("  after a failed scene change and snapshot load: %016llx, without them %016llx, CPU %016llx\n",
           (unsigned long long)hg, (unsigned long long)hr, (unsigned long long)hc);
    CHECK(hg == hr && hr == hc, "the failed uploads changed the state");
    for (int s = 0; s < 3; s++) cs_sim_destroy(sims[s]);
}

/* 6: loads, padding, stats. */
static void smaller(void)
{
    printf("6: loads per vertex, no padding, stats\n");
    const int nx = sanitized ? 64 : 128, ny = sanitized ? 32 : 64;
    const double n = (double)nx * ny;
    cs_sim *g = make("cuda", nx, ny, 1);
    cs_sim_step(g, 3);
    emu_kernel_stats_reset();
    emu_count_bytes(1);
    cs_sim_step(g, 9);
    emu_count_bytes(0);
    emu_kernel_stats ks[32];
    const int nk = emu_kernel_stats_get(ks, 32);
    const emu_kernel_stats *k = kernel("k_cloth<MODE_VERLET,", ks, nk);
    CHECK(k != NULL, "no cloth kernel ran");
    if (k) {
        const double loads = (double)k->loads / k->counted / n, read = (double)k->read / k->counted / n;
        const double written = (double)k->written / k->counted / n;
        printf("  k_cloth per vertex: %.1f bytes loaded (%.1f distinct), %.1f written\n", loads, read, written);
        /* Each of 12 springs from both ends with neighbours from device memory: 12 x 24 bytes of
         * neighbour state and 12 rest lengths, besides the vertex's own. */
        CHECK(loads < 100.0, "the cloth kernel loads %.1f bytes a vertex: neighbours do not come from shared memory",
              loads);
        CHECK(read + written <= 75.0, "%.1f bytes a vertex: more than state, mask, rest lengths and change byte",
              read + written);
    }
    emu_counters e0, e1;
    emu_get_counters(&e0);
    cs_backend_stats bs;
    cs_sim_backend_stats(g, &bs);
    emu_get_counters(&e1);
    CHECK(e1.device_bytes_peak == e0.device_bytes_peak && e1.device_bytes == e0.device_bytes,
          "the stats allocated %llu bytes", (unsigned long long)(e1.device_bytes_peak - e0.device_bytes_peak));
    cs_sim_destroy(g);
}

/* 7: implicit_euler waits for a solve's end, not for each of its sums. */
static void implicit_waits(void)
{
    printf("7: implicit_euler's waits\n");
    const int nx = sanitized ? 16 : 32, ny = sanitized ? 12 : 24, frames = sanitized ? 4 : 12;
    cs_sim *g = make("cuda", nx, ny, 0);
    cs_params p;
    cs_sim_params(g, &p);
    p.integrator = CS_IMPLICIT_EULER;
    CHECK(cs_sim_set_params(g, &p) == CS_OK, "implicit_euler refused: %s", cs_sim_error(g));
    rocks(g, 1, 0.05f, 0.0f); /* a rock on the cloth: parts and Newton iterations */
    cs_sim_step(g, 1);
    emu_reset_counters();
    int64_t cg = 0, newton = 0, parts = 0;
    for (int f = 0; f < frames; f++) {
        cs_sim_step(g, 1);
        cs_info info;
        cs_sim_info(g, &info);
        cg += info.solver.cg, newton += info.solver.newton, parts += info.solver.substeps;
    }
    emu_counters e;
    emu_get_counters(&e);
    printf("  %d frames: %lld parts, %lld Newton and %lld CG iterations, %llu waits (%.2f a Newton iteration), "
           "%llu kernels, %llu graph launches, %llu graphs built\n",
           frames, (long long)parts, (long long)newton, (long long)cg, (unsigned long long)e.host_waits,
           newton > 0 ? (double)e.host_waits / (double)newton : 0.0, (unsigned long long)e.kernel_launches,
           (unsigned long long)e.graph_launches, (unsigned long long)e.graph_instantiations);
    CHECK(cg > 2 * newton, "too few CG iterations (%lld for %lld Newton) to tell", (long long)cg, (long long)newton);
    /* a wait for each of an iteration's three sums would be 3 cg waits at least */
    CHECK(e.host_waits < 3 * (uint64_t)cg, "%llu waits for %lld CG iterations: the host waits for their sums",
          (unsigned long long)e.host_waits, (long long)cg);
    /* each iteration one graph, built once for the workspace (the frames before) */
    CHECK(e.graph_launches >= (uint64_t)cg, "%llu graph launches for %lld CG iterations",
          (unsigned long long)e.graph_launches, (long long)cg);
    CHECK(e.graph_instantiations == 0, "%llu graphs built again", (unsigned long long)e.graph_instantiations);
    cs_sim *c = make("cpu", nx, ny, 0);
    CHECK(cs_sim_set_params(c, &p) == CS_OK, "implicit_euler refused on the CPU");
    rocks(c, 1, 0.05f, 0.0f);
    cs_sim_step(c, 1 + frames);
    CHECK(cs_state_hash(g) == cs_state_hash(c), "the state is not the CPU backend's");
    cs_sim_destroy(g);
    cs_sim_destroy(c);
}

int main(void)
{
    sanitized = getenv("CLOTHD_SANITIZED") != NULL;
    rock_sums();
    frames();
    graphs();
    failed_uploads();
    smaller();
    implicit_waits();
    printf(failures ? "datapath: %d checks FAILED\n" : "datapath: every check passed\n", failures);
    return failures ? 1 : 0;
}
