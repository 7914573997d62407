/* cmd_daemon.c - the daemon's probes and metrics: GET /v1/health, /livez, /readyz, /metrics (the
 * rows' request functions, commands_internal.h). */
#include <stdlib.h>

#include "core/clock.h"
#include "core/stream_msg.h"
#include "sim/commands.h"
#include "sim/commands_internal.h"
#include "sim/scenes.h"

int rq_health(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    const api_daemon *d = rq->daemon;
    const int ok = scenes_healthy(d->scenes);
    json_t *stream = d->stream_port ? json_pack("{s:i, s:s, s:s}", "port", d->stream_port, "path", STREAM_PATH,
                                                "protocol", STREAM_PROTOCOL)
                                    : json_null();
    return reply_json(out, ok ? 200 : 503,
                      json_pack("{s:s, s:s, s:s, s:s, s:s, s:o}", "status", ok ? "ok" : "unhealthy", "backend",
                                d->backend, "device", d->device, "backend_note", d->backend_note, "version", d->version,
                                "stream", stream));
}

/* Liveness: the sim thread turned within liveness_timeout s (simloop_last_turn). It says nothing
 * but that: a probe needs no token. */
int rq_livez(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    const api_daemon *d = rq->daemon;
    const double last = d->loop && d->last_turn ? d->last_turn(d->loop) : 0;
    const double ago = clock_mono() - last;
    if (last > 0 && ago <= (double)d->liveness_timeout) return reply_json(out, 200, json_pack("{s:s}", "status", "live"));
    problem pr;
    if (last > 0)
        problem_set(&pr, 503, "not-live", NULL, "the simulation thread has not turned for %.1f s (liveness_timeout: %d s)",
                    ago, d->liveness_timeout);
    else
        problem_set(&pr, 503, "not-live", NULL, "the simulation thread has not started");
    return reply_problem(out, &pr);
}

/* Readiness: serving (not starting, not stopping), and room for another scene (scenes_room). */
int rq_readyz(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    const api_daemon *d = rq->daemon;
    const int life = d->life ? atomic_load(d->life) : DAEMON_SERVING;
    problem pr;
    if (life != DAEMON_SERVING) {
        problem_set(&pr, 503, "not-ready", NULL, "%s",
                    life == DAEMON_STARTING ? "the daemon is starting" : "the daemon is stopping");
        return reply_problem(out, &pr);
    }
    if (scenes_room(d->scenes, &pr) != 0) return reply_problem(out, &pr);
    return reply_json(out, 200, json_pack("{s:s, s:i, s:i}", "status", "ready", "scenes", scenes_count(d->scenes),
                                          "max_scenes", scenes_max(d->scenes)));
}

int rq_metrics(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    const api_daemon *d = rq->daemon;
    const int max = scenes_max(d->scenes);
    scene **all = malloc(sizeof *all * (size_t)max);
    metrics_scene *each = malloc(sizeof *each * (size_t)max);
    const int n = all && each ? scenes_list(d->scenes, all, max) : 0;
    for (int k = 0; k < n; k++) {
        each[k].id = all[k]->id;
        scene_gauges(all[k], &each[k].g);
    }
    char *extra = d->more_metrics ? d->more_metrics(d->more_ctx) : NULL;
    uint64_t cap = 0;
    const uint64_t used = scenes_bytes(d->scenes, &cap);
    const metrics_daemon about = {d->version, d->backend, scenes_count(d->scenes), max, used, cap};
    size_t len = 0;
    char *text = metrics_render(d->m, &about, each, n, extra, &len);
    free(extra);
    for (int k = 0; k < n; k++) scene_release(all[k]);
    free(all);
    free(each);
    return reply_text(out, 200, "text/plain; version=0.0.4; charset=utf-8", text, len);
}
