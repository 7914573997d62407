/* recording.c - the CLR1 recording format: writer's pieces and reader (see recording.h). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "clothd_frame.h"
#include "core/recording.h"

/* The most vertices a hello may name (a cloth of 8192 x 8192): keeps every size below in 64 bits. */
#define REC_MAX_VERTICES (1ll << 26)

static void put_u32(unsigned char *p, uint32_t v)
{
    for (int i = 0; i < 4; i++) p[i] = (unsigned char)(v >> (8 * i));
}
static void put_u64(unsigned char *p, uint64_t v)
{
    for (int i = 0; i < 8; i++) p[i] = (unsigned char)(v >> (8 * i));
}
static uint32_t get_u32(const unsigned char *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}
static uint16_t get_u16(const unsigned char *p) { return (uint16_t)(p[0] | p[1] << 8); }
static uint64_t get_u64(const unsigned char *p) { return (uint64_t)get_u32(p) | (uint64_t)get_u32(p + 4) << 32; }
static double get_f64(const unsigned char *p)
{
    const uint64_t u = get_u64(p);
    double d;
    memcpy(&d, &u, sizeof d);
    return d;
}

/* ---- writing ---- */

void rec_file_header(unsigned char out[REC_HEADER_SIZE])
{
    memcpy(out, REC_MAGIC, 4);
    put_u32(out + 4, REC_VERSION);
    put_u32(out + 8, 0);
    put_u32(out + 12, 0);
}

void rec_record_head(unsigned char out[REC_RECORD_HEAD], uint32_t type, uint32_t len)
{
    put_u32(out, type);
    put_u32(out + 4, len);
}

size_t rec_padding(size_t len) { return (4 - len % 4) % 4; }

uint64_t rec_record_size(uint64_t len) { return REC_RECORD_HEAD + len + rec_padding((size_t)len); }

int rec_index_add_frame(rec_index *ix, const rec_frame *f)
{
    if ((uint64_t)ix->n_frames + ix->n_texts + 1 >= REC_MAX_RECORDS) return -1;
    if (ix->n_frames == ix->cap_frames) {
        const uint32_t cap = ix->cap_frames ? 2 * ix->cap_frames : 256;
        rec_frame *g = realloc(ix->frames, sizeof *g * cap);
        if (!g) return -1;
        ix->frames = g;
        ix->cap_frames = cap;
    }
    ix->frames[ix->n_frames++] = *f;
    return 0;
}

int rec_index_add_text(rec_index *ix, uint64_t offset)
{
    if ((uint64_t)ix->n_frames + ix->n_texts + 1 >= REC_MAX_RECORDS) return -1;
    if (ix->n_texts == ix->cap_texts) {
        const uint32_t cap = ix->cap_texts ? 2 * ix->cap_texts : 64;
        uint64_t *g = realloc(ix->texts, sizeof *g * cap);
        if (!g) return -1;
        ix->texts = g;
        ix->cap_texts = cap;
    }
    ix->texts[ix->n_texts++] = offset;
    return 0;
}

void rec_index_free(rec_index *ix)
{
    free(ix->frames);
    free(ix->texts);
    memset(ix, 0, sizeof *ix);
}

uint64_t rec_index_size(uint64_t n_frames, uint64_t n_texts)
{
    return rec_record_size(8 + REC_INDEX_FRAME * n_frames + REC_INDEX_TEXT * n_texts) + REC_TAIL_SIZE;
}

