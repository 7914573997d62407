/* statefile.c - the state file's layout (see statefile.h). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "clothsim/clothsim.h"
#include "core/json_read.h"
#include "core/json_write.h"
#include "core/params_json.h"
#include "core/statefile.h"

char *statefile_trailer(int paused, const loop_settings *loop, size_t *len)
{
    json_t *o = json_pack("{s:i, s:s, s:o}", "clothd_state", STATEFILE_FORMAT_ONE, "run", paused ? "paused" : "running",
                          "params", loop_to_json(loop));
    char *s = o ? json_dumps(o, JSON_DUMP_FLAGS) : NULL;
    json_decref(o);
    if (s) *len = strlen(s);
    return s;
}

/* A trailer's run state, and for format 3 its daemon-loop settings onto *loop; 0 or -1 (damaged). */
static int read_trailer(const json_t *t, long long format, statefile *out, loop_settings *loop, char *why, size_t why_len)
{
    const json_t *run = json_object_get(t, "run"), *params = json_object_get(t, "params");
    const size_t members = format == 2 ? 2 : 3;
    if (json_object_size(t) != members || !json_is_string(run) ||
        (strcmp(json_string_value(run), "paused") != 0 && strcmp(json_string_value(run), "running") != 0) ||
        (format == 3 && !json_is_object(params))) {
        snprintf(why, why_len, "has a trailer that is not {\"clothd_state\": %lld, \"run\": \"paused\" | \"running\"%s}",
                 format, format == 3 ? ", \"params\": {...}" : "");
        return -1;
    }
    out->paused = strcmp(json_string_value(run), "paused") == 0;
    if (format == 2) return 0;
    problem pr;
    if (loop_from_json(params, loop, &pr) != 0) {
        snprintf(why, why_len, "has a trailer whose params are refused: %s", pr.detail);
        return -1;
    }
    out->loop_given = (int)json_object_size(params);
    return 0;
}

char *statefile_trailer_scenes(int n, const char *const *ids, const int *paused, const loop_settings *const *loops,
                               size_t *len)
{
    json_t *list = json_array();
    for (int k = 0; k < n; k++)
        json_array_append_new(list, json_pack("{s:s, s:s, s:o}", "id", ids[k], "run", paused[k] ? "paused" : "running",
                                              "params", loop_to_json(loops[k])));
    json_t *o = json_pack("{s:i, s:o}", "clothd_state", STATEFILE_FORMAT, "scenes", list);
    char *s = o ? json_dumps(o, JSON_DUMP_FLAGS) : NULL;
    json_decref(o);
    if (s) *len = strlen(s);
    return s;
}

void statefile_free(statefile *f)
{
    free(f->scenes);
    f->scenes = NULL;
    f->n_scenes = 0;
}

/* Format 4's trailer: one entry per snapshot found, in order ({id, run, params}), each id a
 * scene id, none twice. 0 or -1 (damaged). */
static int read_scenes(const json_t *t, statefile *out, const loop_settings *defaults, char *why, size_t why_len)
{
    const json_t *list = json_object_get(t, "scenes");
    if (json_object_size(t) != 2 || !json_is_array(list)) {
        snprintf(why, why_len, "has a trailer that is not {\"clothd_state\": 4, \"scenes\": [...]}");
        return -1;
    }
    if (json_array_size(list) != (size_t)out->n_scenes) {
        snprintf(why, why_len, "names %zu scenes in its trailer but holds %d snapshots", json_array_size(list), out->n_scenes);
        return -1;
    }
    for (int k = 0; k < out->n_scenes; k++) {
        const json_t *e = json_array_get(list, (size_t)k), *id = json_object_get(e, "id");
        statefile_scene *sc = &out->scenes[k];
        if (!json_is_object(e) || !json_is_string(id) || !scene_id_valid(json_string_value(id))) {
            snprintf(why, why_len, "has a trailer whose scene %d has no valid id ([a-z0-9][a-z0-9_-]{0,62})", k);
            return -1;
        }
        snprintf(sc->id, sizeof sc->id, "%s", json_string_value(id));
        for (int j = 0; j < k; j++)
            if (strcmp(out->scenes[j].id, sc->id) == 0) {
                snprintf(why, why_len, "names the scene '%s' twice", sc->id);
                return -1;
            }
        json_t *rest = json_deep_copy(e); /* {run, params}: format 3's trailer but for its format */
        json_object_del(rest, "id");
        json_object_set_new(rest, "clothd_state", json_integer(3));
        statefile one = {0};
        sc->loop = *defaults;
        char inner[200];
        const int rc = read_trailer(rest, 3, &one, &sc->loop, inner, sizeof inner);
        json_decref(rest);
        if (rc != 0) {
            snprintf(why, why_len, "has a trailer whose scene '%s' is refused: %s", sc->id, inner);
            return -1;
        }
        sc->paused = one.paused;
        sc->loop_given = one.loop_given;
    }
    return 0;
}

/* The snapshots at the file's start, one after another, up to the trailer (or the file's end):
 * each a scene "default" with *loop's settings, and *off where they end. */
