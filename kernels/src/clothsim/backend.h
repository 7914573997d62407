/* clothsim/backend.h - the model/state split and the backend interface.
 *
 * cs_model holds what does not change while stepping (scene, parameters, derived constants);
 * cs_state holds what does (vertex arrays, rest lengths, rocks, counters). The core owns both on
 * the host; a backend advances the state. The CPU backend works on the host arrays in place; a
 * device backend keeps its own copy and syncs through upload/download. Backends are one table of
 * function pointers each, chosen at run time (like raylib's platforms).
 *
 * Every backend runs the same sequence, so that they agree bit for bit (h = dt/2):
 *
 * velocity_verlet, substep s of one step call (x, v, a complete at the call's start):
 *   1. the grabbed vertex g: v[g] = cs_grab_velocity(x[g]).
 *   2. every rock: v += h a, w += h alpha (cs_rock_kick), then cs_rock_drift.
 *      every vertex: if s > 0, v += h a (finishing the previous substep); then v += h a;
 *      x += dt v.
 *   3. every vertex: F = its 12 springs in CS_SPRING_SLOTS order (each spring's force computed
 *      from d = xj - xi, so the far end's is exactly its negation), + cs_air_gravity: the
 *      non-contact resultant Ro; then each touching rock in index order, then the ground;
 *      a = F (inv_mass w). Springs the vertex owns get cs_strain_update into L0_next (when
 *      strain_on). Each rock's reaction is summed per chunk (cs_tree_sum).
 *   4. every rock: cs_rock_force (chunk partials in groups, see CS_CHUNK_GROUP), cs_rock_accel,
 *      cs_rock_kick(h). Swap L0 and L0_next.
 *   After the last substep: every vertex v += h a.
 * symplectic_euler, each substep:
 *   1. every vertex: a as in step 3 above (no strain update).
 *   2. every rock: cs_rock_force, cs_rock_accel, cs_rock_kick(dt), cs_rock_drift(dt);
 *      the grabbed vertex: v[g] = cs_grab_velocity(x[g]).
 *   3. every vertex: v += dt a; x += dt v.
 *   4. when strain_on: every owned spring cs_strain_update from |xj - xi|; swap. */
#ifndef CLOTHSIM_BACKEND_H
#define CLOTHSIM_BACKEND_H

#include "clothsim/clothsim.h"
#include "clothsim/physics.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct cs_model {
    cs_scene scene;
    cs_params params;
    cs_phys phys;           /* what the force functions read (dt for the effective substeps) */
    int32_t substeps;       /* effective substeps per frame (>= params.substeps) */
    double dt;              /* 1 / (frame_rate substeps) */
    double dt_max;          /* stability guard's limit */
    float rest[CS_NTYPES];  /* grid rest length of each spring type */
    int32_t threads;        /* CPU threads; 0 = OpenMP's default */
} cs_model;

typedef struct cs_state {
    int32_t n;                       /* vertices, nx ny */
    float *x, *y, *z;                /* positions (m) */
    float *vx, *vy, *vz;             /* velocities (m/s) */
    float *ax, *ay, *az;             /* accelerations (m/s^2), a_n of velocity Verlet */
    float *w;                        /* 1 for a free vertex, 0 pinned or grabbed */
    float *L0;                       /* CS_NTYPES x n rest lengths, type-major; CS_TORN if absent */
    float *L0_next;                  /* the other half of the rest-length double buffer */
    uint8_t *pinned;                 /* 1 where pinned */
    cs_rock_state *rocks;
    int32_t n_rocks, rock_cap;
    uint32_t next_rock_id;
    int32_t grab;                    /* grabbed vertex or -1 */
    cs_vec3 grab_target;
    uint64_t step;                   /* substeps run since the scene was built */
    double time;                     /* simulated seconds */
    int64_t n_torn;                  /* springs torn */
} cs_state;

typedef struct cs_step_report {
    int64_t torn;     /* springs torn during the call */
    int finite;       /* 1 when every position, velocity and rock value is finite */
    cs_solver_stats solver; /* implicit_euler: what its solver did in the call (zeros otherwise) */
    cs_self_stats self;     /* self_collision: what it did in the call (zeros otherwise) */
} cs_step_report;

/* One simulation of a batch (step_batch): its backend context, model and state, the substeps it
 * is to run (1 .. 100000), and what came of it. */
typedef struct cs_batch_item {
    void *ctx;
    const cs_model *m;
    cs_state *s;
    int32_t substeps;
    cs_step_report rep;
    cs_status status;  /* CS_OK, or this simulation's failure (the others go on) */
} cs_batch_item;

/* Parts of the host state a download brings up to date. A frame needs positions and rocks (and
 * velocities or rest lengths for its scalars); a snapshot, a hash or a command needs all. */
enum {
    CS_SYNC_POSITIONS = 1,
    CS_SYNC_VELOCITIES = 2,
    CS_SYNC_ACCELERATIONS = 4,
    CS_SYNC_REST = 8,
    CS_SYNC_ROCKS = 16,
    CS_SYNC_ALL = 31
};

