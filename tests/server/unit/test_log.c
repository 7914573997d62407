/* test_log.c - the log's lines (core/log.c), read back from stderr through a pipe: text with the
 * level; JSON of one object per line, made by jansson whatever the message holds (quotes, a line
 * feed, bytes that are not UTF-8); the access line's members; levels dropped below --log-level,
 * except the notice. */
#include <fcntl.h>
#include <unistd.h>

#include "core/log.h"
#include "unitkit.h"

/* Runs fn with stderr on a pipe; returns what it wrote (malloc'd). */
static char *captured(void (*fn)(void))
{
    int p[2];
    assert_int_equal(pipe(p), 0);
    fflush(stderr);
    const int saved = dup(STDERR_FILENO);
    assert_true(saved >= 0);
    assert_true(dup2(p[1], STDERR_FILENO) >= 0);
    close(p[1]);
    fn();
    assert_true(dup2(saved, STDERR_FILENO) >= 0);
    close(saved);
    char *out = calloc(1, 65536);
    assert_non_null(out);
    size_t len = 0;
    for (ssize_t n; (n = read(p[0], out + len, 65535 - len)) > 0;) len += (size_t)n;
    close(p[0]);
    return out;
}

static void write_text(void)
{
    log_setup(LOG_FORMAT_TEXT, LOG_INFO);
    log_msg("plain %d", 1);
    log_at(LOG_WARN, "default", "rid-1", "careful");
    log_at(LOG_DEBUG, NULL, NULL, "not written");
    log_access("GET", "/v1/sim", 200, 0.0015, "rid-2", "default");
}

static void test_text(void **unused)
{
    (void)unused;
    char *out = captured(write_text);
    char *l1 = strtok(out, "\n"), *l2 = strtok(NULL, "\n"), *l3 = strtok(NULL, "\n");
    assert_non_null(l3);
    assert_null(strtok(NULL, "\n"));
    assert_int_equal(strlen(l1), strlen("2026-12-05T16:40:00.123Z clothd: plain 1"));
    assert_string_equal(l1 + 24, " clothd: plain 1");
    assert_true(l1[4] == '-' && l1[10] == 'T' && l1[23] == 'Z');
    assert_string_equal(l2 + 24, " clothd warn: careful scene=default id=rid-1");
    assert_string_equal(l3 + 24, " clothd: http GET /v1/sim 200 1.500 ms scene=default id=rid-2");
    free(out);
}

static void write_json(void)
{
    log_setup(LOG_FORMAT_JSON, LOG_DEBUG);
    log_msg("a \"quoted\"\nline \xff\xfe end");
    log_at(LOG_ERROR, NULL, "r\"1", "bad");
    log_access("PUT", "/v1/scenes/{scene}/pins", 422, 0.25, "rid-3", "s1");
    log_setup(LOG_FORMAT_JSON, LOG_ERROR);
    log_msg("dropped");
    log_access("GET", "/v1/sim", 200, 0, NULL, NULL);
    log_notice("listening on http://127.0.0.1:%d", 8080);
    log_setup(LOG_FORMAT_TEXT, LOG_INFO);
}

static json_t *line_json(char *line)
{
    json_error_t e;
    json_t *o = json_loads(line, 0, &e);
    if (!o) fail_msg("not JSON (%s): %s", e.text, line);
    const char *t = json_string_value(json_object_get(o, "time"));
    assert_non_null(t);
    assert_int_equal(strlen(t), 24);
    assert_true(t[10] == 'T' && t[23] == 'Z');
    return o;
}

static void test_json(void **unused)
{
    (void)unused;
    char *out = captured(write_json);
    char *lines[5] = {0};
    int n = 0;
    for (char *l = strtok(out, "\n"); l && n < 5; l = strtok(NULL, "\n")) lines[n++] = l;
    assert_int_equal(n, 4); /* "dropped" and the access line below error are not written */
    json_t *a = line_json(lines[0]);
    assert_string_equal(json_string_value(json_object_get(a, "level")), "info");
    assert_string_equal(json_string_value(json_object_get(a, "msg")), "a \"quoted\"\nline \\xff\\xfe end");
    assert_null(json_object_get(a, "scene"));
    json_t *b = line_json(lines[1]);
    assert_string_equal(json_string_value(json_object_get(b, "level")), "error");
    assert_string_equal(json_string_value(json_object_get(b, "request_id")), "r\"1");
    json_t *c = line_json(lines[2]);
    assert_string_equal(json_string_value(json_object_get(c, "method")), "PUT");
    assert_string_equal(json_string_value(json_object_get(c, "route")), "/v1/scenes/{scene}/pins");
    assert_int_equal(json_integer_value(json_object_get(c, "status")), 422);
    assert_true(json_real_value(json_object_get(c, "duration_ms")) == 250.0);
    assert_string_equal(json_string_value(json_object_get(c, "scene")), "s1");
    assert_string_equal(json_string_value(json_object_get(c, "request_id")), "rid-3");
    json_t *d = line_json(lines[3]);
    assert_string_equal(json_string_value(json_object_get(d, "msg")), "listening on http://127.0.0.1:8080");
    json_decref(a);
    json_decref(b);
    json_decref(c);
    json_decref(d);
    free(out);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_text),
        cmocka_unit_test(test_json),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
