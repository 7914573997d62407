/* serve.c - clothd serve: the rooms wired together. The engine on the chosen backend, the table of
 * scenes (resumed from the state file: persist.c), the sim thread, the recordings, the stream and
 * the HTTP server; then a signal awaited, and the rooms stopped in order (see main.c for which
 * signal does what). */
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "core/access.h"
#include "core/log.h"
#include "core/metrics.h"
#include "daemon.h"
#include "http/http.h"
#include "sim/commands.h"
#include "sim/recordings.h"
#include "sim/scenes.h"
#include "sim/simloop.h"
#include "sdnotify.h"
#include "stream/stream.h"
#ifdef CLOTHD_TEST_HOOKS
#include "testhooks.h"
#endif

/* The daemon's table: the scenes of the state file when there is one, else the scene "default" on
 * the engine sim (taken either way). NULL when the start must stop (logged). */
static scenes *first_table(cs_sim *sim, const clothd_config *cfg, const char *backend)
{
    scenes *table = scenes_new(cfg->set.max_scenes);
    if (!table) {
        log_at(LOG_ERROR, NULL, NULL, "out of memory");
        cs_sim_destroy(sim);
        return NULL;
    }
    scenes_set_budget(table, (uint64_t)cfg->set.max_state_mb << 20, cfg->set.max_rocks, (void *)&stream_sink_ops);
    const int r = resume(table, cfg, backend);
    if (r != 0) {
        cs_sim_destroy(sim);
        if (r < 0) scenes_free(table);
        return r < 0 ? NULL : table;
    }
    scene *sc = scene_new(SCENE_DEFAULT, sim, &cfg->scene.loop, cfg->set.paused, &cfg->set);
    if (!sc || scenes_add(table, sc) != 0) {
        log_at(LOG_ERROR, NULL, NULL, "out of memory");
        scene_release(sc);
        scenes_free(table);
        return NULL;
    }
    scene_release(sc); /* the table's from now on */
    return table;
}

/* The table's hooks: a scene that joins gets its sink (and the test daemon's frame hook); one that
 * leaves closes its streams. */
static void stream_added(void *ctx, scene *sc)
{
    scene_set_sink(sc, stream_scene_sink(ctx, sc));
#ifdef CLOTHD_TEST_HOOKS
    scene_set_frame_hook(sc, testhooks_before_frame);
#endif
}
static void stream_removed(void *ctx, scene *sc) { stream_scene_removed(ctx, sc); }

/* The rooms serve wires around the table, each NULL until it has started. */
typedef struct rooms {
    scenes *table;
    metrics *m;
    simloop *sl;
    recordings *recs;
    stream *st;
    http_server *http;
} rooms;

/* Blocks the signals that stop the daemon (into *sigs), for sigwait. */
static void block_stop_signals(sigset_t *sigs)
{
    sigemptyset(sigs);
    sigaddset(sigs, SIGINT);
    sigaddset(sigs, SIGTERM);
    sigaddset(sigs, SIGUSR1);
    pthread_sigmask(SIG_BLOCK, sigs, NULL); /* every thread inherits it; main waits for them */
}

/* The engine of the settings, with the defaults of its backend where the settings do not give them
 * (settings_backend_defaults: on a GPU a finer cloth and velocity_verlet; into cfg, so the scenes
 * made later have them too); NULL when it cannot start (logged). */
static cs_sim *first_engine(clothd_config *cfg)
{
    cs_sim *sim = make_engine(cfg);
    if (!sim) return NULL;
    clothd_config want = *cfg;
    if (settings_backend_defaults(&want, cs_sim_backend(sim))) {
        if (cs_sim_set_params(sim, &want.scene.params) == CS_OK) cfg->scene.params = want.scene.params;
        if (cs_sim_set_scene(sim, &want.scene.fields) == CS_OK) cfg->scene.fields = want.scene.fields;
        const cs_param_info *integ = cs_param_find("integrator");
        log_msg("the %s backend's defaults: a %d x %d cloth, integrator %s (--nx, --ny and --integrator choose others)",
                cs_sim_backend(sim), (int)cfg->scene.fields.nx, (int)cfg->scene.fields.ny,
                integ->choices[cfg->scene.params.integrator]);
    }
    log_msg("backend: %s on %s (%s)", cs_sim_backend(sim), cs_sim_device(sim), cs_sim_backend_note(sim));
    return sim;
}

/* Hands the stream the table's scenes, and from now on each that joins or leaves. */
static void stream_scenes(stream *st, scenes *table, int max_scenes)
{
    scene **all = malloc(sizeof *all * (size_t)max_scenes);
    const int n = all ? scenes_list(table, all, max_scenes) : 0;
    for (int k = 0; k < n; k++) {
        stream_added(st, all[k]);
        scene_release(all[k]);
    }
    free(all);
    scenes_set_hooks(table, (scenes_hooks){stream_added, stream_removed, st});
}

/* What is left once the HTTP server, the stream and the recordings have stopped: the sim thread,
 * the table, the metrics. */
static void free_sim_side(rooms *r)
{
    simloop_free(r->sl);
    scenes_free(r->table);
    metrics_free(r->m);
}

/* Starts the rooms around r->table: the metrics, the sim thread, the recordings, the stream and
 * the HTTP server (about says what it serves, life where the daemon is). 0, or -1 (logged) with
 * every one of them stopped and freed, the table too. */
