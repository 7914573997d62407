/* cs_testhooks.h - fault injection into libclothsim, for clothd's fault tests only.
 *
 * Built into the library `clothsim_testhooks`, which only the test daemon clothd-testhooks links;
 * the shipped library and daemon contain none of it. It changes state the public API would never
 * let through (a NaN) and breaks a backend the way a lost GPU does, so that the daemon's own
 * recovery paths run as they would for a real fault. No physics here. */
#ifndef CLOTHSIM_TESTHOOKS_H
#define CLOTHSIM_TESTHOOKS_H

#include "clothsim/clothsim.h"

#ifndef CLOTHD_TEST_HOOKS
#error "cs_testhooks.h is for test builds only (CLOTHD_TEST_HOOKS)"
#endif

/* Writes a NaN into the position of one vertex (its x), as a blow-up would: the next step
 * reports CS_E_NONFINITE. CS_E_RANGE for a vertex outside the cloth. */
cs_status cs_test_poison(cs_sim *sim, int32_t vertex);

/* From now on the backend fails as a sticky device error does (CS_E_DEVICE from every step,
 * upload, download and refresh), and the host copy counts as behind the lost device state, so
 * snapshots and reads fail too. Irreversible for this simulation; destroying it still works. */
cs_status cs_test_break_backend(cs_sim *sim);

#endif
