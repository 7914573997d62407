/* clock.h - the two clocks the daemon reads: monotonic seconds (deadlines, pacing, rates) and the
 * wall clock in nanoseconds since the Unix epoch (stamped on what goes out). */
#ifndef CLOTHD_CLOCK_H
#define CLOTHD_CLOCK_H

#include <stdint.h>
#include <time.h>

static inline double clock_mono(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static inline uint64_t clock_wall_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (uint64_t)ts.tv_sec * 1000000000ull + (uint64_t)ts.tv_nsec;
}

#endif
