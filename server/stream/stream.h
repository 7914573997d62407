/* stream.h - the WebSocket stream (PROTOCOL.md, "The stream") on libwebsockets, on its own port
 * and its own service thread.
 *
 * It is a scene's frame sink (sim/sink.h): the sim thread hands it poses and event messages
 * without waiting, and the service thread encodes each pose once per encoding in use and writes
 * the newest one to each client when its socket can take it (latest pose wins: a slow client
 * skips frames and never grows a queue). Each scene has its own channel (its newest pose, its
 * encodings in use, its events). A client streams one scene at a time (?scene=ID, "default"
 * without one; a subscribe naming another switches), reached through a handle it holds from the
 * scene table; it subscribes to an encoding, a frame rate and a scalar, and may grab and release
 * a vertex of its scene (queued to the scene, coalesced per client). */
#ifndef CLOTHD_STREAM_H
#define CLOTHD_STREAM_H

#include <stddef.h>
#include <stdint.h>

#include "core/access.h"
#include "core/settings.h"
#include "sim/scenes.h"
#include "sim/sink.h"

typedef struct stream stream;

/* The sink's functions (also before any stream is made: its `bytes` is part of a scene's cost). */
extern const frame_sink_ops stream_sink_ops;

/* Starts listening (settings: listen, stream_port, stream_max_clients, stream_max_message,
 * stream_stall_timeout, stream_events_mb); NULL and the reason in err on failure. Connections are
 * checked against the access policy (token, Origin) before the upgrade completes. */
stream *stream_start(const clothd_settings *set, scenes *table, const access_policy *acc, char *err, size_t err_len);
/* A new channel for a scene that joins the daemon: the sink its poses and events go to (no sink
 * when out of memory). Any thread; call it once per scene. */
frame_sink stream_scene_sink(stream *st, scene *sc);
/* A scene left the daemon and hands its sink nothing more (scenes.h's removed hook): the clients
 * streaming it are closed (1001, "scene deleted") and its channel is freed. Any thread. */
void stream_scene_removed(stream *st, scene *sc);
int stream_port(stream *st);
/* The HTTP port the viewer is served on (a page's Origin must name it); 0 until set. */
void stream_set_http_port(stream *st, int port);
/* Stops the service thread and closes every client. */
void stream_stop(stream *st);

/* The stream's Prometheus metrics (malloc'd text). */
char *stream_metrics(stream *st);

#endif
