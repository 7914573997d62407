/* metrics.c - Prometheus counters, a substep-time histogram and HTTP requests by route. */
#include <dirent.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <unistd.h>

#include "core/metrics.h"

/* Upper bounds (seconds) of the substep-time histogram's buckets. */
static const double bounds[] = {1e-6, 2.5e-6, 5e-6, 1e-5, 2.5e-5, 5e-5, 1e-4, 2.5e-4, 5e-4, 1e-3, 2.5e-3, 1e-2};
#define NB (sizeof bounds / sizeof bounds[0])

typedef struct http_count {
    char route[48];
    char method[8];
    int status;
    uint64_t count;
} http_count;

struct metrics {
    pthread_mutex_t lock;
    uint64_t steps, frames;
    uint64_t bucket[NB + 1]; /* the last is +Inf */
    double seconds;
    http_count *http;
    size_t n_http, cap_http;
    atomic_int threads; /* clothd_sim_threads (the sim thread sets it, readers read it) */
};

metrics *metrics_new(void)
{
    metrics *m = calloc(1, sizeof *m);
    if (m) pthread_mutex_init(&m->lock, NULL);
    return m;
}

void metrics_free(metrics *m)
{
    if (!m) return;
    pthread_mutex_destroy(&m->lock);
    free(m->http);
    free(m);
}

void metrics_threads(metrics *m, int threads) { atomic_store(&m->threads, threads); }

void metrics_frame(metrics *m, int32_t substeps, double seconds)
{
    if (substeps <= 0) return;
    const double each = seconds / substeps;
    size_t b = 0;
    while (b < NB && each > bounds[b]) b++;
    pthread_mutex_lock(&m->lock);
    m->steps += (uint64_t)substeps;
    m->frames++;
    m->bucket[b] += (uint64_t)substeps;
    m->seconds += seconds;
    pthread_mutex_unlock(&m->lock);
}

/* Label values come from closed sets, so no client can grow the number of series: the methods
 * HTTP defines (anything else is "other"); routes are the route table's patterns, "static" and
 * "unknown" (the caller's); statuses are the server's own. */
static const char *const methods[] = {"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS", "CONNECT", "TRACE"};

const char *metrics_method_label(const char *method)
{
    for (size_t k = 0; k < sizeof methods / sizeof methods[0]; k++)
        if (strcmp(method, methods[k]) == 0) return methods[k];
    return "other";
}

void metrics_http(metrics *m, const char *route, const char *method, int status)
{
    method = metrics_method_label(method);
    if (status < 100 || status > 599) status = 0;
    pthread_mutex_lock(&m->lock);
    for (size_t i = 0; i < m->n_http; i++) {
        http_count *h = &m->http[i];
        if (h->status == status && strcmp(h->route, route) == 0 && strcmp(h->method, method) == 0) {
            h->count++;
            pthread_mutex_unlock(&m->lock);
            return;
        }
    }
    if (m->n_http == m->cap_http) {
        const size_t cap = m->cap_http ? 2 * m->cap_http : 32;
        http_count *g = realloc(m->http, sizeof *g * cap);
        if (!g) {
            pthread_mutex_unlock(&m->lock);
            return;
        }
        m->http = g;
        m->cap_http = cap;
    }
    http_count *h = &m->http[m->n_http++];
    snprintf(h->route, sizeof h->route, "%s", route);
    snprintf(h->method, sizeof h->method, "%s", method);
    h->status = status;
    h->count = 1;
    pthread_mutex_unlock(&m->lock);
}

typedef struct sbuf {
    char *p;
    size_t len, cap;
} sbuf;

