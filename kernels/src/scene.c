/* scene.c - building the cloth from a scene: the vertex grid, its springs' rest lengths, the pin
 * presets, and the memory the state and the backends' scratch take. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "cpu_internal.h"

/* Floats per vertex in the host state: x, y, z, v, a (9), w, two rest-length buffers (12). */
#define CS_FLOATS_PER_VERTEX (9 + 1 + 2 * CS_NTYPES)

static void *alloc_floats(size_t count, size_t size)
{
    size_t bytes = count * size;
    bytes = (bytes + 63) / 64 * 64;
    void *p = aligned_alloc(64, bytes ? bytes : 64);
    if (p) memset(p, 0, bytes ? bytes : 64);
    return p;
}

int cs_mul_ok(uint64_t a, uint64_t b, uint64_t *out)
{
    if (a != 0 && b > UINT64_MAX / a) return 0;
    *out = a * b;
    return 1;
}

int cs_add_ok(uint64_t a, uint64_t b, uint64_t *out)
{
    if (b > UINT64_MAX - a) return 0;
    *out = a + b;
    return 1;
}

/* Bytes of the host's scratch beside the state, whichever backend runs: the CPU backend's rock
 * partials (6 floats per chunk and rock, backend_cpu.c) and a device backend's staging buffer of
 * one float4 per vertex (backend_cuda.cu). */
/* The chunks of the scene's rows (cs_phys.nchunks: CS_CHUNK columns of a row each). */
static int chunks_of(const cs_scene *scene, uint64_t *out)
{
    return cs_mul_ok(((uint64_t)scene->nx + CS_CHUNK - 1) / CS_CHUNK, (uint64_t)scene->ny, out);
}

static int scratch_bytes(const cs_scene *scene, uint64_t n, int32_t rocks, uint64_t *out)
{
    uint64_t chunks, partials, stage;
    return chunks_of(scene, &chunks) &&
           cs_mul_ok(chunks, (uint64_t)(rocks > 0 ? rocks : 1) * 6 * sizeof(float), &partials) &&
           cs_mul_ok(n, 4 * sizeof(float), &stage) && cs_add_ok(partials, stage, out);
}

/* Twice the state: a scene change or a snapshot load builds the new state beside the old one and
 * lets the old one go only once the new one is adopted (and a rock change copies the rock list). */
cs_status cs_scene_memory(const cs_scene *scene, const cs_params *params, int32_t rocks, uint64_t *bytes)
{
    if (!scene || !bytes || rocks < 0) return CS_E_INVALID;
    if (scene->nx < 2 || scene->ny < 2) return CS_E_RANGE;
    uint64_t n, state, scratch, total, chunks;
    if (!cs_mul_ok((uint64_t)scene->nx, (uint64_t)scene->ny, &n)) return CS_E_LIMIT;
    if (!cs_mul_ok(n, CS_FLOATS_PER_VERTEX * sizeof(float) + 1, &state) ||
        !cs_add_ok(state, sizeof(cs_state) + (uint64_t)rocks * sizeof(cs_rock_state), &state) ||
        !scratch_bytes(scene, n, rocks, &scratch) || !cs_mul_ok(state, 2, &total) || !cs_add_ok(total, scratch, &total))
        return CS_E_LIMIT;
    /* the workspaces of implicit_euler and self_collision where the parameters use them (both
     * without parameters): the CPU backend's, the larger on the host. No engine runs more than
     * INT32_MAX vertices (its indices are int32). */
    if (n > INT32_MAX || !chunks_of(scene, &chunks)) return CS_E_LIMIT;
    if (!params || params->integrator == CS_IMPLICIT_EULER)
        total += cs_im_work_bytes(scene->nx, scene->ny, (int32_t)chunks); /* chunks <= n */
    if (!params || params->self_collision) total += cs_sc_work_bytes((int32_t)n);
    *bytes = total;
    return CS_OK;
}

cs_status cs_state_alloc(cs_state *s, int32_t n)
{
    memset(s, 0, sizeof *s);
    s->n = n;
    float **arrays[] = {&s->x, &s->y, &s->z, &s->vx, &s->vy, &s->vz, &s->ax, &s->ay, &s->az, &s->w};
    for (size_t i = 0; i < sizeof arrays / sizeof arrays[0]; i++)
        if (!(*arrays[i] = alloc_floats((size_t)n, sizeof(float)))) goto fail;
    if (!(s->L0 = alloc_floats((size_t)n * CS_NTYPES, sizeof(float)))) goto fail;
    if (!(s->L0_next = alloc_floats((size_t)n * CS_NTYPES, sizeof(float)))) goto fail;
    if (!(s->pinned = alloc_floats((size_t)n, 1))) goto fail;
    s->grab = -1;
    s->next_rock_id = 1;
    return CS_OK;
fail:
    cs_state_free(s);
    return CS_E_NOMEM;
}

