/* fuzz_recording.c - a recording file (core/recording.c's rec_read), as the daemon reads the .clr
 * files of recordings_dir at start: a crafted file must never crash it, hang it or make it read
 * past the bytes it has.
 *
 * Besides what ASan and UBSan catch, it checks what recording.h promises of a file it takes: a
 * hello (an object with a vertex count), records inside the file and in order, each frame's
 * keyframe at or before it and texts_before never falling; a complete file ends at its length;
 * and the writer's own index of what was read (rec_index_finish) is read back the same, complete. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "core/recording.h"
#include "fuzz_common.h"

int LLVMFuzzerInitialize(int *argc, char ***argv)
{
    (void)argc, (void)argv;
    json_object_seed(1);
    return 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    rec_file f;
    if (rec_read(data, size, &f) != 0) {
        if (!f.error[0]) fuzz_fail("a refusal without a reason");
        if (f.error_offset > size) fuzz_fail("a refusal at offset %llu of a file of %zu bytes", (unsigned long long)f.error_offset, size);
        return 0;
    }
    if (!json_is_object(f.hello) || f.n_vertices < 1) fuzz_fail("a file taken without its hello");
    if (f.end > size || (f.complete && f.end != size)) fuzz_fail("records end at %llu of %zu", (unsigned long long)f.end, size);
    uint64_t last = 0;
    for (uint32_t k = 0; k < f.ix.n_frames; k++) {
        const rec_frame *e = &f.ix.frames[k];
        if (e->offset <= last || e->offset >= f.end) fuzz_fail("frame %u at %llu", k, (unsigned long long)e->offset);
        if (e->key > k || (k && e->texts_before < f.ix.frames[k - 1].texts_before) || e->texts_before > f.ix.n_texts)
            fuzz_fail("frame %u: key %u, texts_before %u", k, e->key, e->texts_before);
        last = e->offset;
    }
    if (f.ix.n_texts == 0 || f.ix.texts[0] != REC_HEADER_SIZE) fuzz_fail("no hello at offset 16");
    /* What was read, finished by the writer's code, reads back complete and the same. */
    if (!f.complete) {
        size_t len = 0;
        unsigned char *tail = rec_index_finish(&f.ix, f.end, &len);
        unsigned char *whole = tail ? malloc((size_t)f.end + len) : NULL;
        if (whole) {
            memcpy(whole, data, (size_t)f.end);
            memcpy(whole + f.end, tail, len);
            rec_file g;
            if (rec_read(whole, (size_t)f.end + len, &g) != 0) fuzz_fail("a finished file refused: %s", g.error);
            if (!g.complete || g.ix.n_frames != f.ix.n_frames || g.ix.n_texts != f.ix.n_texts)
                fuzz_fail("a finished file read as %d, %u frames, %u texts", g.complete, g.ix.n_frames, g.ix.n_texts);
            rec_file_free(&g);
        }
        free(whole);
        free(tail);
    }
    rec_file_free(&f);
    return 0;
}
