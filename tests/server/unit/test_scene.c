/* test_scene.c - a scene (sim/scene.c) run by hand, as the sim thread runs it: commands through
 * the command table's central checks, what they journal and tell the scene's sink, what the scene
 * publishes; its queue's refusals; handles from the scene table; what a scene costs. */
#include "sim/commands.h"
#include "sim/scenes.h"
#include "unitkit.h"

/* A sink that keeps the events it was told and counts the poses. */
typedef struct recorder {
    json_t *events;
    int poses;
    pose spare;
} recorder;

static pose *rec_begin(void *ctx, unsigned *scalars)
{
    *scalars = 0;
    return &((recorder *)ctx)->spare;
}
static void rec_publish(void *ctx, pose *p)
{
    (void)p;
    ((recorder *)ctx)->poses++;
}
static void rec_discard(void *ctx, pose *p) { (void)ctx, (void)p; }
static void rec_event(void *ctx, const char *json) { json_array_append_new(((recorder *)ctx)->events, json_loads(json, 0, NULL)); }
static uint64_t rec_bytes(int32_t n, int32_t rocks) { return 1000 * (uint64_t)n + (uint64_t)rocks; }
static const frame_sink_ops rec_ops = {
    .begin = rec_begin, .publish = rec_publish, .discard = rec_discard, .event = rec_event, .bytes = rec_bytes};

static recorder rec;
static int answered;

static void done(scene_cmd *c, void *arg)
{
    (void)c, (void)arg;
    answered++;
}

static scene *make(int paused)
{
    clothd_config cfg = uk_defaults();
    cfg.scene.loop.auto_drop_interval = 0;
    scene *sc = scene_new(SCENE_DEFAULT, uk_engine(6, 5), &cfg.scene.loop, paused, &cfg.set);
    assert_non_null(sc);
    json_decref(rec.events);
    pose_free(&rec.spare);
    memset(&rec, 0, sizeof rec);
    rec.events = json_array();
    scene_set_sink(sc, (frame_sink){&rec_ops, &rec});
    return sc;
}

/* Runs a command as the sim thread does: the central checks, then publish and answer. */
static int run(scene *sc, const char *op, const char *body, scene_cmd *c)
{
    memset(c, 0, sizeof *c);
    c->def = command_find(op);
    c->body = body ? json_loads(body, 0, NULL) : NULL;
    c->done = done;
    const int kept = command_run(sc, c);
    if (!kept) {
        scene_publish(sc, command_wants_hash(c) || sc->paused);
        command_finish(sc, c);
    }
    return kept;
}

static void clear(scene_cmd *c)
{
    json_decref(c->body);
    json_decref(c->result);
    free(c->blob);
}

static const char *last_event_name(void)
{
    const json_t *e = json_array_get(rec.events, json_array_size(rec.events) - 1);
    return json_string_value(json_object_get(e, "event"));
}

static void test_published_and_changes(void **unused)
{
    (void)unused;
    scene *sc = make(1);
    size_t len;
    char *sim = scene_doc_copy(sc, DOC_SIM, &len);
    json_t *o = json_loads(sim, 0, NULL);
    assert_string_equal(json_string_value(json_object_get(o, "state")), "paused");
    assert_int_equal(json_integer_value(json_object_get(o, "n_vertices")), 30);
    assert_true(json_is_string(json_object_get(o, "state_hash"))); /* paused: with the hash */
    json_decref(o);
    free(sim);
    scene_cmd c;
    answered = 0;
    assert_int_equal(run(sc, "rock_add", "{\"op\":\"rock_add\",\"rock\":{\"position\":[0,0,2],\"radius\":0.1,\"density\":500}}", &c), 0);
    assert_false(c.failed);
    assert_int_equal(answered, 1);
    assert_int_equal(json_integer_value(json_object_get(c.result, "id")), 1);
    assert_int_equal(json_integer_value(json_object_get(c.result, "applied_step")), 0);
    assert_string_equal(last_event_name(), "rock_add");
    clear(&c);
    cs_rock *rocks;
    assert_int_equal(scene_rocks(sc, &rocks), 1); /* published with the command */
    free(rocks);
    char *j = journal_json(sc->journal, &len);
    uk_assert_json(j, "{\"base_step\":0,\"entries\":[{\"step\":0,\"command\":{\"op\":\"rock_add\",\"rock\":{\"kinematic\":false,"
                      "\"position\":[0.0,0.0,2.0],\"velocity\":[0.0,0.0,0.0],\"angular_velocity\":[0.0,0.0,0.0],"
                      "\"orientation\":[0.0,0.0,0.0,1.0],\"radius\":0.1,\"density\":500.0}}}]}");
    free(j);
    /* The daemon-loop settings through PATCH /v1/params, published with the engine's. */
    assert_int_equal(run(sc, "params", "{\"op\":\"params\",\"params\":{\"seed\":42,\"k_bend\":7}}", &c), 0);
    assert_false(c.failed);
    assert_int_equal(sc->loop.seed, 42);
    clear(&c);
    char *params = scene_doc_copy(sc, DOC_PARAMS, &len);
    o = json_loads(params, 0, NULL);
    assert_int_equal(json_integer_value(json_object_get(o, "seed")), 42);
    assert_true(json_number_value(json_object_get(o, "k_bend")) == 7.0);
    json_decref(o);
    free(params);
    /* A rebuild starts the journal afresh. */
    assert_int_equal(run(sc, "reset", "{\"op\":\"reset\"}", &c), 0);
    clear(&c);
    j = journal_json(sc->journal, &len);
    assert_string_equal(j, "{\"base_step\":0,\"entries\":[]}");
    free(j);
    assert_true(rec.poses > 0);
    scene_release(sc);
}

