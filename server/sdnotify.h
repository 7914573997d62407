/* sdnotify.h - systemd's notification protocol (sd_notify(3)), without libsystemd: datagrams of
 * "KEY=VALUE" lines to the AF_UNIX socket named by $NOTIFY_SOCKET (a path, or an abstract name
 * written with a leading '@'). Type=notify waits for READY=1; WatchdogSec= sets $WATCHDOG_USEC
 * (and $WATCHDOG_PID), and a service that sends no WATCHDOG=1 for that long is killed and
 * restarted. clothd sends WATCHDOG=1 from the sim thread's heartbeat (simloop_set_beat), so a
 * wedged sim thread is what the watchdog catches. Without $NOTIFY_SOCKET every call does nothing. */
#ifndef CLOTHD_SDNOTIFY_H
#define CLOTHD_SDNOTIFY_H

/* Reads the environment (once, before any thread starts): 0, or -1 when $NOTIFY_SOCKET is set but
 * unusable (logged; the daemon runs on without notifying). */
int sdnotify_init(void);
/* Seconds between two WATCHDOG=1: half of $WATCHDOG_USEC, or 0 when there is no watchdog for this
 * process ($WATCHDOG_PID names another, or no socket). */
double sdnotify_watchdog_every(void);
/* Sends one datagram (e.g. "READY=1\nSTATUS=..."); any thread. Failures are ignored: systemd
 * notices a missing READY or WATCHDOG by itself. */
void sdnotify_send(const char *msg);
/* A simloop beat: WATCHDOG=1. */
void sdnotify_watchdog(void *ctx);

#endif
