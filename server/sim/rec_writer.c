/* rec_writer.c - the recordings' writer thread (see recordings.c): it encodes each frame
 * queued for a running recording with the stream's encoders, appends it and the events to its file
 * (or memory) within max_recordings_mb, then writes its index and tail when it ends. */
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "clothd_frame.h"
#include "core/delta.h"
#include "core/log.h"
#include "core/recording.h"
#include "core/wire.h"
#include "sim/recordings.h"
#include "sim/recordings_internal.h"

/* ---- the writer thread ---- */

static int grow_buf(recording *k, size_t need)
{
    if (need <= k->buf_cap) return 0;
    unsigned char *b = realloc(k->buf, need);
    if (!b) return -1;
    k->buf = b;
    k->buf_cap = need;
    return 0;
}

/* Stops a recording from the writer (the table's lock held): no more items are taken. */
void recording_stop_locked(recording *k, const char *reason)
{
    if (!k->reason[0]) snprintf(k->reason, sizeof k->reason, "%s", reason);
    k->ending = 1;
}

/* One record (type, payload) at the end of the file, within the cap: the bytes it took, 0 when the
 * cap or a failure stopped the recording. */
static uint64_t put_record(recordings *r, recording *k, uint32_t type, const unsigned char *payload, size_t len)
{
    const uint64_t size = rec_record_size(len);
    pthread_mutex_lock(&r->lock);
    const uint64_t after = r->total + size + rec_index_size(k->ix.n_frames + 1, k->ix.n_texts + 1);
    const int over = r->cap && after > r->cap;
    if (over) {
        recording_stop_locked(k, "max_recordings_mb reached");
        k->capped = 1;
    }
    pthread_mutex_unlock(&r->lock);
    if (over) return 0;
    unsigned char head[REC_RECORD_HEAD], pad[4] = {0};
    rec_record_head(head, type, (uint32_t)len);
    if (recording_append(k, head, sizeof head) != 0 || recording_append(k, payload, len) != 0 || recording_append(k, pad, rec_padding(len)) != 0) {
        log_msg("recording %s: write failed: %s; stopped", k->id, strerror(errno));
        pthread_mutex_lock(&r->lock);
        recording_stop_locked(k, "write failed");
        k->capped = 1;      /* what is still queued goes unwritten */
        k->write_failed = 1; /* and no index after a record cut short: the file reads as cut */
        pthread_mutex_unlock(&r->lock);
        return 0;
    }
    return size;
}

/* Encodes a pose in the recording's encoding into k->buf: its length, 0 on failure. *key: a
 * keyframe (any encoding but delta: every frame is its own). */
static size_t encode(recordings *r, recording *k, const pose *p, int *key)
{
    *key = 1;
    if (grow_buf(k, wire_bound(p, k->encoding, SCALAR_NONE)) != 0) return 0;
    if (k->encoding != CLF_DELTA) return wire_encode(p, k->encoding, SCALAR_NONE, k->buf);
    if (!k->enc_ready) {
        if (delta_init(&k->enc, r->quantum) != 0) return 0;
        k->enc_ready = 1;
    }
    unsigned char *section = malloc(delta_bound(p->n));
    if (!section) return 0;
    /* The encoder's clock: frame_rate frames make its keyframe interval, so that a keyframe comes
     * at least every frame_rate frames (a second of sim time at the scene's rate). */
    const double fr = k->frame_rate > 0 ? k->frame_rate : 60.0;
    const uint64_t tick = (uint64_t)ceil((double)DELTA_KEY_INTERVAL_NS / fr);
    const size_t len = delta_encode(&k->enc, p->xyz, p->n, p->nx > 0 ? p->nx : p->n, p->frame, tick * k->ix.n_frames, section, key);
    const size_t out = len ? wire_encode_delta(p, SCALAR_NONE, section, len, k->buf) : 0;
    free(section);
    return out;
}

