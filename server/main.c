/* main.c - clothd: the simulation daemon.
 *
 *   clothd [serve] [--flag value ...]   run the simulation and its HTTP API (default)
 *   clothd replay FILE [--flag value]   rerun a journal bundle, print the final state hash
 *   clothd routes                       print the HTTP route table
 *   clothd --help | --help-markdown | --version
 *
 * serve: settings from the config file, CLOTHD_* variables and flags; the engine on the chosen
 * backend, resumed from --state-file when it exists (a corrupt or foreign file is refused, or
 * moved aside with --state-file-invalid fresh), paused if it was saved paused; the sim thread;
 * the HTTP server. SIGTERM or SIGINT stops accepting, stops the sim thread (within a quarter
 * second of compute, whatever it runs: a long step, a long frame), saves the state file (statefile.h: temp
 * file, fsync, rename, fsync of the directory) and exits 0. A backend failure (SIGUSR1 from the sim thread) keeps
 * answering - /v1/health 503 - while it saves the last checkpoint, then exits 3, for a supervisor
 * to restart from the state file. Exit statuses are in EXIT_STATUSES. */
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <libgen.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "core/access.h"
#include "core/log.h"
#include "core/metrics.h"
#include "core/settings.h"
#include "core/statefile.h"
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

#ifndef CLOTHD_VERSION
#define CLOTHD_VERSION "0.1.0"
#endif

static const char *const backend_names[] = {"auto", "cuda", "cpu"};

enum { EXIT_START = 1, EXIT_USAGE = 2, EXIT_BACKEND = 3, EXIT_SAVE = 4 };
#define EXIT_STATUSES                                                                              \
    "exit status: 0 stopped by SIGTERM/SIGINT (state file saved, if set); 1 could not start\n"     \
    "(including a state file refused); 2 bad command line or settings; 3 the backend failed\n"     \
    "(state file saved, if set: restart to resume); 4 the state file could not be saved (the\n"    \
    "previous one is left as it was)\n\n"

static void usage(FILE *out)
{
    fprintf(out,
            "clothd %s - a cloth-and-rock simulation service\n\n"
            "usage: clothd [serve] [--flag value ...]   run the simulation and its HTTP API\n"
            "       clothd replay FILE [--backend B]    rerun a journal bundle (GET /v1/journal with\n"
            "                                           Accept: application/octet-stream); print the hash\n"
            "       clothd routes                       print the HTTP routes\n"
            "       clothd --help | --version\n"
            "       clothd --help-markdown              the startup settings as a Markdown table\n\n" EXIT_STATUSES,
            CLOTHD_VERSION);
    settings_usage(out);
}

static unsigned char *read_file(const char *path, size_t *len, char *why, size_t why_len)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        snprintf(why, why_len, "%s: %s", path, strerror(errno));
        return NULL;
    }
    size_t cap = 1 << 16, n = 0;
    unsigned char *buf = malloc(cap);
    while (buf) {
        const size_t got = fread(buf + n, 1, cap - n, f);
        n += got;
        if (n < cap) break;
        unsigned char *g = realloc(buf, cap *= 2);
        if (!g) free(buf);
        buf = g;
    }
    const int bad = ferror(f) ? errno : 0; /* fread sets errno when it fails (EISDIR, EIO) */
    fclose(f);
    if (!buf || bad) {
        snprintf(why, why_len, "%s: could not read it (%s)", path, buf ? strerror(bad) : "out of memory");
        free(buf);
        return NULL;
    }
    *len = n;
    return buf;
}

/* Writes a file so that a crash leaves either the old or the new one: temp file, fsync, rename,
 * fsync of the directory. On failure the file at path is untouched, the temp file is removed and
 * why says which step failed and the system's reason (ENOSPC, EACCES, ...). */
