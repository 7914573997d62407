/* sim_internal.h - what the core's source files share: the cs_sim struct and helpers between
 * scene building, the stability guard, commands, reads and snapshots. Not installed. */
#ifndef CLOTHSIM_SIM_INTERNAL_H
#define CLOTHSIM_SIM_INTERNAL_H

#include <string.h>

#include "clothsim/backend.h"
#include "clothsim/clothsim.h"
#include "clothsim/physics.h"

_Static_assert(CS_SPRING_TYPES_PER_VERTEX == CS_NTYPES, "clothsim.h's count of spring types is physics.h's");

/* The distinct (structural, shear, bend) spring counts that vertices of a grid have. */
typedef struct cs_combos {
    int n;
    uint8_t c[36][3];
} cs_combos;

struct cs_sim {
    cs_model model;
    cs_state state;
    const cs_backend *backend;
    void *ctx;
    unsigned host_stale;   /* CS_SYNC_* parts of the host arrays the backend has moved past */
    cs_combos combos;      /* the grid's spring counts, for the guard */
    char backend_note[160];
    char err[256];
    const char *err_param;
    uint64_t memory_limit; /* bytes a scene may cost (memory_cost); 0: no limit */
    cs_cost_fn memory_cost; /* NULL: cs_scene_memory */
    void *memory_ctx;
    int32_t rock_limit;    /* most rocks, 1..CS_MAX_ROCKS */
    cs_solver_stats solver; /* the last step call's, for cs_info */
    cs_self_stats self;     /* the last step call's, for cs_info */
};

/* A new state (a scene built, a snapshot loaded) has had no step: the last step call's statistics
 * (cs_info's solver and self) go with the old one. */
static inline void cs_sim_no_step_yet(cs_sim *sim)
{
    memset(&sim->solver, 0, sizeof sim->solver);
    memset(&sim->self, 0, sizeof sim->self);
}

/* sim.c */
/* CS_E_LIMIT (recorded, naming nx) when a scene under params would cost more than this machine or
 * the memory limit allows; checked before anything is allocated for it. */
cs_status cs_check_memory(cs_sim *sim, const cs_scene *scene, const cs_params *params);
/* 1 when a * b fits 64 bits (then *out = a b). */
int cs_mul_ok(uint64_t a, uint64_t b, uint64_t *out);
/* 1 when a + b fits 64 bits (then *out = a + b). */
int cs_add_ok(uint64_t a, uint64_t b, uint64_t *out);

/* status.c */
/* Records a refusal: the detail (printf-style) and the parameter it concerns (may be NULL). */
cs_status cs_fail(cs_sim *sim, cs_status st, const char *param, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 4, 5)))
#endif
    ;
void cs_ok(cs_sim *sim);

/* scene.c */
/* Allocates a state for n vertices (arrays zeroed, no rocks); CS_E_NOMEM on failure. */
cs_status cs_state_alloc(cs_state *s, int32_t n);
void cs_state_free(cs_state *s);
/* Fills positions, rest lengths and pins of a freshly allocated state from the scene. */
void cs_scene_build(const cs_scene *scene, cs_state *s);
/* Sets the pins of a preset (replacing all) and refreshes the free-vertex mask. */
void cs_state_apply_preset(const cs_scene *scene, cs_state *s, cs_pins preset);
/* Recomputes w from pins and grab; pinned or grabbed vertices get zero acceleration, pinned ones
 * zero velocity. */
void cs_state_update_mask(cs_state *s);
/* Grid offsets (di, dj) of each spring type, from CS_SPRING_TYPES. */
extern const int cs_type_di[CS_NTYPES], cs_type_dj[CS_NTYPES];
/* The far end of spring (type t, owner v) in an nx x ny grid, or -1 when the grid has none. */
int32_t cs_spring_far_end(int32_t nx, int32_t ny, int t, int32_t v);
/* Whether spring (type t, owner v) exists in an nx x ny grid. */
int cs_spring_exists(int32_t nx, int32_t ny, int t, int32_t v);
/* Grid rest length of each spring type. */
void cs_scene_rest(const cs_scene *scene, float rest[CS_NTYPES]);
/* Mass and inertia of a rock from radius and density. */
void cs_rock_mass(cs_rock_state *r);

/* guard.c */
/* The grid's spring-count combinations for the guard (once per scene). */
void cs_guard_scene(cs_combos *out, const cs_scene *scene);
/* Evaluates the stability guard for these parameters and rocks: the effective substeps and
 * dt_max, or CS_E_UNSTABLE with the reason (param: the parameter to blame). */
cs_status cs_guard_eval(cs_sim *sim, const cs_combos *combos, const cs_scene *scene, const cs_params *p,
                        const cs_rock_state *rocks, int32_t n_rocks, const char *param, int32_t *substeps,
                        double *dt_max);
/* How many contacts' stiffness and damping the guard counts at one vertex (see guard.c). */
double cs_guard_contact_weight(const cs_params *p);
/* Fills the model (phys, dt) from scene, params and effective substeps. */
void cs_model_derive(cs_model *m, const cs_scene *scene, const cs_params *p, int32_t substeps, double dt_max);

/* backend.c */
cs_status cs_backend_pick(const char *name, const cs_backend **out, char *note, size_t note_len);
/* Whether backend b implements everything parameters p ask for; else 0 and the reason in why. */
int cs_backend_covers(const cs_backend *b, const cs_params *p, char *why, size_t why_len);
/* The parameter of p that backend b lacks (its reason in why), or NULL when it has everything. */
const char *cs_backend_lacks(const cs_backend *b, const cs_params *p, char *why, size_t why_len);

/* sim.c */
/* Records a backend failure with the backend's own detail. */
cs_status cs_backend_fail(cs_sim *sim, cs_status st, const char *what);
/* Brings the host arrays up to date with the backend. */
cs_status cs_sim_sync(cs_sim *sim, unsigned what);
/* After a command changed the host state: hand it to the backend and recompute accelerations. */
cs_status cs_sim_commit(cs_sim *sim);
/* Re-evaluates the guard for a new rock list and adopts the result; CS_E_UNSTABLE refuses. */
cs_status cs_sim_reguard(cs_sim *sim, const cs_rock_state *rocks, int32_t n_rocks, const char *param);

/* read.c */
/* Elastic energy of every penalty contact of the state (cs_energy.contact). */
double cs_contact_energy(const cs_phys *p, const cs_state *s);
/* Springs of the grid whose rest length says torn: their ids (type n + v, up to cap) and count. */
int64_t cs_torn_list(int32_t nx, int32_t ny, const float *L0, uint32_t *ids, size_t cap);
#define CS_FNV_OFFSET 0xcbf29ce484222325ull
/* FNV-1a 64 of len bytes, continuing from h (start with CS_FNV_OFFSET). */
uint64_t cs_fnv1a(uint64_t h, const void *data, size_t len);

#endif
