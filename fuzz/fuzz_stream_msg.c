/* fuzz_stream_msg.c - a stream client's text message (stream_msg_parse), the answer stream.c
 * sends back (stream_msg_error for a refusal), and a grab or release as the sim thread applies
 * it (command_apply on a small simulation).
 *
 * Besides what ASan and UBSan catch, it checks what stream_msg.h promises: a refusal says what
 * about, with a status and an error message that can be sent (valid JSON); a subscribe holds
 * only known encodings, scalars, rates, quanta, budgets and scene ids; a command is a grab or a release. */
#include <stdint.h>

#include <jansson.h>

#include "core/delta.h"
#include "core/json_read.h"
#include "core/stream_msg.h"
#include "fuzz_common.h"
#include "sim/commands.h"

static cs_sim *sim;
static unsigned char *pristine; /* the state of a fresh fuzz_sim() */
static size_t pristine_len;

int LLVMFuzzerInitialize(int *argc, char ***argv)
{
    (void)argc, (void)argv;
    json_object_seed(1); /* the same hash order on every run */
    sim = fuzz_sim();
    pristine = fuzz_state(sim, &pristine_len);
    return 0;
}

/* The error message stream.c's client_error sends: it must be JSON the client can read. */
static void check_error(const char *about, int status, const char *param, const char *detail)
{
    if (!about) fuzz_fail("a refusal about nothing");
    if (status < 400 || status > 599) fuzz_fail("a refusal with status %d", status);
    char *text = stream_msg_error(about, status, param, detail);
    if (!text) fuzz_fail("no error message for about '%s', param '%s', detail '%s'", about, param ? param : "", detail);
    json_t *back = json_loads(text, 0, NULL);
    if (!json_is_object(back)) fuzz_fail("the error message is not a JSON object: %s", text);
    json_decref(back);
    free(text);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    stream_msg m;
    switch (stream_msg_parse((const char *)data, size, &m)) {
    case STREAM_MSG_REFUSED:
        if (!m.pr.slug) fuzz_fail("a refusal without a problem");
        check_error(m.about, m.pr.status, m.has_param ? m.pr.param : NULL, m.pr.detail);
        break;
    case STREAM_MSG_SUBSCRIBE:
        if (m.encoding < -1 || m.encoding >= STREAM_ENCODINGS || m.scalar < -1 || m.scalar >= SCALAR_KINDS ||
            m.max_fps == 0 || m.max_fps < -1 || m.max_fps > 240)
            fuzz_fail("subscribe to encoding %d, scalar %d, max_fps %d", m.encoding, m.scalar, m.max_fps);
        if (m.quantum != -1 && !delta_quantum_ok(m.quantum)) fuzz_fail("subscribe with quantum %g", m.quantum);
        if (m.max_kbps < -1 || m.max_kbps > STREAM_MAX_KBPS) fuzz_fail("subscribe with max_kbps %lld", m.max_kbps);
        if (m.scene[0] && !scene_id_valid(m.scene)) fuzz_fail("subscribe to scene '%s'", m.scene);
        break;
    case STREAM_MSG_KEYFRAME: break;
    case STREAM_MSG_COMMAND: {
        const char *op = json_string_value(json_object_get(m.cmd, "op"));
        if (!op || (strcmp(op, "grab") != 0 && strcmp(op, "release") != 0)) fuzz_fail("a command with op %s", op ? op : "(none)");
        /* What the sim thread does with it (simloop.c's CMD_APPLY), and the error sent back. */
        fuzz_reset(sim, pristine, pristine_len);
        json_t *journal = NULL, *result = NULL;
        problem pr;
        memset(&pr, 0, sizeof pr);
        loop_settings loop;
        memset(&loop, 0, sizeof loop); /* grab and release leave them be */
        if (command_apply(sim, &loop, m.cmd, &journal, &result, &pr) != 0)
            check_error(op, pr.status, pr.param[0] ? pr.param : NULL, pr.detail);
        else if (!journal)
            fuzz_fail("an accepted %s has no journal entry", op);
        json_decref(journal);
        json_decref(result);
        break;
    }
    default: fuzz_fail("stream_msg_parse returned %d", (int)m.kind);
    }
    stream_msg_free(&m);
    return 0;
}
