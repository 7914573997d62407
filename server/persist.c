/* persist.c - the state file on disk (statefile.h says what it holds): the scenes resumed from it
 * at start, saved to it at exit - whole or not at all (temp file, fsync, rename, fsync of the
 * directory). */
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <libgen.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "core/log.h"
#include "core/statefile.h"
#include "daemon.h"
#include "sim/scenes.h"
#ifdef CLOTHD_TEST_HOOKS
#include "testhooks.h"
#endif

/* ---- saving ---- */

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

int save_on_exit(scenes *table, const char *path)
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

/* ---- resuming ---- */

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

/* What is wrong with a state file that was refused - its layout (fe), or a snapshot the engine
 * refused (st) - or NULL when the file is not to blame (out of memory, a device error, a cloth
 * larger than max_state_mb allows, more rocks than max_rocks). */
static const char *invalid_because(statefile_error fe, cs_status st)
{
    switch (fe) {
    case STATEFILE_OK: break;
    case STATEFILE_FOREIGN: return "is not a clothd state file";
    case STATEFILE_NEWER: return "was written by a newer clothd";
    default: return "is damaged";
    }
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

/* Whether the state file is there: 1, 0 when it does not exist yet (logged: the start goes on
 * afresh), -1 when it cannot be looked at (logged). */
static int state_file_found(const char *path)
{
    struct stat sb;
    if (stat(path, &sb) == 0) return 1;
    if (errno == ENOENT) {
        log_msg("state file: %s does not exist yet; starting afresh (it is written on SIGTERM/SIGINT)", path);
        return 0;
    }
    log_at(LOG_ERROR, NULL, NULL, "cannot resume from the state file %s: %s", path, strerror(errno));
    return -1;
}

/* A state file read: its layout and the scenes made of it, or why not. */
typedef struct loaded {
    statefile layout;
    statefile_error fe;           /* the layout's: STATEFILE_OK, or the reason in why */
    char why[300];
    cs_status st;                 /* the snapshots': CS_OK with layout.n_scenes scenes made, or the
                                   * reason in refused and the parameter it names in param */
    scene **made;
    char refused[400], param[64];
} loaded;

/* Reads the state file at path and makes its scenes (into *l). -1 when it cannot be read, or holds
 * more scenes than max_scenes (logged; nothing to free); else 0, whatever l says of it. */
static int load(scenes *table, const clothd_config *cfg, const char *backend, const char *path, loaded *l)
{
    size_t len = 0;
    unsigned char *buf = read_file(path, &len, l->why, sizeof l->why);
    if (!buf) {
        log_at(LOG_ERROR, NULL, NULL, "cannot resume from the state file: %s", l->why);
        return -1;
    }
    loop_settings saved = cfg->scene.loop;
    l->fe = statefile_parse(buf, len, &l->layout, &saved, l->why, sizeof l->why);
    if (l->fe == STATEFILE_OK && l->layout.n_scenes > scenes_max(table)) {
        log_at(LOG_ERROR, NULL, NULL, "cannot resume from the state file %s: it holds %d scenes, more than max_scenes (%d): raise max_scenes "
                "to resume from it", path, l->layout.n_scenes, scenes_max(table));
        statefile_free(&l->layout);
        free(buf);
        return -1;
    }
    const int n = l->layout.n_scenes;
    l->made = l->fe == STATEFILE_OK ? calloc((size_t)(n ? n : 1), sizeof *l->made) : NULL;
    l->st = l->fe != STATEFILE_OK ? CS_E_FORMAT
            : l->made             ? scenes_of(buf, &l->layout, cfg, backend, l->made, l->refused, sizeof l->refused, l->param,
                                              sizeof l->param)
                                  : CS_E_NOMEM;
    free(buf);
    return 0;
}

/* Logs the scene k of a state file, resumed. */
static void log_resumed(const char *path, const statefile *layout, int k, scene *sc)
{
    cs_info info;
    cs_sim_info(scene_engine(sc), &info);
    char hex[17];
    cs_hash_hex(cs_state_hash(scene_engine(sc)), hex);
    char what[96] = "";
    if (layout->n_scenes > 1 || strcmp(sc->id, SCENE_DEFAULT) != 0) snprintf(what, sizeof what, " the scene '%s'", sc->id);
    log_msg("resumed%s from %s at step %llu, state hash %s, %s as it was saved%s%s", what, path,
            (unsigned long long)info.step, hex, layout->scenes[k].paused ? "paused" : "running",
            layout->format == 1 ? " (a state file of format 1, which kept no run state)" : "",
            layout->format < 3 && layout->loop_given ? "; its daemon-loop settings from its snapshot" : "");
}

/* Adds the scenes made of a state file to the table (l's, taken): 1, or -1 when one cannot join
 * (logged; those after it are released). */
static int add_resumed(scenes *table, const char *path, loaded *l)
{
    int rc = 1;
    for (int k = 0; k < l->layout.n_scenes; k++) {
        scene *sc = l->made[k];
        const int added = rc == 1 ? scenes_add(table, sc) : 0;
        if (added != 0) {
            log_at(LOG_ERROR, NULL, NULL, "cannot resume from the state file %s: %s", path,
                    added == SCENES_NO_ROOM ? "its scenes need more than max_state_mb together (raise it to resume from it)"
                                            : "it names a scene twice");
            rc = -1;
        } else if (rc == 1) {
            log_resumed(path, &l->layout, k, sc);
        }
        scene_release(sc);
    }
    if (l->layout.n_scenes == 0) log_msg("resumed from %s: it holds no scene", path);
    free(l->made);
    statefile_free(&l->layout);
    return rc;
}

/* A state file no scene was made of (l's, freed): kept, and the start stops (-1); or, when the file
 * is to blame and state_file_invalid is fresh, moved aside, and the start goes on afresh (0). */
static int not_resumed(const char *path, const clothd_settings *set, loaded *l)
{
    free(l->made);
    statefile_free(&l->layout);
    const char *bad = invalid_because(l->fe, l->st);
    const char *reason = l->fe != STATEFILE_OK ? l->why : l->refused;
    if (!bad) { /* the file is kept whatever state_file_invalid says */
        log_at(LOG_ERROR, NULL, NULL, "cannot resume from the state file %s: %s%s", path, reason,
                l->st != CS_E_LIMIT                  ? ""
                : strcmp(l->param, "max_rocks") == 0 ? " (raise max_rocks to resume from it)"
                                                     : " (raise max_state_mb to resume from it)");
        return -1;
    }
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

int resume(scenes *table, const clothd_config *cfg, const char *backend)
{
    const char *path = cfg->set.state_file;
    if (!path[0]) return 0;
    remove_stale_temps(path);
    const int found = state_file_found(path);
    if (found <= 0) return found;
    loaded l = {.refused = "out of memory"};
    if (load(table, cfg, backend, path, &l) != 0) return -1;
    return l.st == CS_OK ? add_resumed(table, path, &l) : not_resumed(path, &cfg->set, &l);
}