static int start_rooms(rooms *r, const clothd_config *cfg, const access_policy *acc, const http_info *about,
                       const atomic_int *life)
{
    char err[300];
    r->m = metrics_new();
    r->sl = r->m ? simloop_new(r->table, r->m) : NULL;
    if (r->sl) simloop_set_threads(r->sl, cfg->set.threads);
    if (r->sl && sdnotify_watchdog_every() > 0) simloop_set_beat(r->sl, sdnotify_watchdog, NULL, sdnotify_watchdog_every());
    r->recs = r->sl ? recordings_new(&cfg->set, err, sizeof err) : NULL;
#ifdef CLOTHD_TEST_HOOKS
    if (r->recs && testhooks_recording_slow()) recordings_set_write_hook(r->recs, testhooks_before_recording_write);
#endif
    r->st = r->recs ? stream_start(&cfg->set, r->table, acc, err, sizeof err) : NULL;
    http_info info = *about;
    info.recordings = r->recs;
    info.loop = r->sl;
    info.life = life;
    info.stream = r->st;
    info.stream_port = r->st ? stream_port(r->st) : 0;
    if (r->st) stream_scenes(r->st, r->table, cfg->set.max_scenes);
    r->http = r->st ? http_start(&cfg->set, r->table, r->m, &info, err, sizeof err) : NULL;
    if (r->http && simloop_start(r->sl) == 0) return 0;
    log_msg("%s", !r->m || !r->sl ? "out of memory" : !r->recs || !r->st || !r->http ? err : "cannot start the sim thread");
    http_stop(r->http);
    stream_stop(r->st);
    recordings_free(r->recs);
    free_sim_side(r);
    return -1;
}

/* Says where the daemon serves: in the log, and READY=1 to systemd. */
static void announce(const clothd_settings *set, const access_policy *acc, const rooms *r)
{
    const char *host = strchr(set->listen, ':') ? "[::1]" : set->listen;
    if (strcmp(set->listen, "0.0.0.0") == 0) host = "127.0.0.1";
    log_msg("stream on ws://%s:%d/stream (subprotocol clothd.v1)", set->listen, stream_port(r->st));
    log_notice("listening on http://%s:%d (API at /v1, viewer at /)%s", set->listen, http_port(r->http),
            access_required(acc) ? "; a token is needed (Authorization: Bearer)" : "");
    log_msg("try: curl -s http://%s:%d/v1/sim", host, http_port(r->http));
    log_msg("viewer: http://%s:%d/", host, http_port(r->http));
    char ready[160];
    snprintf(ready, sizeof ready, "READY=1\nSTATUS=serving on port %d, stream on %d", http_port(r->http), stream_port(r->st));
    sdnotify_send(ready);
}

/* Stops the rooms in order after the signal sig and saves the state file; the exit status. */
static int stop_rooms(rooms *r, int sig, const char *state_file)
{
    int rc;
    if (sig == SIGUSR1) {
        /* The API stays up until the state is saved - /v1/health 503, commands 503, reads as
         * they were - so that a supervisor and an operator see why the daemon goes. */
        log_at(LOG_ERROR, NULL, NULL, "backend failed: saving the state and exiting for a restart");
        simloop_stop(r->sl);
        rc = save_on_exit(r->table, state_file) == 0 ? EXIT_BACKEND : EXIT_SAVE;
        http_quiesce(r->http);
        http_stop(r->http);
        stream_stop(r->st);
        recordings_free(r->recs); /* running ones stop ("shutdown") with their index */
    } else {
        log_msg("signal %d: stopping", sig);
        http_quiesce(r->http);
        simloop_stop(r->sl);
        http_stop(r->http);
        stream_stop(r->st);
        recordings_free(r->recs); /* running ones stop ("shutdown") with their index */
        rc = save_on_exit(r->table, state_file) == 0 ? 0 : EXIT_SAVE;
    }
    free_sim_side(r);
    return rc;
}

/* serve with the access policy acc: the rooms started, a signal awaited, the rooms stopped; the
 * exit status. */
static int serve_with(clothd_config *cfg, const access_policy *acc)
{
#ifdef CLOTHD_TEST_HOOKS
    testhooks_init();
#endif
    sigset_t sigs;
    block_stop_signals(&sigs);
    sdnotify_init();

    cs_sim *sim = first_engine(cfg);
    if (!sim) return EXIT_START;
    static char backend[16], device[256], note[256]; /* the engine sim may not be kept */
    snprintf(backend, sizeof backend, "%s", cs_sim_backend(sim));
    snprintf(device, sizeof device, "%s", cs_sim_device(sim));
    snprintf(note, sizeof note, "%s", cs_sim_backend_note(sim));
    const http_info about = {backend, device, note, CLOTHD_VERSION, NULL, 0, acc, NULL, NULL, NULL};
    static atomic_int life = DAEMON_STARTING; /* GET /readyz */
    rooms r = {.table = first_table(sim, cfg, backend)};
    if (!r.table) return EXIT_START;
    scenes_set_factory(r.table, &cfg->scene, &cfg->set, backend);
    if (start_rooms(&r, cfg, acc, &about, &life) != 0) return EXIT_START;
    atomic_store(&life, DAEMON_SERVING);
    stream_set_http_port(r.st, http_port(r.http));
    announce(&cfg->set, acc, &r);

    int sig = 0;
    while (sigwait(&sigs, &sig) != 0) {
    }
    atomic_store(&life, DAEMON_STOPPING);
    sdnotify_send("STOPPING=1");
    return stop_rooms(&r, sig, cfg->set.state_file);
}

/* The access policy first: a daemon that would listen unguarded refuses before anything starts. */
int serve(clothd_config *cfg)
{
    char err[400];
    access_policy *acc = access_load(&cfg->set, err, sizeof err);
    if (!acc) {
        log_msg("%s", err);
        return EXIT_START;
    }
    const int rc = serve_with(cfg, acc);
    access_free(acc);
    return rc;
}