static int write_atomic(const char *path, const void *data, size_t len, char *why, size_t why_len)
{
    char tmp[1100];
    snprintf(tmp, sizeof tmp, "%s.tmp.%ld", path, (long)getpid());
    const int fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
    if (fd < 0) {
        snprintf(why, why_len, "cannot create %s: %s", tmp, strerror(errno));
        return -1;
    }
    const char *failed = "write";
    int err = 0;
    const unsigned char *p = data;
    size_t left = len;
    while (left && !err) {
        const ssize_t w = write(fd, p, left);
        if (w < 0 && errno == EINTR) continue;
        if (w < 0) err = errno;
        else if (w == 0) err = EIO;
        else {
            p += w;
            left -= (size_t)w;
        }
    }
    if (!err && fsync(fd) != 0) failed = "fsync", err = errno;
    if (close(fd) != 0 && !err) failed = "close", err = errno;
#ifdef CLOTHD_TEST_HOOKS
    if (!err) testhooks_before_rename(tmp);
#endif
    if (!err && rename(tmp, path) != 0) failed = "rename", err = errno;
    if (err) {
        unlink(tmp);
        snprintf(why, why_len, "cannot %s %s: %s", failed, tmp, strerror(err));
        return -1;
    }
    char dir[1100];
    snprintf(dir, sizeof dir, "%s", path);
    const int dfd = open(dirname(dir), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (dfd < 0 || fsync(dfd) != 0)
        log_msg("state file: %s is in place, but its directory could not be synced (%s): a power cut may lose it",
                path, strerror(errno));
    if (dfd >= 0) close(dfd);
    return 0;
}

/* Appends a scene's state to buf - its engine's snapshot, or its last checkpoint when the engine
 * cannot be read any more (a lost device): 0, or -1 with the reason. */
static int append_state(scene *sc, unsigned char **buf, size_t *len, char *why, size_t why_len)
{
    cs_sim *sim = scene_engine(sc);
    size_t cl = 0, n = cs_snapshot_size(sim);
    const unsigned char *cp = scene_last_checkpoint(sc, &cl);
    unsigned char *g = realloc(*buf, *len + (n > cl ? n : cl));
    if (!g) return snprintf(why, why_len, "out of memory"), -1;
    *buf = g;
    if (cs_snapshot_save(sim, g + *len, n, &n) == CS_OK) {
        *len += n;
        return 0;
    }
    if (!cp || !cl) {
        snprintf(why, why_len, "the engine of the scene '%s' could not be read (%s) and there is no checkpoint", sc->id,
                 cs_sim_error(sim));
        return -1;
    }
    log_msg("state file: the engine could not be read (%s); saving the last checkpoint%s%s%s", cs_sim_error(sim),
            strcmp(sc->id, SCENE_DEFAULT) ? " of the scene '" : "", strcmp(sc->id, SCENE_DEFAULT) ? sc->id : "",
            strcmp(sc->id, SCENE_DEFAULT) ? "'" : "");
    memcpy(g + *len, cp, cl);
    *len += cl;
    return 0;
}

/* Saves every scene of the table as a state file (statefile.h): format 3 when the one scene is
 * "default", else format 4. *paused gets how many were saved paused. 0, or -1 with the reason. */
static int save_state(scenes *table, const char *path, int *n, int *paused, char *why, size_t why_len)
{
    const int max = scenes_max(table);
    scene **all = malloc(sizeof *all * (size_t)max);
    const char **ids = malloc(sizeof *ids * (size_t)max);
    int *run = malloc(sizeof *run * (size_t)max);
    const loop_settings **loops = malloc(sizeof *loops * (size_t)max);
    *n = all && ids && run && loops ? scenes_list(table, all, max) : 0;
    *paused = 0;
    unsigned char *buf = NULL;
    size_t len = 0, tlen = 0;
    int rc = all && ids && run && loops ? 0 : (snprintf(why, why_len, "out of memory"), -1);
    for (int k = 0; k < *n && rc == 0; k++) {
        ids[k] = all[k]->id;
        run[k] = scene_paused_for_save(all[k]);
        loops[k] = scene_loop(all[k]);
        *paused += run[k];
        rc = append_state(all[k], &buf, &len, why, why_len);
    }
    char *trailer = NULL;
    if (rc == 0) {
        trailer = *n == 1 && strcmp(ids[0], SCENE_DEFAULT) == 0 ? statefile_trailer(run[0], loops[0], &tlen)
                                                                : statefile_trailer_scenes(*n, ids, run, loops, &tlen);
        unsigned char *g = trailer ? realloc(buf, len + tlen) : NULL;
        if (!g) rc = (snprintf(why, why_len, "out of memory"), -1);
        else {
            buf = g;
            memcpy(buf + len, trailer, tlen);
            rc = write_atomic(path, buf, len + tlen, why, why_len);
        }
    }
    for (int k = 0; k < *n; k++) scene_release(all[k]);
    free(trailer);
    free(buf);
    free(all);
    free(ids);
    free(run);
    free(loops);
    return rc;
}

/* Removes <state file>.tmp.<pid> files: what a save interrupted by a crash or SIGKILL left. They
 * are never read (the state file itself is only ever replaced whole, by rename). */
static void remove_stale_temps(const char *path)
{
    char dir[600], base[600];
    snprintf(dir, sizeof dir, "%s", path);
    snprintf(base, sizeof base, "%s", path);
    const char *d = dirname(dir), *b = basename(base);
    const size_t blen = strlen(b);
    DIR *dp = opendir(d);
    if (!dp) return;
    for (struct dirent *e; (e = readdir(dp));) {
        const char *n = e->d_name;
        if (strncmp(n, b, blen) != 0 || strncmp(n + blen, ".tmp.", 5) != 0) continue;
        const char *pid = n + blen + 5; /* within n: its first blen + 5 characters matched */
        if (!*pid || strspn(pid, "0123456789") != strlen(pid)) continue;
        char full[1200];
        snprintf(full, sizeof full, "%s/%s", d, n);
        if (unlink(full) == 0) log_msg("state file: removed %s, left by a save that did not finish", full);
    }
    closedir(dp);
}

/* What is wrong with a state file whose snapshot the engine refused, or NULL when the file is not
 * to blame (out of memory, a device error, a cloth larger than max_state_mb allows, more rocks
 * than max_rocks). */
static const char *invalid_because(cs_status st)
{
    switch (st) {
    case CS_E_VERSION: return "was written by another version of clothd";
    case CS_E_FORMAT: return "is damaged";
    case CS_E_RANGE:
    case CS_E_UNSTABLE: return "holds a state this build cannot run";
    default: return NULL;
    }
}

/* Moves a bad state file to <path>.bad-<UTC time>[-k], so that nothing is lost. */
static int move_aside(const char *path, char *to, size_t to_len)
{
    char stamp[32];
    const time_t now = time(NULL);
    struct tm tm;
    gmtime_r(&now, &tm);
    strftime(stamp, sizeof stamp, "%Y%m%dT%H%M%SZ", &tm);
    for (int k = 0; k < 100; k++) {
        if (k) snprintf(to, to_len, "%s.bad-%s-%d", path, stamp, k);
        else snprintf(to, to_len, "%s.bad-%s", path, stamp);
        if (access(to, F_OK) != 0 && errno == ENOENT) return rename(path, to);
    }
    errno = EEXIST;
    return -1;
}

static cs_sim *make_engine_on(const clothd_config *cfg, const char *backend);

/* Makes the scenes a state file holds (formats 1 to 3: one, "default"), each on an engine of the
 * backend with its snapshot, paused as it was saved or when --paused; CS_OK, or the status of the
 * snapshot refused with the scenes made so far released: the engine's reason in why (naming the
 * scene unless it is the one "default"), the parameter it names in param. */
static cs_status scenes_of(const unsigned char *buf, const statefile *f, const clothd_config *cfg, const char *backend,
                           scene **out, char *why, size_t why_len, char *param, size_t param_len)
{
    cs_status st = CS_OK;
    int k = 0;
    for (; k < f->n_scenes && st == CS_OK; k++) {
        const statefile_scene *e = &f->scenes[k];
        cs_sim *sim = make_engine_on(cfg, backend);
        st = sim ? cs_snapshot_load(sim, buf + e->offset, e->snapshot_len) : CS_E_NOMEM;
        if (st != CS_OK) {
            const int named = f->n_scenes > 1 || strcmp(e->id, SCENE_DEFAULT) != 0;
            snprintf(why, why_len, "%s%s%s%s", named ? "the scene '" : "", named ? e->id : "", named ? "': " : "",
                     sim ? cs_sim_error(sim) : "out of memory");
            snprintf(param, param_len, "%s", sim ? cs_sim_error_param(sim) : "");
            cs_sim_destroy(sim);
            break;
        }
        out[k] = scene_new(e->id, sim, &e->loop, e->paused || cfg->set.paused, &cfg->set);
        if (!out[k]) st = CS_E_NOMEM;
    }
    if (st != CS_OK)
        for (int j = 0; j < k; j++) scene_release(out[j]);
    return st;
}

/* Resumes the table's scenes from the state file when there is one. Returns 1 (resumed), 0
 * (nothing to resume: the configured scene starts), or -1 when the start must stop (logged). A
 * file that is corrupt, foreign or from another version stops it too, unless state_file_invalid
 * is fresh: then it is moved aside and the start goes on with the configured scene. A file of
 * more scenes than max_scenes, or of scenes that need more than max_state_mb together, or a
 * snapshot the engine cannot take for want of memory or rocks, stops it and is kept. */
static int resume(scenes *table, const clothd_config *cfg, const char *backend)
{
    const clothd_settings *set = &cfg->set;
    const char *path = set->state_file;
    if (!path[0]) return 0;
    remove_stale_temps(path);
    struct stat sb;
    if (stat(path, &sb) != 0) {
        if (errno == ENOENT) {
            log_msg("state file: %s does not exist yet; starting afresh (it is written on SIGTERM/SIGINT)", path);
            return 0;
        }
        log_at(LOG_ERROR, NULL, NULL, "cannot resume from the state file %s: %s", path, strerror(errno));
        return -1;
    }
    char why[300];
    size_t len = 0;
    unsigned char *buf = read_file(path, &len, why, sizeof why);
    if (!buf) {
        log_at(LOG_ERROR, NULL, NULL, "cannot resume from the state file: %s", why);
        return -1;
    }
    statefile layout;
    loop_settings saved = cfg->scene.loop;
    const statefile_error fe = statefile_parse(buf, len, &layout, &saved, why, sizeof why);
    if (fe == STATEFILE_OK && layout.n_scenes > scenes_max(table)) {
        log_at(LOG_ERROR, NULL, NULL, "cannot resume from the state file %s: it holds %d scenes, more than max_scenes (%d): raise max_scenes "
                "to resume from it", path, layout.n_scenes, scenes_max(table));
        statefile_free(&layout);
        free(buf);
        return -1;
    }
    scene **made = fe == STATEFILE_OK ? calloc((size_t)(layout.n_scenes ? layout.n_scenes : 1), sizeof *made) : NULL;
    char loaded[400] = "out of memory", param[64] = "";
    const cs_status st = fe != STATEFILE_OK ? CS_E_FORMAT
                         : made             ? scenes_of(buf, &layout, cfg, backend, made, loaded, sizeof loaded, param, sizeof param)
                                            : CS_E_NOMEM;
    free(buf);
    const char *bad = fe == STATEFILE_FOREIGN  ? "is not a clothd state file"
                      : fe == STATEFILE_NEWER  ? "was written by a newer clothd"
                      : fe != STATEFILE_OK     ? "is damaged"
                      : st == CS_OK            ? NULL
                                               : invalid_because(st);
    if (st == CS_OK) {
        int rc = 1;
        for (int k = 0; k < layout.n_scenes; k++) {
            scene *sc = made[k];
            const int added = rc == 1 ? scenes_add(table, sc) : 0;
            if (added != 0) {
                log_at(LOG_ERROR, NULL, NULL, "cannot resume from the state file %s: %s", path,
                        added == SCENES_NO_ROOM ? "its scenes need more than max_state_mb together (raise it to resume from it)"
                                                : "it names a scene twice");
                rc = -1;
            } else if (rc == 1) {
                cs_info info;
                cs_sim_info(scene_engine(sc), &info);
                char hex[17];
                cs_hash_hex(cs_state_hash(scene_engine(sc)), hex);
                char what[96] = "";
                if (layout.n_scenes > 1 || strcmp(sc->id, SCENE_DEFAULT) != 0) snprintf(what, sizeof what, " the scene '%s'", sc->id);
                log_msg("resumed%s from %s at step %llu, state hash %s, %s as it was saved%s%s", what, path,
                        (unsigned long long)info.step, hex, layout.scenes[k].paused ? "paused" : "running",
                        layout.format == 1 ? " (a state file of format 1, which kept no run state)" : "",
                        layout.format < 3 && layout.loop_given ? "; its daemon-loop settings from its snapshot" : "");
            }
            scene_release(sc);
        }
        if (layout.n_scenes == 0) log_msg("resumed from %s: it holds no scene", path);
        free(made);
        statefile_free(&layout);
        return rc;
    }
    free(made);
    const char *reason = fe != STATEFILE_OK ? why : loaded;
    if (!bad) { /* the file is kept whatever state_file_invalid says */
        log_at(LOG_ERROR, NULL, NULL, "cannot resume from the state file %s: %s%s", path, reason,
                st != CS_E_LIMIT                  ? ""
                : strcmp(param, "max_rocks") == 0 ? " (raise max_rocks to resume from it)"
                                                  : " (raise max_state_mb to resume from it)");
        statefile_free(&layout);
        return -1;
    }
    statefile_free(&layout);
    if (set->state_file_invalid != STATE_INVALID_FRESH) {
        log_at(LOG_ERROR, NULL, NULL, "cannot resume from the state file %s: it %s (%s). Refusing to start: fix or remove it, or set "
                "--state-file-invalid fresh (CLOTHD_STATE_FILE_INVALID=fresh) to move it aside and start afresh",
                path, bad, reason);
        return -1;
    }
    char aside[700];
    if (move_aside(path, aside, sizeof aside) != 0) {
        log_at(LOG_ERROR, NULL, NULL, "cannot resume from the state file %s: it %s (%s), and it could not be moved aside: %s", path, bad,
                reason, strerror(errno));
        return -1;
    }
    log_msg("state file %s %s (%s): moved to %s; starting afresh (state_file_invalid = fresh)", path, bad, reason,
            aside);
    return 0;
}

static cs_sim *make_engine_on(const clothd_config *cfg, const char *backend)
{
    char err[300];
    cs_status st;
    void *sink = (void *)&stream_sink_ops; /* what the stream holds is part of a scene's cost */
    cs_sim *sim = scene_engine_new(&cfg->scene, &cfg->set, backend, sink, &st, err, sizeof err);
    if (!sim) log_at(LOG_ERROR, NULL, NULL, "cannot start the simulation: %s", err);
    return sim;
}

static cs_sim *make_engine(const clothd_config *cfg) { return make_engine_on(cfg, backend_names[cfg->set.backend]); }

/* ---- replay ---- */

static int replay(const char *file, const clothd_config *cfg)
{
    char why[300];
    size_t len = 0;
    unsigned char *buf = read_file(file, &len, why, sizeof why);
    if (!buf) {
        fprintf(stderr, "clothd replay: %s\n", why);
        return 1;
    }
    /* The bundle: a snapshot (its header says how long it is) followed by the journal JSON. */
    const size_t snap_len = cs_snapshot_length(buf, len);
    if (snap_len == 0) {
        fprintf(stderr, "clothd replay: %s is not a journal bundle (GET /v1/journal with Accept: application/octet-stream)\n",
                file);
        free(buf);
        return 1;
    }
    json_error_t jerr;
    json_t *j = json_loadb((const char *)buf + snap_len, len - snap_len, JSON_REJECT_DUPLICATES, &jerr);
    cs_sim *sim = j ? make_engine(cfg) : NULL;
    int rc = 1;
    if (!j) {
        fprintf(stderr, "clothd replay: the journal in %s is not JSON: %s\n", file, jerr.text);
    } else if (sim && cs_snapshot_load(sim, buf, snap_len) != CS_OK) {
        fprintf(stderr, "clothd replay: the snapshot in %s is refused: %s\n", file, cs_sim_error(sim));
    } else if (sim) {
        cs_info info;
        size_t k;
        json_t *e;
        loop_settings loop = cfg->scene.loop; /* a params command sets them too; they change no state */
        rc = 0;
        json_array_foreach(json_object_get(j, "entries"), k, e)
        {
            const long long step = (long long)json_integer_value(json_object_get(e, "step"));
            cs_sim_info(sim, &info);
            json_t *journal = NULL, *result = NULL;
            problem pr;
            if (step < (long long)info.step || cs_sim_step(sim, step - (long long)info.step) != CS_OK ||
                command_apply(sim, &loop, json_object_get(e, "command"), &journal, &result, &pr) != 0) {
                fprintf(stderr, "clothd replay: entry %zu (step %lld) could not be replayed: %s\n", k, step,
                        pr.detail[0] ? pr.detail : cs_sim_error(sim));
                rc = 1;
                break;
            }
            json_decref(journal);
            json_decref(result);
        }
        const long long last = (long long)json_integer_value(json_object_get(j, "step"));
        cs_sim_info(sim, &info);
        if (rc == 0 && last > (long long)info.step && cs_sim_step(sim, last - (long long)info.step) != CS_OK) {
            fprintf(stderr, "clothd replay: stepping to %lld failed: %s\n", last, cs_sim_error(sim));
            rc = 1;
        }
        if (rc == 0) {
            char hex[17];
            cs_sim_info(sim, &info);
            cs_hash_hex(cs_state_hash(sim), hex);
            printf("%s\n", hex);
            fprintf(stderr, "clothd replay: step %llu, state hash %s\n", (unsigned long long)info.step, hex);
        }
    }
    json_decref(j);
    cs_sim_destroy(sim);
    free(buf);
    return rc;
}

/* ---- serve ---- */

/* Saves the state file (when one is set) once the sim thread has stopped: 0, or -1 (logged; the
 * previous file is left as it was). */
static int save_on_exit(scenes *table, const char *path)
{
    if (!path[0]) return 0;
    char why[1400];
    int n = 0, paused = 0;
    if (save_state(table, path, &n, &paused, why, sizeof why) != 0) {
        log_at(LOG_ERROR, NULL, NULL, "could not save the state to %s: %s; the previous state file, if any, is unchanged", path, why);
        return -1;
    }
    scene *only = n == 1 ? scenes_get(table, SCENE_DEFAULT) : NULL;
    if (only) log_msg("state saved to %s (%s)", path, paused ? "paused" : "running");
    else log_msg("state saved to %s (%d scenes: %d paused, %d running)", path, n, paused, n - paused);
    scene_release(only);
    return 0;
}

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

static int serve_with(clothd_config *cfg, const access_policy *acc)
{
#ifdef CLOTHD_TEST_HOOKS
    testhooks_init();
#endif
    sigset_t sigs;
    sigemptyset(&sigs);
    sigaddset(&sigs, SIGINT);
    sigaddset(&sigs, SIGTERM);
    sigaddset(&sigs, SIGUSR1);
    pthread_sigmask(SIG_BLOCK, &sigs, NULL); /* every thread inherits it; main waits for them */
    sdnotify_init();

    char err[300];
    cs_sim *sim = make_engine(cfg);
    if (!sim) return EXIT_START;
    if (strcmp(cs_sim_backend(sim), "cuda") == 0 && !cfg->scene_size_given) {
        cs_scene sc = cfg->scene.fields;
        sc.nx = sc.ny = 256; /* a GPU takes a finer cloth in real time */
        if (cs_sim_set_scene(sim, &sc) == CS_OK) cfg->scene.fields = sc;
    }
    log_msg("backend: %s on %s (%s)", cs_sim_backend(sim), cs_sim_device(sim), cs_sim_backend_note(sim));
    static char backend[16], device[256], note[256]; /* the engine sim may not be kept */
    snprintf(backend, sizeof backend, "%s", cs_sim_backend(sim));
    snprintf(device, sizeof device, "%s", cs_sim_device(sim));
    snprintf(note, sizeof note, "%s", cs_sim_backend_note(sim));
    const http_info about = {backend, device, note, CLOTHD_VERSION, NULL, 0, acc, NULL, NULL, NULL};
    static atomic_int life = DAEMON_STARTING; /* GET /readyz */
    scenes *table = first_table(sim, cfg, backend);
    if (!table) return EXIT_START;
    scenes_set_factory(table, &cfg->scene, &cfg->set, backend);
    metrics *m = metrics_new();
    simloop *sl = m ? simloop_new(table, m) : NULL;
    if (sl && sdnotify_watchdog_every() > 0) simloop_set_beat(sl, sdnotify_watchdog, NULL, sdnotify_watchdog_every());
    recordings *recs = sl ? recordings_new(&cfg->set, err, sizeof err) : NULL;
#ifdef CLOTHD_TEST_HOOKS
    if (recs && testhooks_recording_slow()) recordings_set_write_hook(recs, testhooks_before_recording_write);
#endif
    stream *st = recs ? stream_start(&cfg->set, table, acc, err, sizeof err) : NULL;
    http_info info = about;
    info.recordings = recs;
    info.loop = sl;
    info.life = &life;
    info.stream = st;
    info.stream_port = st ? stream_port(st) : 0;
    if (st) {
        scene **all = malloc(sizeof *all * (size_t)cfg->set.max_scenes);
        const int n = all ? scenes_list(table, all, cfg->set.max_scenes) : 0;
        for (int k = 0; k < n; k++) {
            stream_added(st, all[k]);
            scene_release(all[k]);
        }
        free(all);
        scenes_set_hooks(table, (scenes_hooks){stream_added, stream_removed, st});
    }
    http_server *http = st ? http_start(&cfg->set, table, m, &info, err, sizeof err) : NULL;
    const int started = http && simloop_start(sl) == 0;
    if (started) atomic_store(&life, DAEMON_SERVING);
    if (!started) {
        log_msg("%s", !m || !sl ? "out of memory" : !recs || !st || !http ? err : "cannot start the sim thread");
        http_stop(http);
        stream_stop(st);
        recordings_free(recs);
        simloop_free(sl);
        scenes_free(table);
        metrics_free(m);
        return EXIT_START;
    }
    const char *host = strchr(cfg->set.listen, ':') ? "[::1]" : cfg->set.listen;
    if (strcmp(cfg->set.listen, "0.0.0.0") == 0) host = "127.0.0.1";
    log_msg("stream on ws://%s:%d/stream (subprotocol clothd.v1)", cfg->set.listen, stream_port(st));
    stream_set_http_port(st, http_port(http));
    log_notice("listening on http://%s:%d (API at /v1, viewer at /)%s", cfg->set.listen, http_port(http),
            access_required(acc) ? "; a token is needed (Authorization: Bearer)" : "");
    log_msg("try: curl -s http://%s:%d/v1/sim", host, http_port(http));
    log_msg("viewer: http://%s:%d/", host, http_port(http));
    char ready[160];
    snprintf(ready, sizeof ready, "READY=1\nSTATUS=serving on port %d, stream on %d", http_port(http), stream_port(st));
    sdnotify_send(ready);

    int sig = 0;
    while (sigwait(&sigs, &sig) != 0) {
    }
    atomic_store(&life, DAEMON_STOPPING);
    sdnotify_send("STOPPING=1");
    int rc;
    if (sig == SIGUSR1) {
        /* The API stays up until the state is saved - /v1/health 503, commands 503, reads as
         * they were - so that a supervisor and an operator see why the daemon goes. */
        log_at(LOG_ERROR, NULL, NULL, "backend failed: saving the state and exiting for a restart");
        simloop_stop(sl);
        rc = save_on_exit(table, cfg->set.state_file) == 0 ? EXIT_BACKEND : EXIT_SAVE;
        http_quiesce(http);
        http_stop(http);
        stream_stop(st);
        recordings_free(recs); /* running ones stop ("shutdown") with their index */
    } else {
        log_msg("signal %d: stopping", sig);
        http_quiesce(http);
        simloop_stop(sl);
        http_stop(http);
        stream_stop(st);
        recordings_free(recs); /* running ones stop ("shutdown") with their index */
        rc = save_on_exit(table, cfg->set.state_file) == 0 ? 0 : EXIT_SAVE;
    }
    simloop_free(sl);
    scenes_free(table);
    metrics_free(m);
    return rc;
}

/* The access policy first: a daemon that would listen unguarded refuses before anything starts. */
static int serve(clothd_config *cfg)
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

int main(int argc, char **argv, char **envp)
{
    signal(SIGPIPE, SIG_IGN);
    /* Past a file size limit (RLIMIT_FSIZE) a write fails with EFBIG, and the save says so,
     * instead of the signal killing the daemon mid-save. */
    signal(SIGXFSZ, SIG_IGN);
    const char *sub = "serve";
    int first = 1;
    if (argc > 1 && argv[1][0] != '-') {
        sub = argv[1];
        first = 2;
    }
    if (argc > 1 && (strcmp(argv[1], "--help") == 0 || strcmp(argv[1], "-h") == 0)) {
        usage(stdout);
        return 0;
    }
    if (argc > 1 && strcmp(argv[1], "--help-markdown") == 0) {
        settings_markdown(stdout);
        return 0;
    }
    if (argc > 1 && strcmp(argv[1], "--version") == 0) {
        printf("clothd %s (libclothsim %s)\n", CLOTHD_VERSION, CS_VERSION);
        return 0;
    }
    if (strcmp(sub, "routes") == 0) {
        command_print_routes(stdout);
        return 0;
    }
    const char *file = NULL;
    if (strcmp(sub, "replay") == 0) {
        if (argc <= first) {
            fprintf(stderr, "clothd replay: which file? (clothd --help)\n");
            return EXIT_USAGE;
        }
        file = argv[first++];
    } else if (strcmp(sub, "serve") != 0) {
        fprintf(stderr, "clothd: unknown command '%s' (clothd --help)\n", sub);
        return EXIT_USAGE;
    }
    clothd_config cfg;
    settings_default(&cfg);
    char why[600];
#ifdef CLOTHD_TEST_HOOKS
    const char *skip = "TEST_"; /* the test daemon's hooks (testhooks.h) */
#else
    const char *skip = NULL;
#endif
    if (settings_load(&cfg, argc - first, argv + first, envp, skip, why, sizeof why) != 0) {
        fprintf(stderr, "clothd: %s\n", why);
        return EXIT_USAGE;
    }
    log_setup(cfg.set.log_format, cfg.set.log_level);
    return file ? replay(file, &cfg) : serve(&cfg);
}
