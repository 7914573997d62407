/* clothsim/params.h - the scene and the live parameters, and the one table that describes them.
 *
 * Every tunable of the engine (kernels/MODEL.md) is declared once, in the X-macro lists below: its C field,
 * type, unit, default, range, choices, kind and help text. The structs, the default values, the
 * validation and the table that the daemon, its config file and the viewer's panel read are all
 * generated from these lists, so adding a parameter is one line. */
#ifndef CLOTHSIM_PARAMS_H
#define CLOTHSIM_PARAMS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef enum cs_orientation { CS_HORIZONTAL = 0, CS_VERTICAL = 1 } cs_orientation;
typedef enum cs_pins { CS_PINS_CORNERS = 0, CS_PINS_EDGES = 1, CS_PINS_TOP_EDGE = 2, CS_PINS_NONE = 3 } cs_pins;
typedef enum cs_friction { CS_FRICTION_COULOMB_VISCOUS = 0, CS_FRICTION_RESULTANT = 1 } cs_friction;
typedef enum cs_integrator { CS_VELOCITY_VERLET = 0, CS_SYMPLECTIC_EULER = 1, CS_IMPLICIT_EULER = 2 } cs_integrator;
typedef enum cs_contact_model { CS_CONTACT_VERTEX = 0, CS_CONTACT_SURFACE = 1 } cs_contact_model;

/* Choice lists, in enum order. */
#define CS_CHOICES_ORIENTATION "horizontal", "vertical"
#define CS_CHOICES_PINS "corners", "edges", "top-edge", "none"
#define CS_CHOICES_FRICTION "coulomb_viscous", "resultant"
#define CS_CHOICES_INTEGRATOR "velocity_verlet", "symplectic_euler", "implicit_euler"
#define CS_CHOICES_CONTACT "vertex", "surface"

/* Scene fields: changing one rebuilds the cloth.
 * X(field, TYPE, unit, default, min, max, CHOICES, help): TYPE is INT, FLOAT, BOOL, ENUM or VEC3;
 * a VEC3 default is a parenthesised triple; CHOICES names a CS_CHOICES_* list or NONE. */
#define CS_SCENE_FIELDS(X)                                                                                  \
    X(nx, INT, "-", 64, 2, 4096, NONE, "Vertices along the cloth's first axis (x)")                         \
    X(ny, INT, "-", 64, 2, 4096, NONE, "Vertices along the cloth's second axis (y, or z when vertical)")    \
    X(size_x, FLOAT, "m", 2.0, 1e-3, 1e3, NONE, "Cloth extent along x")                                     \
    X(size_y, FLOAT, "m", 2.0, 1e-3, 1e3, NONE, "Cloth extent along its second axis")                       \
    X(height, FLOAT, "m", 1.0, -1e4, 1e4, NONE, "Height of the cloth's centre")                             \
    X(orientation, ENUM, "-", CS_HORIZONTAL, 0, 1, ORIENTATION, "horizontal: in the xy-plane; vertical: hanging in the xz-plane") \
    X(pins, ENUM, "-", CS_PINS_EDGES, 0, 3, PINS, "Pinned vertices: corners, edges (all four borders), top-edge (curtain) or none") \
    X(areal_density, FLOAT, "kg/m^2", 0.3, 1e-4, 1e4, NONE, "Mass per unit area (a cotton fleece knit: 0.3); every vertex gets an equal share")

/* Live parameters: applied at the next substep.
 * VEC3 defaults and ranges apply to each component. */
