/* rec_adopt.c - the recordings recordings_dir holds when clothd starts (see recordings.c):
 * each .clr file it can read listed as a done or stopped recording, the others left alone. */
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include "clothd_frame.h"
#include "core/log.h"
#include "core/recording.h"
#include "sim/recordings.h"
#include "sim/recordings_internal.h"

/* ---- adopting files ---- */

/* A .clr file of recordings_dir as a listed recording: done when it has its tail, else stopped
 * ("cut"). 0, or -1 when it is not a recording (logged, left alone). */
static int adopt(recordings *r, const char *rid)
{
    char path[SETTING_TEXT_MAX + SCENE_ID_MAX + 8];
    recordings_file_path(r, rid, path, sizeof path);
    const int fd = open(path, O_RDONLY | O_CLOEXEC | O_NOFOLLOW);
    struct stat st;
    if (fd < 0 || fstat(fd, &st) != 0 || !S_ISREG(st.st_mode) || st.st_size <= 0) {
        if (fd >= 0) close(fd);
        log_msg("recordings: %s cannot be read; left alone", path);
        return -1;
    }
    const size_t len = (size_t)st.st_size;
    void *map = mmap(NULL, len, PROT_READ, MAP_PRIVATE, fd, 0);
    close(fd);
    if (map == MAP_FAILED) return -1;
    rec_file f;
    const int rc = rec_read(map, len, &f);
    munmap(map, len);
    if (rc != 0) {
        log_msg("recordings: %s is not a recording clothd can read: %s; left alone", path, f.error);
        return -1;
    }
    recording *k = calloc(1, sizeof *k);
    if (!k) {
        rec_file_free(&f);
        return -1;
    }
    const json_t *m = json_object_get(f.hello, "recording");
    k->owner = r;
    k->on_disk = 1; /* GET reads it, DELETE unlinks it; nothing writes to it */
    k->fd = -1;
    snprintf(k->id, sizeof k->id, "%s", rid);
    snprintf(k->scene_id, sizeof k->scene_id, "%s", json_string_value(json_object_get(m, "scene")) ? json_string_value(json_object_get(m, "scene")) : "");
    k->encoding = f.encoding >= 0 ? f.encoding : CLF_DELTA;
    k->seconds = json_number_value(json_object_get(m, "seconds"));
    k->frame_rate = json_number_value(json_object_get(m, "frame_rate"));
    k->started_ns = (uint64_t)json_integer_value(json_object_get(m, "started_ns"));
    /* Finished: done when its frames span what was asked (a quarter frame's leeway, as when it
     * ran), else it was stopped (the file does not say why). */
    const double span = f.ix.n_frames ? f.ix.frames[f.ix.n_frames - 1].sim_time - f.ix.frames[0].sim_time : 0;
    const int whole = span >= k->seconds - 0.25 / (k->frame_rate > 0 ? k->frame_rate : 60.0);
    k->state = f.complete && whole ? REC_DONE : REC_STOPPED;
    if (k->state == REC_STOPPED) snprintf(k->reason, sizeof k->reason, "%s", f.complete ? "ended early" : "cut");
    k->frames = f.ix.n_frames;
    if (f.ix.n_frames) {
        k->t_first = f.ix.frames[0].sim_time;
        k->t_last = f.ix.frames[f.ix.n_frames - 1].sim_time;
    }
    k->bytes = len;
    k->mem_len = len;
    pthread_mutex_init(&k->dlock, NULL);
    rec_file_free(&f);
    k->next = r->list;
    r->list = k;
    r->count++;
    r->total += len;
    return 0;
}

int recordings_adopt_dir(recordings *r, char *err, size_t err_len)
{
    DIR *d = opendir(r->dir);
    if (!d) {
        snprintf(err, err_len, "recordings_dir %s: %s", r->dir, strerror(errno));
        return -1;
    }
    struct dirent *e;
    int n = 0;
    while ((e = readdir(d)) != NULL) {
        const size_t len = strlen(e->d_name);
        if (len < 5 || strcmp(e->d_name + len - 4, ".clr") != 0 || len - 4 >= SCENE_ID_MAX) continue;
        char rid[SCENE_ID_MAX];
        snprintf(rid, sizeof rid, "%.*s", (int)(len - 4), e->d_name);
        if (!recording_id_valid(rid)) continue;
        if (r->count >= RECORDINGS_MAX) {
            log_msg("recordings: more than %d files in %s; %s and others are not listed", RECORDINGS_MAX, r->dir, e->d_name);
            break;
        }
        if (adopt(r, rid) == 0) n++;
    }
    closedir(d);
    if (n) log_msg("recordings: %d in %s (%.1f MiB)", n, r->dir, (double)r->total / 1048576.0);
    return 0;
}
