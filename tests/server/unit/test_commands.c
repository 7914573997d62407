/* test_commands.c - the command table (sim/commands.c): routes and the methods of a path, the
 * token each needs, the API's paths, the commands requests make of their bodies, the checks made
 * from the columns before a row's function runs, journaled changes by op, and answers. */
#include "sim/commands.h"
#include "sim/scenes.h"
#include "unitkit.h"

static void test_routes(void **unused)
{
    (void)unused;
    route_match m;
    command_route("GET", "/v1/rocks/12", &m);
    assert_non_null(m.def);
    assert_string_equal(m.def->op, "rock_get");
    assert_int_equal(m.id, 12);
    assert_string_equal(m.label, "/v1/rocks/{id}");
    assert_string_equal(m.scene, "default");
    command_route("DELETE", "/v1/rocks/abc", &m);
    assert_string_equal(m.def->op, "rock_remove");
    assert_int_equal(m.id, -1); /* not a number: the id check answers 404 */
    command_route("HEAD", "/v1/sim", &m);
    assert_string_equal(m.def->op, "sim");
    command_route("GET", "/metrics", &m);
    assert_string_equal(m.def->op, "metrics");
    assert_null(m.scene); /* daemon-wide */
    command_route("POST", "/v1/health", &m);
    assert_null(m.def);
    assert_true(m.path_known);
    assert_string_equal(m.allow, "GET, HEAD");
    assert_string_equal(m.label, "/v1/health");
    command_route("PUT", "/v1/rocks", &m);
    assert_null(m.def);
    assert_string_equal(m.allow, "GET, HEAD, POST, DELETE");
    command_route("GET", "/v1/nothing", &m);
    assert_null(m.def);
    assert_false(m.path_known);
    assert_string_equal(m.label, "unknown");
    command_route("GET", "/v1/rocks/1/x", &m);
    assert_null(m.def);
    command_route("GET", "/sim", &m); /* a scene's path without the prefix is none */
    assert_null(m.def);
    /* A scene named by the prefix; the daemon's routes of scenes. */
    command_route("PATCH", "/v1/scenes/b-2/rocks/7", &m);
    assert_string_equal(m.def->op, "rock_set");
    assert_int_equal(m.id, 7);
    assert_string_equal(m.scene, "b-2");
    assert_string_equal(m.label, "/v1/scenes/{scene}/rocks/{id}");
    command_route("GET", "/v1/scenes/Bad!/sim", &m); /* routed; the id is checked by who answers */
    assert_string_equal(m.def->op, "sim");
    assert_string_equal(m.scene, "Bad!");
    command_route("DELETE", "/v1/scenes/x", &m);
    assert_string_equal(m.def->op, "scene_delete");
    assert_string_equal(m.scene, "x");
    command_route("GET", "/v1/scenes", &m);
    assert_string_equal(m.def->op, "scenes");
    assert_null(m.scene);
    command_route("GET", "/v1/scenes/x", &m);
    assert_null(m.def);
    assert_string_equal(m.allow, "DELETE");
    command_route("GET", "/v1/scenes//sim", &m); /* an empty id names nothing */
    assert_null(m.def);
    command_route("GET", "/v1/scenes/x/metrics", &m); /* daemon-wide routes have no scene prefix */
    assert_null(m.def);
    assert_true(scene_id_valid("a") && scene_id_valid("0_a-b") && !scene_id_valid("-a") && !scene_id_valid("A") &&
                !scene_id_valid("") && !scene_id_valid("a.b"));
    char id[70];
    memset(id, 'a', 63), id[63] = '\0';
    assert_true(scene_id_valid(id));
    memset(id, 'a', 64), id[64] = '\0';
    assert_false(scene_id_valid(id));
}

static void test_api_paths_and_access(void **unused)
{
    (void)unused;
    assert_true(command_is_api("/v1"));
    assert_true(command_is_api("/v1/anything"));
    assert_true(command_is_api("/metrics"));
    assert_false(command_is_api("/"));
    assert_false(command_is_api("/index.html"));
    assert_false(command_is_api("/v1x"));
    assert_false(command_is_api("/metrics/x"));
    assert_int_equal(command_access("GET", "/v1/sim"), ACCESS_VIEW);
    assert_int_equal(command_access("HEAD", "/v1/snapshot"), ACCESS_VIEW);
    assert_int_equal(command_access("POST", "/v1/rocks"), ACCESS_CONTROL);
    assert_int_equal(command_access("GET", "/v1/health"), ACCESS_NONE);
    assert_int_equal(command_access("POST", "/v1/health"), ACCESS_NONE); /* a public path stays public: 405 */
    assert_int_equal(command_access("PUT", "/v1/rocks/3"), ACCESS_CONTROL);
    assert_int_equal(command_access("OPTIONS", "/v1/sim"), ACCESS_VIEW);
    assert_int_equal(command_access("DELETE", "/v1/unknown"), ACCESS_CONTROL);
    assert_int_equal(command_access("GET", "/v1/unknown"), ACCESS_VIEW);
    assert_true(command_method_changes("PATCH") && command_method_changes("BREW"));
    assert_false(command_method_changes("GET") || command_method_changes("HEAD") || command_method_changes("OPTIONS"));
}

