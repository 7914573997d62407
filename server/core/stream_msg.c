/* stream_msg.c - a stream client's text message, parsed and checked (see stream_msg.h). */
#include <string.h>

#include "core/delta.h"
#include "core/json_read.h"
#include "core/json_write.h"
#include "core/stream_msg.h"

#define ENCODING_NAME(sym, name) name,
const char *const stream_encoding_names[STREAM_ENCODINGS] = {CLF_ENCODINGS(ENCODING_NAME)};
#undef ENCODING_NAME
const char *const stream_scalar_names[SCALAR_KINDS] = {"none", "speed", "strain"};

static stream_msg_kind refuse(stream_msg *m, const char *about, int has_param)
{
    m->kind = STREAM_MSG_REFUSED;
    m->about = about;
    m->has_param = has_param;
    return m->kind;
}

static int name_index(const json_t *v, const char *const *names, int n)
{
    for (int k = 0; k < n; k++)
        if (json_is_string(v) && strcmp(json_string_value(v), names[k]) == 0) return k;
    return -1;
}

static stream_msg_kind subscribe(stream_msg *m, const json_t *o)
{
    static const char *const fields[] = {"type", "scene", "encoding", "max_fps", "scalar", "quantum", "max_kbps", NULL};
    if (only_fields(o, fields, &m->pr) != 0) return refuse(m, "subscribe", 1);
    const json_t *id = json_object_get(o, "scene");
    if (id && !json_is_string(id)) {
        problem_set(&m->pr, 400, "wrong-type", "scene", "scene must be a scene id, a string (got %s)", json_type_word(id));
        return refuse(m, "subscribe", 1);
    }
    if (id && !scene_id_valid(json_string_value(id))) {
        problem_set(&m->pr, 400, "bad-scene-id", "scene",
                    "a scene id is 1 to 63 of a-z, 0-9, _ and -, starting with a letter or digit (got '%.80s')",
                    json_string_value(id));
        return refuse(m, "subscribe", 1);
    }
    if (id) snprintf(m->scene, sizeof m->scene, "%s", json_string_value(id));
    const json_t *e = json_object_get(o, "encoding"), *f = json_object_get(o, "max_fps"), *c = json_object_get(o, "scalar");
    if (e && (m->encoding = name_index(e, stream_encoding_names, STREAM_ENCODINGS)) < 0) {
        problem_set(&m->pr, 422, "out-of-range", "encoding", "encoding must be f32, q16, meshopt or delta");
        return refuse(m, "subscribe", 1);
    }
    if (f) {
        long long v;
        if (int_from_json(f, 1, 240, "max_fps", &v, &m->pr) != 0) return refuse(m, "subscribe", 1);
        m->max_fps = (int)v;
    }
    if (c && (m->scalar = name_index(c, stream_scalar_names, SCALAR_KINDS)) < 0) {
        problem_set(&m->pr, 422, "out-of-range", "scalar", "scalar must be none, speed or strain");
        return refuse(m, "subscribe", 1);
    }
    const json_t *q = json_object_get(o, "quantum");
    if (q && !json_is_number(q)) {
        problem_set(&m->pr, 400, "wrong-type", "quantum", "quantum must be a number (got %s)", json_type_word(q));
        return refuse(m, "subscribe", 1);
    }
    if (q && !delta_quantum_ok(json_number_value(q))) {
        problem_set(&m->pr, 422, "out-of-range", "quantum", "quantum must be between %g and %g m (got %g)",
                    DELTA_QUANTUM_MIN, DELTA_QUANTUM_MAX, json_number_value(q));
        return refuse(m, "subscribe", 1);
    }
    if (q) m->quantum = json_number_value(q);
    const json_t *k = json_object_get(o, "max_kbps");
    if (k && json_is_null(k)) m->max_kbps = 0; /* no limit */
    else if (k) {
        long long v;
        if (int_from_json(k, 1, STREAM_MAX_KBPS, "max_kbps", &v, &m->pr) != 0) return refuse(m, "subscribe", 1);
        m->max_kbps = v;
    }
    return m->kind = STREAM_MSG_SUBSCRIBE;
}

static stream_msg_kind grab(stream_msg *m, const json_t *o)
{
    static const char *const fields[] = {"type", "vertex", "target", NULL};
    float target[3];
    /* The vertex is checked against the cloth by the sim thread (command_apply). */
    if (only_fields(o, fields, &m->pr) != 0 || !json_object_get(o, "vertex") ||
        vec3_from_json(json_object_get(o, "target"), target, "target", &m->pr) != 0) {
        if (!json_object_get(o, "vertex")) problem_set(&m->pr, 400, "wrong-type", "vertex", "vertex is required");
        return refuse(m, "grab", 1);
    }
    m->cmd = json_pack("{s:s, s:O, s:O}", "op", "grab", "vertex", json_object_get(o, "vertex"), "target",
                       json_object_get(o, "target"));
    return m->kind = STREAM_MSG_COMMAND;
}

stream_msg_kind stream_msg_parse(const char *text, size_t len, stream_msg *m)
{
    memset(m, 0, sizeof *m);
    m->encoding = m->max_fps = m->scalar = -1;
    m->quantum = -1;
    m->max_kbps = -1;
    json_error_t err;
    m->root = json_loadb(text ? text : "", text ? len : 0, JSON_REJECT_DUPLICATES, &err);
    if (!m->root || !json_is_object(m->root)) {
        problem_set(&m->pr, 400, "invalid-json", NULL, "a message must be a JSON object%s%s", m->root ? "" : ": ",
                    m->root ? "" : err.text);
        return refuse(m, "message", 0);
    }
    const char *type = json_string_value(json_object_get(m->root, "type"));
    if (!type) {
        problem_set(&m->pr, 400, "wrong-type", "type", "a message needs a string type");
        return refuse(m, "message", 1);
    }
    if (strcmp(type, "subscribe") == 0) return subscribe(m, m->root);
    if (strcmp(type, "grab") == 0) return grab(m, m->root);
    if (strcmp(type, "keyframe") == 0) {
        static const char *const fields[] = {"type", NULL};
        if (only_fields(m->root, fields, &m->pr) != 0) return refuse(m, "keyframe", 1);
        return m->kind = STREAM_MSG_KEYFRAME;
    }
    if (strcmp(type, "release") == 0) {
        static const char *const fields[] = {"type", NULL};
        if (only_fields(m->root, fields, &m->pr) != 0) return refuse(m, "release", 1);
        m->cmd = json_pack("{s:s}", "op", "release");
        return m->kind = STREAM_MSG_COMMAND;
    }
    problem_set(&m->pr, 400, "unknown-field", "type", "unknown message type '%.64s'", type);
    return refuse(m, type, 1);
}

void stream_msg_free(stream_msg *m)
{
    json_decref(m->cmd);
    json_decref(m->root);
    m->cmd = m->root = NULL;
    m->about = NULL;
}

char *stream_msg_error(const char *about, int status, const char *param, const char *detail)
{
    json_t *o = json_pack("{s:s, s:i, s:o, s:o}", "type", "error", "status", status, "detail", json_text(detail),
                          "about", json_text(about ? about : "message"));
    if (param) json_object_set_new(o, "param", json_text(param));
    char *text = json_dumps(o, JSON_DUMP_FLAGS);
    json_decref(o);
    return text;
}
