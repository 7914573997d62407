/* stream_msg.h - a stream client's text message, parsed and checked (PROTOCOL.md, Client messages):
 * subscribe (which may name a scene), keyframe, grab and release. Pure: no session and no socket; stream.c acts on the result, so
 * the parser can be tested and fuzzed on its own. */
#ifndef CLOTHD_STREAM_MSG_H
#define CLOTHD_STREAM_MSG_H

#include <stddef.h>

#include <jansson.h>

#include "clothd_frame.h"
#include "core/pose.h"
#include "core/problem.h"

/* Where the stream is served, and its subprotocol. */
#define STREAM_PATH "/stream"
#define STREAM_PROTOCOL "clothd.v1"

#define STREAM_ENCODINGS CLF_ENCODING_COUNT
/* Longest scene id, its NUL included (ids match [a-z0-9][a-z0-9_-]{0,62}). */
#define STREAM_SCENE_ID_MAX 64
/* The largest max_kbps a client may ask for (10 Gbit/s). */
#define STREAM_MAX_KBPS 10000000
/* The names of proto/clothd_frame.h's encodings (CLF_ENCODINGS) and of pose.h's scalars. */
extern const char *const stream_encoding_names[STREAM_ENCODINGS];
extern const char *const stream_scalar_names[SCALAR_KINDS];

typedef enum stream_msg_kind {
    STREAM_MSG_REFUSED,   /* an error goes back to the client: about, pr, has_param */
    STREAM_MSG_SUBSCRIBE, /* scene, encoding, max_fps, scalar, quantum, max_kbps */
    STREAM_MSG_COMMAND,   /* cmd: a grab or release for the sim thread */
    STREAM_MSG_KEYFRAME   /* a delta client asks for a keyframe */
} stream_msg_kind;

typedef struct stream_msg {
    stream_msg_kind kind;
    /* STREAM_MSG_SUBSCRIBE: the values given, -1 for the ones not given (they stay as they are) */
    int encoding, max_fps, scalar;
    double quantum; /* delta's grid (m), within DELTA_QUANTUM_MIN..MAX; -1 when not given */
    long long max_kbps; /* 1..STREAM_MAX_KBPS; 0 for null (no limit); -1 when not given */
    char scene[STREAM_SCENE_ID_MAX]; /* the scene to switch to (a valid id); "" when not given */
    /* STREAM_MSG_COMMAND: {"op": "grab", "vertex", "target"} or {"op": "release"} (owned) */
    json_t *cmd;
    /* STREAM_MSG_REFUSED: what the message was about ("message", "subscribe", "grab", "release",
     * or an unknown type), status and detail, and pr.param when has_param */
    const char *about;
    problem pr;
    int has_param;
    json_t *root; /* the parsed message: `about` may point into it */
} stream_msg;

/* Parses one text message of len bytes (not NUL-terminated); returns m->kind. */
stream_msg_kind stream_msg_parse(const char *text, size_t len, stream_msg *m);
/* Releases what m holds (cmd, unless the caller took it and set it to NULL). */
void stream_msg_free(stream_msg *m);

/* The text of an error message to a client: {"type": "error", "status", "detail", "about"} and
 * "param" when not NULL (malloc'd; NULL only when out of memory). */
char *stream_msg_error(const char *about, int status, const char *param, const char *detail);

#endif
