/* guard.c - the stability guard (kernels/MODEL.md, Time) and the model derived from the
 * parameters.
 *
 * An explicit integrator of a mass m held by stiffness K and damping C is stable for
 * dt < (sqrt(C^2 + 2 m K) - C) / K, evaluated here as 2 m / (sqrt(C^2 + 2 m K) + C) (the same
 * value without the cancellation, and finite when K = 0). This is the Gershgorin bound on the
 * highest frequency when every stiffness in K couples the vertex to another moving mass (a spring
 * puts k on the diagonal and k off it: 2 K in all, hence the 2 m K).
 *
 * For a vertex, K and C add up its springs (as the grid has them; tearing only makes the true
 * limit larger) and what a rock's contacts can add at it:
 *   - vertex contact: one contact, k_contact and c_contact + c_tangent (the viscous friction is a
 *     damper too while it is below the Coulomb cap);
 *   - surface contact: a contact of weight w at the vertex adds k_contact w to its Gershgorin row
 *     (k w w_j to the diagonal and the other vertices, summing to k w, and next to nothing to the
 *     far heavier rock's); one rock's contacts can weigh up to 6 at a vertex (six faces around a
 *     vertex at the bottom of a shallow dimple each claim it with a weight near 1), so K gets
 *     6 / 2 = 3 k_contact in the form above, and C 3 (c_contact + c_tangent); the ground's own
 *     contact adds half of one more (cs_guard_contact_weight).
 * For a dynamic rock, M with one rock contact (k_rock M and c_rock M: rock contacts scale with the
 * reduced mass, see physics.h, so this limit is the same for every rock), and in the surface
 * model its cloth contacts too:
 * at most as many as the cloth's rest triangles that fit on its surface, 4 pi (R + offset)^2 /
 * (hx hy / 2), plus one, each k_contact. dt_max = stability_safety x the smallest limit. */
#include <math.h>

#include "sim_internal.h"

void cs_guard_scene(cs_combos *out, const cs_scene *scene)
{
    /* The counts of springs at (i, j) depend on i only through its distance to the borders,
     * so columns 0, 1, 2, nx-3, nx-2, nx-1 (and the same rows) cover every combination. */
    const int32_t nx = scene->nx, ny = scene->ny;
    int32_t is[6], js[6];
    int ni = 0, nj = 0;
    const int32_t cand_i[6] = {0, 1, 2, nx - 3, nx - 2, nx - 1}, cand_j[6] = {0, 1, 2, ny - 3, ny - 2, ny - 1};
    for (int k = 0; k < 6; k++) {
        if (cand_i[k] >= 0 && cand_i[k] < nx) is[ni++] = cand_i[k];
        if (cand_j[k] >= 0 && cand_j[k] < ny) js[nj++] = cand_j[k];
    }
    out->n = 0;
    for (int a = 0; a < ni; a++) {
        for (int b = 0; b < nj; b++) {
            const int32_t v = js[b] * nx + is[a];
            int cnt[3] = {0, 0, 0};
            for (int t = 0; t < CS_NTYPES; t++) {
                /* The vertex's own springs of type t and the one its neighbour at -(di, dj) owns. */
                const int cls = t / 2;
                cnt[cls] += cs_spring_exists(nx, ny, t, v);
                const int32_t i2 = is[a] - cs_type_di[t], j2 = js[b] - cs_type_dj[t];
                if (i2 >= 0 && i2 < nx && j2 >= 0 && j2 < ny) cnt[cls]++;
            }
            out->c[out->n][0] = (uint8_t)cnt[0];
            out->c[out->n][1] = (uint8_t)cnt[1];
            out->c[out->n][2] = (uint8_t)cnt[2];
            out->n++;
        }
    }
}

double cs_guard_contact_weight(const cs_params *p)
{
    /* Against a rock (or the ground) a contact is a spring to a far heavier body: k on the
     * diagonal only, which the form above counts twice. Vertex model: a rock's contact and the
     * ground's, k each, 2 k in all: 1 k_contact in K. Surface model: a rock's contacts up to 6 k,
     * the ground's k: 3.5 k_contact (3 without the ground). */
    if (p->contact_model == CS_CONTACT_SURFACE) return p->ground ? 3.5 : 3.0;
    return 1.0;
}

static double limit(double m, double K, double C)
{
    const double den = sqrt(C * C + 2 * m * K) + C;
    return den > 0 ? 2 * m / den : INFINITY;
}

static double vertex_mass(const cs_scene *s)
{
    return (double)s->areal_density * s->size_x * s->size_y / ((double)s->nx * s->ny);
}

