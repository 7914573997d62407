/* settings.h - the one table of everything clothd can be told, and reading it from text.
 *
 * A row is a startup setting (listen, port, limits, ...: CLI flags, CLOTHD_* variables and the
 * config file only), an engine parameter (clothsim/params.h: the scene fields and the live
 * parameters) or a daemon-loop setting (live too, but the daemon's: pacing, automatic drops,
 * checkpoints). Every row has the same shape - name, type, unit, default, range or choices,
 * kind, help - so that the command line, the environment, the config file, --help,
 * --help-markdown and GET /v1/params/schema each loop over one table once.
 *
 * Startup and daemon-loop settings are declared once in the X-macros below, in the engine's row
 * shape; engine parameters come from the engine's own table. Adding any is one line. */
#ifndef CLOTHD_SETTINGS_H
#define CLOTHD_SETTINGS_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "clothsim/params.h"

/* The viewer assembled by the build (build/web); an installed clothd is told --web-root. */
#ifndef CLOTHD_WEB_ROOT
#define CLOTHD_WEB_ROOT "web"
#endif

/* Choice lists of the startup settings, in enum order. */
#define CLOTHD_CHOICES_BACKEND "auto", "cuda", "cpu"
#define CLOTHD_CHOICES_STATE_FILE_INVALID "refuse", "fresh"
#define CLOTHD_CHOICES_LOG_FORMAT "text", "json"
#define CLOTHD_CHOICES_LOG_LEVEL "debug", "info", "warn", "error"
enum { BACKEND_AUTO, BACKEND_CUDA, BACKEND_CPU };
enum { STATE_INVALID_REFUSE, STATE_INVALID_FRESH };
enum { LOG_FORMAT_TEXT, LOG_FORMAT_JSON };
enum { LOG_DEBUG, LOG_INFO, LOG_WARN, LOG_ERROR };

/* X(name, TYPE, unit, default, min, max, CHOICES, help), as clothsim/params.h: TYPE is STR (a
 * string default), INT, FLOAT, BOOL or ENUM (an index default; CHOICES names a CLOTHD_CHOICES_*
 * list). */