void cs_state_free(cs_state *s)
{
    free(s->x);
    free(s->y);
    free(s->z);
    free(s->vx);
    free(s->vy);
    free(s->vz);
    free(s->ax);
    free(s->ay);
    free(s->az);
    free(s->w);
    free(s->L0);
    free(s->L0_next);
    free(s->pinned);
    free(s->rocks);
    memset(s, 0, sizeof *s);
    s->grab = -1;
}

#define CS_TYPE_DI(t, di, dj) di,
#define CS_TYPE_DJ(t, di, dj) dj,
const int cs_type_di[CS_NTYPES] = {CS_SPRING_TYPES(CS_TYPE_DI)};
const int cs_type_dj[CS_NTYPES] = {CS_SPRING_TYPES(CS_TYPE_DJ)};

int32_t cs_spring_far_end(int32_t nx, int32_t ny, int t, int32_t v)
{
    const int32_t i = v % nx, j = v / nx;
    return cs_far_end_on_grid(nx, ny, i, j, cs_type_di[t], cs_type_dj[t]) ? (j + cs_type_dj[t]) * nx + i + cs_type_di[t] : -1;
}

int cs_spring_exists(int32_t nx, int32_t ny, int t, int32_t v) { return cs_spring_far_end(nx, ny, t, v) >= 0; }

void cs_scene_rest(const cs_scene *scene, float rest[CS_NTYPES])
{
    const double hx = scene->size_x / (scene->nx - 1), hy = scene->size_y / (scene->ny - 1);
    rest[CS_SX] = (float)hx;
    rest[CS_SY] = (float)hy;
    rest[CS_D1] = rest[CS_D2] = (float)sqrt(hx * hx + hy * hy);
    rest[CS_BX] = (float)(2 * hx);
    rest[CS_BY] = (float)(2 * hy);
}

void cs_scene_build(const cs_scene *scene, cs_state *s)
{
    const int32_t nx = scene->nx, ny = scene->ny, n = nx * ny;
    for (int32_t j = 0; j < ny; j++) {
        for (int32_t i = 0; i < nx; i++) {
            const int32_t v = j * nx + i;
            const double u = -0.5 * scene->size_x + scene->size_x * i / (nx - 1);
            const double w = -0.5 * scene->size_y + scene->size_y * j / (ny - 1);
            s->x[v] = (float)u;
            if (scene->orientation == CS_VERTICAL) {
                s->y[v] = 0.0f;
                s->z[v] = (float)(scene->height + w);
            } else {
                s->y[v] = (float)w;
                s->z[v] = (float)scene->height;
            }
        }
    }
    /* Rest lengths from the float positions themselves, so the cloth starts exactly at rest. */
    for (int t = 0; t < CS_NTYPES; t++) {
        for (int32_t v = 0; v < n; v++) {
            const int32_t o = cs_spring_far_end(nx, ny, t, v);
            const float len = o < 0 ? CS_TORN : cs_len(cs_v3(s->x[o] - s->x[v], s->y[o] - s->y[v], s->z[o] - s->z[v]));
            s->L0[(size_t)t * n + v] = len;
        }
    }
    s->grab = -1;
    s->n_rocks = 0;
    s->next_rock_id = 1;
    s->step = 0;
    s->time = 0;
    s->n_torn = 0;
    cs_state_apply_preset(scene, s, (cs_pins)scene->pins);
}

void cs_state_apply_preset(const cs_scene *scene, cs_state *s, cs_pins preset)
{
    const int32_t nx = scene->nx, ny = scene->ny;
    for (int32_t j = 0; j < ny; j++) {
        for (int32_t i = 0; i < nx; i++) {
            const int border_i = i == 0 || i == nx - 1, border_j = j == 0 || j == ny - 1;
            int pin = 0;
            switch (preset) {
            case CS_PINS_CORNERS: pin = border_i && border_j; break;
            case CS_PINS_EDGES: pin = border_i || border_j; break;
            case CS_PINS_TOP_EDGE: pin = j == ny - 1; break;
            case CS_PINS_NONE: pin = 0; break;
            }
            s->pinned[j * nx + i] = (uint8_t)pin;
        }
    }
    cs_state_update_mask(s);
}

void cs_state_update_mask(cs_state *s)
{
    for (int32_t v = 0; v < s->n; v++) {
        const int fixed = s->pinned[v] || v == s->grab;
        s->w[v] = fixed ? 0.0f : 1.0f;
        if (fixed) s->ax[v] = s->ay[v] = s->az[v] = 0.0f;
        if (s->pinned[v]) s->vx[v] = s->vy[v] = s->vz[v] = 0.0f;
    }
}

void cs_rock_mass(cs_rock_state *r)
{
    const double R = r->radius, M = r->density * (4.0 / 3.0) * 3.14159265358979323846 * R * R * R;
    const double I = 0.4 * M * R * R;
    r->mass = (float)M;
    r->inertia = (float)I;
    r->inv_mass = r->kinematic ? 0.0f : (float)(1.0 / M);
    r->inv_inertia = r->kinematic ? 0.0f : (float)(1.0 / I);
}
