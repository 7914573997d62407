/* cmd_recordings.c - the daemon's recordings: POST /v1/recordings, GET /v1/recordings,
 * GET and DELETE /v1/recordings/{rid} (the rows' request functions, commands_internal.h). */
#include <stdio.h>
#include <stdlib.h>

#include "sim/commands.h"
#include "sim/commands_internal.h"
#include "sim/recordings.h"

/* The answer of a "wake" nobody waits for: it is freed. */
static void free_wake(scene_cmd *cmd, void *arg)
{
    (void)arg;
    json_decref(cmd->result);
    free(cmd->blob);
    free(cmd);
}

static int no_recordings(api_reply *out)
{
    problem pr;
    problem_set(&pr, 503, "unavailable", NULL, "this clothd keeps no recordings");
    return reply_problem(out, &pr);
}

int rq_recording_start(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    recordings *r = rq->daemon->recordings;
    if (!r) return no_recordings(out);
    problem pr;
    json_t *answer;
    char rid[SCENE_ID_MAX];
    if (recordings_start(r, rq->sc, rq->object, &answer, rid, &pr) != 0) return reply_problem(out, &pr);
    /* A paused scene publishes only after a command: this one has it hand the recording its
     * first pose now (a running one does with its next frame). */
    scene_cmd *wake = calloc(1, sizeof *wake);
    if (wake) {
        wake->def = command_find("wake");
        wake->done = free_wake;
        scene_submit(rq->sc, wake);
    }
    snprintf(out->location, sizeof out->location, "/v1/recordings/%s", rid);
    return reply_json(out, 201, answer);
}

int rq_recordings(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    recordings *r = rq->daemon->recordings;
    if (!r) return no_recordings(out);
    return reply_json(out, 200, recordings_list(r));
}

int rq_recording_get(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    recordings *r = rq->daemon->recordings;
    if (!r) return no_recordings(out);
    problem pr;
    unsigned char *bytes;
    size_t len;
    void *copy;
    if (recordings_bytes(r, rq->rid, &bytes, &len, &copy, &pr) != 0) {
        reply_problem(out, &pr);
        if (pr.status == 503) out->retry_after = 1;
        return API_NOW;
    }
    snprintf(out->disposition, sizeof out->disposition, "attachment; filename=\"%s.clr\"", rq->rid);
    out->release = recordings_release;
    out->release_cls = copy;
    return reply_text(out, 200, RECORDING_TYPE, (char *)bytes, len);
}

int rq_recording_delete(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    recordings *r = rq->daemon->recordings;
    if (!r) return no_recordings(out);
    problem pr;
    if (recordings_delete(r, rq->rid, &pr) != 0) return reply_problem(out, &pr);
    return reply_json(out, 200, json_pack("{s:s, s:b}", "id", rq->rid, "deleted", 1));
}
