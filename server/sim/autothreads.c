/* autothreads.c - the sim thread's count of CPU threads (see autothreads.h). */
#include "sim/autothreads.h"

#include <string.h>

void autothreads_init(autothreads *a, int most)
{
    memset(a, 0, sizeof *a);
    a->most = most < 1 ? 1 : most > AUTOTHREADS_MOST ? AUTOTHREADS_MOST : most;
    a->now = 1;
    a->start = -1;
}

void autothreads_ran(autothreads *a, double seconds, double work)
{
    if (seconds > 0) a->busy += seconds;
    if (work > 0) a->work += work;
}

/* Busy on one thread fewer than now: from what a unit of work cost there, else as if the
 * threads sped the step up in full. */
static double busy_on_fewer(const autothreads *a, double busy)
{
    const int t = a->now;
    if (a->cost[t - 1] > 0 && a->cost[t] > 0) return busy * a->cost[t - 1] / a->cost[t];
    return busy * (double)t / (double)(t - 1);
}

/* A new window from now. */
static void restart(autothreads *a, double now)
{
    a->start = now;
    a->busy = a->work = 0;
}

int autothreads_turn(autothreads *a, double now, int greedy)
{
    if (a->start < 0 || now < a->start) restart(a, now);
    if (greedy && a->now != a->most) { /* a new window begins on every thread */
        a->now = a->most;
        restart(a, now);
        return a->now;
    }
    const double wall = now - a->start;
    if (wall < AUTOTHREADS_WINDOW) return a->now;
    const double busy = a->busy / wall;
    if (a->work > 0) {
        const double c = a->busy / a->work;
        a->cost[a->now] = a->cost[a->now] > 0 ? 0.5 * (a->cost[a->now] + c) : c;
    }
    if (!greedy && a->work > 0) {
        if (busy > AUTOTHREADS_UP && a->now < a->most) a->now++;
        else if (a->now > 1 && busy_on_fewer(a, busy) < AUTOTHREADS_DOWN) a->now--;
    }
    restart(a, now);
    return a->now;
}
