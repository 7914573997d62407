/* statefile.h - the state file (--state-file): what SIGTERM saves and a start resumes from.
 *
 * Format 2: the engine's snapshot (its header says how long it is), then a JSON trailer with
 * what the daemon keeps beside the engine's state:
 *
 *   {"clothd_state": 2, "run": "paused" | "running"}
 *
 * Format 1 - what clothd wrote before the trailer - is the bare snapshot; it is still read, and
 * resumes running (what it did then). A trailer of a later format is refused with a reason that
 * says so, and so is one that is not this JSON (damaged), or a file that does not start with a
 * snapshot (foreign: a journal bundle has a snapshot followed by other JSON). */
#ifndef CLOTHD_STATEFILE_H
#define CLOTHD_STATEFILE_H

#include <stddef.h>

#define STATEFILE_FORMAT 2

typedef enum statefile_error {
    STATEFILE_OK = 0,
    STATEFILE_FOREIGN, /* not a clothd state file */
    STATEFILE_DAMAGED, /* truncated, or a trailer that cannot be read */
    STATEFILE_NEWER    /* a format this build does not read */
} statefile_error;

typedef struct statefile {
    size_t snapshot_len; /* the snapshot is the file's first snapshot_len bytes */
    int format;          /* 1 or 2 */
    int paused;          /* the run state it was saved in */
} statefile;

/* The trailer for a state saved paused or running (malloc'd, *len bytes, no NUL counted). */
char *statefile_trailer(int paused, size_t *len);
/* Reads a state file's layout: STATEFILE_OK with *out, or the error with the reason in why. */
statefile_error statefile_parse(const unsigned char *buf, size_t len, statefile *out, char *why, size_t why_len);

#endif
