/* commands.h - the command table: every route of the HTTP API and every command the sim thread
 * runs, one row each, as Redis keeps its commands. A row says
 *
 *   op          the command's name (a journaled command's "op")
 *   method, path  its route: the path below a scene's prefix (SCOPE_SCENE: "/v1/scenes/{scene}"
 *               names a scene, "/v1" the scene "default"; the prefix, not the row, is what names
 *               a scene), or whole (SCOPE_DAEMON); no method: not a route (queued by another
 *               request or by the stream)
 *   body        what its body must be: ignored, none (empty or {}), a JSON object, bytes
 *   access      what the request's token must grant: anyone, view, control
 *   flags       a rock {id} in the path, only while paused, 201, rebuilds the cloth, ...
 *   request     the HTTP side: an answer now from what the scene published, or the command to
 *               queue for the sim thread
 *   change | control   the sim thread: a journaled change of the engine (changes.h), or a control
 *               of the scene itself (controls.h)
 *
 * and the checks that do not depend on a command - the route, the method, the token, a rock id,
 * the body, a pause, a failed backend, a step in progress - are made here, once, from those
 * columns, before any row's function runs. Adding a command is one row (commands.c) and one
 * function (a request function in the cmd_*.c file of its resource: commands_internal.h). `clothd
 * routes`, the HTTP server (http.c) and the stream (grabs) read this table; command_apply finds a
 * journaled command by its op (the sim thread, clothd replay). */
#ifndef CLOTHD_COMMANDS_H
#define CLOTHD_COMMANDS_H

#include <stdatomic.h>
#include <stddef.h>
#include <stdio.h>

#include <jansson.h>

#include "core/access.h"
#include "core/metrics.h"
#include "sim/scene.h"

struct scenes;

/* Where the daemon is in its life (GET /readyz). */
enum { DAEMON_STARTING, DAEMON_SERVING, DAEMON_STOPPING };

/* The prefix of a scene's routes (SCOPE_SCENE) that address the scene "default", and the one
 * before a scene's id in the routes that name their scene. */
#define API_PREFIX "/v1"
#define SCENES_PREFIX "/v1/scenes/"

typedef enum command_scope { SCOPE_DAEMON, SCOPE_SCENE } command_scope;

typedef enum body_policy {
    BODY_IGNORED, /* a read: whatever it carries is not looked at */
    BODY_NONE,    /* empty or {} (any Content-Type) */
    BODY_OBJECT,  /* a JSON object (any Content-Type) */
    BODY_BYTES    /* bytes, not empty (a snapshot) */
} body_policy;

enum {
    CMD_ROCK_ID = 1 << 0,       /* the path's {id} names a rock: 1 .. 2^32 - 1, else 404 */
    CMD_PAUSED = 1 << 1,        /* only while paused: 409 otherwise */
    CMD_CREATED = 1 << 2,       /* answers 201 */
    CMD_REBUILDS = 1 << 3,      /* rebuilds the cloth (step 0): the journal starts afresh */
    CMD_CHANGES = 1 << 4,       /* changes the state without being journaled (a snapshot restored) */
    CMD_ANSWER_SIM = 1 << 5,    /* answered with GET /v1/sim's JSON, from the publication after it */
    CMD_HASH = 1 << 6,          /* that publication carries the state hash */
    CMD_AFTER_FAILURE = 1 << 7, /* still runs once the backend has failed (it needs no engine) */
    CMD_OCTETS_ASKED = 1 << 8,  /* its bytes are application/octet-stream when asked for, else JSON */
    CMD_COSTS = 1 << 9          /* may change what the scene costs (max_state_mb: the workspaces its
                                   parameters use) */
};

typedef struct command command;
typedef struct api_request api_request;

/* What the daemon-wide routes read: /v1/health, /livez, /readyz and /metrics. */
typedef struct api_daemon {
    const char *backend, *device, *backend_note, *version;
    int stream_port;                  /* 0: no stream */
    struct scenes *scenes;
    struct recordings *recordings;    /* NULL: none (a daemon without them answers 503) */
    metrics *m;
    char *(*more_metrics)(void *ctx); /* the HTTP server's and the stream's (malloc'd text), or NULL */
    void *more_ctx;
    double (*last_turn)(void *loop);  /* the sim thread's heartbeat (/livez: simloop_last_turn) */
    void *loop;                       /* its argument; NULL: no sim thread, never live */
    int liveness_timeout;             /* s */
    const atomic_int *life;           /* DAEMON_*; NULL: serving */
} api_daemon;

/* A request as a row's functions see it, whatever carried it. */
struct api_request {
    const command *def;
    scene *sc;                 /* the scene addressed, held for the request; NULL for SCOPE_DAEMON */
    const char *body;          /* len bytes */
    size_t len;
    json_t *object;            /* BODY_OBJECT: the body (the dispatcher's; incref to keep it) */
    long long id;              /* the path's {id}, -1 when not digits */
    int binary;                /* the client accepts application/octet-stream */
    int hash;                  /* ?hash=1 or ?hash=true */
    const api_daemon *daemon;
    const char *scene_id;      /* the path's {scene} (a daemon-wide row's), or NULL */
    const char *rid;           /* the path's {rid} (a recording's id, maybe not a valid one), or NULL */
};

