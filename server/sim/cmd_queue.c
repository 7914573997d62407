/* cmd_queue.c - the rows whose request makes a command for the sim thread: a control (pause,
 * resume, a step, snapshots, the cloth's state) or a journaled change (the rows' request
 * functions, commands_internal.h). */
#include <string.h>

#include "core/params_json.h"
#include "core/settings.h"
#include "sim/changes.h"
#include "sim/commands.h"
#include "sim/commands_internal.h"

/* The row's own command, as it came (a control with no body, or its body as is). */
int rq_queue(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)out;
    if (rq->object) later->body = json_incref(rq->object);
    return API_LATER;
}

int rq_step(const api_request *rq, api_reply *out, scene_cmd *later)
{
    int frames;
    long long n;
    problem pr;
    /* Refused here: it reaches no step in progress. */
    if (step_from_json(rq->object, &frames, &n, &pr) != 0) return reply_problem(out, &pr);
    return rq_queue(rq, out, later);
}

int rq_cloth_state(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)out;
    later->body = json_pack("{s:b}", "binary", rq->binary);
    return API_LATER;
}

int rq_snapshot_put(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)out;
    later->blob_in = (const unsigned char *)rq->body;
    later->blob_in_len = rq->len;
    return API_LATER;
}

/* A journaled command from the (parsed) body: its member or members, the path's id, its op. */
int make_change(const command *d, json_t *object, long long id, json_t **cmd, problem *pr)
{
    *cmd = NULL;
    if (d->change == change_params) {
        /* Refused here without bothering the sim thread, unless the refusal is a range's: the sim
         * thread merges the patch with the parameters of the moment it applies it (so an
         * out-of-range there may be none here). */
        clothd_config defaults;
        settings_default(&defaults);
        if (params_from_json(object, SET_LIVE, &defaults.scene, pr) != 0 && strcmp(pr->slug, "out-of-range") != 0)
            return -1;
    }
    json_t *c;
    if (d->member) c = json_pack("{s:O}", d->member, object);
    else if (d->body == BODY_OBJECT) c = json_copy(object);
    else c = json_object();
    if (c && (d->flags & CMD_ROCK_ID)) json_object_set_new(c, "id", json_integer((json_int_t)id));
    if (!c || json_object_set_new(c, "op", json_string(d->op)) != 0) {
        json_decref(c);
        return problem_set(pr, 500, "internal", NULL, "out of memory");
    }
    *cmd = c;
    return 0;
}

int rq_change(const api_request *rq, api_reply *out, scene_cmd *later)
{
    problem pr;
    json_t *empty = rq->object ? NULL : json_object();
    const int bad = make_change(rq->def, rq->object ? rq->object : empty, rq->id, &later->body, &pr);
    json_decref(empty);
    if (bad) return reply_problem(out, &pr);
    return API_LATER;
}