#define CLOTHD_SETTINGS(X)                                                                             \
    X(config, STR, "-", "", 0, 0, NONE, "Config file of 'name = value' lines (CLI and environment only)") \
    X(listen, STR, "-", "127.0.0.1", 0, 0, NONE, "Address the HTTP API listens on")                    \
    X(port, INT, "-", 8080, 0, 65535, NONE, "HTTP port; 0 picks a free one and logs it")               \
    X(stream_port, INT, "-", 8081, 0, 65535, NONE, "WebSocket stream port; 0 picks a free one")        \
    X(backend, ENUM, "-", BACKEND_AUTO, 0, 2, BACKEND, "Physics backend: auto uses CUDA when a device is present") \
    X(token_file, STR, "-", "", 0, 0, NONE, "File holding the control token (all routes)")             \
    X(view_token_file, STR, "-", "", 0, 0, NONE, "File holding the view token (GET routes and the stream)") \
    X(insecure, BOOL, "-", 0, 0, 1, NONE, "Allow listening beyond loopback without a token (anyone who reaches it has control)") \
    X(allowed_hosts, STR, "-", "", 0, 0, NONE, "Host names the API answers to besides IP addresses and localhost (comma-separated; * any)") \
    X(allowed_origins, STR, "-", "", 0, 0, NONE, "Page origins that may change the state and open the stream besides the viewer's own (comma-separated scheme://host[:port]; * any)") \
    X(state_file, STR, "-", "", 0, 0, NONE, "State saved here (crash-safe) on SIGTERM/SIGINT and after a backend failure; resumed from at start") \
    X(state_file_invalid, ENUM, "-", STATE_INVALID_REFUSE, 0, 1, STATE_FILE_INVALID, "A corrupt or foreign state file at start: refuse to start, or move it to <file>.bad-<time> and start afresh") \
    X(web_root, STR, "-", CLOTHD_WEB_ROOT, 0, 0, NONE, "Directory of the viewer's static files, served at /") \
    X(paused, BOOL, "-", 0, 0, 1, NONE, "Start paused (POST /v1/sim/resume runs it)")                  \
    X(threads, INT, "-", 0, 0, 256, NONE, "CPU backend threads; 0 = auto: the fewest, up to one per core, that keep the scenes in real time (every one for a step or max_speed)")                     \
    X(http_threads, INT, "-", 2, 1, 64, NONE, "Threads serving HTTP")                                  \
    X(http_nice, INT, "-", 5, 0, 19, NONE, "Niceness of the HTTP threads: under overload the simulation keeps the CPU") \
    X(max_body, INT, "-", 1048576, 1024, 1073741824, NONE, "Largest request body in bytes (413 beyond)") \
    X(max_connections, INT, "-", 512, 1, 100000, NONE, "Most HTTP connections at once")                \
    X(max_connections_per_ip, INT, "-", 64, 1, 100000, NONE, "Most HTTP connections at once from one address") \
    X(rate_limit, INT, "-", 50, 0, 1000000, NONE, "Changing requests (POST, PUT, PATCH, DELETE) per second per address, after the burst; 0 = no limit (429 beyond)") \
    X(rate_burst, INT, "-", 500, 1, 1000000, NONE, "Changing requests one address may make at once before rate_limit applies") \
    X(connection_timeout, INT, "-", 60, 1, 86400, NONE, "Seconds an idle HTTP connection stays open")  \
    X(header_timeout, INT, "-", 10, 1, 3600, NONE, "Seconds a client has to send a request's head, from when its connection was opened or its previous answer sent (slowloris)") \
    X(min_body_rate, INT, "-", 1024, 0, 1073741824, NONE, "Slowest a request body may arrive, in bytes per second on average after header_timeout; 0 = no minimum") \
    X(max_rocks, INT, "-", 256, 1, 1024, NONE, "Most rocks in the simulation")                         \
    X(max_state_mb, INT, "-", 1024, 1, 1048576, NONE, "MiB the scenes may take together (each one's state, checkpoints, frame and encode buffers, the backend's scratch, the workspaces of implicit_euler and self_collision while on), estimated before any allocation (a scene, scene change, snapshot or parameter change past it is 422)") \
    X(max_scenes, INT, "-", 64, 1, 4096, NONE, "Most scenes the daemon holds (POST /v1/scenes is 422 beyond)") \
    X(stream_max_clients, INT, "-", 64, 1, 10000, NONE, "Most WebSocket clients at once")              \
    X(stream_max_message, INT, "-", 4096, 64, 1048576, NONE, "Largest message a stream client may send, in bytes") \
    X(stream_stall_timeout, INT, "-", 30, 1, 3600, NONE, "Seconds a stream client may leave a new frame unread before it is disconnected") \
    X(stream_delta_quantum, FLOAT, "m", 0.0001, 1e-6, 0.01, NONE, "Grid spacing of the stream's delta frames for clients that do not subscribe with their own quantum") \
    X(journal_max, INT, "-", 100000, 10, 10000000, NONE, "Journal entries kept before it restarts from a new base snapshot") \
    X(journal_max_mb, INT, "-", 64, 1, 65536, NONE, "MiB of journal entries kept before it restarts from a new base snapshot") \
    X(stream_events_mb, INT, "-", 16, 1, 65536, NONE, "MiB of recent events kept for stream clients to read; one that falls further behind is disconnected") \
    X(queue_max, INT, "-", 1024, 1, 1000000, NONE, "Most commands waiting for the simulation thread (503 busy beyond)") \
    X(max_recordings_mb, INT, "-", 256, 1, 1048576, NONE, "MiB all recordings may take together, in memory or in recordings_dir (a recording whose estimate does not fit is 422; one that reaches it mid-way stops)") \
    X(recordings_dir, STR, "-", "", 0, 0, NONE, "Directory recordings are written to as <id>.clr, sequentially as frames come (crash-safe), and listed from at start; empty = in memory") \
    X(liveness_timeout, INT, "s", 10, 1, 3600, NONE, "Seconds the sim thread may go without a turn before GET /livez answers 503") \
    X(log_format, ENUM, "-", LOG_FORMAT_TEXT, 0, 1, LOG_FORMAT, "Log lines on stderr: text, or json (one object per line)") \
    X(log_level, ENUM, "-", LOG_INFO, 0, 3, LOG_LEVEL, "Least severe log lines written: debug, info, warn or error")