/* Writes one item of a recording (outside the table's lock). */
static void write_item(recordings *r, recording *k, rec_item *it)
{
    uint64_t at;
    pthread_mutex_lock(&k->dlock);
    at = k->mem_len;
    pthread_mutex_unlock(&k->dlock);
    if (it->kind == REC_TEXT) {
        /* In the index first (it may be full), so that no record is written that it lacks. */
        if (rec_index_add_text(&k->ix, at) != 0) {
            pthread_mutex_lock(&r->lock);
            k->events_dropped++;
            pthread_mutex_unlock(&r->lock);
            return;
        }
        const uint64_t size = put_record(r, k, REC_TEXT, (const unsigned char *)it->text, strlen(it->text));
        if (!size) k->ix.n_texts--;
        if (size) {
            pthread_mutex_lock(&r->lock);
            k->bytes += size;
            r->total += size;
            pthread_mutex_unlock(&r->lock);
        }
        return;
    }
    if (r->before_write) r->before_write();
    int key = 1;
    const size_t len = encode(r, k, it->p, &key);
    if (!len) {
        pthread_mutex_lock(&r->lock);
        k->frames_dropped++;
        pthread_mutex_unlock(&r->lock);
        return;
    }
    if (key) k->last_key = k->ix.n_frames;
    const rec_frame f = {at, it->p->sim_time, key ? k->ix.n_frames : k->last_key, k->ix.n_texts};
    if (rec_index_add_frame(&k->ix, &f) != 0) {
        pthread_mutex_lock(&r->lock);
        k->frames_dropped++;
        pthread_mutex_unlock(&r->lock);
        return;
    }
    const uint64_t size = put_record(r, k, REC_FRAME, k->buf, len);
    if (!size) {
        k->ix.n_frames--;
        return;
    }
    pthread_mutex_lock(&r->lock);
    if (k->frames == 0) k->t_first = f.sim_time;
    k->t_last = f.sim_time;
    k->frames++;
    k->bytes += size;
    r->total += size;
    pthread_mutex_unlock(&r->lock);
}

/* Writes the index and tail of a recording that ended (outside the lock); its state then. */
static void finish(recordings *r, recording *k)
{
    pthread_mutex_lock(&k->dlock);
    const uint64_t at = k->mem_len;
    pthread_mutex_unlock(&k->dlock);
    size_t len = 0;
    unsigned char *tail = k->write_failed ? NULL : rec_index_finish(&k->ix, at, &len);
    const int ok = tail && recording_append(k, tail, len) == 0;
    free(tail);
    if (ok && k->fd >= 0 && fsync(k->fd) != 0) log_msg("recording %s: fsync: %s", k->id, strerror(errno));
    if (!ok && !k->write_failed) log_msg("recording %s: its index could not be written: %s", k->id, strerror(errno));
    pthread_mutex_lock(&r->lock);
    if (ok) {
        k->bytes += len;
        r->total += len;
    }
    k->state = k->reason[0] ? REC_STOPPED : REC_DONE;
    pthread_mutex_unlock(&r->lock);
}

/* The table's lock held: the next recording with work for the writer. */
static recording *next_work(recordings *r)
{
    for (recording *k = r->list; k; k = k->next)
        if (!k->busy && ((k->deleting && !k->sc) || k->count || (k->ending && k->state == REC_RECORDING))) return k;
    return NULL;
}

static void unlink_locked(recordings *r, recording *k)
{
    for (recording **p = &r->list; *p; p = &(*p)->next)
        if (*p == k) {
            *p = k->next;
            break;
        }
    r->count--;
    r->total -= k->bytes < r->total ? k->bytes : r->total;
}

void *recordings_writer(void *arg)
{
    recordings *r = arg;
    sigset_t all;
    sigfillset(&all);
    pthread_sigmask(SIG_BLOCK, &all, NULL);
    pthread_mutex_lock(&r->lock);
    for (;;) {
        recording *k = next_work(r);
        if (!k) {
            if (r->stop) break;
            pthread_cond_wait(&r->work, &r->lock);
            continue;
        }
        if (k->deleting && !k->sc) { /* off its scene: nobody hands it anything more */
            unlink_locked(r, k);
            pthread_mutex_unlock(&r->lock);
            if (k->on_disk) {
                char path[SETTING_TEXT_MAX + SCENE_ID_MAX + 8];
                recordings_file_path(r, k->id, path, sizeof path);
                if (unlink(path) != 0) log_msg("recording %s: could not remove %s: %s", k->id, path, strerror(errno));
            }
            recording_free(k);
            pthread_mutex_lock(&r->lock);
            pthread_cond_broadcast(&r->freed);
            continue;
        }
        k->busy++;
        if (k->count && !k->capped) {
            rec_item it = k->items[k->head];
            k->head = (k->head + 1) % REC_QUEUE_ITEMS;
            k->count--;
            pthread_mutex_unlock(&r->lock);
            write_item(r, k, &it);
            free(it.text);
            pthread_mutex_lock(&r->lock);
            if (it.p) k->spare[k->n_spare++] = it.p;
        } else if (k->count) { /* stopped at the cap: what is still queued goes unwritten */
            rec_item it = k->items[k->head];
            k->head = (k->head + 1) % REC_QUEUE_ITEMS;
            k->count--;
            free(it.text);
            if (it.p) {
                k->spare[k->n_spare++] = it.p;
                k->frames_dropped++;
            }
        } else {
            pthread_mutex_unlock(&r->lock);
            finish(r, k);
            pthread_mutex_lock(&r->lock);
        }
        k->busy--;
        pthread_cond_broadcast(&r->freed);
    }
    pthread_mutex_unlock(&r->lock);
    return NULL;
}
