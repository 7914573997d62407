/* settings.h - clothd's startup settings, and the one view over them and the engine's parameter
 * table that CLI flags, CLOTHD_* environment variables, the config file and
 * GET /v1/params/schema all read.
 *
 * Startup settings are declared once in the X-macro below; engine parameters come from
 * clothsim/params.h. Adding either is one line. */
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

/* X(field, TYPE, default, min, max, choices, help): TYPE is STR, INT, BOOL or ENUM (choices a
 * string "a|b|c", default an index). */
#define CLOTHD_SETTINGS(X)                                                                             \
    X(config, STR, "", 0, 0, NULL, "Config file of 'name = value' lines (CLI and environment only)")  \
    X(listen, STR, "127.0.0.1", 0, 0, NULL, "Address the HTTP API listens on")                        \
    X(port, INT, 8080, 0, 65535, NULL, "HTTP port; 0 picks a free one and logs it")                   \
    X(stream_port, INT, 8081, 0, 65535, NULL, "WebSocket stream port; 0 picks a free one")            \
    X(backend, ENUM, 0, 0, 2, "auto|cuda|cpu", "Physics backend: auto uses CUDA when a device is present") \
    X(token_file, STR, "", 0, 0, NULL, "File holding the control token (all routes)")                 \
    X(view_token_file, STR, "", 0, 0, NULL, "File holding the view token (GET routes and the stream)") \
    X(insecure, BOOL, 0, 0, 1, NULL, "Allow listening beyond loopback without a token (anyone who reaches it has control)") \
    X(allowed_hosts, STR, "", 0, 0, NULL, "Host names the API answers to besides IP addresses and localhost (comma-separated; * any)") \
    X(allowed_origins, STR, "", 0, 0, NULL, "Page origins that may change the state and open the stream besides the viewer's own (comma-separated scheme://host[:port]; * any)") \
    X(state_file, STR, "", 0, 0, NULL, "State saved here (crash-safe) on SIGTERM/SIGINT and after a backend failure; resumed from at start") \
    X(state_file_invalid, ENUM, 0, 0, 1, "refuse|fresh", "A corrupt or foreign state file at start: refuse to start, or move it to <file>.bad-<time> and start afresh") \
    X(web_root, STR, CLOTHD_WEB_ROOT, 0, 0, NULL, "Directory of the viewer's static files, served at /")         \
    X(paused, BOOL, 0, 0, 1, NULL, "Start paused (POST /v1/sim/resume runs it)")                      \
    X(threads, INT, 0, 0, 256, NULL, "CPU backend threads; 0 = one per core")                         \
    X(http_threads, INT, 2, 1, 64, NULL, "Threads serving HTTP")                                      \
    X(http_nice, INT, 10, 0, 19, NULL, "Niceness of the HTTP threads: under overload the simulation keeps the CPU") \
    X(max_body, INT, 1048576, 1024, 1073741824, NULL, "Largest request body in bytes (413 beyond)")    \
    X(max_connections, INT, 512, 1, 100000, NULL, "Most HTTP connections at once")                    \
    X(max_connections_per_ip, INT, 64, 1, 100000, NULL, "Most HTTP connections at once from one address") \
    X(rate_limit, INT, 50, 0, 1000000, NULL, "Changing requests (POST, PUT, PATCH, DELETE) per second per address, after the burst; 0 = no limit (429 beyond)") \
    X(rate_burst, INT, 500, 1, 1000000, NULL, "Changing requests one address may make at once before rate_limit applies") \
    X(connection_timeout, INT, 60, 1, 86400, NULL, "Seconds an idle HTTP connection stays open")       \
    X(header_timeout, INT, 10, 1, 3600, NULL, "Seconds a client has to send a request's head, from when its connection was opened or its previous answer sent (slowloris)") \
    X(min_body_rate, INT, 1024, 0, 1073741824, NULL, "Slowest a request body may arrive, in bytes per second on average after header_timeout; 0 = no minimum") \
    X(max_rocks, INT, 256, 1, 1024, NULL, "Most rocks in the simulation")                             \
    X(max_state_mb, INT, 1024, 1, 1048576, NULL, "MiB a scene may take in all (its state, checkpoints, frame and encode buffers, the backend's scratch), estimated before any allocation (a bigger scene or snapshot is 422)") \
    X(stream_max_clients, INT, 64, 1, 10000, NULL, "Most WebSocket clients at once")                  \
    X(stream_max_message, INT, 4096, 64, 1048576, NULL, "Largest message a stream client may send, in bytes") \
    X(stream_stall_timeout, INT, 30, 1, 3600, NULL, "Seconds a stream client may leave a new frame unread before it is disconnected") \
    X(journal_max, INT, 100000, 10, 10000000, NULL, "Journal entries kept before it restarts from a new base snapshot") \
    X(journal_max_mb, INT, 64, 1, 65536, NULL, "MiB of journal entries kept before it restarts from a new base snapshot") \
    X(stream_events_mb, INT, 16, 1, 65536, NULL, "MiB of recent events kept for stream clients to read; one that falls further behind is disconnected") \
    X(queue_max, INT, 1024, 1, 1000000, NULL, "Most commands waiting for the simulation thread (503 busy beyond)")

