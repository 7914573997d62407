/* recording.h - the recording file format CLR1 (proto/PROTOCOL.md, "Recordings"): its writer's
 * pieces and its reader. Pure: bytes in, bytes out, no file and no thread.
 *
 * A file is a 16-byte header (magic "CLR1", version 1, flags 0, reserved 0) and records from
 * offset 16, each {u32 type, u32 payload length L, L bytes, zero padding to 4 bytes}: text (1, a
 * stream text message; the first is the scene's hello with a "recording" member), frame (2, one
 * CLF1 binary frame of proto/clothd_frame.h) and index (3, written once at the end), then a
 * 16-byte tail {"CLRX", u32 0, u64 offset of the index record}. All little-endian.
 *
 * The reader checks a whole file the same way whether it ends with its tail or was cut (a
 * recording still running, a daemon killed): it scans every record from offset 16 and checks
 * each one; a file with a valid tail has its index compared with what the scan found, entry by
 * entry; a file without one counts up to its last complete record. Limits: a payload fits the
 * bytes left, at most REC_MAX_RECORDS records. */
#ifndef CLOTHD_CORE_RECORDING_H
#define CLOTHD_CORE_RECORDING_H

#include <stddef.h>
#include <stdint.h>

#include <jansson.h>

#define REC_MAGIC "CLR1"
#define REC_TAIL_MAGIC "CLRX"
#define REC_VERSION 1u
#define REC_HEADER_SIZE 16u
#define REC_RECORD_HEAD 8u
#define REC_TAIL_SIZE 16u
#define REC_INDEX_FRAME 24u /* bytes of one frame's index entry */
#define REC_INDEX_TEXT 8u   /* ... of one text's */
#define REC_MAX_RECORDS (1u << 24)

enum { REC_TEXT = 1, REC_FRAME = 2, REC_INDEX = 3 };

/* One frame as the index lists it. */
typedef struct rec_frame {
    uint64_t offset;       /* of its record, from the file's start */
    double sim_time;       /* the frame's own */
    uint32_t key;          /* the ordinal of the keyframe it needs (itself unless a delta) */
    uint32_t texts_before; /* text records before its record */
} rec_frame;

/* What a file holds, as the writer keeps it and the reader finds it. */
typedef struct rec_index {
    rec_frame *frames;
    uint64_t *texts;       /* offsets of the text records */
    uint32_t n_frames, n_texts;
    uint32_t cap_frames, cap_texts;
} rec_index;

/* ---- writing ---- */

/* The file's 16-byte header. */
void rec_file_header(unsigned char out[REC_HEADER_SIZE]);
/* A record's 8-byte head. */
void rec_record_head(unsigned char out[REC_RECORD_HEAD], uint32_t type, uint32_t len);
/* Zero bytes after a payload of len bytes (0-3). */
size_t rec_padding(size_t len);
/* Bytes a record of a payload of len bytes takes (head, payload, padding). */
uint64_t rec_record_size(uint64_t len);
/* Adds an entry; 0 or -1 (out of memory, or REC_MAX_RECORDS reached). */
int rec_index_add_frame(rec_index *ix, const rec_frame *f);
int rec_index_add_text(rec_index *ix, uint64_t offset);
void rec_index_free(rec_index *ix);
/* The end of a file whose index record starts at offset `at`: the index record and the tail
 * (malloc'd, *len bytes), or NULL (out of memory). */
unsigned char *rec_index_finish(const rec_index *ix, uint64_t at, size_t *len);
/* Bytes rec_index_finish makes for n_frames frames and n_texts texts. */
uint64_t rec_index_size(uint64_t n_frames, uint64_t n_texts);

/* ---- reading ---- */

typedef struct rec_file {
    int complete;          /* the tail and index were found and match the records */
    rec_index ix;
    json_t *hello;         /* the first record, parsed */
    int32_t n_vertices;    /* the hello's (scene.nx x scene.ny) */
    int encoding;          /* of the frames (clothd_frame.h), -1 before the first */
    uint64_t end;          /* where the records read end (the file's length when complete) */
    char error[200];       /* why it was refused */
    uint64_t error_offset; /* ... and where */
} rec_file;

/* Reads a file of len bytes: 0 with *out filled (rec_file_free it), or -1 with out->error and
 * out->error_offset (nothing else to free). */
int rec_read(const unsigned char *buf, size_t len, rec_file *out);
void rec_file_free(rec_file *f);

/* Checks one CLF1 frame of n vertices (header, flags, sizes; a delta's head): 0 with *encoding,
 * and for delta *kind (a clf_delta_kind) and *key_id; -1 with the reason. */
int rec_check_frame(const unsigned char *p, size_t len, int32_t n, int *encoding, int *kind, uint32_t *key_id, char *why,
                    size_t why_len);

#endif
