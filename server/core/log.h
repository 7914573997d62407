/* log.h - one line per event on stderr, with a UTC timestamp and a level: text
 *
 *   2026-12-05T16:40:00.123Z clothd: listening on ...
 *   2026-12-05T16:40:00.123Z clothd warn: ...
 *
 * or, with --log-format json, one JSON object per line (written by jansson, never by hand):
 *
 *   {"time":"2026-12-05T16:40:00.123Z","level":"info","msg":"listening on ...","scene":"default",
 *    "request_id":"..."}
 *
 * ("scene" and "request_id" only where known). Lines below --log-level are not written. Each
 * line is one write(2), so threads do not interleave. log_setup is called once, before any
 * thread starts; until then lines are text at info. */
#ifndef CLOTHD_LOG_H
#define CLOTHD_LOG_H

#if defined(__GNUC__)
#define CLOTHD_PRINTF(f, a) __attribute__((format(printf, f, a)))
#else
#define CLOTHD_PRINTF(f, a)
#endif

/* format: LOG_FORMAT_TEXT or _JSON; level: the least severe written (LOG_DEBUG .. LOG_ERROR:
 * settings.h). */
void log_setup(int format, int level);
/* Whether a line of this level is written. */
int log_enabled(int level);

/* An info line. */
void log_msg(const char *fmt, ...) CLOTHD_PRINTF(1, 2);
/* An info line written whatever --log-level says (the line that names the port bound). */
void log_notice(const char *fmt, ...) CLOTHD_PRINTF(1, 2);
/* A line of a level, about a scene and a request when known (NULL: not). */
void log_at(int level, const char *scene, const char *request_id, const char *fmt, ...) CLOTHD_PRINTF(4, 5);

/* The access log: one info line per HTTP request answered - its method, the route's pattern from
 * the command table (never the raw path: "unknown" for none, "static" for the viewer's files), the
 * status, how long it took from its head to its answer, its request id and the scene it addressed
 * (NULL: none). JSON adds them as members "method", "route", "status", "duration_ms". */
void log_access(const char *method, const char *route, int status, double seconds, const char *request_id,
                const char *scene);

#endif
