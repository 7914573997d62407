/* log.h - one line per event on stderr, with a UTC timestamp. */
#ifndef CLOTHD_LOG_H
#define CLOTHD_LOG_H

void log_msg(const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 1, 2)))
#endif
    ;

#endif