/* What the table holds: every route's token as its method wants (reads view, changes control,
 * /v1/health and the probes none), the journaled commands by their ops, `clothd routes`. */
static void test_table(void **unused)
{
    (void)unused;
    static const char *const journaled[] = {"params", "scene", "reset", "rock_add", "rock_set", "rock_remove",
                                            "rocks_clear", "pins", "grab", "release"};
    int routes = 0, changes = 0;
    for (size_t i = 0; i < command_count(); i++) {
        const command *c = command_at(i);
        assert_ptr_equal(command_find(c->op), c);
        assert_true((c->change != NULL) + (c->control != NULL) <= 1);
        if (c->change) changes++;
        if (!c->method) continue;
        routes++;
        assert_non_null(c->request);
        const int open = strcmp(c->op, "health") == 0 || strcmp(c->op, "livez") == 0 || strcmp(c->op, "readyz") == 0;
        const access_level want = open ? ACCESS_NONE
                                  : strcmp(c->method, "GET") == 0 ? ACCESS_VIEW : ACCESS_CONTROL;
        assert_int_equal(c->access, want);
    }
    assert_int_equal(changes, 10);
    for (int k = 0; k < 10; k++) assert_non_null(command_find(journaled[k])->change);
    assert_int_equal(routes, 35); /* 29, the 4 of recordings and the 2 probes */
    char *out = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&out, &len);
    command_print_routes(f);
    fclose(f);
    int lines = 0;
    for (char *p = out; *p; p++) lines += *p == '\n';
    assert_int_equal(lines, 35 + 25); /* each of the 25 routes of a scene also under /v1/scenes/{scene} */
    assert_non_null(strstr(out, "GET /v1/health\n"));
    assert_non_null(strstr(out, "GET /livez\n"));
    assert_non_null(strstr(out, "GET /readyz\n"));
    assert_null(strstr(out, "/v1/scenes/{scene}/livez"));
    assert_non_null(strstr(out, "DELETE /v1/scenes/{scene}\n"));
    assert_non_null(strstr(out, "PATCH /v1/scenes/{scene}/rocks/{id}\n"));
    assert_null(strstr(out, "/v1/scenes/{scene}/metrics"));
    assert_non_null(strstr(out, "PATCH /v1/rocks/{id}\n"));
    assert_non_null(strstr(out, "GET /metrics\n"));
    assert_null(strstr(out, "hash"));
    assert_non_null(strstr(out, "POST /v1/scenes/{scene}/recordings\n"));
    assert_non_null(strstr(out, "GET /v1/recordings/{rid}\n"));
    assert_null(strstr(out, "GET /v1/scenes/{scene}/recordings")); /* the list is the daemon's */
    free(out);
}

static void made(const char *op, const char *body, long long id, const char *expected)
{
    json_t *cmd;
    problem pr;
    if (command_from_request(op, body, strlen(body), id, &cmd, &pr) != 0) fail_msg("%s %s: %s", op, body, pr.detail);
    char *text = uk_dump(cmd);
    uk_assert_json(text, expected);
    free(text);
    json_decref(cmd);
}

static void refused(const char *op, const char *body, int status, const char *slug, const char *param)
{
    json_t *cmd = NULL;
    problem pr;
    memset(&pr, 0, sizeof pr);
    assert_int_equal(command_from_request(op, body, strlen(body), 1, &cmd, &pr), -1);
    assert_null(cmd);
    assert_int_equal(pr.status, status);
    assert_string_equal(pr.slug, slug);
    assert_string_equal(pr.param, param ? param : "");
}

