/* params.c - the parameter table generated from the X-macro lists of params.h: defaults,
 * range checks and the rules that tie parameters together. */
#include "clothsim/params.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

static const char *const cs_ch_ORIENTATION[] = {CS_CHOICES_ORIENTATION, NULL};
static const char *const cs_ch_PINS[] = {CS_CHOICES_PINS, NULL};
static const char *const cs_ch_FRICTION[] = {CS_CHOICES_FRICTION, NULL};
static const char *const cs_ch_INTEGRATOR[] = {CS_CHOICES_INTEGRATOR, NULL};
static const char *const cs_ch_CONTACT[] = {CS_CHOICES_CONTACT, NULL};
#define CS_CH_NONE NULL
#define CS_CH_ORIENTATION cs_ch_ORIENTATION
#define CS_CH_PINS cs_ch_PINS
#define CS_CH_FRICTION cs_ch_FRICTION
#define CS_CH_INTEGRATOR cs_ch_INTEGRATOR
#define CS_CH_CONTACT cs_ch_CONTACT

#define CS_VEC3_UNPACK(a, b, c) {a, b, c}
#define CS_DEF_INT(d) {(double)(d), 0, 0}
#define CS_DEF_FLOAT(d) {(double)(d), 0, 0}
#define CS_DEF_BOOL(d) {(double)(d), 0, 0}
#define CS_DEF_ENUM(d) {(double)(d), 0, 0}
#define CS_DEF_VEC3(t) CS_VEC3_UNPACK t

