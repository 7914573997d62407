/* test_stream_msg.c - a stream client's text messages (core/stream_msg.c), as PROTOCOL.md gives
 * them: subscribe, grab, release, and what is refused with which status and param. */
#include "core/stream_msg.h"
#include "unitkit.h"

static stream_msg_kind parse(const char *text, stream_msg *m) { return stream_msg_parse(text, strlen(text), m); }

static void test_subscribe(void **unused)
{
    (void)unused;
    stream_msg m;
    assert_int_equal(parse("{\"type\":\"subscribe\",\"encoding\":\"meshopt\",\"max_fps\":30,\"scalar\":\"strain\"}", &m),
                     STREAM_MSG_SUBSCRIBE);
    assert_int_equal(m.encoding, 2);
    assert_int_equal(m.max_fps, 30);
    assert_int_equal(m.scalar, SCALAR_STRAIN);
    stream_msg_free(&m);
    /* What is not given stays as it is: -1. */
    assert_int_equal(parse("{\"type\":\"subscribe\",\"encoding\":\"q16\"}", &m), STREAM_MSG_SUBSCRIBE);
    assert_int_equal(m.encoding, 1);
    assert_int_equal(m.max_fps, -1);
    assert_int_equal(m.scalar, -1);
    assert_true(m.quantum == -1);
    stream_msg_free(&m);
    /* delta, with its grid; and a keyframe ask. */
    assert_int_equal(parse("{\"type\":\"subscribe\",\"encoding\":\"delta\",\"quantum\":0.0005}", &m), STREAM_MSG_SUBSCRIBE);
    assert_int_equal(m.encoding, 3);
    assert_true(m.quantum == 0.0005);
    stream_msg_free(&m);
    assert_int_equal(parse("{\"type\":\"subscribe\",\"quantum\":1e-6}", &m), STREAM_MSG_SUBSCRIBE);
    assert_true(m.quantum == 1e-6 && m.encoding == -1);
    stream_msg_free(&m);
    assert_int_equal(parse("{\"type\":\"subscribe\",\"max_kbps\":800}", &m), STREAM_MSG_SUBSCRIBE);
    assert_true(m.max_kbps == 800 && m.quantum == -1);
    stream_msg_free(&m);
    assert_int_equal(parse("{\"type\":\"subscribe\",\"max_kbps\":null}", &m), STREAM_MSG_SUBSCRIBE);
    assert_true(m.max_kbps == 0);
    stream_msg_free(&m);
    assert_int_equal(parse("{\"type\":\"keyframe\"}", &m), STREAM_MSG_KEYFRAME);
    stream_msg_free(&m);
    /* A scene to switch to: the id as given (63 characters at most); none given is "". */
    assert_int_equal(parse("{\"type\":\"subscribe\",\"scene\":\"lab-2_b\"}", &m), STREAM_MSG_SUBSCRIBE);
    assert_string_equal(m.scene, "lab-2_b");
    assert_int_equal(m.encoding, -1);
    stream_msg_free(&m);
    assert_int_equal(parse("{\"type\":\"subscribe\",\"scene\":\"0123456789012345678901234567890123456789012345678901234567890ab\"}", &m),
                     STREAM_MSG_SUBSCRIBE);
    assert_int_equal(strlen(m.scene), 63);
    stream_msg_free(&m);
    assert_int_equal(parse("{\"type\":\"subscribe\",\"encoding\":\"q16\"}", &m), STREAM_MSG_SUBSCRIBE);
    assert_string_equal(m.scene, "");
    stream_msg_free(&m);
}

static void expect_refused(const char *text, int status, const char *about, const char *param)
{
    stream_msg m;
    assert_int_equal(parse(text, &m), STREAM_MSG_REFUSED);
    assert_int_equal(m.pr.status, status);
    assert_string_equal(m.about, about);
    if (param) {
        assert_true(m.has_param);
        assert_string_equal(m.pr.param, param);
    } else {
        assert_false(m.has_param);
    }
    stream_msg_free(&m);
}