static statefile_error read_snapshots(const unsigned char *buf, size_t len, statefile *out, const loop_settings *loop,
                                      size_t *off, char *why, size_t why_len)
{
    int cap = 0;
    while (*off < len && buf[*off] != '{') {
        cs_snapshot_info head;
        if (cs_snapshot_peek(buf + *off, len - *off, &head) != CS_OK) {
            snprintf(why, why_len, *off ? "has bytes after its snapshot %d that are neither a snapshot nor a trailer"
                                        : "does not start with a clothsim snapshot", out->n_scenes);
            return *off ? STATEFILE_DAMAGED : STATEFILE_FOREIGN;
        }
        if (head.length == 0) {
            snprintf(why, why_len, "snapshot length does not match its header (truncated?)");
            return STATEFILE_DAMAGED;
        }
        if (out->n_scenes == STATEFILE_MAX_SCENES) {
            snprintf(why, why_len, "holds more than %d snapshots", STATEFILE_MAX_SCENES);
            return STATEFILE_DAMAGED;
        }
        if (out->n_scenes == cap) {
            cap = cap ? 2 * cap : 4;
            statefile_scene *g = realloc(out->scenes, sizeof *g * (size_t)cap);
            if (!g) {
                snprintf(why, why_len, "could not be read: out of memory");
                return STATEFILE_DAMAGED;
            }
            out->scenes = g;
        }
        statefile_scene *sc = &out->scenes[out->n_scenes++];
        memset(sc, 0, sizeof *sc);
        snprintf(sc->id, sizeof sc->id, "%s", SCENE_DEFAULT);
        sc->offset = *off;
        sc->snapshot_len = head.length;
        sc->loop = *loop;
        *off += head.length;
    }
    if (len == 0) {
        snprintf(why, why_len, "does not start with a clothsim snapshot");
        return STATEFILE_FOREIGN;
    }
    return STATEFILE_OK;
}

/* Whether t, the JSON after the snapshots (len bytes of it, which err says why it could not be
 * read), is a trailer of a format this build reads for out's snapshots: STATEFILE_OK with the
 * format in *f, or the error. */
static statefile_error trailer_format(const json_t *t, size_t len, const json_error_t *err, const statefile *out,
                                      long long *f, char *why, size_t why_len)
{
    const json_t *format = json_object_get(t, "clothd_state");
    *f = json_is_integer(format) ? (long long)json_integer_value(format) : 0;
    if (!json_is_object(t)) {
        snprintf(why, why_len, "has %zu bytes after its snapshot that are not a state file's trailer (%s)", len,
                 len ? err->text : "none");
        return out->n_scenes ? STATEFILE_DAMAGED : STATEFILE_FOREIGN;
    }
    if (!format) {
        snprintf(why, why_len, "is not a state file: its snapshot is followed by other JSON (a journal bundle?)");
        return STATEFILE_FOREIGN;
    }
    if (!json_is_integer(format) || *f < 2) {
        snprintf(why, why_len, "has a trailer with a bad clothd_state");
        return STATEFILE_DAMAGED;
    }
    if (*f > STATEFILE_FORMAT) {
        snprintf(why, why_len, "state file format %lld; this build reads formats 1 to %d", *f, STATEFILE_FORMAT);
        return STATEFILE_NEWER;
    }
    if (*f < 4 && out->n_scenes != 1) {
        snprintf(why, why_len, "holds %d snapshots, but a state file of format %lld holds one", out->n_scenes, *f);
        return STATEFILE_DAMAGED;
    }
    return STATEFILE_OK;
}

/* What the trailer t of format f says of out's scenes: formats 2 and 3 of the one snapshot (off
 * bytes of buf: format 2's daemon-loop settings are in it), format 4 of each (over *loop's). */
static statefile_error read_trailer_of(const json_t *t, long long f, const unsigned char *buf, size_t off, statefile *out,
                                       const loop_settings *loop, char *why, size_t why_len)
{
    if (f < 4) {
        statefile_scene *sc = &out->scenes[0];
        if (read_trailer(t, f, out, &sc->loop, why, why_len) != 0) return STATEFILE_DAMAGED;
        if (f == 2) out->loop_given = loop_from_snapshot(&sc->loop, buf, off);
        sc->paused = out->paused;
        sc->loop_given = out->loop_given;
        return STATEFILE_OK;
    }
    if (read_scenes(t, out, loop, why, why_len) != 0) return STATEFILE_DAMAGED;
    if (out->n_scenes) {
        out->paused = out->scenes[0].paused;
        out->loop_given = out->scenes[0].loop_given;
    }
    return STATEFILE_OK;
}

statefile_error statefile_parse(const unsigned char *buf, size_t len, statefile *out, loop_settings *loop, char *why,
                                size_t why_len)
{
    memset(out, 0, sizeof *out);
    size_t off = 0;
    statefile_error e = read_snapshots(buf, len, out, loop, &off, why, why_len);
    if (e != STATEFILE_OK) {
        statefile_free(out);
        return e;
    }
    out->snapshot_len = out->n_scenes ? out->scenes[0].snapshot_len : 0;
    if (off == len && out->n_scenes == 1) { /* format 1: the snapshot alone */
        out->format = 1;
        out->loop_given = out->scenes[0].loop_given = loop_from_snapshot(&out->scenes[0].loop, buf, off);
        *loop = out->scenes[0].loop;
        return STATEFILE_OK;
    }
    json_error_t err;
    json_t *t = off < len ? json_loadb((const char *)buf + off, len - off, JSON_REJECT_DUPLICATES, &err) : NULL;
    long long f = 0;
    e = trailer_format(t, len - off, &err, out, &f, why, why_len);
    if (e == STATEFILE_OK) e = read_trailer_of(t, f, buf, off, out, loop, why, why_len);
    json_decref(t);
    if (e != STATEFILE_OK) {
        statefile_free(out);
        return e;
    }
    out->format = (int)f;
    if (out->n_scenes) *loop = out->scenes[0].loop;
    return STATEFILE_OK;
}
