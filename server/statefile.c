/* statefile.c - the state file's layout (see statefile.h). */
#include <stdio.h>
#include <string.h>

#include <jansson.h>

#include "clothsim/clothsim.h"
#include "pjson.h"
#include "statefile.h"

char *statefile_trailer(int paused, size_t *len)
{
    json_t *o = json_pack("{s:i, s:s}", "clothd_state", STATEFILE_FORMAT, "run", paused ? "paused" : "running");
    char *s = o ? json_dumps(o, PJSON_DUMP_FLAGS) : NULL;
    json_decref(o);
    if (s) *len = strlen(s);
    return s;
}

statefile_error statefile_parse(const unsigned char *buf, size_t len, statefile *out, char *why, size_t why_len)
{
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
        out->paused = 0;
        return STATEFILE_OK;
    }
    json_error_t err;
    json_t *t = json_loadb((const char *)buf + snap, len - snap, JSON_REJECT_DUPLICATES, &err);
    const json_t *format = json_object_get(t, "clothd_state"), *run = json_object_get(t, "run");
    statefile_error e = STATEFILE_OK;
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
    } else if (json_object_size(t) != 2 || !json_is_string(run) ||
               (strcmp(json_string_value(run), "paused") != 0 && strcmp(json_string_value(run), "running") != 0)) {
        snprintf(why, why_len, "has a trailer that is not {\"clothd_state\": 2, \"run\": \"paused\" | \"running\"}");
        e = STATEFILE_DAMAGED;
    } else {
        out->format = 2;
        out->paused = strcmp(json_string_value(run), "paused") == 0;
    }
    json_decref(t);
    return e;
}