/* An answer: status, body (malloc'd, the receiver's), its content type, Retry-After (0: none),
 * Location (empty: none). */
typedef struct api_reply {
    int status;
    char *body;
    size_t len;
    const char *ctype;
    int retry_after;
    char location[SCENE_ID_MAX + 24];
    char disposition[SCENE_ID_MAX + 40]; /* Content-Disposition (empty: none) */
    void (*release)(void *cls);          /* frees body once it is sent (NULL: free(body)) */
    void *release_cls;
} api_reply;

/* What a row's request function did: answered (*now), or made the command (*later) for the sim
 * thread: its def (the row's own unless it set another), body and bytes. */
enum { API_NOW = 0, API_LATER = 1 };

struct command {
    const char *op;
    const char *method; /* NULL: no route */
    command_scope scope;
    const char *path;
    body_policy body;
    access_level access;
    unsigned flags;
    const char *member;     /* a change's BODY_OBJECT becomes this member of the command; NULL: its members */
    const char *interrupts; /* why a step in progress ends when this command comes; NULL: it goes on beside it */
    const char *blob_type;  /* the content type of its bytes (NULL: JSON) */
    int (*request)(const api_request *rq, api_reply *now, scene_cmd *later);
    int (*change)(cs_sim *sim, loop_settings *loop, const json_t *cmd, json_t **journal, json_t **result, problem *pr);
    int (*control)(scene *sc, scene_cmd *c);
};

/* ---- the table ---- */

size_t command_count(void);
const command *command_at(size_t i);
/* The row of an op, or NULL. */
const command *command_find(const char *op);
/* A route's whole pattern ("/v1/rocks/{id}", "/metrics"), for metrics and `clothd routes`; a
 * scene's route under the prefix that names its scene ("/v1/scenes/{scene}/rocks/{id}"). */
const char *command_pattern(const command *c);
const char *command_scene_pattern(const command *c);
/* Writes the routes, "METHOD PATTERN" per line, a scene's both with and without the prefix that
 * names its scene (clothd routes; the spec test reads it). */
void command_print_routes(FILE *out);

/* ---- the HTTP side ---- */

typedef struct route_match {
    const command *def; /* the row of the method and path; NULL when none */
    int path_known;     /* no row, but the path is a route's (405: allow lists its methods) */
    char allow[64];
    long long id;       /* the path's {id}: -1 when it is not a number */
    const char *label;  /* the route's pattern, "unknown" when the path is none (metrics) */
    const char *scene;  /* the scene it addresses (SCOPE_SCENE) or names (a daemon-wide row's
                         * {scene}), maybe not a valid id (scene_id_valid); NULL when none */
    char scene_buf[SCENE_ID_MAX + 1];
    const char *rid;    /* the path's {rid}: a recording's id, maybe not a valid one; NULL when none */
    char rid_buf[SCENE_ID_MAX + 1];
} route_match;

/* Finds the row of a method (HEAD takes a GET row) and a request's path. */
void command_route(const char *method, const char *path, route_match *m);
/* Whether a path is the API's (problem+json answers, the token) rather than the viewer's files. */
int command_is_api(const char *path);
/* Whether a method changes anything (POST, PUT, PATCH, DELETE and the others HTTP does not define
 * as safe): the cross-site rule and the rate limit apply to those. */
int command_method_changes(const char *method);
/* What a request's token must grant: its row's access; for a path of no row of that method, the
 * path's when it is public, else control for a changing method and view for the others. */
access_level command_access(const char *method, const char *path);
/* The central checks (a rock id, the body), then the row's request function. */
int command_request(const api_request *rq, api_reply *now, scene_cmd *later);
/* The answer of a command the sim thread has run (its results are taken from c). */
void command_answer(scene_cmd *c, int binary, api_reply *out);
/* The problem as an answer. */
void api_problem(api_reply *out, const problem *pr);

/* The command a journaled row makes of a request's body (len bytes, any Content-Type): its
 * member, or its members, id from the path for a rock's, and its op. What can be checked without
 * the simulation is checked here (a bad body, a params patch of unknown names or wrong types);
 * the change checks the rest on the sim thread. 0 with *cmd (a new reference), or -1 with the
 * problem. */
int command_from_request(const char *op, const char *body, size_t len, long long id, json_t **cmd, problem *pr);

/* ---- the sim thread ---- */

/* Applies a journaled command to sim and loop (clothd replay, and command_change): the row of its
 * op's change. */
int command_apply(cs_sim *sim, loop_settings *loop, const json_t *cmd, json_t **journal, json_t **result, problem *pr);
/* Applies a journaled command to a scene, journals it with the step it applied at, and tells the
 * scene's listeners; *result gets applied_step. */
int command_change(scene *sc, const json_t *cmd, const char *request_id, json_t **result, problem *pr);
/* Runs a queued command on its scene: the central checks, then its change or control. 1 when the
 * scene keeps it to answer later (a step in progress), else 0 (answer it with command_finish after
 * the publication that follows). */
int command_run(scene *sc, scene_cmd *c);
/* Whether the publication after c carries the state hash. */
int command_wants_hash(const scene_cmd *c);
/* Answers c (done()), with GET /v1/sim's JSON where its row answers so. */
void command_finish(scene *sc, scene_cmd *c);

#endif
