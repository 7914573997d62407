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

double autothreads_cost(const autothreads *a, int t)
{
    return a->work_sum[t] > 0 ? a->busy_sum[t] / a->work_sum[t] : 0.0;
}

/* Busy on one thread fewer than now: from what a unit of work cost there, else as if the
 * threads sped the step up in full. */
static double busy_on_fewer(const autothreads *a, double busy)
{
    const int t = a->now;
    const double fewer = autothreads_cost(a, t - 1), now = autothreads_cost(a, t);
    if (fewer > 0 && now > 0) return busy * fewer / now;
    return busy * (double)t / (double)(t - 1);
}

/* Whether t threads were measured to buy too little over t - 1: a unit of work cost no less than
 * `gain` of what it cost on one thread fewer (both measured). */
static int no_gain(const autothreads *a, int t, double gain)
{
    const double more = autothreads_cost(a, t), fewer = autothreads_cost(a, t - 1);
    return more > 0 && fewer > 0 && more >= gain * fewer;
}

/* What a thread more must cut a unit's cost to when the scenes would be busy `busy` without it:
 * behind (AUTOTHREADS_BEHIND), anything; else below AUTOTHREADS_GAIN. */
static double gain_for(double busy) { return busy > AUTOTHREADS_BEHIND ? 1.0 : AUTOTHREADS_GAIN; }

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
        a->calm = 0;
        restart(a, now);
        return a->now;
    }
    const double wall = now - a->start;
    if (wall < AUTOTHREADS_WINDOW) return a->now;
    const double busy = a->busy / wall;
    if (a->work > 0) { /* this count's windows, summed with the older ones fading */
        const int t = a->now;
        a->busy_sum[t] = AUTOTHREADS_FADE * a->busy_sum[t] + a->busy;
        a->work_sum[t] = AUTOTHREADS_FADE * a->work_sum[t] + a->work;
    }
    if (!greedy && a->work > 0) {
        const int t = a->now;
        a->windows++;
        if (busy > AUTOTHREADS_UP && t < a->most && (!no_gain(a, t + 1, gain_for(busy)) || a->windows >= a->probe)) {
            a->now++;
            a->probe = a->windows + AUTOTHREADS_PROBE;
        } else if (t > 1) {
            const double fewer = busy_on_fewer(a, busy);
            a->calm = fewer < AUTOTHREADS_DOWN ? a->calm + 1 : 0;
            if (a->calm >= AUTOTHREADS_CALM || no_gain(a, t, gain_for(fewer))) a->now--;
        }
        if (a->now != t) a->calm = 0;
    }
    restart(a, now);
    return a->now;
}
