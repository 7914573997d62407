/* journal.c - the command journal (see journal.h). */
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "core/journal.h"
#include "core/json_write.h"

struct journal {
    pthread_mutex_t lock;
    char **entries; /* each {"step": N, "command": {...}} */
    size_t n, cap, max;
    size_t bytes, max_bytes; /* of the entries: their text and the index's pointer to each */
    unsigned char *base;
    size_t base_len;
    uint64_t base_step;
};

journal *journal_new(size_t max_entries, size_t max_bytes)
{
    journal *j = calloc(1, sizeof *j);
    if (!j) return NULL;
    pthread_mutex_init(&j->lock, NULL);
    j->max = max_entries;
    j->max_bytes = max_bytes;
    return j;
}

static void clear(journal *j)
{
    for (size_t k = 0; k < j->n; k++) free(j->entries[k]);
    j->n = 0;
    j->bytes = 0;
}

void journal_free(journal *j)
{
    if (!j) return;
    clear(j);
    free(j->entries);
    free(j->base);
    pthread_mutex_destroy(&j->lock);
    free(j);
}

int journal_rebase(journal *j, const void *snapshot, size_t len, uint64_t base_step)
{
    unsigned char *copy = malloc(len ? len : 1);
    if (!copy) return -1;
    memcpy(copy, snapshot, len);
    pthread_mutex_lock(&j->lock);
    clear(j);
    free(j->base);
    j->base = copy;
    j->base_len = len;
    j->base_step = base_step;
    pthread_mutex_unlock(&j->lock);
    return 0;
}

int journal_append(journal *j, uint64_t step, const json_t *command)
{
    json_t *e = json_pack("{s:I, s:O}", "step", (json_int_t)step, "command", (json_t *)command);
    char *s = json_dumps(e, JSON_DUMP_FLAGS);
    json_decref(e);
    if (!s) return -1;
    pthread_mutex_lock(&j->lock);
    if (j->n == j->cap) {
        const size_t cap = j->cap ? 2 * j->cap : 64;
        char **grown = realloc(j->entries, sizeof *grown * cap);
        if (!grown) {
            pthread_mutex_unlock(&j->lock);
            free(s);
            return -1;
        }
        j->entries = grown;
        j->cap = cap;
    }
    j->entries[j->n++] = s;
    j->bytes += strlen(s) + 1 + sizeof *j->entries;
    pthread_mutex_unlock(&j->lock);
    return 0;
}

int journal_full(journal *j)
{
    pthread_mutex_lock(&j->lock);
    const int full = j->n >= j->max || j->bytes >= j->max_bytes;
    pthread_mutex_unlock(&j->lock);
    return full;
}

/* The JSON text, with "step" when step_field is non-negative. Caller holds the lock. */
static char *render(journal *j, long long step_field, size_t *len)
{
    size_t total = 96;
    for (size_t k = 0; k < j->n; k++) total += strlen(j->entries[k]) + 1;
    char *out = malloc(total);
    if (!out) return NULL;
    size_t at = (size_t)snprintf(out, total, "{\"base_step\":%llu,", (unsigned long long)j->base_step);
    if (step_field >= 0) at += (size_t)snprintf(out + at, total - at, "\"step\":%lld,", step_field);
    at += (size_t)snprintf(out + at, total - at, "\"entries\":[");
    for (size_t k = 0; k < j->n; k++) {
        if (k) out[at++] = ',';
        const size_t l = strlen(j->entries[k]);
        memcpy(out + at, j->entries[k], l);
        at += l;
    }
    out[at++] = ']';
    out[at++] = '}';
    out[at] = '\0';
    *len = at;
    return out;
}

char *journal_json(journal *j, size_t *len)
{
    pthread_mutex_lock(&j->lock);
    char *s = render(j, -1, len);
    pthread_mutex_unlock(&j->lock);
    return s;
}

unsigned char *journal_bundle(journal *j, uint64_t step, size_t *len)
{
    pthread_mutex_lock(&j->lock);
    size_t jl = 0;
    char *text = render(j, (long long)step, &jl);
    unsigned char *out = text ? malloc(j->base_len + jl) : NULL;
    if (out) {
        memcpy(out, j->base, j->base_len);
        memcpy(out + j->base_len, text, jl);
        *len = j->base_len + jl;
    }
    pthread_mutex_unlock(&j->lock);
    free(text);
    return out;
}