typedef struct clothd_settings {
#define CLOTHD_SETTING_FIELD_STR(name) char name[512];
#define CLOTHD_SETTING_FIELD_INT(name) int32_t name;
#define CLOTHD_SETTING_FIELD_BOOL(name) int32_t name;
#define CLOTHD_SETTING_FIELD_ENUM(name) int32_t name;
#define CLOTHD_SETTING_FIELD(name, type, def, lo, hi, choices, help) CLOTHD_SETTING_FIELD_##type(name)
    CLOTHD_SETTINGS(CLOTHD_SETTING_FIELD)
} clothd_settings;

enum { BACKEND_AUTO, BACKEND_CUDA, BACKEND_CPU };
enum { STATE_INVALID_REFUSE, STATE_INVALID_FRESH };

/* Everything a configuration source can set: startup settings, scene, live parameters, and which
 * scene fields were given explicitly (the daemon picks a larger default cloth on CUDA). */
typedef struct clothd_config {
    clothd_settings set;
    cs_scene scene;
    cs_params params;
    int scene_size_given;
} clothd_config;

void settings_default(clothd_config *c);

/* Sets one item by name ("port", "k_bend", ...) from its text form: numbers, true/false,
 * choice names, and "x,y,z" for vectors. Returns 0, or -1 with a reason. */
int settings_set_text(clothd_config *c, const char *name, const char *text, char *why, size_t why_len);

/* Largest config file read (a real one is a few hundred bytes). */
#define CONFIG_MAX_BYTES (1 << 20)

/* Applies a config file's text: 'name = value' lines, '#' starts a comment, blank lines are
 * skipped; len bytes, not NUL-terminated. `name` (the file's) prefixes a reason: "NAME:LINE: ...".
 * Returns 0, or -1 with the reason at the first bad line (the lines before it stay applied). */
int settings_parse_config(clothd_config *c, const char *text, size_t len, const char *name, char *why,
                          size_t why_len);

/* Applies, in order of precedence, the config file (--config or CLOTHD_CONFIG), CLOTHD_*
 * variables of env (one that names no setting is ignored with a warning), then argv flags
 * (--name value or --name=value; dashes and underscores alike). Returns 0, or -1 with the reason
 * (an unknown flag or config key, a bad value). argv[0] and a leading subcommand are the
 * caller's to skip: argc/argv here are only flags. */
int settings_load(clothd_config *c, int argc, char **argv, char **env, char *why, size_t why_len);

/* Help text of every flag, for --help. */
void settings_usage(FILE *out);

/* The startup settings as a Markdown table (clothd --help-markdown), for README. */
void settings_markdown(FILE *out);

/* The startup rows for the schema: name, type name, default text, min, max, choices, help. */
typedef struct setting_info {
    const char *name, *type, *help, *choices;
    double min, max;
    const char *def_text;
    double def_number;
} setting_info;
size_t settings_count(void);
const setting_info *settings_at(size_t i);

#endif
