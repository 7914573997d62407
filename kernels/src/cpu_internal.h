/* cpu_internal.h - what the CPU backend's files share: backend_cpu.c (the explicit integrators and
 * the backend's table), implicit_cpu.c (integrator implicit_euler) and selfcontact_cpu.c
 * (self_collision). Not installed. */
#ifndef CLOTHSIM_CPU_INTERNAL_H
#define CLOTHSIM_CPU_INTERNAL_H

#include "sim_internal.h"

/* A loop, `for (...) ...` as the last argument, shared among `threads` OpenMP threads by the
 * clauses given (schedule, reduction), or run plainly when threads is 1: libgomp enters a
 * parallel region even for one thread, and ends it with a futex system call whether or not a
 * thread waits - thousands a frame under implicit_euler, a fifth of a one-thread step on the
 * build machine (2026-12-06). Written once, compiled both ways; nothing in the loop may depend on
 * the thread that runs it. */
#define CS_PRAGMA(text) _Pragma(#text)
#define CS_PARALLEL_FOR(threads, clauses, ...)                                                     \
    do {                                                                                          \
        if ((threads) > 1) {                                                                      \
            CS_PRAGMA(omp parallel for num_threads(threads) clauses) __VA_ARGS__                   \
        } else {                                                                                  \
            __VA_ARGS__                                                                           \
        }                                                                                         \
    } while (0)

/* Sums the written leaves idx[0..n) of contrib (6 rows of CS_CHUNK) by exactly cs_tree_sum's tree,
 * the others counting as +0 (backend_cpu.c). */
void cs_cpu_tree_sum_sparse(const float (*contrib)[CS_CHUNK], const uint8_t *idx, int n, int b, float out[6]);
/* New rest lengths of row r's springs from the current positions into L0_next; returns the springs
 * torn (backend_cpu.c). */
int cs_cpu_strain_row(const cs_phys *p, cs_state *s, int32_t r);

/* implicit_cpu.c: the workspace of implicit_euler (NULL until first used), freed with the context. */
typedef struct cs_im_work cs_im_work;
void cs_im_free(cs_im_work *w);
/* Bytes the workspace takes for an nx x ny cloth of nchunks chunks (cs_scene_memory counts them). */
uint64_t cs_im_work_bytes(int32_t nx, int32_t ny, int32_t nchunks);
/* Runs substeps of implicit_euler on threads threads (with self_collision, each part followed by
 * cs_sc_end on *sc). Returns CS_OK, or CS_E_NOMEM (nothing changed). *torn receives springs torn. */
/* selfcontact_cpu.c: the workspace of self_collision (NULL until first used), freed with the
 * context, and what its passes did. */
typedef struct cs_sc_work cs_sc_work;
void cs_sc_free(cs_sc_work *w);
/* The most bytes the workspace takes for n vertices, its pair lists full (cs_scene_memory counts
 * them). */
uint64_t cs_sc_work_bytes(int32_t n);
/* The state changed from outside, or a spring tore: the lists of pairs are found again. */
void cs_sc_forget(cs_sc_work *w);
/* With self_collision the rate for implicit_euler's parts of a substep h (cs_im_splits): the
 * fastest a vertex of a repelling pair that may touch within h moves about the cloth's common
 * motion, over CS_SC_PART self_thickness (cs_sc_near_speed; 0 where no pair may touch). Finds the
 * lists at the positions now when those it has do not hold every such pair. CS_E_NOMEM: none. */
cs_status cs_sc_part_rate(cs_sc_work **w, const cs_phys *p, const cs_state *s, float h, int threads, float *rate);
/* Keeps the positions a substep starts from. CS_E_NOMEM: nothing kept. */
cs_status cs_sc_begin(cs_sc_work **w, const cs_state *s);
/* After the substep: repulsion, then the bound (selfcontact.h); st (may be NULL) counts. */
cs_status cs_sc_end(cs_sc_work *w, const cs_phys *p, cs_state *s, int threads, cs_self_stats *st);

cs_status cs_im_step(cs_im_work **w, const cs_model *m, cs_state *s, int32_t substeps, int threads,
                     cs_step_report *rep, int64_t *torn, cs_sc_work **sc);
/* The cloth's forces at the current state (a = F/m); the rocks' a and alpha stay (under
 * implicit_euler the cloth's last push over a part, rocks_push). */
cs_status cs_im_refresh(cs_im_work **w, const cs_model *m, cs_state *s, int threads);

#endif