#define CS_LIVE_FIELDS(X)                                                                                   \
    X(gravity, VEC3, "m/s^2", (0.0, 0.0, -9.81), -1e3, 1e3, NONE, "Gravitational acceleration")  \
    X(wind, VEC3, "m/s", (0.0, 0.0, 0.0), -1e3, 1e3, NONE, "Air velocity seen by the cloth's drag") \
    X(k_structural, FLOAT, "N/m", 2000.0, 0, 1e9, NONE, "Stiffness of the springs to the 4 direct neighbours (the sheet stretches with about k_structural + k_shear / 2 + 4 k_bend N/m)") \
    X(k_shear, FLOAT, "N/m", 200.0, 0, 1e9, NONE, "Stiffness of the diagonal springs")                     \
    X(k_bend, FLOAT, "N/m", 20.0, 0, 1e9, NONE, "Stiffness of the springs that skip one vertex")           \
    X(c_spring, FLOAT, "N s/m", 0.01, 0, 1e6, NONE, "Damping along every spring")                          \
    X(drag, FLOAT, "1/s", 0.2, 0, 1e3, NONE, "Air drag on cloth vertices, relative to the wind")          \
    X(plastic_yield, FLOAT, "-", 0.0, 0, 100, NONE, "Strain past which a stretched spring's rest length grows; 0 = off") \
    X(tear_strain, FLOAT, "-", 0.0, 0, 100, NONE, "Strain past which a spring is removed for good; 0 = off") \
    X(plastic_rate, FLOAT, "1/s", 0.0, 0, 1e6, NONE, "Speed of plastic flow; 0 = instant (rest length jumps to the length)") \
    X(k_contact, FLOAT, "N/m", 500.0, 0, 1e9, NONE, "Penalty stiffness of cloth-rock and cloth-ground contact") \
    X(c_contact, FLOAT, "N s/m", 0.05, 0, 1e6, NONE, "Normal damping of cloth contact")                    \
    X(c_tangent, FLOAT, "N s/m", 0.02, 0, 1e6, NONE, "Viscous tangential friction coefficient of cloth contact (coulomb_viscous)") \
    X(mu, FLOAT, "-", 0.5, 0, 100, NONE, "Coulomb friction coefficient of cloth contact")                 \
    X(contact_offset, FLOAT, "m", 0.01, 0, 10, NONE, "Cloth thickness: contact starts this far from a surface") \
    X(friction_model, ENUM, "-", CS_FRICTION_COULOMB_VISCOUS, 0, 1, FRICTION, "coulomb_viscous (seed 000) or resultant (seed 003)") \
    X(contact_model, ENUM, "-", CS_CONTACT_SURFACE, 0, 1, CONTACT, "surface: rocks meet the cloth's triangles; vertex: seed 000's contact per vertex") \
    X(max_depenetration_speed, FLOAT, "m/s", 3.0, 0, 1e4, NONE, "No contact pushes two bodies apart faster than this; 0 = no cap") \
    X(placement_overlap, FLOAT, "m", 0.0, 0, 10, NONE, "How far a rock placement may overlap another rock or hold the cloth inside its radius; deeper is refused") \
    X(k_rock, FLOAT, "N/(m kg)", 1e6, 0, 1e10, NONE, "Stiffness of rock-rock and rock-ground contact per kg of the pair's reduced mass") \
    X(c_rock, FLOAT, "N s/(m kg)", 500.0, 0, 1e8, NONE, "Normal and tangential damping of rock contact per kg of reduced mass") \
    X(mu_rock, FLOAT, "-", 0.5, 0, 100, NONE, "Coulomb friction coefficient of rock contact")             \
    X(ground, BOOL, "-", 1, 0, 1, NONE, "Whether the ground plane exists")                                 \
    X(ground_z, FLOAT, "m", 0.0, -1e4, 1e4, NONE, "Height of the ground plane")                            \
    X(frame_rate, FLOAT, "1/s", 60.0, 1, 1000, NONE, "Frames per second of simulated time")                \
    X(substeps, INT, "-", 30, 1, 100000, NONE, "Substeps per frame requested; the stability guard may run more") \
    X(max_substeps, INT, "-", 1000, 1, 100000, NONE, "Most substeps per frame the stability guard may choose") \
    X(auto_substeps, BOOL, "-", 1, 0, 1, NONE, "Raise substeps when a change needs it (else refuse the change)") \
    X(stability_safety, FLOAT, "-", 0.7, 0.01, 1, NONE, "Fraction of the stable time step the guard allows") \
    X(integrator, ENUM, "-", CS_IMPLICIT_EULER, 0, 2, INTEGRATOR, "velocity_verlet (kick-drift-kick), symplectic_euler, or implicit_euler (backward Euler solved by Newton and multigrid-preconditioned conjugate gradients: stiff springs cost no substeps); the daemon on the CUDA backend defaults to velocity_verlet") \
    X(grab_speed, FLOAT, "m/s", 5.0, 0.001, 1000, NONE, "Fastest a grabbed vertex moves toward its target") \
    X(implicit_substeps, INT, "-", 1, 1, 100000, NONE, "Substeps per frame under implicit_euler (a substep is cut in parts while cloth near a rock would close on it by more than contact_offset or a quarter of its radius)") \
    X(solver_iterations, INT, "-", 2, 1, 100, NONE, "implicit_euler: most Newton iterations per substep") \
    X(solver_tolerance, FLOAT, "-", 1e-3, 1e-7, 0.5, NONE, "implicit_euler: a substep stops once its residual (the net force's norm) is this fraction of its first") \
    X(cg_iterations, INT, "-", 30, 1, 1000, NONE, "implicit_euler: most conjugate-gradient iterations per Newton iteration, each preconditioned by one multigrid V-cycle") \
    X(self_collision, BOOL, "-", 0, 0, 1, NONE, "Whether the cloth collides with itself: its layers push apart and never pass through each other") \
    X(self_thickness, FLOAT, "m", 0.005, 1e-4, 0.5, NONE, "self_collision: layers of the cloth push apart while closer than this") \

