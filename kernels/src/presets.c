/* presets.c - named scenes that show self_collision (kernels/MODEL.md, "Scene presets"): each sets
 * scene fields and live parameters over the caller's, then, once the cloth is built, its pins and
 * rocks. One table: the daemon's PUT /v1/scene {"preset"} and its listing read it. */
#include <string.h>

#include "clothsim/clothsim.h"

typedef struct preset {
    const char *name, *description;
    void (*scene)(cs_scene *sc, cs_params *p);
    cs_status (*populate)(cs_sim *sim, const cs_scene *sc);
} preset;

/* What every preset shares: a 1 m square cloth of 32 x 32, self_collision on under implicit_euler
 * (the explicit integrators pay the pass every substep), no pins of the scene's own. */
static void common(cs_scene *sc, cs_params *p)
{
    sc->nx = sc->ny = 32;
    sc->size_x = sc->size_y = 1.0f;
    sc->pins = CS_PINS_NONE;
    p->self_collision = 1;
    p->integrator = CS_IMPLICIT_EULER;
    p->wind[0] = p->wind[1] = p->wind[2] = 0.0f;
}

/* A towel over a line: pinned along its middle row, 1.2 m up, its halves hanging down either side
 * and blown against each other by a 3 m/s side wind. */
static void towel_scene(cs_scene *sc, cs_params *p)
{
    common(sc, p);
    sc->orientation = CS_HORIZONTAL;
    sc->height = 1.2f;
    p->wind[1] = 3.0f;
}

static cs_status towel_pins(cs_sim *sim, const cs_scene *sc)
{
    int32_t row[1024];
    const int32_t j = sc->ny / 2, n = sc->nx < 1024 ? sc->nx : 1024;
    for (int32_t i = 0; i < n; i++) row[i] = j * sc->nx + i;
    return cs_pin(sim, row, (size_t)n, true);
}

/* A cloth dropped over a stone: free, 0.9 m up, over a 0.25 m stone resting on the ground. */
static void stone_scene(cs_scene *sc, cs_params *p)
{
    common(sc, p);
    sc->orientation = CS_HORIZONTAL;
    sc->height = 0.9f;
}

/* A stone of radius r at (x, 0, z). */
static cs_status add_stone(cs_sim *sim, float r, float x, float z, bool kinematic)
{
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.radius = r;
    d.position[0] = x;
    d.position[2] = z;
    d.kinematic = kinematic;
    uint32_t id;
    return cs_rock_add(sim, &d, &id);
}

static cs_status stone_rock(cs_sim *sim, const cs_scene *sc)
{
    (void)sc;
    return add_stone(sim, 0.25f, 0.0f, 0.25f, true);
}

/* A sheet crumpling on the ground: free and upright, its lower edge 0.1 m above the ground, blown
 * over by a 2 m/s side wind so that it folds onto itself as it lands (lying flat, it stayed a
 * single layer under the stone: without self_collision nothing crossed in 10 s under
 * implicit_euler); a 0.15 m stone dropped onto the pile from 1.5 m. */
static void crumple_scene(cs_scene *sc, cs_params *p)
{
    common(sc, p);
    sc->orientation = CS_VERTICAL;
    sc->height = 0.6f;
    p->wind[1] = 2.0f;
}

static cs_status crumple_rock(cs_sim *sim, const cs_scene *sc)
{
    (void)sc;
    return add_stone(sim, 0.15f, 0.1f, 1.5f, false);
}

static const preset presets[] = {
    {"towel-on-line", "a towel pinned over a line, blown by a side wind", towel_scene, towel_pins},
    {"cloth-over-stone", "a free cloth dropped over a stone on the ground", stone_scene, stone_rock},
    {"sheet-crumple", "an upright sheet blown over onto the ground, folding on itself, and a stone dropped on it", crumple_scene, crumple_rock},
};

int cs_preset_count(void) { return (int)(sizeof presets / sizeof presets[0]); }

const char *cs_preset_name(int k) { return k >= 0 && k < cs_preset_count() ? presets[k].name : NULL; }

const char *cs_preset_description(int k) { return k >= 0 && k < cs_preset_count() ? presets[k].description : NULL; }

int cs_preset_find(const char *name)
{
    for (int k = 0; name && k < cs_preset_count(); k++)
        if (strcmp(presets[k].name, name) == 0) return k;
    return -1;
}

void cs_preset_scene(int k, cs_scene *scene, cs_params *params)
{
    if (k >= 0 && k < cs_preset_count()) presets[k].scene(scene, params);
}

cs_status cs_preset_populate(cs_sim *sim, int k)
{
    if (!sim || k < 0 || k >= cs_preset_count()) return CS_E_INVALID;
    cs_scene sc;
    cs_sim_scene(sim, &sc);
    return presets[k].populate(sim, &sc);
}
