/* rectap.h - what the sim thread asks of a scene's running recordings, between its frames
 * (simloop.c), beside what the scene hands them through their sink (sim/sink.h, rec_tap.c).
 * rec_tap.c implements these; they never wait on a writer. */
#ifndef CLOTHD_RECTAP_H
#define CLOTHD_RECTAP_H

struct scene;

/* Whether a running recording of the scene wants the pose of now: one that has none yet, or any
 * when the scene changed since the last pose recorded (changed). */
int recordings_want(struct scene *sc, int changed);
/* Whether each running recording of the scene has room for one more pose (1 when none runs): a
 * step in progress, or a scene at max_speed, waits for its recordings' writer rather than have
 * them drop frames (a scene in real time goes on, and they drop and count). */
int recordings_room(struct scene *sc);

#endif