#define CS_FIELD_DECL_INT(name) int32_t name;
#define CS_FIELD_DECL_FLOAT(name) float name;
#define CS_FIELD_DECL_BOOL(name) int32_t name; /* 0 or 1 */
#define CS_FIELD_DECL_ENUM(name) int32_t name;
#define CS_FIELD_DECL_VEC3(name) float name[3];
#define CS_FIELD_DECL(name, type, unit, def, lo, hi, choices, help) CS_FIELD_DECL_##type(name)

/* The scene: what the cloth is built from. Fill with cs_scene_default(). */
typedef struct cs_scene {
    CS_SCENE_FIELDS(CS_FIELD_DECL)
} cs_scene;

/* The live parameters. Fill with cs_params_default(). */
typedef struct cs_params {
    CS_LIVE_FIELDS(CS_FIELD_DECL)
} cs_params;

typedef enum cs_param_type { CS_T_INT, CS_T_FLOAT, CS_T_BOOL, CS_T_ENUM, CS_T_VEC3 } cs_param_type;
typedef enum cs_param_kind { CS_KIND_SCENE, CS_KIND_LIVE } cs_param_kind;

/* One row of the parameter table. */
typedef struct cs_param_info {
    const char *name;
    cs_param_type type;
    const char *unit;
    double def[3];             /* default (one component unless VEC3) */
    double min, max;           /* inclusive range of each component (enum: index range) */
    const char *const *choices;/* enum names in index order, NULL-terminated; NULL otherwise */
    cs_param_kind kind;
    const char *help;
    size_t offset;             /* of the field in cs_scene (scene) or cs_params (live) */
} cs_param_info;

/* The table: scene fields first, then live parameters. */
size_t cs_param_count(void);
const cs_param_info *cs_param_at(size_t i);
/* Row by name, or NULL. */
const cs_param_info *cs_param_find(const char *name);
const char *cs_param_type_name(cs_param_type t);  /* "int", "float", "bool", "enum", "vec3" */
const char *cs_param_kind_name(cs_param_kind k);  /* "scene", "live" */
/* Enum choice index of a name, or -1. */
int cs_param_choice(const cs_param_info *p, const char *name);
/* Number of choices of an enum (0 otherwise). */
int cs_param_choice_count(const cs_param_info *p);

/* The struct a row's field lives in: cs_scene for scene rows, cs_params for live rows. */
#define CS_PARAM_BASE(p, scene, params) ((p)->kind == CS_KIND_SCENE ? (void *)(scene) : (void *)(params))

/* Reads component i (0..2; 0 unless VEC3) of a row's field as a double (bool 0/1, enum index). */
double cs_param_get(const cs_param_info *p, const void *base, int i);
/* Checks v[0..n) (n = 3 for VEC3, else 1) against the row: finite, in range, whole for int/enum,
 * 0/1 for bool. Returns 0 when acceptable, else -1 with a reason in why. Changes nothing. */
int cs_param_check(const cs_param_info *p, const double *v, char *why, size_t why_len);
/* Checks then writes v into the row's field; returns cs_param_check's result. */
int cs_param_set(const cs_param_info *p, void *base, const double *v, char *why, size_t why_len);

void cs_scene_default(cs_scene *s);
void cs_params_default(cs_params *p);
/* The integrator that runs the default scene cheapest on a backend ("cpu", "cuda"): the table's
 * default, implicit_euler, measured on the CPU; velocity_verlet on CUDA, by its cost model
 * (kernels/MODEL.md, "Decisions the model leaves open"). The daemon and the benchmark's batches
 * take it where the integrator is not given. */
cs_integrator cs_params_default_integrator(const char *backend);
/* Validates every field and the relations between them; on failure returns -1, the offending
 * name (static string) in *bad and a reason in why. */
int cs_scene_validate(const cs_scene *s, const char **bad, char *why, size_t why_len);
int cs_params_validate(const cs_params *p, const char **bad, char *why, size_t why_len);

#ifdef __cplusplus
}
#endif
#endif
