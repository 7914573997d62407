/* test_cost.c - the CUDA backend's cost model (cuda_cost in cost_cuda.cuh, what clothd-bench
 * prints and its roofline predictions rest on) against the bytes the kernels actually touch, as
 * the CPU imitation of CUDA counts them: for each kernel, the distinct bytes of device memory it
 * reads and writes per vertex per launch, and its launches per frame, for both integrators with and
 * without strain. Prints the measured table. Then a batch (cs_sims_step): its kernels launched per
 * frame are the model's launches_per_frame however many scenes it holds, and the bytes they touch
 * per vertex-substep are the model's. Plain C; exit 0 pass, 1 fail. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "clothsim/backend.h"
#include "clothsim/clothsim.h"
#include "emu.h"

static int failures;

/* The kernel a cost-model row describes, as its launch is written. */
static const char *launch_of(const char *row)
{
    static const char *map[][2] = {
        {"k_cloth (velocity Verlet)", "k_cloth<MODE_VERLET, S, R>"},
        {"k_cloth (the last substep of a graph)", "k_cloth<MODE_VERLET_LAST, S, R>"},
        {"k_cloth (symplectic Euler)", "k_cloth<MODE_EULER, false, R>"},
        {"k_cloth (the last substep of a graph, Euler)", "k_cloth<MODE_EULER_LAST, false, R>"},
        {"k_drift_first (the first substep of a graph)", "k_drift_first"},
        {"k_strain", "k_strain"},
    };
    for (size_t i = 0; i < sizeof map / sizeof map[0]; i++)
        if (strcmp(map[i][0], row) == 0) return map[i][1];
    return NULL;
}

static void check(int nx, int ny, int integrator, int strain)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = nx, sc.ny = ny;
    p.integrator = integrator;
    p.plastic_yield = strain ? 0.5f : 0.0f; /* the strain pass runs; at rest nothing yields */
    p.tear_strain = strain ? 2.0f : 0.0f;
    p.max_substeps = 100000;
    p.contact_model = CS_CONTACT_VERTEX; /* the cost model counts the vertex model's traffic */
    cs_sim *sim = NULL;
    char err[256];
    if (cs_sim_create(&sc, &p, "cuda", &sim, err, sizeof err) != CS_OK) {
        printf("creating the sim: %s\n", err);
        exit(1);
    }
    cs_info info;
    cs_sim_info(sim, &info);
    const int32_t F = info.substeps;
    const size_t n = (size_t)nx * ny;
    float *xyz = malloc(sizeof(float) * 3 * n);
    cs_sim_step_frames(sim, 1);
    cs_read_positions(sim, xyz, 3 * n);
    emu_kernel_stats_reset();
    emu_counters e0, e1;
    emu_get_counters(&e0);
    emu_count_bytes(1);
    const int frames = getenv("CLOTHD_SANITIZED") ? 1 : 2; /* ASan and UBSan: slower */
    for (int k = 0; k < frames; k++) {
        cs_sim_step_frames(sim, 1);
        cs_read_positions(sim, xyz, 3 * n);
    }
    emu_count_bytes(0);
    emu_get_counters(&e1);
    cs_cost_model cm;
    cs_sim_cost(sim, cs_backend_cuda(), &cm);
    emu_kernel_stats ks[32];
    const int nk = emu_kernel_stats_get(ks, 32);
    printf("%d x %d, %s, %s, %d substeps a frame:\n", nx, ny, integrator == CS_VELOCITY_VERLET ? "velocity Verlet" : "symplectic Euler",
           strain ? "strain on" : "strain off", (int)F);
    printf("  %-46s %21s %21s %17s\n", "kernel", "read B/vertex", "written B/vertex", "launches/frame");
    printf("  %-46s %10s %10s %10s %10s %8s %8s\n", "", "model", "counted", "model", "counted", "model", "counted");
    for (int r = 0; r < cm.n; r++) {
        const cs_kernel_cost *row = &cm.k[r];
        const char *launch = launch_of(row->name);
        if (!launch) {
            /* Not a kernel: the frame's device copy, counted as copied bytes. */
            const double d2d = (double)(e1.bytes_d2d - e0.bytes_d2d) / frames / (double)n;
            printf("  %-46s %10.2f %10.2f %10.2f %10.2f\n", row->name, row->read, d2d, row->written, d2d);
            if (fabs(d2d - row->read) > 0.01 || fabs(d2d - row->written) > 0.01) {
                printf("  FAILED: %s copies %.2f bytes a vertex a frame, the model says %.2f\n", row->name, d2d,
                       row->read);
                failures++;
            }
            continue;
        }
        const emu_kernel_stats *k = NULL;
        for (int i = 0; i < nk; i++)
            if (strcmp(ks[i].name, launch) == 0) k = &ks[i];
        if (!k || !k->counted) {
            printf("  FAILED: %s (%s) never ran\n", row->name, launch);
            failures++;
            continue;
        }
        const double rd = (double)k->read / k->counted / (double)n, wr = (double)k->written / k->counted / (double)n;
        const double per_frame = (double)k->launches / frames;
        printf("  %-46s %10.2f %10.2f %10.2f %10.2f %8.1f %8.1f\n", row->name, row->read, rd, row->written, wr,
               row->per_frame, per_frame);
        /* Exact but for bytes that do not scale with the cloth (the scene struct is not counted). */
        if (fabs(rd - row->read) > 0.01 || fabs(wr - row->written) > 0.01 || fabs(per_frame - row->per_frame) > 1e-9) {
            printf("  FAILED: %s: the model is off\n", row->name);
            failures++;
        }
    }
    const double graphs = (double)(e1.graph_launches - e0.graph_launches) / frames;
    printf("  graph launches a frame: model %.1f, counted %.1f; %.1f bytes a vertex-substep in all\n",
           cm.graphs_per_frame, graphs, cm.bytes_per_vertex_substep);
    if (fabs(graphs - cm.graphs_per_frame) > 1e-9) {
        printf("  FAILED: graph launches\n");
        failures++;
    }
    free(xyz);
    cs_sim_destroy(sim);
}

