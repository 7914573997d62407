/* stream.h - the WebSocket stream of DESIGN.md section 4 on libwebsockets, on its own port and
 * its own service thread.
 *
 * The sim thread hands over raw frames (stream_frame_begin/publish) and event messages
 * (stream_event) without waiting; the service thread encodes each frame once per encoding in use
 * and writes the newest one to each client when its socket can take it (latest frame wins: a slow
 * client skips frames and never grows a queue). Clients subscribe to an encoding, a frame rate and
 * a scalar, and may grab and release a vertex (queued to the sim thread, coalesced per client). */
#ifndef CLOTHD_STREAM_H
#define CLOTHD_STREAM_H

#include <stddef.h>
#include <stdint.h>

#include "core/pose.h"
#include "core/settings.h"

struct simloop;
struct access_policy;
typedef struct stream stream;

/* Starts listening (settings: listen, stream_port, stream_max_clients, stream_max_message,
 * stream_stall_timeout); NULL and the reason in err on failure. Connections are checked against
 * the access policy (token, Origin) before the upgrade completes. */
stream *stream_start(const clothd_settings *set, struct simloop *sl, const struct access_policy *acc, char *err,
                     size_t err_len);
int stream_port(stream *st);
/* The HTTP port the viewer is served on (a page's Origin must name it); 0 until set. */
void stream_set_http_port(stream *st, int port);
/* Stops the service thread and closes every client. */
void stream_stop(stream *st);

/* From the sim thread: a frame buffer to fill, or NULL when no client listens. *scalars gets the
 * scalars someone subscribed to (bit SCALAR_SPEED, bit SCALAR_STRAIN). */
pose *stream_frame_begin(stream *st, unsigned *scalars);
/* Hands the filled frame over (it becomes the newest; the service thread is woken). */
void stream_frame_publish(stream *st, pose *f);
/* Hands a frame buffer back unpublished (nothing new to show, or it could not be filled). */
void stream_frame_discard(stream *st, pose *f);
/* A text message for every client (an event); copied. */
void stream_event(stream *st, const char *json);

/* Bytes the stream may hold for a scene of n vertices and `rocks` rocks: its raw frames (the one
 * the sim thread fills, the newest, the one being sent, a spare) and one encoded frame for each
 * encoding and scalar (part of the scene's cost: simloop_scene_cost). */
uint64_t stream_memory(int32_t n, int32_t rocks);

/* The stream's Prometheus metrics (malloc'd text). */
char *stream_metrics(stream *st);

#endif
