/* rock_json.h - rocks to and from the API's JSON. */
#ifndef CLOTHD_ROCK_JSON_H
#define CLOTHD_ROCK_JSON_H

#include <jansson.h>

#include "clothsim/clothsim.h"
#include "core/problem.h"

/* A rock as the API shows it: {id, kinematic, position, velocity, angular_velocity, orientation,
 * radius, density, mass}. */
json_t *rock_to_json(const cs_rock *r);
/* The fields a rock is made of (no id, no mass: the engine derives them), as a journaled command
 * keeps them. */
json_t *rock_def_to_json(const cs_rock_def *d);
/* Applies the members of obj onto def: position, velocity, angular_velocity, orientation,
 * radius, density, kinematic. With `creating`, position and radius are required. */
int rock_from_json(const json_t *obj, cs_rock_def *def, int creating, problem *pr);
/* The rocks of a list as a JSON array. */
json_t *rocks_to_json(const cs_rock *rocks, int n);

#endif
