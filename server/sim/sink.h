/* sink.h - where a scene's poses and events go. The sim side declares this interface and calls
 * it without waiting; the stream implements it (stream/stream.c), so that nothing on the sim side
 * includes the stream. A scene without a sink (clothd replay, the unit tests) publishes its reads
 * and hands out nothing.
 *
 * A pose goes out in three calls: begin (a buffer to fill, or NULL when nobody listens), then
 * publish (it becomes the newest) or discard (it is handed back unfilled). */
#ifndef CLOTHD_SINK_H
#define CLOTHD_SINK_H

#include <stdint.h>

#include "core/pose.h"

typedef struct frame_sink_ops {
    /* A pose buffer to fill, or NULL when no one listens; *scalars: the scalars someone wants (bit
     * 1 << SCALAR_SPEED, 1 << SCALAR_STRAIN). */
    pose *(*begin)(void *ctx, unsigned *scalars);
    /* Hands the filled pose over: it becomes the newest. */
    void (*publish)(void *ctx, pose *p);
    /* Hands a pose buffer back unpublished (nothing new to show, or it could not be filled). */
    void (*discard)(void *ctx, pose *p);
    /* A text message for every listener (an event); copied. */
    void (*event)(void *ctx, const char *json);
    /* Bytes the sink may hold for a scene of n vertices and `rocks` rocks (part of what a scene
     * costs: scene_cost). Callable before any sink is made. */
    uint64_t (*bytes)(int32_t n, int32_t rocks);
} frame_sink_ops;

typedef struct frame_sink {
    const frame_sink_ops *ops; /* NULL: no sink */
    void *ctx;
} frame_sink;

#endif
