/* metrics.h - counters for GET /metrics (Prometheus text format 0.0.4). */
#ifndef CLOTHD_METRICS_H
#define CLOTHD_METRICS_H

#include <stddef.h>
#include <stdint.h>

typedef struct metrics metrics;

/* Values the sim thread publishes, shown as gauges. */
typedef struct metrics_gauges {
    double realtime_factor;
    double sim_time; /* simulated seconds (clothd_sim_seconds_total: back to 0 when the cloth is rebuilt) */
    int64_t rocks, vertices, torn;
    int paused, healthy;
} metrics_gauges;

metrics *metrics_new(void);
void metrics_free(metrics *m);
/* A frame of `substeps` substeps took `seconds` of compute. */
void metrics_frame(metrics *m, int32_t substeps, double seconds);
/* The CPU threads the scenes step on now (clothd_sim_threads). */
void metrics_threads(metrics *m, int threads);
/* One HTTP request answered: its route pattern (e.g. "/v1/rocks/{id}"), method (a method HTTP
 * does not define counts as "other") and status. */
void metrics_http(metrics *m, const char *route, const char *method, int status);
/* The label a request method gets: itself when HTTP defines it, else "other". */
const char *metrics_method_label(const char *method);
/* One scene's gauges, labelled with its id. */
typedef struct metrics_scene {
    const char *id;
    metrics_gauges g;
} metrics_scene;

/* The daemon's own series: clothd_build_info and the capacity gauges. */
typedef struct metrics_daemon {
    const char *version, *backend;
    int scenes, max_scenes;
    uint64_t state_bytes, state_cap; /* what the scenes cost together, and max_state_mb (0: none) */
} metrics_daemon;

/* The exposition text (malloc'd): the daemon's series (d; NULL: none), the process_* family (read
 * from /proc/self and getrusage), the counters, and the gauges of n scenes, each series labelled
 * scene="ID"; `extra` (may be NULL) is appended as is. */
char *metrics_render(metrics *m, const metrics_daemon *d, const metrics_scene *scenes, int n, const char *extra,
                     size_t *len);

#endif