/* The daemon's own live parameters of a scene: how the sim thread paces it, drops rocks into it
 * and keeps its checkpoints. Changed with PATCH /v1/params like the engine's, kept by the daemon
 * beside the engine (not in its snapshots: the state file keeps them). Same row shape. */
#define CLOTHD_LOOP_SETTINGS(X)                                                                        \
    X(time_scale, FLOAT, "-", 1.0, 0.001, 1000, NONE, "Simulated seconds per wall-clock second")       \
    X(max_speed, BOOL, "-", 0, 0, 1, NONE, "Run as fast as the backend can, ignoring time_scale")     \
    X(auto_drop_interval, FLOAT, "s", 3.0, 0, 3600, NONE, "Simulated seconds between automatic rock drops; 0 = off") \
    X(auto_drop_max, INT, "-", 8, 0, 1024, NONE, "Automatic rocks kept; past this the oldest is removed") \
    X(seed, INT, "-", 1, 0, 2147483647, NONE, "Seed of the automatic drops' random positions")       \
    X(checkpoint_interval, INT, "frames", 60, 1, 1000000, NONE, "Frames between in-memory checkpoints used to roll back")

/* A STR setting holds at most this many bytes, its NUL included. */
#define SETTING_TEXT_MAX 512

#define CLOTHD_FIELD_DECL_STR(name) char name[SETTING_TEXT_MAX];
#define CLOTHD_FIELD_DECL_INT CS_FIELD_DECL_INT
#define CLOTHD_FIELD_DECL_FLOAT CS_FIELD_DECL_FLOAT
#define CLOTHD_FIELD_DECL_BOOL CS_FIELD_DECL_BOOL
#define CLOTHD_FIELD_DECL_ENUM CS_FIELD_DECL_ENUM
#define CLOTHD_FIELD_DECL(name, type, unit, def, lo, hi, choices, help) CLOTHD_FIELD_DECL_##type(name)

/* The startup settings' values. */
typedef struct clothd_settings {
    CLOTHD_SETTINGS(CLOTHD_FIELD_DECL)
} clothd_settings;

/* The daemon-loop settings' values. */
typedef struct loop_settings {
    CLOTHD_LOOP_SETTINGS(CS_FIELD_DECL)
} loop_settings;

/* What a scene is built from and runs with: its scene fields, the engine's live parameters and the
 * daemon-loop settings. */
typedef struct scene_config {
    cs_scene fields;
    cs_params params;
    loop_settings loop;
} scene_config;

/* The daemon-loop settings a snapshot holds: one written before they left the engine's table
 * (cs_snapshot_value) carries them; a newer one none. Returns how many it set in loop. */
int loop_from_snapshot(loop_settings *loop, const void *snapshot, size_t len);

/* Everything a configuration source can set, and whether the cloth's size and the integrator were
 * given (the daemon picks other defaults for them on CUDA: settings_backend_defaults). */
typedef struct clothd_config {
    clothd_settings set;
    scene_config scene;
    int scene_size_given, integrator_given;
} clothd_config;

/* The defaults that depend on the backend the engine runs on (its cs_sim_backend), applied to cfg
 * where the settings did not give them: on CUDA a cloth of 256 x 256 (a GPU keeps a finer cloth in
 * real time) and cs_params_default_integrator's integrator. Returns 1 when it changed cfg. */
int settings_backend_defaults(clothd_config *cfg, const char *backend);

/* ---- the table ---- */

