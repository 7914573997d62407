/* rock_json.c - rocks to and from JSON (see rock_json.h). */
#include <math.h>
#include <string.h>

#include "core/json_read.h"
#include "core/json_write.h"
#include "core/rock_json.h"

static json_t *floats(const float *v, int n)
{
    json_t *a = json_array();
    for (int k = 0; k < n; k++) json_array_append_new(a, json_float(v[k]));
    return a;
}

json_t *rocks_to_json(const cs_rock *rocks, int n)
{
    json_t *list = json_array();
    for (int k = 0; k < n; k++) json_array_append_new(list, rock_to_json(&rocks[k]));
    return list;
}

json_t *rock_def_to_json(const cs_rock_def *d)
{
    cs_rock r;
    memset(&r, 0, sizeof r);
    r.def = *d;
    json_t *o = rock_to_json(&r);
    json_object_del(o, "id");
    json_object_del(o, "mass");
    return o;
}

json_t *rock_to_json(const cs_rock *r)
{
    const cs_rock_def *d = &r->def;
    return json_pack("{s:I, s:b, s:o, s:o, s:o, s:o, s:o, s:o, s:o}", "id", (json_int_t)r->id, "kinematic",
                     d->kinematic, "position", floats(d->position, 3), "velocity", floats(d->velocity, 3),
                     "angular_velocity", floats(d->angular_velocity, 3), "orientation", floats(d->orientation, 4),
                     "radius", json_float(d->radius), "density", json_float(d->density), "mass", json_float(r->mass));
}

static int positive_float(const json_t *v, const char *name, float *out, problem *pr)
{
    if (!json_is_number(v)) return problem_set(pr, 400, "wrong-type", name, "%s must be a number", name);
    const double d = json_number_value(v);
    if (!(d > 0) || !isfinite((float)d)) return problem_set(pr, 422, "out-of-range", name, "%s must be a positive number", name);
    *out = (float)d;
    return 0;
}

int rock_from_json(const json_t *obj, cs_rock_def *def, int creating, problem *pr)
{
    static const char *const fields[] = {"position", "velocity", "angular_velocity", "orientation", "radius",
                                         "density",  "kinematic", NULL};
    if (!json_is_object(obj)) return problem_set(pr, 400, "wrong-type", NULL, "the body must be a JSON object");
    if (only_fields(obj, fields, pr) != 0) return -1;
    if (creating && !json_object_get(obj, "position")) return problem_set(pr, 422, "out-of-range", "position", "position is required");
    if (creating && !json_object_get(obj, "radius")) return problem_set(pr, 422, "out-of-range", "radius", "radius is required");
    cs_rock_def d = *def;
    const json_t *v;
    if ((v = json_object_get(obj, "position")) && vec3_from_json(v, d.position, "position", pr) != 0) return -1;
    if ((v = json_object_get(obj, "velocity")) && vec3_from_json(v, d.velocity, "velocity", pr) != 0) return -1;
    if ((v = json_object_get(obj, "angular_velocity")) && vec3_from_json(v, d.angular_velocity, "angular_velocity", pr) != 0)
        return -1;
    if ((v = json_object_get(obj, "orientation"))) {
        if (!json_is_array(v) || json_array_size(v) != 4)
            return problem_set(pr, 400, "wrong-type", "orientation", "orientation must be an array of 4 numbers");
        for (size_t k = 0; k < 4; k++) {
            const json_t *e = json_array_get(v, k);
            if (!json_is_number(e))
                return problem_set(pr, 400, "wrong-type", "orientation", "orientation must be an array of 4 numbers");
            d.orientation[k] = (float)json_number_value(e);
        }
    }
    if ((v = json_object_get(obj, "radius")) && positive_float(v, "radius", &d.radius, pr) != 0) return -1;
    if ((v = json_object_get(obj, "density")) && positive_float(v, "density", &d.density, pr) != 0) return -1;
    if ((v = json_object_get(obj, "kinematic"))) {
        if (!json_is_boolean(v)) return problem_set(pr, 400, "wrong-type", "kinematic", "kinematic must be true or false");
        d.kinematic = json_is_true(v);
    }
    *def = d;
    return 0;
}
