/* statefile.h - the state file (--state-file): what SIGTERM saves and a start resumes from.
 *
 * Format 3: the engine's snapshot (its header says how long it is), then a JSON trailer with
 * what the daemon keeps beside the engine's state - the run state and the daemon-loop settings
 * (settings.h), which the engine's snapshot does not hold:
 *
 *   {"clothd_state": 3, "run": "paused" | "running", "params": {"time_scale": 1, ...}}
 *
 * Format 4 holds every scene of the daemon: their snapshots one after another, then the trailer
 *
 *   {"clothd_state": 4, "scenes": [{"id": "default", "run": "paused" | "running", "params": {...}}, ...]}
 *
 * naming them in the snapshots' order (no scene at all: the trailer alone). clothd writes format 3
 * when its one scene is "default" (what older builds read), format 4 otherwise.
 *
 * Older formats still load, as the scene "default". Format 2 is the snapshot and {"clothd_state": 2, "run": ...}; format
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

#define STATEFILE_FORMAT 4
#define STATEFILE_FORMAT_ONE 3 /* the one scene "default" */

typedef enum statefile_error {
    STATEFILE_OK = 0,
    STATEFILE_FOREIGN, /* not a clothd state file */
    STATEFILE_DAMAGED, /* truncated, or a trailer that cannot be read */
    STATEFILE_NEWER    /* a format this build does not read */
} statefile_error;

/* One scene of a state file. */
typedef struct statefile_scene {
    char id[64];
    size_t offset, snapshot_len; /* its snapshot's bytes in the file */
    int paused;                  /* the run state it was saved in */
    loop_settings loop;          /* its daemon-loop settings: those it held over the defaults given */
    int loop_given;              /* how many it held (in its trailer or its snapshot) */
} statefile_scene;

/* Most scenes a state file may hold (a daemon's max_scenes is at most this). */
#define STATEFILE_MAX_SCENES 4096

typedef struct statefile {
    size_t snapshot_len; /* the first snapshot is the file's first snapshot_len bytes */
    int format;          /* 1 to 4 */
    int paused;          /* the first scene's run state */
    int loop_given;      /* how many daemon-loop settings the first scene held */
    int n_scenes;        /* formats 1 to 3: one, "default" */
    statefile_scene *scenes; /* malloc'd: statefile_free */
} statefile;

/* Format 3's trailer for the scene "default" saved paused or running with these daemon-loop
 * settings (malloc'd, *len bytes, no NUL counted). */
char *statefile_trailer(int paused, const loop_settings *loop, size_t *len);
/* Format 4's trailer for n scenes, in the order their snapshots come. */
char *statefile_trailer_scenes(int n, const char *const *ids, const int *paused, const loop_settings *const *loops,
                               size_t *len);
/* Reads a state file's layout: STATEFILE_OK with *out (statefile_free it) - each scene's
 * daemon-loop settings are those of *loop with what it holds over them, and the first scene's are
 * set in *loop too - or the error with the reason in why (*loop unchanged, nothing to free). A
 * scene's id must be a scene id (scene_id_valid) and no id may come twice. */
statefile_error statefile_parse(const unsigned char *buf, size_t len, statefile *out, loop_settings *loop, char *why,
                                size_t why_len);
void statefile_free(statefile *f);

#endif