static void test_refusals(void **unused)
{
    (void)unused;
    /* text, status, about, param (NULL: none) */
    static const struct { const char *text; int status; const char *about, *param; } cases[] = {
        {"{\"type\":\"subscribe\",\"quantum\":0.0101}", 422, "subscribe", "quantum"},
        {"{\"type\":\"subscribe\",\"quantum\":9e-7}", 422, "subscribe", "quantum"},
        {"{\"type\":\"subscribe\",\"quantum\":0}", 422, "subscribe", "quantum"},
        {"{\"type\":\"subscribe\",\"quantum\":\"1e-4\"}", 400, "subscribe", "quantum"},
        {"{\"type\":\"subscribe\",\"quantum\":NaN}", 400, "message", NULL},
        {"{\"type\":\"subscribe\",\"quantum\":1e999}", 400, "message", NULL},
        {"{\"type\":\"keyframe\",\"now\":1}", 400, "keyframe", "now"},
        {"{\"type\":\"subscribe\",\"max_kbps\":0}", 422, "subscribe", "max_kbps"},
        {"{\"type\":\"subscribe\",\"max_kbps\":10000001}", 422, "subscribe", "max_kbps"},
        {"{\"type\":\"subscribe\",\"max_kbps\":\"x\"}", 400, "subscribe", "max_kbps"},
        {"not json", 400, "message", NULL},
        {"{\"type\":\"subscribe\",\"scene\":\"Lab\"}", 400, "subscribe", "scene"},
        {"{\"type\":\"subscribe\",\"scene\":\"\"}", 400, "subscribe", "scene"},
        {"{\"type\":\"subscribe\",\"scene\":\"a\\u0000b\"}", 400, "message", NULL}, /* jansson refuses NUL */
        {"{\"type\":\"subscribe\",\"scene\":\"0123456789012345678901234567890123456789012345678901234567890abc\"}", 400, "subscribe", "scene"},
        {"{\"type\":\"subscribe\",\"scene\":7}", 400, "subscribe", "scene"},
        {"{\"type\":\"subscribe\",\"scene\":null}", 400, "subscribe", "scene"},
        {"[1, 2]", 400, "message", NULL},
        {"{\"type\": 3}", 400, "message", "type"},
        {"{\"type\": \"dance\"}", 400, "dance", "type"},
        {"{\"type\":\"subscribe\",\"encoding\":\"png\"}", 422, "subscribe", "encoding"},
        {"{\"type\":\"subscribe\",\"max_fps\":0}", 422, "subscribe", "max_fps"},
        {"{\"type\":\"subscribe\",\"max_fps\":241}", 422, "subscribe", "max_fps"},
        {"{\"type\":\"subscribe\",\"max_fps\":\"fast\"}", 400, "subscribe", "max_fps"},
        {"{\"type\":\"subscribe\",\"scalar\":\"heat\"}", 422, "subscribe", "scalar"},
        {"{\"type\":\"subscribe\",\"colour\":1}", 400, "subscribe", "colour"},
        {"{\"type\":\"grab\",\"target\":[0,0,1]}", 400, "grab", "vertex"},
        {"{\"type\":\"grab\",\"vertex\":3,\"target\":[0,0]}", 400, "grab", "target"},
        {"{\"type\":\"release\",\"vertex\":3}", 400, "release", "vertex"},
        {"{\"type\":\"subscribe\",\"type\":\"grab\"}", 400, "message", NULL}, /* a key twice */
    };
    for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k++)
        expect_refused(cases[k].text, cases[k].status, cases[k].about, cases[k].param);
}

/* grab and release become the commands the HTTP API makes of PUT and DELETE /v1/grab. */
static void test_commands(void **unused)
{
    (void)unused;
    stream_msg m;
    assert_int_equal(parse("{\"type\":\"grab\",\"vertex\":12,\"target\":[0.5,0,1.25]}", &m), STREAM_MSG_COMMAND);
    char *text = uk_dump(m.cmd);
    uk_assert_json(text, "{\"op\":\"grab\",\"vertex\":12,\"target\":[0.5,0,1.25]}");
    free(text);
    stream_msg_free(&m);
    assert_int_equal(parse("{\"type\":\"release\"}", &m), STREAM_MSG_COMMAND);
    text = uk_dump(m.cmd);
    uk_assert_json(text, "{\"op\":\"release\"}");
    free(text);
    stream_msg_free(&m);
}

static void test_error_text(void **unused)
{
    (void)unused;
    char *e = stream_msg_error("grab", 403, NULL, "needs the control token");
    uk_assert_json(e, "{\"type\":\"error\",\"status\":403,\"detail\":\"needs the control token\",\"about\":\"grab\"}");
    free(e);
    /* Bytes that are not UTF-8 (a cut client text) are dropped, not the message. */
    e = stream_msg_error("dance\xc3", 400, "type", "unknown message type 'dance\xc3'");
    uk_assert_json(e, "{\"type\":\"error\",\"status\":400,\"detail\":\"unknown message type 'dance'\",\"about\":\"dance\",\"param\":\"type\"}");
    free(e);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_subscribe),
        cmocka_unit_test(test_refusals),
        cmocka_unit_test(test_commands),
        cmocka_unit_test(test_error_text),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
