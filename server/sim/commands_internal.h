/* commands_internal.h - what the command table's files share (not for use outside them): the
 * rows' request functions, which commands.c's table names, and the answers they build.
 *
 *   commands.c        the table, the routes it makes, the central checks and the sim thread's side
 *   cmd_daemon.c      the daemon's probes and metrics (/v1/health, /livez, /readyz, /metrics)
 *   cmd_scenes.c      the daemon's scenes (/v1/scenes)
 *   cmd_reads.c       a scene's reads, from what it published (/v1/sim, /params, /rocks, ...)
 *   cmd_recordings.c  the daemon's recordings (/v1/recordings)
 *   cmd_queue.c       the rows whose request makes a command for the sim thread
 *
 * It declares the types of commands.h it names rather than include it (which the files include
 * beside it): commands.c includes this header, so one that included commands.h back would be an
 * include cycle. */
#ifndef CLOTHD_COMMANDS_INTERNAL_H
#define CLOTHD_COMMANDS_INTERNAL_H

#include <stddef.h>

#include <jansson.h>

#include "core/problem.h"
#include "sim/scene.h"

typedef struct command command;
typedef struct api_request api_request;
typedef struct api_reply api_reply;

#define JSON_TYPE "application/json"
#define OCTETS "application/octet-stream"
#define RECORDING_TYPE "application/vnd.clothd.recording"

/* ---- answers (commands.c): each fills *out and returns API_NOW ---- */

/* body (malloc'd, len bytes) as it is. */
int reply_text(api_reply *out, int status, const char *ctype, char *body, size_t len);
/* o as JSON (o is taken). */
int reply_json(api_reply *out, int status, json_t *o);
/* The problem as problem+json. */
int reply_problem(api_reply *out, const problem *pr);

/* ---- the rows' request functions (a row's `request`: commands.h) ---- */

/* cmd_daemon.c */
int rq_health(const api_request *rq, api_reply *out, scene_cmd *later);
int rq_livez(const api_request *rq, api_reply *out, scene_cmd *later);
int rq_readyz(const api_request *rq, api_reply *out, scene_cmd *later);
int rq_metrics(const api_request *rq, api_reply *out, scene_cmd *later);

/* cmd_scenes.c */
int rq_scenes(const api_request *rq, api_reply *out, scene_cmd *later);
int rq_scene_create(const api_request *rq, api_reply *out, scene_cmd *later);
int rq_scene_delete(const api_request *rq, api_reply *out, scene_cmd *later);

/* cmd_reads.c */
int rq_sim(const api_request *rq, api_reply *out, scene_cmd *later);
int rq_params(const api_request *rq, api_reply *out, scene_cmd *later);
int rq_fields(const api_request *rq, api_reply *out, scene_cmd *later);
int rq_schema(const api_request *rq, api_reply *out, scene_cmd *later);
int rq_rocks(const api_request *rq, api_reply *out, scene_cmd *later);
int rq_rock(const api_request *rq, api_reply *out, scene_cmd *later);
int rq_journal(const api_request *rq, api_reply *out, scene_cmd *later);

/* cmd_recordings.c */
int rq_recording_start(const api_request *rq, api_reply *out, scene_cmd *later);
int rq_recordings(const api_request *rq, api_reply *out, scene_cmd *later);
int rq_recording_get(const api_request *rq, api_reply *out, scene_cmd *later);
int rq_recording_delete(const api_request *rq, api_reply *out, scene_cmd *later);

/* cmd_queue.c */
int rq_queue(const api_request *rq, api_reply *out, scene_cmd *later);
int rq_step(const api_request *rq, api_reply *out, scene_cmd *later);
int rq_cloth_state(const api_request *rq, api_reply *out, scene_cmd *later);
int rq_snapshot_put(const api_request *rq, api_reply *out, scene_cmd *later);
int rq_change(const api_request *rq, api_reply *out, scene_cmd *later);
/* A journaled command from the (parsed) body: its member or members, the path's id, its op
 * (rq_change, command_from_request). 0 with *cmd (a new reference), or -1 with the problem. */
int make_change(const command *d, json_t *object, long long id, json_t **cmd, problem *pr);

#endif