#define CS_SCENE_ROW(name, type, unit, def, lo, hi, choices, help) \
    {#name, CS_T_##type, unit, CS_DEF_##type(def), lo, hi, CS_CH_##choices, CS_KIND_SCENE, help, offsetof(cs_scene, name)},
#define CS_LIVE_ROW(name, type, unit, def, lo, hi, choices, help) \
    {#name, CS_T_##type, unit, CS_DEF_##type(def), lo, hi, CS_CH_##choices, CS_KIND_LIVE, help, offsetof(cs_params, name)},

static const cs_param_info cs_table[] = {CS_SCENE_FIELDS(CS_SCENE_ROW) CS_LIVE_FIELDS(CS_LIVE_ROW)};
#define CS_TABLE_LEN (sizeof cs_table / sizeof cs_table[0])

size_t cs_param_count(void) { return CS_TABLE_LEN; }

const cs_param_info *cs_param_at(size_t i) { return i < CS_TABLE_LEN ? &cs_table[i] : NULL; }

const cs_param_info *cs_param_find(const char *name)
{
    if (!name) return NULL;
    for (size_t i = 0; i < CS_TABLE_LEN; i++)
        if (strcmp(cs_table[i].name, name) == 0) return &cs_table[i];
    return NULL;
}

const char *cs_param_type_name(cs_param_type t)
{
    static const char *const names[] = {"int", "float", "bool", "enum", "vec3"};
    return (unsigned)t < 5 ? names[t] : "?";
}

const char *cs_param_kind_name(cs_param_kind k) { return k == CS_KIND_SCENE ? "scene" : "live"; }

int cs_param_choice(const cs_param_info *p, const char *name)
{
    if (!p || !p->choices || !name) return -1;
    for (int i = 0; p->choices[i]; i++)
        if (strcmp(p->choices[i], name) == 0) return i;
    return -1;
}

int cs_param_choice_count(const cs_param_info *p)
{
    int n = 0;
    if (p && p->choices)
        while (p->choices[n]) n++;
    return n;
}

static int components(const cs_param_info *p) { return p->type == CS_T_VEC3 ? 3 : 1; }

double cs_param_get(const cs_param_info *p, const void *base, int i)
{
    const char *field = (const char *)base + p->offset;
    switch (p->type) {
    case CS_T_FLOAT: return *(const float *)field;
    case CS_T_VEC3: return ((const float *)field)[i >= 0 && i < 3 ? i : 0];
    default: return *(const int32_t *)field;
    }
}

int cs_param_check(const cs_param_info *p, const double *v, char *why, size_t why_len)
{
    for (int i = 0; i < components(p); i++) {
        const double x = v[i];
        if (!isfinite(x)) {
            snprintf(why, why_len, "%s must be a finite number", p->name);
            return -1;
        }
        if (p->type == CS_T_BOOL && x != 0 && x != 1) {
            snprintf(why, why_len, "%s must be true or false", p->name);
            return -1;
        }
        if ((p->type == CS_T_INT || p->type == CS_T_ENUM) && x != floor(x)) {
            snprintf(why, why_len, "%s must be a whole number", p->name);
            return -1;
        }
        /* a float field is checked against its limits as a float holds them (0.01 is held as
         * 0.0099999998: a value at the limit, stored and checked again, stays in range) */
        const int flt = p->type == CS_T_FLOAT || p->type == CS_T_VEC3;
        const double lo = flt ? (double)(float)p->min : p->min, hi = flt ? (double)(float)p->max : p->max;
        if (x < lo || x > hi) {
            snprintf(why, why_len, "%s must be between %g and %g (got %g)", p->name, p->min, p->max, x);
            return -1;
        }
        /* A float field must hold the value without overflowing to infinity or flushing a
         * non-zero value to zero. */
        if ((p->type == CS_T_FLOAT || p->type == CS_T_VEC3) && x != 0 && (float)x == 0.0f) {
            snprintf(why, why_len, "%s is too small to represent (got %g)", p->name, x);
            return -1;
        }
    }
    return 0;
}

int cs_param_set(const cs_param_info *p, void *base, const double *v, char *why, size_t why_len)
{
    if (cs_param_check(p, v, why, why_len) != 0) return -1;
    char *field = (char *)base + p->offset;
    switch (p->type) {
    case CS_T_FLOAT: *(float *)field = (float)v[0]; break;
    case CS_T_VEC3:
        for (int i = 0; i < 3; i++) ((float *)field)[i] = (float)v[i];
        break;
    default: *(int32_t *)field = (int32_t)v[0]; break;
    }
    return 0;
}

static void fill_defaults(cs_param_kind kind, void *base)
{
    char why[8];
    for (size_t i = 0; i < CS_TABLE_LEN; i++)
        if (cs_table[i].kind == kind) cs_param_set(&cs_table[i], base, cs_table[i].def, why, sizeof why);
}

void cs_scene_default(cs_scene *s)
{
    memset(s, 0, sizeof *s);
    fill_defaults(CS_KIND_SCENE, s);
}

void cs_params_default(cs_params *p)
{
    memset(p, 0, sizeof *p);
    fill_defaults(CS_KIND_LIVE, p);
}

cs_integrator cs_params_default_integrator(const char *backend)
{
    cs_params p;
    cs_params_default(&p);
    return backend && strcmp(backend, "cuda") == 0 ? CS_VELOCITY_VERLET : p.integrator;
}

static int validate_rows(cs_param_kind kind, const void *base, const char **bad, char *why, size_t why_len)
{
    for (size_t i = 0; i < CS_TABLE_LEN; i++) {
        const cs_param_info *p = &cs_table[i];
        if (p->kind != kind) continue;
        double v[3];
        for (int c = 0; c < components(p); c++) v[c] = cs_param_get(p, base, c);
        if (cs_param_check(p, v, why, why_len) != 0) {
            if (bad) *bad = p->name;
            return -1;
        }
    }
    return 0;
}

int cs_scene_validate(const cs_scene *s, const char **bad, char *why, size_t why_len)
{
    return validate_rows(CS_KIND_SCENE, s, bad, why, why_len);
}

int cs_params_validate(const cs_params *p, const char **bad, char *why, size_t why_len)
{
    if (validate_rows(CS_KIND_LIVE, p, bad, why, why_len) != 0) return -1;
    if (p->substeps > p->max_substeps) {
        if (bad) *bad = "substeps";
        snprintf(why, why_len, "substeps (%d) must not exceed max_substeps (%d)", (int)p->substeps,
                 (int)p->max_substeps);
        return -1;
    }
    return 0;
}
