/* cmd_reads.c - a scene's reads: GET /v1/sim, /params, /params/schema, /scene, /rocks, /rocks/{id},
 * /journal, answered from what the scene published (the rows' request functions,
 * commands_internal.h). */
#include <stdlib.h>

#include "core/params_json.h"
#include "core/rock_json.h"
#include "sim/commands.h"
#include "sim/commands_internal.h"

/* A published text of the request's scene. */
static int reply_doc(const api_request *rq, scene_doc doc, api_reply *out)
{
    size_t len = 0;
    char *j = scene_doc_copy(rq->sc, doc, &len);
    return reply_text(out, 200, JSON_TYPE, j, len);
}

int rq_sim(const api_request *rq, api_reply *out, scene_cmd *later)
{
    if (rq->hash) {
        later->def = command_find("hash");
        return API_LATER;
    }
    return reply_doc(rq, DOC_SIM, out);
}

int rq_params(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    return reply_doc(rq, DOC_PARAMS, out);
}

int rq_fields(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    return reply_doc(rq, DOC_FIELDS, out);
}

int rq_schema(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)rq, (void)later;
    return reply_json(out, 200, schema_to_json());
}

int rq_rocks(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    cs_rock *rocks;
    const int n = scene_rocks(rq->sc, &rocks);
    json_t *list = rocks_to_json(rocks, n);
    free(rocks);
    return reply_json(out, 200, json_pack("{s:o}", "rocks", list));
}

int rq_rock(const api_request *rq, api_reply *out, scene_cmd *later)
{
    (void)later;
    cs_rock *rocks;
    const int n = scene_rocks(rq->sc, &rocks);
    json_t *found = NULL;
    for (int k = 0; k < n && !found; k++)
        if (rocks[k].id == (uint32_t)rq->id) found = rock_to_json(&rocks[k]);
    free(rocks);
    if (found) return reply_json(out, 200, found);
    problem pr;
    problem_set(&pr, 404, "not-found", "id", "no rock with id %lld", rq->id);
    return reply_problem(out, &pr);
}

int rq_journal(const api_request *rq, api_reply *out, scene_cmd *later)
{
    if (rq->binary) {
        later->def = command_find("bundle");
        return API_LATER;
    }
    size_t len = 0;
    char *j = journal_json(rq->sc->journal, &len);
    return reply_text(out, 200, JSON_TYPE, j, len);
}