static void test_run_state(void **unused)
{
    (void)unused;
    scene *sc = make(0);
    scene_cmd c, step;
    /* A step only while paused (the PAUSED column): 409. */
    assert_int_equal(run(sc, "step", "{\"frames\":3}", &c), 0);
    assert_true(c.failed);
    assert_int_equal(c.pr.status, 409);
    assert_string_equal(c.pr.detail, "step only while paused: POST /v1/sim/pause first");
    clear(&c);
    assert_int_equal(run(sc, "pause", NULL, &c), 0);
    assert_true(sc->paused);
    json_t *o = json_loads((char *)c.blob, 0, NULL); /* answered with GET /v1/sim's JSON */
    assert_string_equal(json_string_value(json_object_get(o, "state")), "paused");
    json_decref(o);
    assert_string_equal(last_event_name(), "paused");
    clear(&c);
    /* Kept as the step in progress; a cancel ends it (and says there was one). */
    answered = 0;
    assert_int_equal(run(sc, "step", "{\"frames\":3}", &step), 1);
    assert_ptr_equal(sc->job.cmd, &step);
    assert_int_equal(answered, 0);
    assert_int_equal(run(sc, "step_cancel", NULL, &c), 0);
    assert_int_equal(answered, 2);
    assert_true(json_is_true(json_object_get(c.result, "cancelled")));
    assert_true(json_is_true(json_object_get(step.result, "interrupted")));
    assert_string_equal(json_string_value(json_object_get(step.result, "interrupted_by")), "cancel");
    assert_null(sc->job.cmd);
    clear(&c);
    clear(&step);
    /* Another command that changes the state ends a step too ("command"). */
    assert_int_equal(run(sc, "step", "{\"substeps\":5}", &step), 1);
    assert_int_equal(run(sc, "rocks_clear", "{\"op\":\"rocks_clear\"}", &c), 0);
    assert_string_equal(json_string_value(json_object_get(step.result, "interrupted_by")), "command");
    clear(&c);
    clear(&step);
    assert_int_equal(run(sc, "resume", NULL, &c), 0);
    assert_false(sc->paused);
    clear(&c);
    scene_release(sc);
}

static void test_snapshot_and_reads(void **unused)
{
    (void)unused;
    scene *sc = make(1);
    scene_cmd c, put;
    assert_int_equal(run(sc, "snapshot_get", NULL, &c), 0);
    assert_false(c.failed);
    assert_true(c.blob_len == cs_snapshot_size(sc->engine));
    const uint64_t h = cs_state_hash(sc->engine);
    scene_cmd grab;
    assert_int_equal(run(sc, "grab", "{\"op\":\"grab\",\"vertex\":14,\"target\":[0,0,2]}", &grab), 0);
    clear(&grab);
    assert_true(cs_state_hash(sc->engine) != h);
    memset(&put, 0, sizeof put);
    put.def = command_find("snapshot_put");
    put.blob_in = c.blob;
    put.blob_in_len = c.blob_len;
    put.done = done;
    assert_int_equal(command_run(sc, &put), 0);
    assert_false(put.failed);
    assert_true(cs_state_hash(sc->engine) == h);
    assert_string_equal(last_event_name(), "snapshot_restored");
    clear(&put);
    clear(&c);
    assert_int_equal(run(sc, "cloth_state", "{\"binary\":true}", &c), 0);
    assert_int_equal(c.blob_len, 30 * 6 * sizeof(float));
    clear(&c);
    assert_int_equal(run(sc, "cloth_state", "{\"binary\":false}", &c), 0);
    json_t *o = json_loads((char *)c.blob, 0, NULL);
    assert_int_equal(json_array_size(json_object_get(o, "positions")), 30);
    assert_int_equal(json_integer_value(json_object_get(o, "nx")), 6);
    json_decref(o);
    clear(&c);
    scene_release(sc);
}

