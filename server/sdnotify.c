/* sdnotify.c - sd_notify's datagram protocol (see sdnotify.h). */
#include <errno.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include "core/log.h"
#include "core/settings.h" /* the log levels */
#include "sdnotify.h"

static int fd = -1;
static struct sockaddr_un addr;
static socklen_t addr_len;
static double watchdog_every;

int sdnotify_init(void)
{
    const char *name = getenv("NOTIFY_SOCKET");
    if (!name || !*name) return 0;
    const size_t n = strlen(name);
    if ((name[0] != '/' && name[0] != '@') || n >= sizeof addr.sun_path) {
        log_at(LOG_WARN, NULL, NULL, "NOTIFY_SOCKET=%.200s is not an absolute path or an @abstract name that fits: "
               "systemd is not notified", name);
        return -1;
    }
    memset(&addr, 0, sizeof addr);
    addr.sun_family = AF_UNIX;
    memcpy(addr.sun_path, name, n);
    if (name[0] == '@') addr.sun_path[0] = '\0'; /* abstract: no trailing NUL counts */
    addr_len = (socklen_t)(offsetof(struct sockaddr_un, sun_path) + n + (name[0] == '/'));
    fd = socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    if (fd < 0) {
        log_at(LOG_WARN, NULL, NULL, "NOTIFY_SOCKET: %s: systemd is not notified", strerror(errno));
        return -1;
    }
    const char *usec = getenv("WATCHDOG_USEC"), *pid = getenv("WATCHDOG_PID");
    char *end = NULL;
    const unsigned long long us = usec ? strtoull(usec, &end, 10) : 0;
    const int ours = !pid || !*pid || strtoll(pid, NULL, 10) == (long long)getpid();
    if (usec && end && !*end && us > 0 && ours) watchdog_every = (double)us / 2e6;
    else if (usec && *usec && ours) log_at(LOG_WARN, NULL, NULL, "WATCHDOG_USEC=%.40s is not a number of microseconds: no watchdog", usec);
    /* Not for the processes this one might start */
    unsetenv("NOTIFY_SOCKET");
    unsetenv("WATCHDOG_USEC");
    unsetenv("WATCHDOG_PID");
    if (watchdog_every > 0) log_msg("systemd: notifying %s, WATCHDOG=1 every %.3f s", name, watchdog_every);
    else log_msg("systemd: notifying %s", name);
    return 0;
}

double sdnotify_watchdog_every(void) { return fd >= 0 ? watchdog_every : 0; }

void sdnotify_send(const char *msg)
{
    if (fd < 0) return;
    while (sendto(fd, msg, strlen(msg), MSG_NOSIGNAL, (const struct sockaddr *)&addr, addr_len) < 0 && errno == EINTR) {
    }
}

void sdnotify_watchdog(void *ctx)
{
    (void)ctx;
    sdnotify_send("WATCHDOG=1");
}
