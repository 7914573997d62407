/* json_read.c - reading a request's JSON (see json_read.h). */
#include <ctype.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "core/json_read.h"

const char *json_type_word(const json_t *v)
{
    switch (json_typeof(v)) {
    case JSON_OBJECT: return "an object";
    case JSON_ARRAY: return "an array";
    case JSON_STRING: return "a string";
    case JSON_INTEGER:
    case JSON_REAL: return "a number";
    case JSON_TRUE:
    case JSON_FALSE: return "a boolean";
    default: return "null";
    }
}

int vec3_from_json(const json_t *v, float out[3], const char *name, problem *pr)
{
    if (!json_is_array(v) || json_array_size(v) != 3)
        return problem_set(pr, 400, "wrong-type", name, "%s must be an array of 3 numbers", name);
    for (size_t k = 0; k < 3; k++) {
        const json_t *e = json_array_get(v, k);
        if (!json_is_number(e)) return problem_set(pr, 400, "wrong-type", name, "%s must be an array of 3 numbers", name);
        const double d = json_number_value(e);
        if (!isfinite(d) || !isfinite((float)d))
            return problem_set(pr, 422, "out-of-range", name, "%s holds a number too large for a float", name);
        out[k] = (float)d;
    }
    return 0;
}

int int_from_json(const json_t *v, double lo, double hi, const char *name, long long *out, problem *pr)
{
    if (!json_is_number(v)) return problem_set(pr, 400, "wrong-type", name, "%s must be a number, not %s", name, json_type_word(v));
    const double d = json_number_value(v);
    if (d != floor(d) || d < lo || d > hi)
        return problem_set(pr, 422, "out-of-range", name, "%s must be a whole number from %.0f to %.0f", name, lo, hi);
    *out = (long long)d;
    return 0;
}

int only_fields(const json_t *obj, const char *const *allowed, problem *pr)
{
    const char *key;
    json_t *v;
    json_object_foreach((json_t *)obj, key, v) {
        int ok = 0;
        for (const char *const *a = allowed; *a && !ok; a++) ok = strcmp(*a, key) == 0;
        if (!ok) return problem_set(pr, 400, "unknown-field", key, "unknown field '%s'", key);
    }
    return 0;
}

/* Bare NaN, Infinity and -Infinity, and numbers past a double's range (1e999), are not JSON and
 * jansson refuses them, but they are values a client meant (Python's json module writes NaN): they
 * are answered as values out of range, 422 naming their field. To find that field the body is read
 * again with each such token, where a value may stand, written as a string: MARK and the token. */
#define MARK "\xEF\xBF\xBF" /* U+FFFF, which the copy writes as \uFFFF */
#define MARKS_MOST 16         /* tokens marked at most (past them: malformed, 400) */
#define TOKEN_MOST 32         /* bytes a marked token may have */

/* Whether the token t (n bytes) is one of those values. */
static int nonfinite_token(const char *t, size_t n)
{
    if ((n == 3 && memcmp(t, "NaN", 3) == 0) || (n == 8 && memcmp(t, "Infinity", 8) == 0) ||
        (n == 9 && memcmp(t, "-Infinity", 9) == 0))
        return 1;
    if (n > TOKEN_MOST || !(isdigit((unsigned char)t[0]) || (t[0] == '-' && n > 1 && isdigit((unsigned char)t[1]))))
        return 0;
    char buf[TOKEN_MOST + 1], *end;
    memcpy(buf, t, n);
    buf[n] = 0;
    const double d = strtod(buf, &end);
    return *end == 0 && isinf(d);
}

static int token_byte(char c) { return isalnum((unsigned char)c) || c == '+' || c == '-' || c == '.'; }

/* body with those tokens marked (malloc'd, its length into *n), or NULL when it has none or more
 * than MARKS_MOST (or no memory). One pass: strings are copied as they are, and a value may stand
 * after '[', ':' or ','. */
