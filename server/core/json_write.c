/* json_write.c - writing JSON for the API (see json_write.h). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "core/json_write.h"

/* The length of the well-formed UTF-8 sequence s starts with (RFC 3629: no overlong forms, no
 * surrogates, nothing past U+10FFFF), or 0 when it starts with none. Reads no byte past a NUL. */
static size_t utf8_sequence(const unsigned char *s)
{
    const unsigned c = s[0];
    if (c < 0x80) return 1;
    size_t n;
    unsigned lo = 0x80, hi = 0xBF; /* the range of the second byte */
    if (c >= 0xC2 && c <= 0xDF) {
        n = 2;
    } else if (c >= 0xE0 && c <= 0xEF) {
        n = 3;
        if (c == 0xE0) lo = 0xA0;
        if (c == 0xED) hi = 0x9F;
    } else if (c >= 0xF0 && c <= 0xF4) {
        n = 4;
        if (c == 0xF0) lo = 0x90;
        if (c == 0xF4) hi = 0x8F;
    } else {
        return 0;
    }
    if (s[1] < lo || s[1] > hi) return 0;
    for (size_t k = 2; k < n; k++)
        if (s[k] < 0x80 || s[k] > 0xBF) return 0;
    return n;
}

json_t *json_text(const char *s)
{
    json_t *j = json_string(s);
    if (j || !s) return j;
    const size_t len = strlen(s);
    char *copy = malloc(len + 1);
    if (!copy) return NULL;
    size_t out = 0;
    for (const unsigned char *p = (const unsigned char *)s; *p;) {
        const size_t n = utf8_sequence(p);
        if (n == 0) {
            p++; /* a byte of a cut character: dropped */
            continue;
        }
        memcpy(copy + out, p, n);
        out += n;
        p += n;
    }
    copy[out] = '\0';
    j = json_string(copy);
    free(copy);
    return j;
}

json_t *json_float(float f)
{
    if (!isfinite(f)) return json_null();
    char text[32];
    for (int digits = 6; digits < 9; digits++) {
        snprintf(text, sizeof text, "%.*g", digits, (double)f);
        const double d = strtod(text, NULL);
        if ((float)d == f) return json_real(d);
    }
    return json_real((double)f);
}