unsigned char *rec_index_finish(const rec_index *ix, uint64_t at, size_t *len)
{
    const uint64_t payload = 8 + (uint64_t)REC_INDEX_FRAME * ix->n_frames + (uint64_t)REC_INDEX_TEXT * ix->n_texts;
    const size_t total = (size_t)rec_index_size(ix->n_frames, ix->n_texts);
    unsigned char *b = calloc(1, total);
    if (!b) return NULL;
    rec_record_head(b, REC_INDEX, (uint32_t)payload);
    unsigned char *p = b + REC_RECORD_HEAD;
    put_u32(p, ix->n_frames);
    put_u32(p + 4, ix->n_texts);
    p += 8;
    for (uint32_t k = 0; k < ix->n_frames; k++, p += REC_INDEX_FRAME) {
        const rec_frame *f = &ix->frames[k];
        uint64_t t;
        memcpy(&t, &f->sim_time, sizeof t);
        put_u64(p, f->offset);
        put_u64(p + 8, t);
        put_u32(p + 16, f->key);
        put_u32(p + 20, f->texts_before);
    }
    for (uint32_t k = 0; k < ix->n_texts; k++, p += REC_INDEX_TEXT) put_u64(p, ix->texts[k]);
    unsigned char *tail = b + total - REC_TAIL_SIZE;
    memcpy(tail, REC_TAIL_MAGIC, 4);
    put_u32(tail + 4, 0);
    put_u64(tail + 8, at);
    *len = total;
    return b;
}

/* ---- reading ---- */

int rec_check_frame(const unsigned char *p, size_t len, int32_t n, int *encoding, int *kind, uint32_t *key_id, char *why,
                    size_t why_len)
{
    *kind = -1;
    *key_id = 0;
    if (len < CLF_HEADER_SIZE || memcmp(p, CLF_MAGIC, 4) != 0) {
        snprintf(why, why_len, "a frame record that is not a CLF1 frame");
        return -1;
    }
    if (get_u16(p + CLF_OFF_HEADER_SIZE) != CLF_HEADER_SIZE) {
        snprintf(why, why_len, "a frame with header size %u (72 expected)", (unsigned)get_u16(p + CLF_OFF_HEADER_SIZE));
        return -1;
    }
    const unsigned flags = get_u16(p + CLF_OFF_FLAGS);
    if (flags & CLF_FLAG_RESERVED) {
        snprintf(why, why_len, "a frame with unknown flags 0x%x", flags);
        return -1;
    }
    const uint32_t nv = get_u32(p + CLF_OFF_N_VERTICES), nr = get_u32(p + CLF_OFF_N_ROCKS);
    if (nv != (uint32_t)n) {
        snprintf(why, why_len, "a frame of %u vertices in a recording of %d", (unsigned)nv, (int)n);
        return -1;
    }
    *encoding = (int)(flags & CLF_FLAG_ENCODING_MASK);
    const uint64_t un = (uint64_t)n;
    uint64_t pos;
    switch (*encoding) {
    case CLF_F32: pos = 12 * un; break;
    case CLF_Q16: pos = CLF_ALIGN4(6 * un); break;
    case CLF_MESHOPT:
        if (len < CLF_HEADER_SIZE + 4) {
            snprintf(why, why_len, "a meshopt frame without its byte count");
            return -1;
        }
        pos = 4 + CLF_ALIGN4((uint64_t)get_u32(p + CLF_HEADER_SIZE));
        break;
    default: {
        if (len < CLF_HEADER_SIZE + CLF_DELTA_HEAD) {
            snprintf(why, why_len, "a delta frame without its 44-byte head");
            return -1;
        }
        const unsigned char *s = p + CLF_HEADER_SIZE;
        const uint32_t k = get_u32(s + CLF_DELTA_OFF_KIND);
        if (k > CLF_DELTA_DELTA) {
            snprintf(why, why_len, "a delta frame of kind %u", (unsigned)k);
            return -1;
        }
        *kind = (int)k;
        *key_id = get_u32(s + CLF_DELTA_OFF_KEY_ID);
        if (*key_id == 0) {
            snprintf(why, why_len, "a delta frame with keyframe id 0");
            return -1;
        }
        pos = CLF_DELTA_HEAD + CLF_ALIGN4((uint64_t)get_u32(s + CLF_DELTA_OFF_LENGTH));
        break;
    }
    }
    const uint64_t want = CLF_HEADER_SIZE + pos + ((flags & CLF_FLAG_SCALAR) ? CLF_ALIGN4(un) : 0) + (uint64_t)nr * CLF_ROCK_SIZE;
    if (want != len) {
        snprintf(why, why_len, "a frame of %zu bytes whose header says %llu", len, (unsigned long long)want);
        return -1;
    }
    return 0;
}