static void test_commands_from_requests(void **unused)
{
    (void)unused;
    made("params", "{\"k_bend\": 3, \"seed\": 4}", 1, "{\"op\":\"params\",\"params\":{\"k_bend\":3,\"seed\":4}}");
    made("params", "{\"k_bend\": -1}", 1, "{\"op\":\"params\",\"params\":{\"k_bend\":-1}}"); /* 422 is the sim thread's */
    made("scene", "{\"nx\": 8}", 1, "{\"op\":\"scene\",\"scene\":{\"nx\":8}}");
    made("rock_add", "{\"position\":[0,0,2],\"radius\":0.1}", 1, "{\"op\":\"rock_add\",\"rock\":{\"position\":[0,0,2],\"radius\":0.1}}");
    made("rock_set", "{\"radius\":0.2}", 7, "{\"op\":\"rock_set\",\"id\":7,\"rock\":{\"radius\":0.2}}");
    made("rock_remove", "", 9, "{\"op\":\"rock_remove\",\"id\":9}");
    made("rock_remove", " {} ", 9, "{\"op\":\"rock_remove\",\"id\":9}");
    made("pins", "{\"preset\":\"none\"}", 1, "{\"op\":\"pins\",\"preset\":\"none\"}");
    made("grab", "{\"vertex\":3,\"target\":[0,0,1]}", 1, "{\"op\":\"grab\",\"vertex\":3,\"target\":[0,0,1]}");
    made("reset", "", 1, "{\"op\":\"reset\"}");
    made("release", "{}", 1, "{\"op\":\"release\"}");
    made("rocks_clear", "\n", 1, "{\"op\":\"rocks_clear\"}");
    refused("reset", "{\"x\":1}", 400, "unknown-field", "x");
    refused("params", "{\"nope\":1}", 400, "unknown-field", "nope");
    refused("params", "{\"nx\":9}", 400, "unknown-field", "nx"); /* a scene field */
    refused("params", "{\"k_bend\":\"soft\"}", 422, "wrong-type", "k_bend"); /* a parameter's */
    refused("rock_add", "", 400, "invalid-json", NULL);
    refused("scene", "[1]", 400, "wrong-type", NULL);
    refused("pins", "{\"preset\":", 400, "invalid-json", NULL);
    refused("pause", "", 500, "internal", NULL); /* not a journaled command */
}

/* The checks made from the columns, before a row's request function: a rock id, the body. */
static void test_central_checks(void **unused)
{
    (void)unused;
    api_reply now;
    scene_cmd later;
    api_request rq = {command_find("rock_get"), NULL, "", 0, NULL, 0, 0, 0, NULL, NULL, NULL};
    assert_int_equal(command_request(&rq, &now, &later), API_NOW);
    assert_int_equal(now.status, 404);
    assert_non_null(strstr(now.body, "no rock with that id"));
    free(now.body);
    rq.id = 4294967296LL;
    assert_int_equal(command_request(&rq, &now, &later), API_NOW);
    assert_int_equal(now.status, 404);
    free(now.body);
    rq = (api_request){command_find("snapshot_put"), NULL, "", 0, NULL, -1, 0, 0, NULL, NULL, NULL};
    assert_int_equal(command_request(&rq, &now, &later), API_NOW);
    assert_int_equal(now.status, 400);
    assert_non_null(strstr(now.body, "urn:clothd:problem:bad-snapshot"));
    free(now.body);
    rq = (api_request){command_find("step"), NULL, "{\"frames\": 0}", 13, NULL, -1, 0, 0, NULL, NULL, NULL};
    assert_int_equal(command_request(&rq, &now, &later), API_NOW);
    assert_int_equal(now.status, 422);
    free(now.body);
    rq = (api_request){command_find("pause"), NULL, "{\"now\": true}", 13, NULL, -1, 0, 0, NULL, NULL, NULL};
    assert_int_equal(command_request(&rq, &now, &later), API_NOW);
    assert_int_equal(now.status, 400);
    free(now.body);
    /* Accepted: the command for the sim thread, with its row. */
    rq = (api_request){command_find("step"), NULL, "{\"frames\": 2}", 13, NULL, -1, 0, 0, NULL, NULL, NULL};
    assert_int_equal(command_request(&rq, &now, &later), API_LATER);
    assert_ptr_equal(later.def, command_find("step"));
    char *text = uk_dump(later.body);
    uk_assert_json(text, "{\"frames\":2}");
    free(text);
    json_decref(later.body);
    rq = (api_request){command_find("rock_set"), NULL, "{\"radius\": 0.3}", 15, NULL, 5, 0, 0, NULL, NULL, NULL};
    assert_int_equal(command_request(&rq, &now, &later), API_LATER);
    text = uk_dump(later.body);
    uk_assert_json(text, "{\"op\":\"rock_set\",\"id\":5,\"rock\":{\"radius\":0.3}}");
    free(text);
    json_decref(later.body);
}