cs_status cs_guard_eval(cs_sim *sim, const cs_combos *combos, const cs_scene *scene, const cs_params *p,
                        const cs_rock_state *rocks, int32_t n_rocks, const char *param, int32_t *substeps,
                        double *dt_max)
{
    const double m = vertex_mass(scene);
    const double mult = cs_guard_contact_weight(p);
    const int implicit = p->integrator == CS_IMPLICIT_EULER;
    double lim = INFINITY;
    if (implicit && n_rocks > 0 && sim && sim->backend && !(sim->backend->caps & CS_CAP_IMPLICIT_ROCKS))
        return cs_fail(sim, CS_E_UNSTABLE, param ? param : "integrator",
                       "the %s backend does not have rocks under integrator implicit_euler yet: remove the rocks, "
                       "use velocity_verlet, or the cpu backend",
                       sim->backend->name);
    /* implicit_euler: the cloth's springs are solved implicitly, its rock contacts are a
     * constraint after the solve and the rocks' own contacts sub-cycle at rock_dt: none bounds the
     * substep (contact cuts it into parts as it runs: cs_im_splits) */
    for (int c = 0; c < (implicit ? 0 : combos->n); c++) {
        const double ns = combos->c[c][0], nsh = combos->c[c][1], nb = combos->c[c][2];
        const double K = ns * p->k_structural + nsh * p->k_shear + nb * p->k_bend + mult * p->k_contact;
        const double C = (ns + nsh + nb) * p->c_spring + mult * (p->c_contact + p->c_tangent) + m * p->drag / 2;
        const double l = limit(m, K, C);
        if (l < lim) lim = l;
    }
    const double face = (double)scene->size_x / (scene->nx - 1) * scene->size_y / (scene->ny - 1) / 2;
    for (int32_t r = 0; r < (implicit ? 0 : n_rocks); r++) {
        if (rocks[r].kinematic) continue;
        const double M = rocks[r].mass;
        double K = p->k_rock * M, C = p->c_rock * M;
        if (p->contact_model == CS_CONTACT_SURFACE) {
            const double reach = (double)rocks[r].radius + p->contact_offset;
            const double contacts = floor(4 * 3.14159265358979323846 * reach * reach / face) + 3; /* cs_surface_max_touch */
            K += contacts * p->k_contact;
            C += contacts * (p->c_contact + p->c_tangent);
        }
        const double l = limit(M, K, C);
        if (l < lim) lim = l;
    }
    const double dtm = p->stability_safety * lim;
    const int32_t base = implicit ? p->implicit_substeps : p->substeps;
    const double dt = 1.0 / ((double)p->frame_rate * base);
    double need = isfinite(dtm) ? ceil(1.0 / ((double)p->frame_rate * dtm)) : 1.0;
    if (need < 1) need = 1;
    if (!(need <= 1e9)) need = 1e9;
    int32_t eff = base;
    if (dt > dtm) {
        if (!p->auto_substeps)
            return cs_fail(sim, CS_E_UNSTABLE, param ? param : implicit ? "implicit_substeps" : "substeps",
                           "unstable: dt %.3g s exceeds the stable dt_max %.3g s; %.0f substeps per frame are "
                           "needed (auto_substeps is off)",
                           dt, dtm, need);
        if (need > p->max_substeps)
            return cs_fail(sim, CS_E_UNSTABLE, param ? param : "max_substeps",
                           "unstable: dt_max is %.3g s, which needs %.0f substeps per frame, more than "
                           "max_substeps (%d)",
                           dtm, need, (int)p->max_substeps);
        eff = (int32_t)need;
    }
    *substeps = eff;
    /* nothing bounds the step (implicit_euler without rocks, a cloth without stiffness): a frame */
    *dt_max = isfinite(dtm) ? dtm : 1.0 / (double)p->frame_rate;
    return CS_OK;
}

void cs_model_derive(cs_model *m, const cs_scene *scene, const cs_params *p, int32_t substeps, double dt_max)
{
    cs_phys *f = &m->phys;
    m->scene = *scene;
    m->params = *p;
    m->substeps = substeps;
    m->dt = 1.0 / ((double)p->frame_rate * substeps);
    m->dt_max = dt_max;
    cs_scene_rest(scene, m->rest);

    f->nx = scene->nx;
    f->ny = scene->ny;
    f->n = scene->nx * scene->ny;
    f->nseg = (scene->nx + CS_CHUNK - 1) / CS_CHUNK;
    f->nchunks = scene->ny * f->nseg;
    f->k[CS_SX] = f->k[CS_SY] = p->k_structural;
    f->k[CS_D1] = f->k[CS_D2] = p->k_shear;
    f->k[CS_BX] = f->k[CS_BY] = p->k_bend;
    f->c_spring = p->c_spring;
    f->mass = (float)vertex_mass(scene);
    f->inv_mass = 1.0f / f->mass;
    f->drag = p->drag;
    f->gravity = cs_v3_from(p->gravity);
    f->wind = cs_v3_from(p->wind);
    f->k_contact = p->k_contact;
    f->c_contact = p->c_contact;
    f->c_tangent = p->c_tangent;
    f->mu = p->mu;
    f->contact_offset = p->contact_offset;
    f->face_area = (float)((double)scene->size_x / (scene->nx - 1) * scene->size_y / (scene->ny - 1) / 2);
    f->friction = p->friction_model;
    f->contact_model = p->contact_model;
    f->max_sep = p->max_depenetration_speed > 0.0f ? p->max_depenetration_speed : 3.0e38f;
    f->k_rock = p->k_rock;
    f->c_rock = p->c_rock;
    f->mu_rock = p->mu_rock;
    f->ground = p->ground;
    f->ground_z = p->ground_z;
    f->dt = (float)m->dt;
    f->hdt = 0.5f * f->dt;
    f->plastic_yield = p->plastic_yield;
    f->tear_strain = p->tear_strain;
    const float pf = p->plastic_rate * f->dt;
    f->plastic_f = p->plastic_rate == 0.0f ? 1.0f : (pf < 1.0f ? pf : 1.0f);
    f->strain_on = p->plastic_yield > 0.0f || p->tear_strain > 0.0f;
    f->integrator = p->integrator;
    f->grab_speed = p->grab_speed;
    f->plastic_rate = p->plastic_rate;
    f->rock_dt = (float)(p->stability_safety * limit(1.0, p->k_rock, p->c_rock));
    f->solver_iterations = p->solver_iterations;
    f->cg_iterations = p->cg_iterations;
    f->solver_tolerance = p->solver_tolerance;
    f->most_splits = substeps > 0 && p->max_substeps / substeps > 1 ? p->max_substeps / substeps : 1;
    f->self_on = p->self_collision;
    f->self_thickness = p->self_thickness;
    f->self_hx = (float)((double)scene->size_x / (scene->nx - 1));
    f->self_hy = (float)((double)scene->size_y / (scene->ny - 1));
}