/* A backend's cost model: for each kernel (or CPU pass), the distinct bytes of memory it reads
 * and writes per vertex each time it runs, and how often it runs. Counted from the kernels; for
 * CUDA checked against the bytes the CPU imitation of CUDA sees them touch (tests/gpu). */
typedef struct cs_kernel_cost {
    const char *name;
    double read, written;  /* bytes per vertex per run */
    double fixed;          /* bytes per run that do not scale with the cloth (rocks, parameters) */
    double per_substep;    /* runs per substep, amortized (once per graph of G substeps: 1/G) */
    double per_frame;      /* runs per frame */
} cs_kernel_cost;

#define CS_COST_ROWS 32
typedef struct cs_cost_model {
    cs_kernel_cost k[CS_COST_ROWS];
    int n;
    double bytes_per_vertex_substep; /* sum of (read + written) per_substep */
    double fixed_per_substep;        /* sum of fixed per_substep */
    double launches_per_frame;       /* kernels (or parallel passes) per frame */
    double graphs_per_frame;         /* CUDA graph launches per frame (0: none) */
    double nodes_per_substep;        /* kernels per substep on the critical path */
    double waits_per_substep;        /* host waits for the device (a round trip each) per substep */
    /* A batch of such simulations (step_batch) launches the kernels above once for all of them:
     * launches_per_frame is the whole batch's, whatever its size. What each simulation adds is
     * host work: the runtime calls the batch makes for it per step call, without and with its
     * frame read. 0 where the backend has no batched step. */
    double batch_calls_per_scene, batch_calls_per_read_scene;
} cs_cost_model;

typedef struct cs_backend {
    const char *name;
    /* 1 if usable on this machine; else 0 and the reason in why. */
    int (*available)(char *why, size_t why_len);
    cs_status (*create)(void **ctx, char *err, size_t err_len);
    void (*destroy)(void *ctx);
    /* The host state changed from outside (scene, command, snapshot): take all of it. On failure
     * the backend's own state is as it was before the call (a device keeps its old copy). */
    cs_status (*upload)(void *ctx, const cs_model *m, cs_state *s);
    /* Bring these parts of the host state up to date (what: CS_SYNC_* bits). */
    cs_status (*download)(void *ctx, const cs_model *m, cs_state *s, unsigned what);
    /* Recompute accelerations of cloth and rocks from the current positions and velocities. */
    cs_status (*refresh)(void *ctx, const cs_model *m, cs_state *s);
    /* Advance the given number of substeps. Counters (step, time) are the core's. */
    cs_status (*step)(void *ctx, const cs_model *m, cs_state *s, int32_t substeps, cs_step_report *rep);
    /* Human-readable device, e.g. the CPU backend and the threads it uses for this model. */
    const char *(*device)(void *ctx, const cs_model *m);
    /* Detail of the backend's last failure ("" when none). */
    const char *(*error)(void *ctx);
    /* What it knows of its speed for this model (zeros where nothing). */
    void (*stats)(void *ctx, const cs_model *m, cs_backend_stats *out);
    /* Its cost model for this model and rock count; needs no device. */
    void (*cost)(const cs_model *m, int32_t n_rocks, cs_cost_model *out);
    /* CS_CAP_* it implements; a parameter that needs one it lacks is refused on it (and "auto"
     * then picks the CPU backend). Last, so a table that predates a flag leaves it 0. */
    unsigned caps;
    /* Steps several simulations of this backend in one call, each by its own substeps, with the
     * same sequence as step(): what each ends with is bitwise what its own step() gives. Returns
     * CS_OK, or a failure of the whole call (then every item failed). NULL: the core calls step()
     * for each in turn. */
    cs_status (*step_batch)(cs_batch_item *items, int n);
} cs_backend;

/* contact_model surface (physics.h, "surface contact"). */
#define CS_CAP_SURFACE_CONTACT 1u
/* integrator implicit_euler (implicit.h). */
#define CS_CAP_IMPLICIT 2u
/* rocks under integrator implicit_euler (implicit.h's push after the solve) */
#define CS_CAP_IMPLICIT_ROCKS 4u
/* self_collision (selfcontact.h) */
#define CS_CAP_SELF_COLLISION 8u

/* Adds a row to a cost model and its totals. */
void cs_cost_add(cs_cost_model *c, const char *name, double read, double written, double fixed, double per_substep,
                 double per_frame);

/* The cost model of a backend (cs_backend_cpu, cs_backend_cuda()) for this simulation's scene,
 * parameters and rocks, whichever backend the simulation runs on. */
cs_status cs_sim_cost(cs_sim *sim, const cs_backend *backend, cs_cost_model *out);

/* The CPU backend; always available. */
extern const cs_backend cs_backend_cpu;
/* The CUDA backend, or NULL when this build has none. */
const cs_backend *cs_backend_cuda(void);

#ifdef __cplusplus
}
#endif
#endif
