/* log.c - timestamped lines on stderr, text or JSON (see log.h). */
#include <jansson.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "core/log.h"
#include "core/settings.h"

static int log_format = LOG_FORMAT_TEXT, log_level = LOG_INFO;
static const char *const level_names[] = {CLOTHD_CHOICES_LOG_LEVEL};

void log_setup(int format, int level)
{
    log_format = format == LOG_FORMAT_JSON ? LOG_FORMAT_JSON : LOG_FORMAT_TEXT;
    log_level = level < LOG_DEBUG ? LOG_DEBUG : level > LOG_ERROR ? LOG_ERROR : level;
}

int log_enabled(int level) { return level >= log_level; }

/* RFC 3339 UTC with milliseconds: "2026-12-05T16:40:00.123Z" (25 bytes with the NUL). */
static void timestamp(char out[32])
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    struct tm tm;
    gmtime_r(&ts.tv_sec, &tm);
    const size_t at = strftime(out, 32, "%Y-%m-%dT%H:%M:%S", &tm);
    snprintf(out + at, 32 - at, ".%03dZ", (int)(ts.tv_nsec / 1000000));
}

static void put(const char *line, size_t len)
{
    if (write(STDERR_FILENO, line, len) < 0) return;
}

/* One line: msg (already formatted), the level, and for JSON the known fields and `more`'s
 * members (taken). */
static void emit(int level, const char *scene, const char *request_id, const char *msg, json_t *more)
{
    char ts[32];
    timestamp(ts);
    const char *lv = level_names[level < LOG_DEBUG ? LOG_DEBUG : level > LOG_ERROR ? LOG_ERROR : level];
    if (log_format == LOG_FORMAT_TEXT) {
        char line[1400];
        const int known_scene = scene && scene[0], known_id = request_id && request_id[0];
        int n = snprintf(line, sizeof line, "%s clothd%s%s: %s%s%s%s%s", ts, level == LOG_INFO ? "" : " ",
                         level == LOG_INFO ? "" : lv, msg, known_scene ? " scene=" : "", known_scene ? scene : "",
                         known_id ? " id=" : "", known_id ? request_id : "");
        size_t at = n < 0 ? 0 : (size_t)n < sizeof line - 1 ? (size_t)n : sizeof line - 2;
        line[at++] = '\n';
        put(line, at);
        json_decref(more);
        return;
    }
    json_t *o = json_object();
    if (!o) {
        json_decref(more);
        return;
    }
    json_object_set_new(o, "time", json_string(ts));
    json_object_set_new(o, "level", json_string(lv));
    /* jansson refuses text that is not UTF-8: such a message is written with its bytes escaped */
    json_t *m = json_string(msg);
    if (!m) {
        char safe[1024];
        size_t k = 0;
        for (const unsigned char *p = (const unsigned char *)msg; *p && k + 5 < sizeof safe; p++)
            k += (size_t)snprintf(safe + k, sizeof safe - k, *p < 0x80 ? "%c" : "\\x%02x", *p);
        m = json_string(safe);
    }
    json_object_set_new(o, "msg", m);
    if (scene && scene[0]) json_object_set_new(o, "scene", json_string(scene));
    if (request_id && request_id[0]) json_object_set_new(o, "request_id", json_string(request_id));
    if (more) json_object_update(o, more);
    json_decref(more);
    char *s = json_dumps(o, JSON_COMPACT | JSON_ENSURE_ASCII);
    json_decref(o);
    if (!s) return;
    const size_t len = strlen(s);
    char *line = realloc(s, len + 2);
    if (!line) {
        free(s);
        return;
    }
    line[len] = '\n';
    put(line, len + 1);
    free(line);
}

static void vlog(int level, const char *scene, const char *request_id, const char *fmt, va_list ap)
{
    if (!log_enabled(level)) return;
    char msg[1024];
    vsnprintf(msg, sizeof msg, fmt, ap);
    emit(level, scene, request_id, msg, NULL);
}

void log_msg(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vlog(LOG_INFO, NULL, NULL, fmt, ap);
    va_end(ap);
}

void log_notice(const char *fmt, ...)
{
    char msg[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    emit(LOG_INFO, NULL, NULL, msg, NULL);
}

void log_at(int level, const char *scene, const char *request_id, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vlog(level, scene, request_id, fmt, ap);
    va_end(ap);
}

void log_access(const char *method, const char *route, int status, double seconds, const char *request_id,
                const char *scene)
{
    if (!log_enabled(LOG_INFO)) return;
    const double ms = seconds * 1e3;
    char msg[160];
    snprintf(msg, sizeof msg, "http %s %s %d %.3f ms", method, route, status, ms);
    json_t *more = log_format == LOG_FORMAT_JSON
                       ? json_pack("{s:s, s:s, s:i, s:f}", "method", method, "route", route, "status", status,
                                   "duration_ms", ms)
                       : NULL;
    emit(LOG_INFO, scene, request_id, msg, more);
}