static void refused_at_once(scene_cmd *c, void *arg)
{
    (void)arg;
    answered++;
    assert_true(c->failed);
    assert_int_equal(c->pr.status, 503);
}

static void test_queue(void **unused)
{
    (void)unused;
    clothd_config cfg = uk_defaults();
    cfg.set.queue_max = 2;
    scene *sc = scene_new("q", uk_engine(3, 3), &cfg.scene.loop, 1, &cfg.set);
    scene_cmd a = {0}, b = {0}, c = {0};
    a.def = b.def = c.def = command_find("publish");
    a.done = b.done = c.done = refused_at_once;
    answered = 0;
    scene_submit(sc, &a);
    scene_submit(sc, &b);
    scene_submit(sc, &c); /* past queue_max: 503 busy at once */
    assert_int_equal(answered, 1);
    assert_string_equal(c.pr.slug, "busy");
    scene_cmd *list = scene_take_queue(sc);
    assert_ptr_equal(list, &a);
    assert_ptr_equal(a.next, &b);
    assert_null(b.next);
    scene_close(sc);
    scene_submit(sc, &c); /* stopping: 503 at once */
    assert_int_equal(answered, 2);
    assert_string_equal(c.pr.slug, "unavailable");
    scene_release(sc);
}

static void test_table_and_handles(void **unused)
{
    (void)unused;
    clothd_config cfg = uk_defaults();
    scenes *t = scenes_new(2);
    scene *a = scene_new(SCENE_DEFAULT, uk_engine(3, 3), &cfg.scene.loop, 1, &cfg.set);
    scene *b = scene_new("other", uk_engine(3, 3), &cfg.scene.loop, 1, &cfg.set);
    scene *dup = scene_new(SCENE_DEFAULT, uk_engine(3, 3), &cfg.scene.loop, 1, &cfg.set);
    assert_int_equal(scenes_add(t, a), 0);
    assert_int_equal(scenes_add(t, dup), -1); /* the id is taken */
    assert_int_equal(scenes_add(t, b), 0);
    assert_int_equal(scenes_add(t, dup), SCENES_TAKEN); /* taken (and full) */
    scene *third = scene_new("third", uk_engine(3, 3), &cfg.scene.loop, 1, &cfg.set);
    assert_int_equal(scenes_add(t, third), SCENES_FULL);
    scene_release(third);
    scene_release(dup);
    assert_int_equal(scenes_count(t), 2);
    scene *h = scenes_get(t, SCENE_DEFAULT);
    assert_ptr_equal(h, a);
    assert_int_equal(atomic_load(&a->refs), 3); /* ours, the table's, the handle */
    assert_null(scenes_get(t, "none"));
    scene *list[4];
    assert_int_equal(scenes_list(t, list, 4), 2);
    assert_ptr_equal(list[1], b);
    scene_release(list[0]);
    scene_release(list[1]);
    scene_release(a);
    scene_release(b);
    /* The table gone, a held handle still reaches its scene; its release frees it. */
    scenes_free(t);
    assert_int_equal(atomic_load(&h->refs), 1);
    size_t len;
    char *sim = scene_doc_copy(h, DOC_SIM, &len);
    assert_non_null(sim);
    free(sim);
    scene_release(h);
}

/* A scene's cost: what the engine and the daemon keep, and what its sink holds. */
static void test_cost(void **unused)
{
    (void)unused;
    cs_scene f;
    cs_scene_default(&f);
    f.nx = 10, f.ny = 20;
    uint64_t bare, with_sink, engine, snap;
    assert_int_equal(scene_cost(&f, NULL, 4, NULL, &bare), CS_OK);
    assert_int_equal(scene_cost(&f, NULL, 4, (void *)&rec_ops, &with_sink), CS_OK);
    assert_true(with_sink - bare == 1000 * 200 + 4);
    assert_int_equal(cs_scene_memory(&f, NULL, 4, &engine), CS_OK);
    assert_int_equal(cs_snapshot_bytes(&f, 4, &snap), CS_OK);
    assert_true(bare > engine + 2 * snap); /* and the answers, scratch and torn lists beside */
    f.nx = f.ny = 4096;
    assert_int_equal(scene_cost(&f, NULL, 1024, NULL, &bare), CS_OK);
    assert_true(bare > (uint64_t)4096 * 4096 * 100);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_published_and_changes),
        cmocka_unit_test(test_run_state),
        cmocka_unit_test(test_snapshot_and_reads),
        cmocka_unit_test(test_queue),
        cmocka_unit_test(test_table_and_handles),
        cmocka_unit_test(test_cost),
    };
    const int rc = cmocka_run_group_tests(tests, NULL, NULL);
    json_decref(rec.events);
    pose_free(&rec.spare);
    return rc;
}