static int refuse(rec_file *out, uint64_t at, const char *why)
{
    json_decref(out->hello);
    rec_index_free(&out->ix);
    out->hello = NULL;
    snprintf(out->error, sizeof out->error, "%s (at offset %llu)", why, (unsigned long long)at);
    out->error_offset = at;
    return -1;
}

/* The hello: a JSON object of type "hello" whose scene names its size; its vertex count. */
static int read_hello(rec_file *out, const unsigned char *p, size_t len, uint64_t at)
{
    json_t *h = json_loadb((const char *)p, len, JSON_REJECT_DUPLICATES, NULL);
    const json_t *sc = json_object_get(h, "scene"), *nx = json_object_get(sc, "nx"), *ny = json_object_get(sc, "ny");
    const char *type = json_string_value(json_object_get(h, "type"));
    if (!type || strcmp(type, "hello") != 0 || !json_is_integer(nx) || !json_is_integer(ny)) {
        json_decref(h);
        return refuse(out, at, "the first record is not the scene's hello (a text of type hello with scene.nx and scene.ny)");
    }
    const long long x = json_integer_value(nx), y = json_integer_value(ny);
    if (x < 1 || y < 1 || x > REC_MAX_VERTICES || y > REC_MAX_VERTICES || x * y > REC_MAX_VERTICES) {
        json_decref(h);
        return refuse(out, at, "the hello's cloth size is out of range");
    }
    out->hello = h;
    out->n_vertices = (int32_t)(x * y);
    return 0;
}

/* Whether the file's last 16 bytes are a tail: its index record's offset in *at. */
static int has_tail(const unsigned char *buf, size_t len, uint64_t *at)
{
    if (len < REC_HEADER_SIZE + REC_TAIL_SIZE) return 0;
    const unsigned char *t = buf + len - REC_TAIL_SIZE;
    if (memcmp(t, REC_TAIL_MAGIC, 4) != 0 || get_u32(t + 4) != 0) return 0;
    *at = get_u64(t + 8);
    return 1;
}

/* The index record at `at` (payload len bytes) against what the scan found. */
static int check_index(rec_file *out, const unsigned char *p, uint64_t len, uint64_t at)
{
    if (len < 8) return refuse(out, at, "an index shorter than its counts");
    const uint32_t nf = get_u32(p), nt = get_u32(p + 4);
    if (nf != out->ix.n_frames || nt != out->ix.n_texts)
        return refuse(out, at, "an index whose counts do not match the records");
    if (len != 8 + (uint64_t)REC_INDEX_FRAME * nf + (uint64_t)REC_INDEX_TEXT * nt)
        return refuse(out, at, "an index whose length does not match its counts");
    const unsigned char *e = p + 8;
    for (uint32_t k = 0; k < nf; k++, e += REC_INDEX_FRAME) {
        const rec_frame *f = &out->ix.frames[k];
        const double t = get_f64(e + 8);
        if (get_u64(e) != f->offset || memcmp(&t, &f->sim_time, sizeof t) != 0 || get_u32(e + 16) != f->key ||
            get_u32(e + 20) != f->texts_before)
            return refuse(out, at, "an index entry of a frame that does not match its record");
    }
    for (uint32_t k = 0; k < nt; k++, e += REC_INDEX_TEXT)
        if (get_u64(e) != out->ix.texts[k]) return refuse(out, at, "an index entry of a text that does not match its record");
    return 0;
}

