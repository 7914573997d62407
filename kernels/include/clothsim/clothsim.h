/* clothsim/clothsim.h - libclothsim, the physics core of clothd: a mass-spring cloth and rigid
 * spherical rocks with penalty contact (kernels/MODEL.md).
 *
 * One cs_sim owns a scene, its parameters and its state, and steps them on a backend (CPU or
 * CUDA). Every call validates its input; a refused call returns a cs_status other than CS_OK,
 * leaves the simulation exactly as it was, and explains itself through cs_sim_error() (and
 * cs_sim_error_param() when one parameter is to blame). The library never exits, aborts or prints.
 *
 * Not thread-safe: one thread drives a cs_sim (the daemon's sim thread). Vertex index = j nx + i. */
#ifndef CLOTHSIM_CLOTHSIM_H
#define CLOTHSIM_CLOTHSIM_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "clothsim/params.h"

#ifdef __cplusplus
extern "C" {
#endif

#define CS_VERSION "0.1.0"
/* Most rocks one simulation holds. */
#define CS_MAX_ROCKS 1024
/* The largest rock id. Ids run 1, 2, ... within a scene and are never reused; once this one has
 * been given, cs_rock_add refuses (CS_E_LIMIT) until the scene is rebuilt, so the next id always
 * fits its 32 bits and every state can be saved and loaded again. */
#define CS_ROCK_ID_MAX 4294967294u
/* The largest step count, 2^63 - 1 (what a signed 64-bit JSON integer holds): stepping past it is
 * refused (CS_E_LIMIT), and so is a snapshot beyond it. */
#define CS_STEP_MAX 9223372036854775807ull

typedef enum cs_status {
    CS_OK = 0,
    CS_E_INVALID = -1,   /* malformed argument: NULL, not finite, wrong size, bad name */
    CS_E_RANGE = -2,     /* a value outside its range (a vertex index, a parameter) */
    CS_E_NOT_FOUND = -3, /* no rock with that id */
    CS_E_UNSTABLE = -4,  /* the stability guard refuses the change */
    CS_E_LIMIT = -5,     /* too many rocks, or a scene too large to allocate */
    CS_E_NOMEM = -6,     /* out of memory */
    CS_E_NONFINITE = -7, /* the state holds a NaN or an infinity */
    CS_E_FORMAT = -8,    /* a snapshot is truncated, corrupted or not a snapshot */
    CS_E_VERSION = -9,   /* a snapshot written by another format version */
    CS_E_BACKEND = -10,  /* the backend is unavailable or failed */
    CS_E_DEVICE = -11,   /* sticky device error: the device state is lost */
    CS_E_OVERLAP = -12   /* a rock placed into another rock or into the cloth */
} cs_status;

/* Short lowercase name of a status ("ok", "invalid", "unstable", ...). */
const char *cs_status_name(cs_status s);
/* One sentence describing a status in general. */
const char *cs_status_message(cs_status s);

typedef struct cs_sim cs_sim;

/* Creates a simulation of the scene with the parameters on a backend: "cpu", "cuda" or "auto"
 * (CUDA when a device is present, else CPU). NULL scene or params means the defaults. On failure
 * *out is NULL and err says why. */
cs_status cs_sim_create(const cs_scene *scene, const cs_params *params, const char *backend, cs_sim **out,
                        char *err, size_t err_len);
void cs_sim_destroy(cs_sim *sim);

/* Detail of the last refused call (empty after a success). */
const char *cs_sim_error(const cs_sim *sim);
/* Name of the parameter the last refusal is about, or "" when none. */
const char *cs_sim_error_param(const cs_sim *sim);
/* Backend in use ("cpu" or "cuda"), and the device it runs on (for the CPU backend: the threads
 * cs_sim_set_threads gave it). The device string stays valid until the next call. */
const char *cs_sim_backend(const cs_sim *sim);
const char *cs_sim_device(const cs_sim *sim);
/* Why this backend was chosen (for "auto": whether a CUDA device was found). */
const char *cs_sim_backend_note(const cs_sim *sim);
/* CPU threads (1..256; 0 = OpenMP's default). Results do not depend on it. */
cs_status cs_sim_set_threads(cs_sim *sim, int threads);
/* The threads the CPU backend runs for 0: OpenMP's default (one per core, or OMP_NUM_THREADS);
 * 1 when built without OpenMP. */
int cs_cpu_threads(void);

/* Host bytes a scene costs the engine under params with up to `rocks` rocks: its state twice (a
 * scene change or a snapshot load builds the new one beside the old), the backends' host scratch
 * (the CPU backend's per-chunk rock partials, a device backend's staging buffer), and the CPU
 * backend's workspaces where params use them: implicit_euler's, self_collision's with its pair
 * lists full (three sets of at most 341 keys a vertex: 8.3 kB a vertex in all); NULL params count
 * both.
 * Computed with overflow checks; CS_E_LIMIT when it overflows or passes INT32_MAX vertices. */
cs_status cs_scene_memory(const cs_scene *scene, const cs_params *params, int32_t rocks, uint64_t *bytes);
/* Bytes of a snapshot of a scene with `rocks` rocks (cs_snapshot_size of such a state). */
cs_status cs_snapshot_bytes(const cs_scene *scene, int32_t rocks, uint64_t *bytes);
/* What a scene costs whoever runs it under params, in bytes: cs_scene_memory's part and what the
 * owner keeps per scene besides (checkpoints, frame buffers); CS_OK, or CS_E_LIMIT when it
 * overflows. */
typedef cs_status (*cs_cost_fn)(const cs_scene *scene, const cs_params *params, int32_t rocks, void *ctx,
                                uint64_t *bytes);
/* Caps what a scene change, a snapshot or a change of parameters may bring (0: no cap): a scene
 * whose cost - cost(scene, params, the rock limit, ctx), or cs_scene_memory when cost is NULL -
 * passes `bytes` is CS_E_LIMIT, refused before anything is allocated for it: naming nx, or, for a
 * change of parameters that costs more than the ones it replaces (implicit_euler's workspace,
 * self_collision's), the parameter that does. Workspaces the parameters no longer use are freed. */
cs_status cs_sim_set_memory_limit(cs_sim *sim, uint64_t bytes, cs_cost_fn cost, void *ctx);
/* Most rocks this simulation takes, 1..CS_MAX_ROCKS (CS_MAX_ROCKS when created): cs_rock_add and
 * cs_snapshot_load refuse more with CS_E_LIMIT naming max_rocks. Rocks already there stay. */
cs_status cs_sim_set_rock_limit(cs_sim *sim, int32_t rocks);
int32_t cs_sim_rock_limit(const cs_sim *sim);

/* ---- scene and parameters ---- */
void cs_sim_scene(const cs_sim *sim, cs_scene *out);
/* Rebuilds the cloth from a new scene: rocks removed, grab released, pins from the scene's
 * preset, step 0. */
cs_status cs_sim_set_scene(cs_sim *sim, const cs_scene *scene);
/* Rebuilds the current scene. */
cs_status cs_sim_reset(cs_sim *sim);
void cs_sim_params(const cs_sim *sim, cs_params *out);
/* Replaces every live parameter at once, or none (CS_E_RANGE, CS_E_UNSTABLE, CS_E_LIMIT past the
 * memory limit: cs_sim_set_memory_limit). */
cs_status cs_sim_set_params(cs_sim *sim, const cs_params *params);

/* ---- time ---- */
/* Runs substeps (0..1e9). Returns CS_E_NONFINITE when the state stopped being finite; the
 * state is then left as it is for the caller to restore from a snapshot. CS_E_LIMIT (nothing
 * run) when the step count would pass CS_STEP_MAX. */
cs_status cs_sim_step(cs_sim *sim, int64_t substeps);
/* Runs frames of the effective substeps each. */
cs_status cs_sim_step_frames(cs_sim *sim, int64_t frames);
/* Steps many simulations together: sims[k] by substeps[k] (0..1e9; 0: not stepped), each[k] its
 * result as cs_sim_step would give it (and its error in cs_sim_error). Simulations of one backend
 * run in one batched call (the CPU backend shares them among its threads by work; CUDA covers
 * them all in one launch per substep); what each ends with is bitwise what cs_sim_step gives it
 * alone. CS_E_INVALID, nothing run, for NULL arrays, a NULL or repeated simulation, or n past
 * CS_BATCH_MAX; else CS_OK (each[] says how each fared). */
#define CS_BATCH_MAX 4096
cs_status cs_sims_step(cs_sim *const *sims, size_t n, const int64_t *substeps, cs_status *each);

/* What the implicit solver did over a span of substeps (integrator implicit_euler). */
typedef struct cs_solver_stats {
    int32_t substeps;   /* substeps solved: more than asked where contact cut one in parts */
    int32_t newton;     /* Newton iterations, summed */
    int32_t cg;         /* conjugate-gradient iterations (one multigrid V-cycle each), summed */
    float residual;     /* the largest final residual of a substep, relative to its first */
    int32_t lost;       /* rock contacts a vertex had no room for (more than 4 rocks at once), summed */
} cs_solver_stats;

/* What self_collision did over the last step call (zeros while it is off, and on a backend
 * without it). */
typedef struct cs_self_stats {
    int32_t passes;   /* its passes: one after each substep (each part under implicit_euler) */
    int32_t broad;    /* full broad phases: hash grids built and every vertex's pairs found again (by a pass, or
                       * by implicit_euler's gather for a substep's parts) */
    int64_t pairs;    /* repelling pairs in the lists those found, summed */
    int64_t contacts; /* pairs that pushed apart (counted by each of their vertices), summed */
    int64_t cut;      /* vertices the bound cut back, summed */
    int64_t lost;     /* vertices left without their list of pairs (no memory), summed */
} cs_self_stats;

typedef struct cs_info {
    uint64_t step;       /* substeps since the scene was built */
    double time;         /* simulated seconds */
    int32_t substeps;    /* effective substeps per frame */
    double dt, dt_max;   /* substep and the stability guard's limit (s) */
    int32_t n_vertices, n_springs, n_rocks;
    int64_t n_torn;
    cs_solver_stats solver; /* the last step call's (zeros until implicit_euler has run) */
    cs_self_stats self;     /* the last step call's */
} cs_info;
void cs_sim_info(const cs_sim *sim, cs_info *out);

/* ---- rocks ---- */
typedef struct cs_rock_def {
    float position[3];         /* m */
    float velocity[3];         /* m/s */
    float angular_velocity[3]; /* rad/s */
    float orientation[4];      /* quaternion x, y, z, w; normalised when set */
    float radius;              /* m, > 0 */
    float density;             /* kg/m^3, > 0 */
    bool kinematic;            /* moves with its velocity, ignores forces */
} cs_rock_def;

typedef struct cs_rock {
    uint32_t id;
    cs_rock_def def;           /* its current state */
    float mass, inertia;       /* M = rho 4/3 pi R^3, I = 2/5 M R^2 */
} cs_rock;

/* A resting rock of radius 0.1 m and density 2500 kg/m^3 (stone: granite is 2700) at the origin. */
void cs_rock_def_default(cs_rock_def *def);
/* Adds a rock; ids start at 1 and are never reused within a scene (CS_E_LIMIT past the rock
 * limit, or once CS_ROCK_ID_MAX has been given). CS_E_OVERLAP when it would overlap another rock
 * (centres closer than the sum of the radii) or hold part of the cloth's surface inside it (closer
 * to its centre than its radius: deeper than contact_offset into its contact layer);
 * cs_sim_error() names what it overlaps. */
cs_status cs_rock_add(cs_sim *sim, const cs_rock_def *def, uint32_t *id);
cs_status cs_rock_get(cs_sim *sim, uint32_t id, cs_rock *out);
/* Changes every field of a rock (teleport, new radius, kinematic or not). A new position or radius
 * is checked for overlaps as cs_rock_add does (CS_E_OVERLAP). */
cs_status cs_rock_set(cs_sim *sim, uint32_t id, const cs_rock_def *def);
cs_status cs_rock_remove(cs_sim *sim, uint32_t id);
/* Removes every rock; returns how many. */
int32_t cs_rock_clear(cs_sim *sim);
int32_t cs_rock_count(const cs_sim *sim);
/* The rock at index 0..count-1 (in order of addition). */
cs_status cs_rock_at(cs_sim *sim, int32_t index, cs_rock *out);

/* ---- scene presets: named scenes that show self_collision (presets.c) ---- */
int cs_preset_count(void);
const char *cs_preset_name(int k);        /* NULL past the count */
const char *cs_preset_description(int k); /* NULL past the count */
int cs_preset_find(const char *name);     /* its index, or -1 */
/* Sets preset k's scene fields and live parameters over those given. */
void cs_preset_scene(int k, cs_scene *scene, cs_params *params);
/* Once the scene is built: preset k's pins and rocks. */
cs_status cs_preset_populate(cs_sim *sim, int k);

/* ---- pins and grab ---- */
/* Replaces every pin with a preset. */
cs_status cs_pins_preset(cs_sim *sim, cs_pins preset);
/* Pins or unpins the listed vertices, all or none. A pinned vertex stops (velocity 0). */
cs_status cs_pin(cs_sim *sim, const int32_t *vertices, size_t count, bool pinned);
bool cs_is_pinned(const cs_sim *sim, int32_t vertex);
/* Moves one vertex kinematically toward target at grab_speed at most; replaces an earlier grab. */
cs_status cs_grab(cs_sim *sim, int32_t vertex, const float target[3]);
cs_status cs_release(cs_sim *sim);
/* The grabbed vertex (and its target) or -1. */
int32_t cs_grabbed(const cs_sim *sim, float target[3]);

/* ---- reads (each brings the host copy up to date first) ---- */
/* xyz must hold 3 n floats: interleaved x, y, z in vertex order. */
cs_status cs_read_positions(cs_sim *sim, float *xyz, size_t n_floats);
cs_status cs_read_velocities(cs_sim *sim, float *xyz, size_t n_floats);
/* 6 n floats, type-major (structural along x and along y, the two shear diagonals, bend along x
 * and along y), each indexed by the spring's lower-index end; -1 where torn or absent at a border. */
cs_status cs_read_rest_lengths(cs_sim *sim, float *out, size_t n_floats);
/* Ids (type n + v) of torn springs, up to cap of them; returns how many are torn in all. */
int64_t cs_read_torn(cs_sim *sim, uint32_t *ids, size_t cap);
/* n floats: each vertex's largest stretch (|d| - L0) / L0 among the intact structural springs it
 * ends (the two it owns and the two its left and lower neighbours own), 0 when none is stretched. */
cs_status cs_read_strain(cs_sim *sim, float *out, size_t n_floats);
/* Spring types a vertex owns: cs_read_rest_lengths gives this many floats per vertex, and a cloth
 * of n vertices has fewer than this many times n springs. */
#define CS_SPRING_TYPES_PER_VERTEX 6

typedef struct cs_energy {
    double kinetic, spring, gravity; /* J; gravity is -sum m g . x */
    double contact;                  /* elastic energy of every penalty contact (cloth-rock, cloth-ground,
                                        rock-rock, rock-ground), J */
    double total;                    /* the sum of the four */
} cs_energy;
cs_status cs_energy_get(cs_sim *sim, cs_energy *out);
/* FNV-1a 64 over positions, velocities, accelerations, rest lengths and rock state. */
uint64_t cs_state_hash(cs_sim *sim);
/* The hash as 16 lowercase hex digits and a NUL. */
void cs_hash_hex(uint64_t hash, char out[17]);

/* What the backend knows of its own speed (0 where it does not say). */
typedef struct cs_backend_stats {
    double bytes_per_vertex_substep; /* memory traffic per vertex and substep, from its cost model */
    double peak_bandwidth;           /* the device's memory bandwidth by its clock and bus width, bytes/s */
} cs_backend_stats;
/* Fills the stats (allocates nothing and measures nothing). */
cs_status cs_sim_backend_stats(cs_sim *sim, cs_backend_stats *out);

/* ---- snapshots: the whole state as a versioned, checksummed byte buffer ---- */
size_t cs_snapshot_size(cs_sim *sim);
/* Writes a snapshot into buf (cap bytes); *len receives its size. CS_E_NONFINITE when the state
 * is not finite (what a load refuses is never written). */
cs_status cs_snapshot_save(cs_sim *sim, void *buf, size_t cap, size_t *len);
/* Bytes of the snapshot buf starts with, from its header (a snapshot may be followed by other
 * data: a journal, a state file's trailer); 0 when buf does not start with a snapshot's header or
 * is shorter than the header says. */
size_t cs_snapshot_length(const void *buf, size_t len);
/* What a snapshot's header says, read without loading it. */
typedef struct cs_snapshot_info {
    size_t length;    /* bytes of the snapshot (cs_snapshot_length); 0 when buf is shorter than that */
    uint32_t version; /* format version (0 when buf is shorter than the version field) */
    bool readable;    /* written in a format and with a parameter table this build loads */
} cs_snapshot_info;
/* CS_OK with *out when buf starts with a snapshot's magic (however short or damaged the rest);
 * CS_E_FORMAT when it does not: it is no snapshot at all. */
cs_status cs_snapshot_peek(const void *buf, size_t len, cs_snapshot_info *out);
/* A parameter's value (out[0..3): 3 components for a vector, else 1) as the snapshot buf starts
 * with holds it, by name - also one of a row the table has since lost, which a snapshot written
 * before still carries (clothd's daemon-loop settings, once engine parameters). CS_E_NOT_FOUND
 * when the snapshot has no such row; CS_E_FORMAT or CS_E_VERSION when it is none this build reads. */
cs_status cs_snapshot_value(const void *buf, size_t len, const char *name, double out[3]);
/* Restores a snapshot, or changes nothing (CS_E_FORMAT, CS_E_VERSION, ...). What a command would
 * refuse a snapshot is refused too: parameters out of range or unstable (CS_E_UNSTABLE), more
 * rocks than the rock limit or a scene past the memory limit (CS_E_LIMIT), and states no command
 * or step makes (CS_E_FORMAT): a next rock id of 0 or not above every rock's, a step past
 * CS_STEP_MAX, a negative or non-finite time, a pinned vertex that moves, a fixed vertex (pinned
 * or grabbed) with an acceleration, a grab target beyond 1e6 m. */
cs_status cs_snapshot_load(cs_sim *sim, const void *buf, size_t len);

#ifdef __cplusplus
}
#endif
#endif