/* One frame of `count` equal scenes in one batch: launches and bytes against the cost model. */
static void check_batch(int nx, int ny, int count)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    p.integrator = CS_VELOCITY_VERLET; /* the explicit step's batch (implicit_euler's: emu.batch) */
    sc.nx = nx, sc.ny = ny;
    p.plastic_yield = 0.5f, p.tear_strain = 2.0f, p.max_substeps = 100000;
    p.contact_model = CS_CONTACT_VERTEX;
    cs_sim *sims[8];
    int64_t substeps[8];
    cs_status each[8];
    for (int k = 0; k < count; k++) {
        char err[256];
        if (cs_sim_create(&sc, &p, "cuda", &sims[k], err, sizeof err) != CS_OK) {
            printf("creating the sim: %s\n", err);
            exit(1);
        }
    }
    cs_info info;
    cs_sim_info(sims[0], &info);
    for (int k = 0; k < count; k++) substeps[k] = info.substeps;
    cs_sims_step(sims, (size_t)count, substeps, each); /* settle: the first call's frame copy */
    emu_kernel_stats_reset();
    emu_counters e0, e1;
    emu_get_counters(&e0);
    emu_count_bytes(1);
    const cs_status st = cs_sims_step(sims, (size_t)count, substeps, each);
    emu_count_bytes(0);
    emu_get_counters(&e1);
    cs_cost_model cm;
    cs_sim_cost(sims[0], cs_backend_cuda(), &cm);
    emu_kernel_stats ks[32];
    const int nk = emu_kernel_stats_get(ks, 32);
    double bytes = 0;
    for (int i = 0; i < nk; i++) bytes += (double)(ks[i].read + ks[i].written);
    const double launches = (double)(e1.kernel_launches - e0.kernel_launches);
    /* The frame copy is the model's last row, on the device, and was not asked for here. */
    const double frame = cm.k[cm.n - 1].read + cm.k[cm.n - 1].written;
    const double per_vs = bytes / ((double)count * nx * ny * info.substeps) + frame / info.substeps;
    printf("batch of %d scenes of %d x %d, %d substeps a frame: %.0f kernels launched (model %.0f for any batch), "
           "%.2f bytes a vertex-substep (model %.2f)\n",
           count, nx, ny, (int)info.substeps, launches, cm.launches_per_frame, per_vs, cm.bytes_per_vertex_substep);
    if (st != CS_OK || fabs(launches - cm.launches_per_frame) > 1e-9 || fabs(per_vs - cm.bytes_per_vertex_substep) > 0.01) {
        printf("  FAILED: the batch is not what the model says\n");
        failures++;
    }
    for (int k = 0; k < count; k++) cs_sim_destroy(sims[k]);
}

int main(void)
{
    const int small = getenv("CLOTHD_SANITIZED") != NULL; /* ASan and UBSan: slower */
    check(small ? 64 : 128, small ? 32 : 64, CS_VELOCITY_VERLET, 1);
    check(small ? 48 : 128, small ? 32 : 64, CS_VELOCITY_VERLET, 0);
    check(small ? 48 : 96, small ? 24 : 48, CS_SYMPLECTIC_EULER, 1);
    check(small ? 48 : 96, small ? 24 : 48, CS_SYMPLECTIC_EULER, 0);
    check_batch(24, 16, 1); /* small: what it checks does not depend on the size */
    check_batch(24, 16, 4);
    printf(failures ? "cost model: %d rows FAILED\n" : "cost model: every row matches what the kernels touch\n",
           failures);
    return failures ? 1 : 0;
}