int rec_read(const unsigned char *buf, size_t len, rec_file *out)
{
    memset(out, 0, sizeof *out);
    out->encoding = -1;
    if (len < REC_HEADER_SIZE || memcmp(buf, REC_MAGIC, 4) != 0) return refuse(out, 0, "not a clothd recording (magic CLR1)");
    if (get_u32(buf + 4) != REC_VERSION) return refuse(out, 4, "a recording of another version than 1");
    if (get_u32(buf + 8) != 0) return refuse(out, 8, "a recording with flags set");
    uint64_t tail_at = 0;
    const int tail = has_tail(buf, len, &tail_at);
    uint64_t at = REC_HEADER_SIZE;
    uint32_t records = 0, last_key_id = 0, last_key = 0;
    int have_key = 0;
    char why[160];
    out->end = at;
    while (at + REC_RECORD_HEAD <= len) {
        const uint32_t type = get_u32(buf + at), plen = get_u32(buf + at + 4);
        const uint64_t size = rec_record_size(plen);
        if (type < REC_TEXT || type > REC_INDEX) return refuse(out, at, "a record of unknown type");
        if (size > len - at) break; /* cut short: what came before counts */
        if (++records > REC_MAX_RECORDS) return refuse(out, at, "more than 2^24 records");
        const unsigned char *p = buf + at + REC_RECORD_HEAD;
        if (records == 1 && type != REC_TEXT) return refuse(out, at, "the first record is not the scene's hello");
        if (type == REC_INDEX) {
            const uint64_t after = at + size;
            if (tail && tail_at == at && after + REC_TAIL_SIZE == len) {
                if (check_index(out, p, plen, at) != 0) return -1;
                out->complete = 1;
                out->end = len;
                return 0;
            }
            if (len - after >= REC_TAIL_SIZE) return refuse(out, at, "an index record without its tail");
            out->end = at; /* the tail was cut: the records before count */
            return 0;
        }
        if (type == REC_TEXT) {
            if (memchr(p, 0, plen)) return refuse(out, at, "a text record holding a NUL");
            if (records == 1) {
                if (read_hello(out, p, plen, at) != 0) return -1;
            } else {
                json_t *j = json_loadb((const char *)p, plen, 0, NULL);
                const int ok = j != NULL;
                json_decref(j);
                if (!ok) return refuse(out, at, "a text record that is not JSON");
            }
            if (rec_index_add_text(&out->ix, at) != 0) return refuse(out, at, "out of memory");
        } else {
            int enc, kind;
            uint32_t key_id;
            if (rec_check_frame(p, plen, out->n_vertices, &enc, &kind, &key_id, why, sizeof why) != 0) return refuse(out, at, why);
            if (out->encoding >= 0 && enc != out->encoding) return refuse(out, at, "frames of two encodings");
            out->encoding = enc;
            rec_frame f = {at, get_f64(p + CLF_OFF_SIM_TIME), out->ix.n_frames, out->ix.n_texts};
            if (enc == CLF_DELTA) {
                if (CLF_DELTA_KIND_IS_KEY(kind)) {
                    if (have_key && key_id <= last_key_id) return refuse(out, at, "a keyframe whose id does not grow");
                    have_key = 1;
                    last_key_id = key_id;
                    last_key = out->ix.n_frames;
                } else if (!have_key || key_id != last_key_id) {
                    return refuse(out, at, "a delta frame whose keyframe is not the last keyframe before it");
                }
                f.key = last_key;
            }
            if (rec_index_add_frame(&out->ix, &f) != 0) return refuse(out, at, "out of memory");
        }
        at += size;
        out->end = at;
    }
    if (records == 0) {
        /* Only the header (a recording that has not written its hello yet): nothing to read. */
        return refuse(out, REC_HEADER_SIZE, "a recording without its hello");
    }
    return 0;
}

void rec_file_free(rec_file *f)
{
    json_decref(f->hello);
    rec_index_free(&f->ix);
    f->hello = NULL;
}
