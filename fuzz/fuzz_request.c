/* fuzz_request.c - request bodies of the HTTP API, through the daemon's own code: the body to a
 * command (command_from_request, what http.c does for PATCH /v1/params, PUT /v1/scene,
 * POST /v1/rocks, PATCH and DELETE /v1/rocks/{id}, PUT /v1/pins, PUT and DELETE /v1/grab,
 * POST /v1/sim/reset, DELETE /v1/rocks), the command applied to a small simulation
 * (command_apply, what the sim thread does), POST /v1/sim/step's body (step_from_json), and a
 * journal entry's command as `clothd replay` applies it.
 *
 * Input: one byte that picks the request (see KEYS), then the body.
 *
 * Besides what ASan and UBSan catch, it checks what commands.h promises: a refusal is a problem
 * with a body and leaves the simulation unchanged; an accepted command's journal entry, written
 * as the journal writes it and read back, does exactly the same to a fresh simulation, then and
 * after a substep. */
#include <stdint.h>

#include <jansson.h>

#include "core/json_read.h"
#include "core/json_write.h"
#include "fuzz_common.h"
#include "sim/commands.h"

/* The first byte: one of these characters (a readable corpus), or any other byte modulo their
 * number. */
static const char KEYS[] = "psrudczngltj";
static const char *const OPS[] = {"params", "scene", "rock_add", "rock_set", "rock_remove", "rocks_clear",
                                  "reset", "pins", "grab", "release"};
#define N_OPS (sizeof OPS / sizeof OPS[0])
#define STEP N_OPS      /* 't': POST /v1/sim/step */
#define JOURNAL (N_OPS + 1) /* 'j': a journal entry's command (clothd replay) */

static cs_sim *sim_a, *sim_b;   /* the request's, and the replay's */
static unsigned char *pristine; /* the state of a fresh fuzz_sim() */
static loop_settings fuzz_loop; /* the daemon-loop settings' defaults */
static size_t pristine_len;

int LLVMFuzzerInitialize(int *argc, char ***argv)
{
    (void)argc, (void)argv;
    json_object_seed(1); /* the same hash order on every run */
    sim_a = fuzz_sim();
    sim_b = fuzz_sim();
    pristine = fuzz_state(sim_a, &pristine_len);
    clothd_config defaults;
    settings_default(&defaults);
    fuzz_loop = defaults.scene.loop;
    return 0;
}

/* A refusal must be an answer the API can send. */
static void check_problem(const problem *pr, const char *what)
{
    if (pr->status < 400 || pr->status > 599 || !pr->slug)
        fuzz_fail("%s: refused with status %d, slug %s", what, pr->status, pr->slug ? pr->slug : "(none)");
    char *body = problem_body(pr);
    if (!body) fuzz_fail("%s: no problem body for '%s' (param '%s')", what, pr->detail, pr->param);
    json_t *back = json_loads(body, 0, NULL);
    if (!json_is_object(back)) fuzz_fail("%s: the problem body is not a JSON object: %s", what, body);
    json_decref(back);
    free(body);
}

static void apply(const json_t *cmd, const char *what)
{
    cs_sim *a = sim_a, *b = sim_b;
    fuzz_reset(a, pristine, pristine_len);
    json_t *journal = NULL, *result = NULL;
    problem pr;
    memset(&pr, 0, sizeof pr);
    loop_settings loop_a = fuzz_loop, loop_b = fuzz_loop;
    if (command_apply(a, &loop_a, cmd, &journal, &result, &pr) != 0) {
        check_problem(&pr, what);
        if (journal || result) fuzz_fail("%s: a refusal returned a journal entry or a result", what);
        if (!fuzz_state_is(a, pristine, pristine_len)) fuzz_fail("%s: a refused command changed the simulation", what);
        return;
    }
    if (!journal) fuzz_fail("%s: an accepted command has no journal entry", what);
    if (result) {
        char *text = json_dumps(result, JSON_DUMP_FLAGS);
        if (!text) fuzz_fail("%s: the result cannot be written as JSON", what);
        free(text);
    }
    /* The journal keeps entries as text (journal_append) and replay reads them back. */
    char *text = json_dumps(journal, JSON_DUMP_FLAGS);
    if (!text) fuzz_fail("%s: the journal entry cannot be written as JSON", what);
    json_error_t err;
    json_t *again = json_loads(text, JSON_REJECT_DUPLICATES, &err);
    if (!again) fuzz_fail("%s: the journal entry does not read back: %s", what, err.text);
    fuzz_reset(b, pristine, pristine_len);
    json_t *j2 = NULL, *r2 = NULL;
    if (command_apply(b, &loop_b, again, &j2, &r2, &pr) != 0)
        fuzz_fail("%s: the journal entry %s is refused on replay: %s", what, text, pr.detail);
    if (!fuzz_same_state(a, b) || memcmp(&loop_a, &loop_b, sizeof loop_a) != 0)
        fuzz_fail("%s: replaying the journal entry %s gives another state", what, text);
    /* One substep of whatever the command set up: the same on both. */
    const cs_status sa = cs_sim_step(a, 1), sb = cs_sim_step(b, 1);
    if (sa != sb) fuzz_fail("%s: a substep after %s: %s, after its replay: %s", what, text, cs_status_name(sa), cs_status_name(sb));
    if (sa == CS_OK && !fuzz_same_state(a, b)) fuzz_fail("%s: a substep after %s and after its replay differ", what, text);
    free(text);
    json_decref(again);
    json_decref(j2);
    json_decref(r2);
    json_decref(journal);
    json_decref(result);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1) return 0;
    const char *key = data[0] ? strchr(KEYS, data[0]) : NULL;
    const size_t pick = key ? (size_t)(key - KEYS) : data[0] % (sizeof KEYS - 1);
    const char *body = (const char *)data + 1;
    const size_t len = size - 1;
    problem pr;
    memset(&pr, 0, sizeof pr);
    if (pick < N_OPS) {
        json_t *cmd;
        if (command_from_request(OPS[pick], body, len, 1, &cmd, &pr) != 0) {
            check_problem(&pr, OPS[pick]);
            return 0;
        }
        apply(cmd, OPS[pick]);
        json_decref(cmd);
    } else if (pick == STEP) {
        json_t *b;
        if (request_body_object(body, len, 1, &b, &pr) != 0) {
            check_problem(&pr, "step");
            return 0;
        }
        int frames = -1;
        long long n = 0;
        if (step_from_json(b, &frames, &n, &pr) != 0) check_problem(&pr, "step");
        else if ((frames != 0 && frames != 1) || n < 1 || n > 100000) fuzz_fail("step: %d, %lld accepted", frames, n);
        json_decref(b);
    } else {
        json_error_t err;
        json_t *cmd = json_loadb(body, len, JSON_REJECT_DUPLICATES, &err);
        if (cmd) apply(cmd, "journal");
        json_decref(cmd);
    }
    return 0;
}