/* The engine's types, and text. */
typedef enum setting_type {
    SET_INT = CS_T_INT,
    SET_FLOAT = CS_T_FLOAT,
    SET_BOOL = CS_T_BOOL,
    SET_ENUM = CS_T_ENUM,
    SET_VEC3 = CS_T_VEC3,
    SET_STR
} setting_type;

/* scene: rebuilds the cloth (PUT /v1/scene); live: applied at the next substep (PATCH
 * /v1/params); startup: read once at start. */
typedef enum setting_kind { SET_SCENE, SET_LIVE, SET_STARTUP } setting_kind;

/* The struct a row's value lives in. */
typedef enum setting_home { IN_SETTINGS, IN_FIELDS, IN_PARAMS, IN_LOOP } setting_home;

/* One row. */
typedef struct setting {
    const char *name;
    setting_type type;
    const char *unit;
    double def[3];              /* numbers: the default (one component unless VEC3; enum: its index) */
    const char *def_text;       /* STR: the default */
    double min, max;            /* inclusive range of each component (enum: of the index) */
    const char *const *choices; /* ENUM: the names in index order, NULL-terminated */
    setting_kind kind;
    const char *help;
    setting_home home;
    size_t offset;              /* of the field in its struct */
} setting;

/* The table: scene fields, live parameters (the engine's, then the daemon-loop settings), then
 * startup settings. */
size_t settings_count(void);
const setting *settings_at(size_t i);
/* The row of a name ("k_bend", "port"), or NULL. */
const setting *settings_find(const char *name);
/* "int", "float", "bool", "enum", "vec3", "string"; "scene", "live", "startup". */
const char *setting_type_name(setting_type t);
const char *setting_kind_name(setting_kind k);

/* Where a row's value lives: in c's startup settings or its scene (c->set is not needed for
 * scene and live rows, nor c->scene for startup ones). */
void *setting_field(const setting *s, clothd_settings *set, scene_config *scene);
/* Component i (0..2; 0 unless VEC3) of a number row's value, as a double (bool 0/1, enum index). */
double setting_get(const setting *s, const void *field, int i);
/* Checks v (3 components for VEC3, else 1) against a number row - finite, in range, whole for int
 * and enum, 0/1 for bool - and writes it to the field; 0, or -1 with the reason in why. */
int setting_set(const setting *s, void *field, const double *v, char *why, size_t why_len);
/* The index of an ENUM row's choice name, or -1. */
int setting_choice(const setting *s, const char *name);

/* ---- text: the command line, the environment, the config file ---- */

void settings_default(clothd_config *c);

/* Sets one item by name ("port", "k_bend", ...; dashes and underscores alike) from its text form:
 * numbers, true/false, choice names, and "x,y,z" for vectors. 0, or -1 with a reason. */
int settings_set_text(clothd_config *c, const char *name, const char *text, char *why, size_t why_len);

/* Largest config file read (a real one is a few hundred bytes). */
#define CONFIG_MAX_BYTES (1 << 20)

/* Applies a config file's text: 'name = value' lines, '#' starts a comment, blank lines are
 * skipped; len bytes, not NUL-terminated. `name` (the file's) prefixes a reason: "NAME:LINE: ...".
 * Returns 0, or -1 with the reason at the first bad line (the lines before it stay applied). */
int settings_parse_config(clothd_config *c, const char *text, size_t len, const char *name, char *why,
                          size_t why_len);

/* Applies, in order of precedence, the config file (--config or CLOTHD_CONFIG), CLOTHD_*
 * variables of env (one that names no setting is ignored with a warning, unless its name starts
 * with `skip`: NULL for none), then argv flags (--name value or --name=value; dashes and
 * underscores alike). Returns 0, or -1 with the reason (an unknown flag or config key, a bad
 * value). argv[0] and a leading subcommand are the caller's to skip: argc/argv here are only
 * flags. */
int settings_load(clothd_config *c, int argc, char **argv, char **env, const char *skip, char *why, size_t why_len);

/* Help text of every row, for --help. */
void settings_usage(FILE *out);

/* The startup settings as a Markdown table (clothd --help-markdown), for docs/operating.md. */
void settings_markdown(FILE *out);

#endif
