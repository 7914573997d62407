/* stream_metrics.c - the stream's Prometheus metrics (see stream.h): its counters, and the
 * histograms of what each client got a second. */
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>

#include "stream/stream.h"
#include "stream/stream_internal.h"

static const char *const refused_names[N_REFUSED] = {"path", "version", "host", "origin", "token", "clients", "scene"};

/* A histogram of what each client got a second, observed for each client about once a second:
 * /metrics shows these, never a series per client (its labels would grow with every connection). */
static const double fps_bounds[N_BOUNDS] = {1, 5, 10, 15, 20, 30, 45, 60, 90, 120};
static const double bps_bounds[N_BOUNDS] = {1e3, 1e4, 5e4, 1e5, 5e5, 1e6, 5e6, 1e7, 5e7, 1e8};

static void hist_observe(hist *h, const double *bounds, double v)
{
    int k = 0;
    while (k < N_BOUNDS && v > bounds[k]) k++;
    atomic_fetch_add(&h->bucket[k], 1);
    atomic_fetch_add(&h->sum_milli, (unsigned long long)(v * 1000.0));
}

static void hist_print(FILE *f, const char *name, const char *help, hist *h, const double *bounds)
{
    fprintf(f, "# HELP %s %s\n# TYPE %s histogram\n", name, help, name);
    unsigned long long cum = 0;
    for (int k = 0; k <= N_BOUNDS; k++) {
        cum += atomic_load(&h->bucket[k]);
        if (k < N_BOUNDS) fprintf(f, "%s_bucket{le=\"%g\"} %llu\n", name, bounds[k], cum);
        else fprintf(f, "%s_bucket{le=\"+Inf\"} %llu\n", name, cum);
    }
    fprintf(f, "%s_sum %.3f\n%s_count %llu\n", name, (double)atomic_load(&h->sum_milli) / 1000.0, name, cum);
}

void stream_observe_client(stream *st, double fps, double bps)
{
    hist_observe(&st->client_fps, fps_bounds, fps);
    hist_observe(&st->client_bps, bps_bounds, bps);
}

char *stream_metrics(stream *st)
{
    char *out = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&out, &len);
    if (!f) return NULL;
    fprintf(f, "# HELP clothd_stream_clients WebSocket clients connected.\n# TYPE clothd_stream_clients gauge\n"
               "clothd_stream_clients %d\n", atomic_load(&st->clients));
    const char *what[3] = {"encoded", "sent", "skipped"};
    atomic_ullong *arrays[3] = {st->encoded, st->sent, st->skipped};
    for (int a = 0; a < 3; a++) {
        fprintf(f, "# HELP clothd_stream_frames_%s_total Frames %s, by encoding.\n# TYPE clothd_stream_frames_%s_total counter\n",
                what[a], what[a], what[a]);
        for (int e = 0; e < N_ENC; e++)
            fprintf(f, "clothd_stream_frames_%s_total{encoding=\"%s\"} %llu\n", what[a], stream_encoding_names[e],
                    (unsigned long long)atomic_load(&arrays[a][e]));
    }
    fprintf(f, "# HELP clothd_stream_encode_seconds_total Time spent encoding frames, by encoding.\n"
               "# TYPE clothd_stream_encode_seconds_total counter\n");
    for (int e = 0; e < N_ENC; e++)
        fprintf(f, "clothd_stream_encode_seconds_total{encoding=\"%s\"} %.6f\n", stream_encoding_names[e],
                (double)atomic_load(&st->encode_ns[e]) * 1e-9);
    hist_print(f, "clothd_stream_client_fps",
               "Frames a second a connected client got, observed for each client about once a second.", &st->client_fps,
               fps_bounds);
    hist_print(f, "clothd_stream_client_bytes_per_second",
               "Bytes a second a connected client got, observed for each client about once a second.", &st->client_bps,
               bps_bounds);
    fprintf(f, "# HELP clothd_stream_scene_clients WebSocket clients streaming each scene (at most max_scenes series).\n"
               "# TYPE clothd_stream_scene_clients gauge\n");
    pthread_mutex_lock(&st->feeds_lock);
    /* A scene deleted from the table has no series, though the sim thread has not closed its feed
     * yet (it does so on its next turn): its scene is alive until then (stream_scene_removed). */
    for (const feed *fd = st->feeds; fd; fd = fd->next)
        if (!atomic_load(&fd->closed) && !scene_is_deleted(fd->sc)) fprintf(f, "clothd_stream_scene_clients{scene=\"%s\"} %d\n", fd->id, atomic_load(&fd->clients));
    pthread_mutex_unlock(&st->feeds_lock);
    fprintf(f, "# HELP clothd_stream_scene_closed_total Clients closed because the scene they streamed was deleted.\n"
               "# TYPE clothd_stream_scene_closed_total counter\nclothd_stream_scene_closed_total %llu\n",
            (unsigned long long)atomic_load(&st->scene_closed));
    fprintf(f, "# HELP clothd_stream_bytes_sent_total Bytes written to stream clients.\n"
               "# TYPE clothd_stream_bytes_sent_total counter\nclothd_stream_bytes_sent_total %llu\n",
            (unsigned long long)atomic_load(&st->bytes_sent));
    fprintf(f, "# HELP clothd_stream_disconnected_total Clients disconnected for stalling.\n"
               "# TYPE clothd_stream_disconnected_total counter\nclothd_stream_disconnected_total %llu\n",
            (unsigned long long)atomic_load(&st->stalled));
    fprintf(f, "# HELP clothd_stream_refused_total Connections refused before the upgrade, by reason: path, version, "
               "host, origin, token, scene (an invalid or unknown ?scene=), clients (stream_max_clients).\n# TYPE clothd_stream_refused_total counter\n");
    for (int k = 0; k < N_REFUSED; k++)
        fprintf(f, "clothd_stream_refused_total{reason=\"%s\"} %llu\n", refused_names[k],
                (unsigned long long)atomic_load(&st->refused[k]));
    fclose(f);
    return out;
}
