/* backend.c - choosing a backend by name; the rows of a cost model. */
#include <stdio.h>
#include <string.h>

#include "sim_internal.h"

#ifndef CLOTHSIM_HAVE_CUDA
const cs_backend *cs_backend_cuda(void) { return NULL; }
#endif

/* Picks the backend for a name ("cpu", "cuda", "auto"); note says why. */
cs_status cs_backend_pick(const char *name, const cs_backend **out, char *note, size_t note_len)
{
    const cs_backend *cuda = cs_backend_cuda();
    char why[128] = "";
    if (!name || strcmp(name, "auto") == 0) {
        if (cuda && cuda->available(why, sizeof why)) {
            *out = cuda;
            snprintf(note, note_len, "auto: a CUDA device was found");
        } else {
            *out = &cs_backend_cpu;
            snprintf(note, note_len, "auto: %s", cuda ? why : "this build has no CUDA backend");
        }
        return CS_OK;
    }
    if (strcmp(name, "cpu") == 0) {
        *out = &cs_backend_cpu;
        snprintf(note, note_len, "cpu: asked for");
        return CS_OK;
    }
    if (strcmp(name, "cuda") == 0) {
        if (!cuda) {
            snprintf(note, note_len, "cuda: this build has no CUDA backend");
            return CS_E_BACKEND;
        }
        if (!cuda->available(why, sizeof why)) {
            snprintf(note, note_len, "cuda: %s", why);
            return CS_E_BACKEND;
        }
        *out = cuda;
        snprintf(note, note_len, "cuda: asked for");
        return CS_OK;
    }
    snprintf(note, note_len, "unknown backend '%s' (cpu, cuda or auto)", name);
    return CS_E_INVALID;
}

void cs_cost_add(cs_cost_model *c, const char *name, double read, double written, double fixed, double per_substep,
                 double per_frame)
{
    if (c->n >= CS_COST_ROWS) return;
    cs_kernel_cost *k = &c->k[c->n++];
    k->name = name;
    k->read = read;
    k->written = written;
    k->fixed = fixed;
    k->per_substep = per_substep;
    k->per_frame = per_frame;
    c->bytes_per_vertex_substep += (read + written) * per_substep;
    c->fixed_per_substep += fixed * per_substep;
    c->launches_per_frame += per_frame;
}

const char *cs_backend_lacks(const cs_backend *b, const cs_params *p, char *why, size_t why_len)
{
    if (p->contact_model == CS_CONTACT_SURFACE && !(b->caps & CS_CAP_SURFACE_CONTACT)) {
        snprintf(why, why_len, "the %s backend does not have contact_model surface yet (use contact_model vertex, or "
                 "the cpu backend)", b->name);
        return "contact_model";
    }
    if (p->integrator == CS_IMPLICIT_EULER && !(b->caps & CS_CAP_IMPLICIT)) {
        snprintf(why, why_len, "the %s backend does not have integrator implicit_euler yet (use velocity_verlet, or "
                 "the cpu backend)", b->name);
        return "integrator";
    }
    if (p->self_collision && !(b->caps & CS_CAP_SELF_COLLISION)) {
        snprintf(why, why_len, "the %s backend does not have self_collision yet (use the cpu backend)", b->name);
        return "self_collision";
    }
    return NULL;
}

int cs_backend_covers(const cs_backend *b, const cs_params *p, char *why, size_t why_len)
{
    return cs_backend_lacks(b, p, why, why_len) == NULL;
}
