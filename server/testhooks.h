/* testhooks.h - fault injection for clothd's fault tests, in the test daemon clothd-testhooks
 * only (built with CLOTHD_TEST_HOOKS by tests/server; the shipped clothd has none of it). Driven
 * by environment variables, each a one-shot:
 *
 *   CLOTHD_TEST_NAN_FRAME=N           after frame N, a NaN goes into the cloth (the next frame
 *                                     finds the state non-finite)
 *   CLOTHD_TEST_BACKEND_FAIL_FRAME=N  after frame N, the backend fails as a lost GPU does (the
 *                                     next frame gets CS_E_DEVICE)
 *   CLOTHD_TEST_SAVE_PAUSE_MS=M       while saving the state file, wait M ms between writing the
 *                                     temp file and renaming it (a test kills the daemon there)
 *   CLOTHD_TEST_RECORDING_WRITE_MS=M  the recordings' writer waits M ms before each frame it
 *                                     writes (a slow disk: it falls behind the scene); not one-shot
 *   CLOTHD_TEST_WEDGE_FRAME=N         after frame N, the sim thread stops for CLOTHD_TEST_WEDGE_MS
 *                                     ms (a wedged thread: GET /livez goes 503), then goes on
 *
 * Frames count as GET /v1/sim's `frame`. Each hook logs what it does. */
#ifndef CLOTHD_TESTHOOKS_H
#define CLOTHD_TESTHOOKS_H

#include <stdint.h>

#include "clothsim/clothsim.h"

#ifndef CLOTHD_TEST_HOOKS
#error "testhooks.h is for the test daemon only (CLOTHD_TEST_HOOKS)"
#endif

/* Reads the variables (before any thread starts); logs the hooks that are armed. */
void testhooks_init(void);
/* From the sim thread, before it steps the frame after `frame`. */
void testhooks_before_frame(cs_sim *sim, uint64_t frame);
/* From the state file writer, between writing `tmp` and renaming it. */
void testhooks_before_rename(const char *tmp);
/* Whether CLOTHD_TEST_RECORDING_WRITE_MS is set; and from the recordings' writer, before each frame. */
int testhooks_recording_slow(void);
void testhooks_before_recording_write(void);

#endif
