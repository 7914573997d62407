/* autodrop.c - the automatic drops (see autodrop.h). */
#include <string.h>

#include "core/log.h"
#include "sim/autodrop.h"
#include "sim/commands.h"

/* splitmix64: the drops' random numbers, from `seed`. */
static uint64_t next_u64(uint64_t *s)
{
    uint64_t z = (*s += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}
static double uniform(uint64_t *s) { return (double)(next_u64(s) >> 11) * (1.0 / 9007199254740992.0); }

/* A rock of the drawn size at the drawn spot, for the scene's cloth. */
static json_t *drawn_rock(scene *sc)
{
    cs_scene f;
    cs_sim_scene(sc->engine, &f);
    const double size = f.size_x < f.size_y ? f.size_x : f.size_y;
    const double u = uniform(&sc->rng), v = uniform(&sc->rng), w = uniform(&sc->rng);
    const double radius = (0.025 + 0.035 * w) * size;
    if (f.orientation == CS_HORIZONTAL) {
        /* Dropped from above, anywhere over the middle 70% of the net. */
        const double z = f.height + 0.4 * (f.size_x > f.size_y ? f.size_x : f.size_y);
        return json_pack("{s:[f,f,f], s:f, s:[f,f,f]}", "position", (u - 0.5) * 0.7 * f.size_x, (v - 0.5) * 0.7 * f.size_y,
                         z, "radius", radius, "angular_velocity", 4.0 * (u - 0.5), 4.0 * (v - 0.5), 0.0);
    }
    /* Thrown at the hanging curtain from in front of it. */
    return json_pack("{s:[f,f,f], s:f, s:[f,f,f]}", "position", (u - 0.5) * 0.7 * f.size_x, -0.5 * f.size_y,
                     f.height + (v - 0.5) * 0.6 * f.size_y, "radius", radius, "velocity", 0.0, 4.0, 1.0);
}

void autodrop_after_frame(scene *sc)
{
    const loop_settings *p = &sc->loop;
    if (p->seed != sc->seed) scene_reseed(sc);
    if (p->auto_drop_interval <= 0 || p->auto_drop_max <= 0) return;
    cs_info info;
    cs_sim_info(sc->engine, &info);
    if (info.time < sc->next_drop) return;
    sc->next_drop = info.time + p->auto_drop_interval;
    json_t *result = NULL;
    problem pr;
    /* The oldest automatic rocks go first. */
    while (sc->n_autos > 0 && sc->n_autos >= p->auto_drop_max) {
        json_t *cmd = json_pack("{s:s, s:I, s:s}", "op", "rock_remove", "id", (json_int_t)sc->autos[0], "by", "auto");
        if (command_change(sc, cmd, NULL, &result, &pr) == 0) json_decref(result);
        json_decref(cmd);
        memmove(sc->autos, sc->autos + 1, sizeof sc->autos[0] * (size_t)(sc->n_autos - 1));
        sc->n_autos--;
    }
    if (cs_rock_count(sc->engine) >= cs_sim_rock_limit(sc->engine)) return;
    json_t *cmd = json_pack("{s:s, s:o, s:s}", "op", "rock_add", "rock", drawn_rock(sc), "by", "auto");
    if (command_change(sc, cmd, NULL, &result, &pr) == 0) {
        sc->autos[sc->n_autos++] = (uint32_t)json_integer_value(json_object_get(result, "id"));
        json_decref(result);
    } else {
        log_msg("automatic drop refused: %s", pr.detail);
    }
    json_decref(cmd);
}
