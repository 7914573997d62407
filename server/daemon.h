/* daemon.h - what clothd's own files share (the daemon's, not the libraries'):
 *
 *   main.c     the subcommands, the settings they run with, a file read whole and the engine
 *   serve.c    clothd serve: the rooms started, a signal awaited, the rooms stopped in order
 *   persist.c  the state file on disk: the scenes resumed from it at start, saved to it at exit
 *   replay.c   clothd replay: a journal bundle rerun to its state hash */
#ifndef CLOTHD_DAEMON_H
#define CLOTHD_DAEMON_H

#include <stddef.h>

#include "core/settings.h"
#include "sim/scenes.h"

#ifndef CLOTHD_VERSION
#define CLOTHD_VERSION "0.1.0"
#endif

enum { EXIT_START = 1, EXIT_USAGE = 2, EXIT_BACKEND = 3, EXIT_SAVE = 4 };
#define EXIT_STATUSES                                                                              \
    "exit status: 0 stopped by SIGTERM/SIGINT (state file saved, if set); 1 could not start\n"     \
    "(including a state file refused); 2 bad command line or settings; 3 the backend failed\n"     \
    "(state file saved, if set: restart to resume); 4 the state file could not be saved (the\n"    \
    "previous one is left as it was)\n\n"

/* ---- main.c ---- */

/* The file at path, read whole (malloc'd, *len bytes), or NULL with the reason in why. */
unsigned char *read_file(const char *path, size_t *len, char *why, size_t why_len);
/* An engine of the settings on the backend named ("auto", "cuda", "cpu"), or NULL (logged). */
cs_sim *make_engine_on(const clothd_config *cfg, const char *backend);
/* An engine of the settings on their backend, or NULL (logged). */
cs_sim *make_engine(const clothd_config *cfg);

/* ---- serve.c ---- */

/* clothd serve: runs until SIGTERM or SIGINT (0), a backend failure (EXIT_BACKEND), or a failed
 * start (EXIT_START); EXIT_SAVE when the state file could not be saved. */
int serve(clothd_config *cfg);

/* ---- persist.c ---- */

/* Resumes the table's scenes from the state file when there is one. Returns 1 (resumed), 0
 * (nothing to resume: the configured scene starts), or -1 when the start must stop (logged). A
 * file that is corrupt, foreign or from another version stops it too, unless state_file_invalid
 * is fresh: then it is moved aside and the start goes on with the configured scene. A file of
 * more scenes than max_scenes, or of scenes that need more than max_state_mb together, or a
 * snapshot the engine cannot take for want of memory or rocks, stops it and is kept. */
int resume(scenes *table, const clothd_config *cfg, const char *backend);
/* Saves the state file (when one is set) once the sim thread has stopped: 0, or -1 (logged; the
 * previous file is left as it was). */
int save_on_exit(scenes *table, const char *path);

/* ---- replay.c ---- */

/* clothd replay FILE: prints the state hash the bundle's journal reaches; 0, or 1 (said on
 * stderr). */
int replay(const char *file, const clothd_config *cfg);

#endif
