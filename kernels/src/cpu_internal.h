/* cpu_internal.h - what the CPU backend's files share: backend_cpu.c (the explicit integrators and
 * the backend's table) and implicit_cpu.c (integrator implicit_euler). Not installed. */
#ifndef CLOTHSIM_CPU_INTERNAL_H
#define CLOTHSIM_CPU_INTERNAL_H

#include "sim_internal.h"

/* Sums the written leaves idx[0..n) of contrib (6 rows of CS_CHUNK) by exactly cs_tree_sum's tree,
 * the others counting as +0 (backend_cpu.c). */
void cs_cpu_tree_sum_sparse(const float (*contrib)[CS_CHUNK], const uint8_t *idx, int n, int b, float out[6]);
/* New rest lengths of row r's springs from the current positions into L0_next; returns the springs
 * torn (backend_cpu.c). */
int cs_cpu_strain_row(const cs_phys *p, cs_state *s, int32_t r);

/* implicit_cpu.c: the workspace of implicit_euler (NULL until first used), freed with the context. */
typedef struct cs_im_work cs_im_work;
void cs_im_free(cs_im_work *w);
/* Runs substeps of implicit_euler on threads threads. Returns CS_OK, or CS_E_NOMEM (nothing
 * changed). *torn receives springs torn. */
cs_status cs_im_step(cs_im_work **w, const cs_model *m, cs_state *s, int32_t substeps, int threads,
                     cs_step_report *rep, int64_t *torn);
/* The cloth's forces at the current state (a = F/m); the rocks' a and alpha stay (under
 * implicit_euler the cloth's last push over a part, rocks_push). */
cs_status cs_im_refresh(cs_im_work **w, const cs_model *m, cs_state *s, int threads);

#endif
