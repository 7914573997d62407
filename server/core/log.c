/* log.c - timestamped lines on stderr (one write each, so threads do not interleave). */
#include <stdarg.h>
#include <stdio.h>
#include <time.h>
#include <unistd.h>

#include "core/log.h"

void log_msg(const char *fmt, ...)
{
    char line[1024];
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    struct tm tm;
    gmtime_r(&ts.tv_sec, &tm);
    size_t at = strftime(line, sizeof line, "%Y-%m-%dT%H:%M:%S", &tm);
    at += (size_t)snprintf(line + at, sizeof line - at, ".%03ldZ clothd: ", ts.tv_nsec / 1000000);
    va_list ap;
    va_start(ap, fmt);
    const int n = vsnprintf(line + at, sizeof line - at, fmt, ap);
    va_end(ap);
    at = n < 0 ? at : (at + (size_t)n < sizeof line - 1 ? at + (size_t)n : sizeof line - 2);
    line[at++] = '\n';
    if (write(STDERR_FILENO, line, at) < 0) return;
}
