/* statefile.c - the state file's layout (see statefile.h). */
#include <stdio.h>
#include <string.h>

#include <jansson.h>

#include "clothsim/clothsim.h"
#include "core/json_write.h"
#include "core/params_json.h"
#include "core/statefile.h"

char *statefile_trailer(int paused, const loop_settings *loop, size_t *len)
{
    json_t *o = json_pack("{s:i, s:s, s:o}", "clothd_state", STATEFILE_FORMAT, "run", paused ? "paused" : "running",
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

statefile_error statefile_parse(const unsigned char *buf, size_t len, statefile *out, loop_settings *loop, char *why,
                                size_t why_len)
{
    memset(out, 0, sizeof *out);
    cs_snapshot_info head;
    if (cs_snapshot_peek(buf, len, &head) != CS_OK) {
        snprintf(why, why_len, "does not start with a clothsim snapshot");
        return STATEFILE_FOREIGN;
    }
    const size_t snap = head.length;
    if (snap == 0) {
        snprintf(why, why_len, "snapshot length does not match its header (truncated?)");
        return STATEFILE_DAMAGED;
    }
    out->snapshot_len = snap;
    if (snap == len) { /* format 1: the snapshot alone */
        out->format = 1;
        out->loop_given = loop_from_snapshot(loop, buf, snap);
        return STATEFILE_OK;
    }
    json_error_t err;
    json_t *t = json_loadb((const char *)buf + snap, len - snap, JSON_REJECT_DUPLICATES, &err);
    const json_t *format = json_object_get(t, "clothd_state");
    statefile_error e = STATEFILE_OK;
    loop_settings next = *loop;
    if (!json_is_object(t)) {
        snprintf(why, why_len, "has %zu bytes after its snapshot that are not a state file's trailer (%s)", len - snap,
                 err.text);
        e = STATEFILE_DAMAGED;
    } else if (!format) {
        snprintf(why, why_len, "is not a state file: its snapshot is followed by other JSON (a journal bundle?)");
        e = STATEFILE_FOREIGN;
    } else if (!json_is_integer(format) || json_integer_value(format) < 2) {
        snprintf(why, why_len, "has a trailer with a bad clothd_state");
        e = STATEFILE_DAMAGED;
    } else if (json_integer_value(format) > STATEFILE_FORMAT) {
        snprintf(why, why_len, "state file format %lld; this build reads formats 1 to %d",
                 (long long)json_integer_value(format), STATEFILE_FORMAT);
        e = STATEFILE_NEWER;
    } else if (read_trailer(t, json_integer_value(format), out, &next, why, why_len) != 0) {
        e = STATEFILE_DAMAGED;
    } else {
        out->format = (int)json_integer_value(format);
        if (out->format == 2) out->loop_given = loop_from_snapshot(&next, buf, snap);
        *loop = next;
    }
    json_decref(t);
    return e;
}
