/* sink.h - where a scene's poses and events go: the sinks a scene hands them to (scene_add_sink).
 * The sim side declares this interface and calls it without waiting; the stream (stream/feed.c)
 * and the recordings (sim/rec_tap.c) implement it, so that the scene includes neither. A scene
 * without a sink (clothd replay, the unit tests) publishes its reads and hands out nothing.
 *
 * A sink either lends the buffer a pose is filled in (the stream: begin, publish, discard) or
 * copies a pose the scene shows it (the recordings: want, take); each is told the events and,
 * when the scene leaves the daemon, gone. Each publication asks them in this order: the lender's
 * begin, each copier's want; then, the pose filled, each copier's take, and the lender's publish
 * (or discard). A member a sink does not implement is NULL.
 *
 * A pose goes out to the lender in three calls: begin (a buffer to fill, or NULL when nobody
 * listens), then publish (it becomes the newest) or discard (it is handed back unfilled). */
#ifndef CLOTHD_SINK_H
#define CLOTHD_SINK_H

#include <stdint.h>

#include "clothsim/clothsim.h"
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
    /* A copier: whether it wants the pose of now (changed: the scene changed since the last pose
     * it took). */
    int (*want)(void *ctx, int changed);
    /* A copier: the pose (positions, rocks, no scalars) and the engine's rocks it was made from,
     * to copy; changed as for want. */
    void (*take)(void *ctx, const pose *p, const cs_rock *rocks, int n_rocks, int changed);
    /* The scene left the daemon: the sink is handed nothing more. */
    void (*gone)(void *ctx);
} frame_sink_ops;

typedef struct frame_sink {
    const frame_sink_ops *ops; /* NULL: no sink */
    void *ctx;
} frame_sink;

#endif
