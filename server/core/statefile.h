/* statefile.h - the state file (--state-file): what SIGTERM saves and a start resumes from.
 *
 * Format 3: the engine's snapshot (its header says how long it is), then a JSON trailer with
 * what the daemon keeps beside the engine's state - the run state and the daemon-loop settings
 * (settings.h), which the engine's snapshot does not hold:
 *
 *   {"clothd_state": 3, "run": "paused" | "running", "params": {"time_scale": 1, ...}}
 *
 * Older formats still load. Format 2 is the snapshot and {"clothd_state": 2, "run": ...}; format
 * 1 - what clothd wrote before the trailer - the bare snapshot, which resumes running (what it
 * did then). Their snapshots were written while the daemon-loop settings were engine parameters,
 * so they carry them: they are taken from there. A trailer of a later format is refused with a
 * reason that says so, and so is one that is not this JSON (damaged; a trailer's params may name
 * daemon-loop settings only, each within its range), or a file that does not start with a
 * snapshot (foreign: a journal bundle has a snapshot followed by other JSON). */
#ifndef CLOTHD_STATEFILE_H
#define CLOTHD_STATEFILE_H

#include <stddef.h>

#include "core/settings.h"

#define STATEFILE_FORMAT 3

typedef enum statefile_error {
    STATEFILE_OK = 0,
    STATEFILE_FOREIGN, /* not a clothd state file */
    STATEFILE_DAMAGED, /* truncated, or a trailer that cannot be read */
    STATEFILE_NEWER    /* a format this build does not read */
} statefile_error;

typedef struct statefile {
    size_t snapshot_len; /* the snapshot is the file's first snapshot_len bytes */
    int format;          /* 1, 2 or 3 */
    int paused;          /* the run state it was saved in */
    int loop_given;      /* how many daemon-loop settings it held (in its trailer or its snapshot) */
} statefile;

/* The trailer for a state saved paused or running with these daemon-loop settings (malloc'd,
 * *len bytes, no NUL counted). */
char *statefile_trailer(int paused, const loop_settings *loop, size_t *len);
/* Reads a state file's layout: STATEFILE_OK with *out and the daemon-loop settings it holds set in
 * *loop (the others left as they are), or the error with the reason in why (*loop unchanged). */
statefile_error statefile_parse(const unsigned char *buf, size_t len, statefile *out, loop_settings *loop, char *why,
                                size_t why_len);

#endif