static void put(sbuf *b, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void put(sbuf *b, const char *fmt, ...)
{
    for (;;) {
        va_list ap;
        va_start(ap, fmt);
        const int n = vsnprintf(b->p ? b->p + b->len : NULL, b->p ? b->cap - b->len : 0, fmt, ap);
        va_end(ap);
        if (n < 0) return;
        if (b->p && b->len + (size_t)n < b->cap) {
            b->len += (size_t)n;
            return;
        }
        const size_t cap = (b->cap ? 2 * b->cap : 4096) + (size_t)n;
        char *g = realloc(b->p, cap);
        if (!g) return;
        b->p = g;
        b->cap = cap;
    }
}

/* A label value as the text format wants it: backslash, double quote and line feed escaped. */
static void put_label(sbuf *b, const char *v)
{
    for (; *v; v++) {
        if (*v == '\\') put(b, "\\\\");
        else if (*v == '"') put(b, "\\\"");
        else if (*v == '\n') put(b, "\\n");
        else put(b, "%c", *v);
    }
}

/* The process_* family as Prometheus' client libraries name it: CPU time, resident memory, open
 * and most file descriptors, start time (since the epoch). A value that cannot be read is left out. */
static void put_process(sbuf *b)
{
    struct rusage ru;
    if (getrusage(RUSAGE_SELF, &ru) == 0)
        put(b, "# HELP process_cpu_seconds_total User and system CPU time spent, in seconds.\n"
               "# TYPE process_cpu_seconds_total counter\nprocess_cpu_seconds_total %.6f\n",
            (double)ru.ru_utime.tv_sec + 1e-6 * (double)ru.ru_utime.tv_usec + (double)ru.ru_stime.tv_sec +
                1e-6 * (double)ru.ru_stime.tv_usec);
    const long page = sysconf(_SC_PAGESIZE);
    FILE *f = fopen("/proc/self/statm", "r");
    unsigned long long size = 0, resident = 0;
    if (f && fscanf(f, "%llu %llu", &size, &resident) == 2 && page > 0) {
        put(b, "# HELP process_resident_memory_bytes Resident memory size in bytes.\n"
               "# TYPE process_resident_memory_bytes gauge\nprocess_resident_memory_bytes %llu\n",
            resident * (unsigned long long)page);
        put(b, "# HELP process_virtual_memory_bytes Virtual memory size in bytes.\n"
               "# TYPE process_virtual_memory_bytes gauge\nprocess_virtual_memory_bytes %llu\n",
            size * (unsigned long long)page);
    }
    if (f) fclose(f);
    DIR *dir = opendir("/proc/self/fd");
    if (dir) {
        long n = -1; /* the directory's own descriptor is not the process's */
        while (readdir(dir)) n++;
        closedir(dir);
        put(b, "# HELP process_open_fds Number of open file descriptors.\n# TYPE process_open_fds gauge\n"
               "process_open_fds %ld\n", n - 2 > 0 ? n - 2 : 0); /* less "." and ".." */
    }
    struct rlimit rl;
    if (getrlimit(RLIMIT_NOFILE, &rl) == 0 && rl.rlim_cur != RLIM_INFINITY)
        put(b, "# HELP process_max_fds Maximum number of open file descriptors.\n# TYPE process_max_fds gauge\n"
               "process_max_fds %llu\n", (unsigned long long)rl.rlim_cur);
    /* Field 22 of /proc/self/stat: the start, in clock ticks after boot (btime in /proc/stat). */
    char stat[1024];
    unsigned long long start = 0, btime = 0;
    f = fopen("/proc/self/stat", "r");
    const size_t got = f ? fread(stat, 1, sizeof stat - 1, f) : 0;
    if (f) fclose(f);
    stat[got] = '\0';
    const char *p = strrchr(stat, ')'); /* after the command's name, which may hold anything */
    int field = 2;
    for (; p && *p && field < 22; p++)
        if (*p == ' ') field++;
    if (p && field == 22) start = strtoull(p, NULL, 10);
    f = fopen("/proc/stat", "r");
    char line[256];
    while (f && fgets(line, sizeof line, f))
        if (sscanf(line, "btime %llu", &btime) == 1) break;
    if (f) fclose(f);
    const long tick = sysconf(_SC_CLK_TCK);
    if (start && btime && tick > 0)
        put(b, "# HELP process_start_time_seconds Start time of the process since the Unix epoch in seconds.\n"
               "# TYPE process_start_time_seconds gauge\nprocess_start_time_seconds %.2f\n",
            (double)btime + (double)start / (double)tick);
}

static void put_daemon(sbuf *b, const metrics_daemon *d)
{
    put(b, "# HELP clothd_build_info The daemon's version and the backend it runs on (always 1).\n"
           "# TYPE clothd_build_info gauge\nclothd_build_info{version=\"");
    put_label(b, d->version);
    put(b, "\",backend=\"");
    put_label(b, d->backend);
    put(b, "\"} 1\n");
    put(b, "# HELP clothd_scenes Scenes the daemon holds.\n# TYPE clothd_scenes gauge\nclothd_scenes %d\n", d->scenes);
    put(b, "# HELP clothd_scenes_max Most scenes the daemon holds (max_scenes).\n# TYPE clothd_scenes_max gauge\n"
           "clothd_scenes_max %d\n", d->max_scenes);
    put(b, "# HELP clothd_state_bytes What the scenes cost together, as max_state_mb counts it, in bytes.\n"
           "# TYPE clothd_state_bytes gauge\nclothd_state_bytes %llu\n", (unsigned long long)d->state_bytes);
    put(b, "# HELP clothd_state_max_bytes The cap on clothd_state_bytes (max_state_mb), in bytes.\n"
           "# TYPE clothd_state_max_bytes gauge\nclothd_state_max_bytes %llu\n", (unsigned long long)d->state_cap);
}

char *metrics_render(metrics *m, const metrics_daemon *d, const metrics_scene *scenes, int n, const char *extra,
                     size_t *len)
{
    sbuf b = {NULL, 0, 0};
    if (d) put_daemon(&b, d);
    put_process(&b);
    pthread_mutex_lock(&m->lock);
    put(&b, "# HELP clothd_steps_total Substeps simulated.\n# TYPE clothd_steps_total counter\nclothd_steps_total %llu\n",
        (unsigned long long)m->steps);
    put(&b, "# HELP clothd_sim_threads CPU threads the scenes step on now (the threads setting, or its automatic count).\n"
            "# TYPE clothd_sim_threads gauge\nclothd_sim_threads %d\n", atomic_load(&m->threads));
    put(&b, "# HELP clothd_frames_total Frames simulated.\n# TYPE clothd_frames_total counter\nclothd_frames_total %llu\n",
        (unsigned long long)m->frames);
    put(&b, "# HELP clothd_substep_seconds Compute time per substep.\n# TYPE clothd_substep_seconds histogram\n");
    uint64_t cum = 0;
    for (size_t k = 0; k < NB; k++) {
        cum += m->bucket[k];
        put(&b, "clothd_substep_seconds_bucket{le=\"%g\"} %llu\n", bounds[k], (unsigned long long)cum);
    }
    cum += m->bucket[NB];
    put(&b, "clothd_substep_seconds_bucket{le=\"+Inf\"} %llu\n", (unsigned long long)cum);
    put(&b, "clothd_substep_seconds_sum %.9g\nclothd_substep_seconds_count %llu\n", m->seconds, (unsigned long long)cum);
    put(&b, "# HELP clothd_http_requests_total HTTP requests answered, by route pattern, method and status.\n"
            "# TYPE clothd_http_requests_total counter\n");
    for (size_t i = 0; i < m->n_http; i++) {
        put(&b, "clothd_http_requests_total{route=\"");
        put_label(&b, m->http[i].route);
        put(&b, "\",method=\"");
        put_label(&b, m->http[i].method);
        put(&b, "\",status=\"%d\"} %llu\n", m->http[i].status, (unsigned long long)m->http[i].count);
    }
    pthread_mutex_unlock(&m->lock);
    static const struct {
        const char *name, *help;
    } gauges[] = {
        {"clothd_realtime_factor", "Simulated seconds per wall-clock second."},
        {"clothd_rocks", "Rocks in the scene."},
        {"clothd_vertices", "Cloth vertices."},
        {"clothd_torn_springs", "Springs torn."},
        {"clothd_paused", "1 while the scene is paused."},
        {"clothd_healthy", "0 once the backend has failed."},
    };
    for (size_t k = 0; k < sizeof gauges / sizeof gauges[0]; k++) {
        put(&b, "# HELP %s %s\n# TYPE %s gauge\n", gauges[k].name, gauges[k].help, gauges[k].name);
        for (int i = 0; i < n; i++) {
            const metrics_gauges *g = &scenes[i].g;
            put(&b, "%s{scene=\"", gauges[k].name);
            put_label(&b, scenes[i].id);
            put(&b, "\"} ");
            switch (k) {
            case 0: put(&b, "%.6g\n", g->realtime_factor); break;
            case 1: put(&b, "%lld\n", (long long)g->rocks); break;
            case 2: put(&b, "%lld\n", (long long)g->vertices); break;
            case 3: put(&b, "%lld\n", (long long)g->torn); break;
            case 4: put(&b, "%d\n", g->paused); break;
            default: put(&b, "%d\n", g->healthy); break;
            }
        }
    }
    put(&b, "# HELP clothd_sim_seconds_total Simulated seconds of the scene (back to 0 when its cloth is rebuilt).\n"
            "# TYPE clothd_sim_seconds_total counter\n");
    for (int i = 0; i < n; i++) {
        put(&b, "clothd_sim_seconds_total{scene=\"");
        put_label(&b, scenes[i].id);
        put(&b, "\"} %.9g\n", scenes[i].g.sim_time);
    }
    if (extra) put(&b, "%s", extra);
    *len = b.len;
    return b.p;
}