static char *nonfinite_marked(const char *b, size_t len, size_t *n)
{
    char *out = malloc(len + MARKS_MOST * (sizeof "\"\\uFFFF\"" - 1) + 1);
    if (!out) return NULL;
    size_t o = 0;
    int in_string = 0, escaped = 0, value = 0, marks = 0;
    for (size_t i = 0; i < len;) {
        const char c = b[i];
        if (in_string) {
            in_string = escaped || c != '"';
            escaped = !escaped && c == '\\';
        } else if (c == ' ' || c == '\t' || c == '\n' || c == '\r') {
            /* (a value may still stand next) */
        } else if (value) {
            size_t t = 0;
            while (i + t < len && t <= TOKEN_MOST && token_byte(b[i + t])) t++;
            value = 0;
            if (t > 0 && nonfinite_token(b + i, t)) {
                if (++marks > MARKS_MOST) break;
                memcpy(out + o, "\"\\uFFFF", 7), o += 7;
                memcpy(out + o, b + i, t), o += t;
                out[o++] = '"';
                i += t;
                continue;
            }
            in_string = c == '"';
            value = c == '[';
        } else {
            in_string = c == '"';
            value = c == '[' || c == ':' || c == ',';
        }
        out[o++] = c;
        i++;
    }
    if (marks == 0 || marks > MARKS_MOST) {
        free(out);
        return NULL;
    }
    *n = o;
    return out;
}

/* The first marked value in v (members in order, depth first): 1 with the innermost member's
 * name holding it into *key (NULL at the top) and the token into *token. */
static int find_mark(const json_t *v, const char *name, const char **key, const char **token)
{
    if (json_is_string(v) && strncmp(json_string_value(v), MARK, 3) == 0) {
        *key = name, *token = json_string_value(v) + 3;
        return 1;
    }
    if (json_is_array(v)) {
        size_t i;
        const json_t *e;
        json_array_foreach(v, i, e) if (find_mark(e, name, key, token)) return 1;
    } else if (json_is_object(v)) {
        const char *k;
        json_t *e;
        json_object_foreach((json_t *)v, k, e) if (find_mark(e, k, key, token)) return 1;
    }
    return 0;
}

/* The problem of a body jansson refused. */
static int malformed(problem *pr, const json_error_t *err)
{
    return problem_set(pr, 400, "invalid-json", NULL, "malformed JSON at line %d, column %d: %s", err->line,
                       err->column, err->text);
}

int request_body_object(const char *body, size_t len, int required, json_t **out, problem *pr)
{
    *out = NULL;
    size_t n = len;
    while (n && isspace((unsigned char)body[n - 1])) n--;
    if (n == 0) {
        if (required) return problem_set(pr, 400, "invalid-json", NULL, "a JSON body is required");
        *out = json_object();
        return 0;
    }
    json_error_t err;
    json_t *o = json_loadb(body, len, JSON_REJECT_DUPLICATES, &err);
    int marked = 0;
    if (!o) {
        size_t mlen = 0;
        char *m = nonfinite_marked(body, len, &mlen);
        json_error_t merr;
        o = m ? json_loadb(m, mlen, JSON_REJECT_DUPLICATES, &merr) : NULL;
        free(m);
        marked = o != NULL;
    }
    if (!o) return malformed(pr, &err);
    if (!json_is_object(o)) {
        json_decref(o);
        return problem_set(pr, 400, "wrong-type", NULL, "the body must be a JSON object");
    }
    if (!required && json_object_size(o)) {
        const char *key = json_object_iter_key(json_object_iter(o));
        problem_set(pr, 400, "unknown-field", key, "this request takes no field ('%s' given)", key);
        json_decref(o);
        return -1;
    }
    const char *key = NULL, *token = NULL;
    if (marked) { /* (a token marked where a member's name stands is malformed JSON after all) */
        if (find_mark(o, NULL, &key, &token))
            problem_set(pr, 422, "out-of-range", key, "%s must be a finite number (got %s)", key ? key : "a value",
                        token);
        else
            malformed(pr, &err);
        json_decref(o);
        return -1;
    }
    *out = o;
    return 0;
}

int scene_id_valid(const char *id)
{
    const size_t n = id ? strlen(id) : 0;
    if (n == 0 || n > 63) return 0;
    for (size_t k = 0; k < n; k++) {
        const char c = id[k];
        const int ok = (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || (k > 0 && (c == '_' || c == '-'));
        if (!ok) return 0;
    }
    return 1;
}