static void test_answers(void **unused)
{
    (void)unused;
    scene_cmd c;
    memset(&c, 0, sizeof c);
    api_reply out;
    c.def = command_find("rock_add");
    c.result = json_pack("{s:i}", "id", 3);
    command_answer(&c, 0, &out);
    assert_int_equal(out.status, 201);
    assert_string_equal(out.ctype, "application/json");
    uk_assert_json(out.body, "{\"id\":3}");
    free(out.body);
    c.def = command_find("params");
    c.failed = 1;
    problem_set(&c.pr, 503, "busy", NULL, "queue full");
    command_answer(&c, 0, &out);
    assert_int_equal(out.status, 503);
    assert_int_equal(out.retry_after, 1);
    assert_string_equal(out.ctype, "application/problem+json");
    uk_assert_json(out.body, "{\"type\":\"urn:clothd:problem:busy\",\"title\":\"Too busy\",\"status\":503,\"detail\":\"queue full\"}");
    free(out.body);
    /* Bytes: the row's type, or octets where the client asked for them. */
    memset(&c, 0, sizeof c);
    c.def = command_find("cloth_state");
    c.blob = (unsigned char *)strdup("{}");
    c.blob_len = 2;
    command_answer(&c, 1, &out);
    assert_string_equal(out.ctype, "application/octet-stream");
    free(out.body);
    c.blob = (unsigned char *)strdup("{}");
    command_answer(&c, 0, &out);
    assert_string_equal(out.ctype, "application/json");
    free(out.body);
    c.def = command_find("snapshot_get");
    c.blob = (unsigned char *)strdup("CSNP");
    c.blob_len = 4;
    command_answer(&c, 0, &out);
    assert_string_equal(out.ctype, "application/octet-stream");
    assert_int_equal(out.len, 4);
    free(out.body);
}

/* A journaled command by its op, on an engine and the daemon-loop settings: the complete command
 * the journal keeps, replayed to the same; a refusal changes nothing. */
static void test_apply(void **unused)
{
    (void)unused;
    cs_sim *sim = uk_engine(6, 5);
    loop_settings loop = uk_defaults().scene.loop;
    json_t *cmd = json_loads("{\"op\":\"params\",\"params\":{\"k_bend\":33,\"time_scale\":2}}", 0, NULL), *journal, *result;
    problem pr;
    assert_int_equal(command_apply(sim, &loop, cmd, &journal, &result, &pr), 0);
    cs_params p;
    cs_sim_params(sim, &p);
    assert_true(p.k_bend == 33.0f && loop.time_scale == 2.0f);
    const json_t *full = json_object_get(journal, "params");
    size_t live = 0;
    for (size_t i = 0; i < settings_count(); i++) live += settings_at(i)->kind == SET_LIVE;
    assert_int_equal(json_object_size(full), live); /* every live parameter: the command is complete */
    assert_true(json_number_value(json_object_get(full, "k_shear")) == 200.0); /* the default, unchanged */
    cs_sim *again = uk_engine(6, 5);
    loop_settings loop2 = uk_defaults().scene.loop;
    json_t *j2, *r2;
    assert_int_equal(command_apply(again, &loop2, journal, &j2, &r2, &pr), 0);
    assert_memory_equal(&loop, &loop2, sizeof loop);
    assert_true(cs_state_hash(sim) == cs_state_hash(again));
    json_decref(j2), json_decref(r2), json_decref(journal), json_decref(result), json_decref(cmd);
    const uint64_t h = cs_state_hash(sim);
    cmd = json_loads("{\"op\":\"params\",\"params\":{\"integrator\":\"velocity_verlet\",\"k_structural\":1e9,\"auto_substeps\":false,\"seed\":77}}", 0, NULL);
    assert_int_equal(command_apply(sim, &loop, cmd, &journal, &result, &pr), -1);
    assert_int_equal(pr.status, 422);
    assert_string_equal(pr.slug, "unstable");
    assert_int_equal(loop.seed, 1); /* all or nothing: the daemon-loop settings too */
    cs_sim_params(sim, &p);
    assert_int_equal(p.integrator, CS_IMPLICIT_EULER); /* and the integrator */
    assert_true(cs_state_hash(sim) == h);
    json_decref(cmd);
    cmd = json_loads("{\"op\":\"dance\"}", 0, NULL);
    assert_int_equal(command_apply(sim, &loop, cmd, &journal, &result, &pr), -1);
    assert_int_equal(pr.status, 400);
    assert_string_equal(pr.detail, "unknown op 'dance'");
    json_decref(cmd);
    cmd = json_loads("{\"op\":\"pause\"}", 0, NULL); /* a control, not a journaled command */
    assert_int_equal(command_apply(sim, &loop, cmd, &journal, &result, &pr), -1);
    json_decref(cmd);
    cs_sim_destroy(sim);
    cs_sim_destroy(again);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_routes),
        cmocka_unit_test(test_api_paths_and_access),
        cmocka_unit_test(test_table),
        cmocka_unit_test(test_commands_from_requests),
        cmocka_unit_test(test_central_checks),
        cmocka_unit_test(test_answers),
        cmocka_unit_test(test_apply),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
