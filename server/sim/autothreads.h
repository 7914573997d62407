/* autothreads.h - how many CPU threads the sim thread's scenes step on when the `threads` setting
 * is 0 (auto): the fewest that keep them in real time, up to `most` (one per core).
 *
 * A thread more is not free: the step wakes it and meets it at a barrier many times a substep,
 * and on a small cloth that costs more than the thread does. On the 2-vCPU build machine the
 * default scene (64 x 64, implicit_euler) keeps real time on one thread with half a core busy, and
 * on two with 1.2 cores (docs/developing.md, "The daemon's threads"). So the loop starts on one thread, takes one more while the
 * scenes barely keep up, and gives one back when the others would keep up without it.
 *
 * It looks at windows of AUTOTHREADS_WINDOW s of wall time: `busy`, the share of the window spent
 * stepping, and the compute per unit of work (vertex-substeps, or under implicit_euler what the
 * solver did: simloop.c's work_of) measured at each count - the count's windows summed, each older
 * one weighing AUTOTHREADS_FADE less, so that one window whose stones cost more than their units
 * say does not decide alone - which says what a thread buys on this machine and these scenes:
 *  - a step in progress or a scene at max_speed (greedy) takes every thread, at once;
 *  - busy above AUTOTHREADS_UP: one thread more (when none is left, the scenes fall behind as they
 *    would on a fixed count), unless that count was measured to buy too little (below);
 *  - busy as it would be on one thread fewer below AUTOTHREADS_DOWN in AUTOTHREADS_CALM windows
 *    in a row: one fewer. That estimate scales busy by the compute per work measured at the
 *    smaller count, or, before there is one, as if each thread sped the step up in full (which
 *    never gives one back too early). A lull between stones does not give the thread back: the
 *    daemon's 128 x 128 scene (a stone every 3 s) gave it back after every quiet window, fell
 *    behind for a window each time a stone landed, and ran at 0.95 of real time on 1.1 cores;
 *    after three in a row, at 0.97-0.99 on 1.4-1.6 (two threads fixed: 0.97-0.99; build machine,
 *    2026-12-07);
 *  - one fewer, too, when a unit of work was measured to cost at least AUTOTHREADS_GAIN of what it
 *    cost on one thread fewer: the thread buys too little for a core (a thread that buys less
 *    than its barriers cost). While the scenes would fall behind without it (busy above
 *    AUTOTHREADS_BEHIND), any gain keeps it (and takes it): only a thread measured to cost more
 *    a unit goes. Such a count is tried again after AUTOTHREADS_PROBE windows, since the scenes
 *    change.
 * A wrong guess corrects itself: the next window measures it. The engine's results do not depend
 * on the count (cs_sim_set_threads), so a change mid-run changes no bits.
 *
 * Pure arithmetic on the times it is given: tests/server/unit/test_autothreads.c. */
#ifndef CLOTHD_AUTOTHREADS_H
#define CLOTHD_AUTOTHREADS_H

#define AUTOTHREADS_WINDOW 1.0 /* s of wall time between two decisions */
#define AUTOTHREADS_UP 0.9     /* busy above this: one thread more */
#define AUTOTHREADS_DOWN 0.75  /* busy on one thread fewer below this: one fewer */
#define AUTOTHREADS_MOST 256   /* the most threads it counts to (the `threads` setting's range) */
#define AUTOTHREADS_GAIN 0.95  /* a thread more must cut the compute per work below this share */
#define AUTOTHREADS_BEHIND 0.98 /* busy above this: the scenes fall behind, and any gain counts */
#define AUTOTHREADS_CALM 3      /* windows in a row that say one fewer suffices before it goes */
#define AUTOTHREADS_PROBE 30   /* windows before a count that bought too little is tried again */
#define AUTOTHREADS_FADE 0.9   /* weight of a count's older windows in its cost, each window on */

typedef struct autothreads {
    int most, now;
    long windows, probe;               /* windows decided; the first one that may try a count again */
    int calm;                          /* windows in a row that one thread fewer would have kept up */
    double start;                      /* wall clock of the window's start (< 0: none yet) */
    double busy, work;                 /* compute s and units of work in the window */
    double busy_sum[AUTOTHREADS_MOST + 1], work_sum[AUTOTHREADS_MOST + 1]; /* each count's windows, fading */
} autothreads;

/* Starts on one thread, of at most `most` (clamped to 1..AUTOTHREADS_MOST). */
void autothreads_init(autothreads *a, int most);
/* Compute s per unit of work measured at t threads: its windows' busy_sum / work_sum (0: none). */
double autothreads_cost(const autothreads *a, int t);
/* A call to the engine at the current count: `seconds` of compute for `work` units (vertex-substeps). */
void autothreads_ran(autothreads *a, double seconds, double work);
/* At a turn of the loop at wall time `now` (s, monotonic), before it steps: the count to step
 * with. greedy: a step is in progress or a scene runs at max_speed. */
int autothreads_turn(autothreads *a, double now, int greedy);

#endif
