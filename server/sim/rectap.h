/* rectap.h - what the sim thread hands a scene's running recordings: the recordings' side of a
 * scene, declared here so that scene.c reaches sim/recordings.c without including it (which
 * includes scene.h: the modules keep no include cycle). recordings.c implements these; they are
 * the sim thread's, called from scene_publish and scene_emit, and never wait on a writer. */
#ifndef CLOTHD_RECTAP_H
#define CLOTHD_RECTAP_H

#include "clothsim/clothsim.h"
#include "core/pose.h"

struct scene;

/* Whether a running recording of the scene wants the pose of now: one that has none yet, or any
 * when the scene changed since the last pose recorded (changed). */
int recordings_want(struct scene *sc, int changed);
/* Hands the pose to the scene's running recordings (copied): to all when the scene changed since
 * the last, else only to those that have none yet; with the scene's hello first for one that
 * starts (the scene's published reads, and these rocks). */
void recordings_frame(struct scene *sc, const pose *p, const cs_rock *rocks, int n_rocks, int changed);
/* Whether each running recording of the scene has room for one more pose (1 when none runs): a
 * step in progress, or a scene at max_speed, waits for its recordings' writer rather than have
 * them drop frames (a scene in real time goes on, and they drop and count). */
int recordings_room(struct scene *sc);
/* Hands an event's text to the scene's running recordings that have their hello (copied). */
void recordings_event(struct scene *sc, const char *text);
/* The scene left the daemon: its recordings stop ("scene deleted"); none starts on it again. */
void recordings_scene_gone(struct scene *sc);

#endif
