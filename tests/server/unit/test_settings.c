/* test_settings.c - the one settings table (core/settings.c): every tunable the daemon takes, in
 * one row shape; defaults; text from the config file, CLOTHD_* variables and flags, in that
 * order of precedence, and their refusals; the rows of docs/operating.md's table; the daemon-loop
 * settings an old snapshot still holds. */
#include <unistd.h>

#include "core/params_json.h"
#include "unitkit.h"

/* Every tunable of the design's parameter table, and the startup settings it names. */
static const char *const design[] = {
    "nx", "ny", "size_x", "size_y", "height", "orientation", "pins", "areal_density", "gravity", "wind",
    "k_structural", "k_shear", "k_bend", "c_spring", "drag", "plastic_yield", "tear_strain", "plastic_rate",
    "k_contact", "c_contact", "c_tangent", "mu", "contact_offset", "friction_model", "k_rock", "c_rock", "mu_rock",
    "ground", "ground_z", "frame_rate", "substeps", "max_substeps", "auto_substeps", "stability_safety",
    "integrator", "time_scale", "max_speed", "grab_speed", "auto_drop_interval", "auto_drop_max", "seed",
    "checkpoint_interval", "listen", "port", "stream_port", "backend", "token_file", "view_token_file", "state_file",
    "web_root"};

static void test_one_table(void **unused)
{
    (void)unused;
    for (size_t i = 0; i < sizeof design / sizeof design[0]; i++) {
        const setting *s = settings_find(design[i]);
        if (!s) fail_msg("%s is not in the table", design[i]);
        int n = 0;
        for (size_t k = 0; k < settings_count(); k++) n += strcmp(settings_at(k)->name, design[i]) == 0;
        assert_int_equal(n, 1);
    }
    /* The daemon-loop settings are live, the daemon's; the engine's are in cs_param_*. */
    const char *loop[] = {"time_scale", "max_speed", "auto_drop_interval", "auto_drop_max", "seed", "checkpoint_interval"};
    for (int k = 0; k < 6; k++) {
        const setting *s = settings_find(loop[k]);
        assert_int_equal(s->kind, SET_LIVE);
        assert_int_equal(s->home, IN_LOOP);
        assert_null(cs_param_find(loop[k]));
    }
    assert_int_equal(settings_find("k_bend")->home, IN_PARAMS);
    assert_int_equal(settings_find("nx")->kind, SET_SCENE);
    assert_int_equal(settings_find("port")->kind, SET_STARTUP);
    assert_string_equal(setting_type_name(settings_find("listen")->type), "string");
    assert_string_equal(setting_kind_name(settings_find("seed")->kind), "live");
    assert_null(settings_find("warp_speed"));
    /* Kinds in table order: scene fields, live parameters, startup settings. */
    for (size_t k = 1; k < settings_count(); k++) assert_true(settings_at(k - 1)->kind <= settings_at(k)->kind);
}

static void test_defaults(void **unused)
{
    (void)unused;
    clothd_config c = uk_defaults();
    assert_string_equal(c.set.listen, "127.0.0.1");
    assert_int_equal(c.set.port, 8080);
    assert_int_equal(c.set.backend, BACKEND_AUTO);
    assert_int_equal(c.scene.fields.nx, 64);
    assert_true(c.scene.params.k_bend == 20.0f && c.scene.params.gravity[2] == -9.81f);
    assert_true(c.scene.loop.time_scale == 1.0f && c.scene.loop.auto_drop_interval == 3.0f && c.scene.loop.seed == 1);
    assert_int_equal(c.scene.loop.checkpoint_interval, 60);
    assert_false(c.scene_size_given);
    assert_false(c.integrator_given);
    assert_int_equal(c.scene.params.integrator, CS_IMPLICIT_EULER);
}

/* The backend's defaults: on the CPU the table's; on CUDA a 256 x 256 cloth and velocity_verlet,
 * each only where the settings did not give it (the file's, the flags' or the environment's). */
static void test_backend_defaults(void **unused)
{
    (void)unused;
    char why[600] = "";
    clothd_config c = uk_defaults(), was = c;
    assert_int_equal(settings_backend_defaults(&c, "cpu"), 0);
    assert_memory_equal(&c.scene, &was.scene, sizeof c.scene);
    assert_int_equal(settings_backend_defaults(&c, "cuda"), 1);
    assert_int_equal(c.scene.fields.nx, 256);
    assert_int_equal(c.scene.fields.ny, 256);
    assert_int_equal(c.scene.params.integrator, CS_VELOCITY_VERLET);
    assert_true(c.scene.params.k_bend == was.scene.params.k_bend); /* nothing else */
    assert_int_equal(settings_backend_defaults(&c, "cuda"), 0);    /* already so */
    clothd_config g = uk_defaults();
    const char *text = "integrator = implicit_euler\nny = 40\n";
    assert_int_equal(settings_parse_config(&g, text, strlen(text), "x.conf", why, sizeof why), 0);
    assert_true(g.integrator_given && g.scene_size_given);
    assert_int_equal(settings_backend_defaults(&g, "cuda"), 0);
    assert_int_equal(g.scene.params.integrator, CS_IMPLICIT_EULER);
    assert_int_equal(g.scene.fields.nx, 64);
    assert_int_equal(g.scene.fields.ny, 40);
}

static int apply(clothd_config *c, const char *text, char *why)
{
    return settings_parse_config(c, text, strlen(text), "x.conf", why, 600);
}

static void test_config_text(void **unused)
{
    (void)unused;
    clothd_config c = uk_defaults();
    char why[600] = "";
    assert_int_equal(apply(&c, "# a comment\nport = 9000\r\n\nk-bend=11   # trailing\n gravity = 0, 0,-3\nbackend=cpu\n"
                               "time_scale = 2.5\npaused = yes\nnx = 9\nlisten = ::1\n", why), 0);
    assert_int_equal(c.set.port, 9000);
    assert_true(c.scene.params.k_bend == 11.0f);
    assert_true(c.scene.params.gravity[0] == 0 && c.scene.params.gravity[2] == -3.0f);
    assert_int_equal(c.set.backend, BACKEND_CPU);
    assert_true(c.scene.loop.time_scale == 2.5f);
    assert_int_equal(c.set.paused, 1);
    assert_int_equal(c.scene.fields.nx, 9);
    assert_true(c.scene_size_given);
    assert_string_equal(c.set.listen, "::1");
    const struct {
        const char *text, *why;
    } bad[] = {
        {"port = 70000", "x.conf:1: port must be a whole number from 0 to 65535 (got '70000')"},
        {"\n\nport = 8.5", "x.conf:3: port must be a whole number from 0 to 65535 (got '8.5')"},
        {"k_bend = soft", "x.conf:1: k_bend must be a number (got 'soft')"},
        {"k_bend = -1", "x.conf:1: k_bend must be between 0 and 1e+09 (got -1)"},
        {"gravity = 1,2", "x.conf:1: gravity must be three numbers 'x,y,z' (got '1,2')"},
        {"backend = tpu", "x.conf:1: backend must be one of auto|cuda|cpu (got 'tpu')"},
        {"integrator = rk4", "x.conf:1: integrator must be one of velocity_verlet|symplectic_euler|implicit_euler (got 'rk4')"},
        {"ground = maybe", "x.conf:1: ground must be true or false (got 'maybe')"},
        {"warp_speed = 9", "x.conf:1: unknown setting 'warp_speed' (clothd --help lists them)"},
        {"no equals here", "x.conf:1: expected 'name = value'"},
        {"seed = 2147483648", "x.conf:1: seed must be a whole number from 0 to 2.14748e+09 (got '2147483648')"},
    };
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
        clothd_config d = uk_defaults();
        assert_int_equal(apply(&d, bad[k].text, why), -1);
        assert_string_equal(why, bad[k].why);
    }
    /* A string too long for its field is refused whole. */
    char longer[700];
    memset(longer, 'a', sizeof longer);
    memcpy(longer, "listen = ", 9);
    longer[sizeof longer - 1] = '\0';
    assert_int_equal(apply(&c, longer, why), -1);
    assert_string_equal(why, "x.conf:1: listen is longer than 511 characters");
    assert_int_equal(settings_parse_config(&c, "nx = 9\0x", 8, "x.conf", why, sizeof why), -1);
    assert_string_equal(why, "x.conf:1: holds a NUL byte");
}

/* config file < CLOTHD_* < flags; a bool flag without a value is true; dashes and underscores
 * alike; a variable that names no setting is passed over (or skipped silently by prefix). */
static void test_precedence(void **unused)
{
    (void)unused;
    char path[] = "/tmp/clothd-settings-XXXXXX";
    const int fd = mkstemp(path);
    assert_true(fd >= 0);
    const char *text = "k_bend = 11\nk_shear = 44\nny = 9\nseed = 5\n";
    assert_int_equal(write(fd, text, strlen(text)), (ssize_t)strlen(text));
    close(fd);
    char conf[64];
    snprintf(conf, sizeof conf, "--config=%s", path);
    char *argv[] = {conf, "--k-shear", "55", "--max_speed", "--seed", "6", NULL};
    char *env[] = {"CLOTHD_K_BEND=22", "CLOTHD_NY=7", "CLOTHD_SEED=9", "CLOTHD_TEST_NAN_FRAME=3", "HOME=/", NULL};
    clothd_config c = uk_defaults();
    char why[600] = "";
    assert_int_equal(settings_load(&c, 6, argv, env, "TEST_", why, sizeof why), 0);
    assert_true(c.scene.params.k_bend == 22.0f);  /* environment over the file */
    assert_true(c.scene.params.k_shear == 55.0f); /* flag over the file */
    assert_int_equal(c.scene.fields.ny, 7);
    assert_int_equal(c.scene.loop.seed, 6);       /* flag over the environment over the file */
    assert_int_equal(c.scene.loop.max_speed, 1);
    assert_string_equal(c.set.config, path);
    char *missing[] = {"--nx", NULL};
    assert_int_equal(settings_load(&c, 1, missing, NULL, NULL, why, sizeof why), -1);
    assert_string_equal(why, "--nx needs a value");
    char *stray[] = {"nx", NULL};
    assert_int_equal(settings_load(&c, 1, stray, NULL, NULL, why, sizeof why), -1);
    assert_string_equal(why, "unexpected argument 'nx'");
    char *bad_env[] = {"CLOTHD_PORT=http", NULL};
    assert_int_equal(settings_load(&c, 0, NULL, bad_env, NULL, why, sizeof why), -1);
    assert_string_equal(why, "environment CLOTHD_PORT: port must be a whole number from 0 to 65535 (got 'http')");
    unlink(path);
}

/* docs/operating.md's table (clothd --help-markdown) is made of the startup rows. */
static void test_markdown(void **unused)
{
    (void)unused;
    char *out = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&out, &len);
    settings_markdown(f);
    fclose(f);
    assert_non_null(strstr(out, "| setting | flag, variable | default | range | meaning |\n|---|---|---|---|---|\n"));
    assert_non_null(strstr(out, "\n| `port` | `--port`, `CLOTHD_PORT` | 8080 | 0 .. 65535 | HTTP port; 0 picks a free one and logs it |\n"));
    assert_non_null(strstr(out, "\n| `backend` | `--backend`, `CLOTHD_BACKEND` | auto | auto, cuda, cpu | Physics backend: auto uses CUDA when a device is present |\n"));
    assert_non_null(strstr(out, "\n| `insecure` | `--insecure`, `CLOTHD_INSECURE` | false | true, false |"));
    assert_non_null(strstr(out, "| `web_root` | `--web-root`, `CLOTHD_WEB_ROOT` | the build's `web/` | - |"));
    assert_null(strstr(out, "k_bend")); /* startup settings only */
    assert_null(strstr(out, "time_scale"));
    free(out);
}

/* The schema lists every row once, with its kind. */
static void test_schema(void **unused)
{
    (void)unused;
    json_t *s = schema_to_json();
    const json_t *list = json_object_get(s, "params");
    assert_int_equal(json_array_size(list), settings_count());
    size_t k;
    json_t *row;
    int live = 0;
    json_array_foreach(list, k, row) {
        const char *name = json_string_value(json_object_get(row, "name"));
        if (strcmp(name, "time_scale") == 0) {
            char *text = uk_dump(row);
            uk_assert_json(text, "{\"name\":\"time_scale\",\"type\":\"float\",\"unit\":\"-\",\"default\":1.0,\"min\":0.001,"
                                 "\"max\":1000.0,\"choices\":null,\"kind\":\"live\",\"help\":\"Simulated seconds per wall-clock second\"}");
            free(text);
        }
        if (strcmp(name, "backend") == 0) {
            char *text = uk_dump(row);
            uk_assert_json(text, "{\"name\":\"backend\",\"type\":\"enum\",\"unit\":\"-\",\"default\":\"auto\",\"min\":null,"
                                 "\"max\":null,\"choices\":[\"auto\",\"cuda\",\"cpu\"],\"kind\":\"startup\",\"help\":"
                                 "\"Physics backend: auto uses CUDA when a device is present\"}");
            free(text);
        }
        live += strcmp(json_string_value(json_object_get(row, "kind")), "live") == 0;
    }
    int engine_live = 0;
    for (size_t i = 0; i < cs_param_count(); i++) engine_live += cs_param_at(i)->kind == CS_KIND_LIVE;
    assert_int_equal(live, engine_live + 6); /* the engine's live rows and the daemon's six */
    json_decref(s);
}

/* An old snapshot's daemon-loop settings (tests/data: clothd 0.1.0's, --time-scale 2.5 --seed 7
 * --auto-drop-interval 0.75 --auto-drop-max 3 --checkpoint-interval 17 --max-speed true); a
 * snapshot of this table holds none. */
static void test_loop_from_snapshot(void **unused)
{
    (void)unused;
    unsigned char file[8192];
    const size_t n = uk_data_file("clothd-0.1.0.state", file, sizeof file);
    loop_settings loop = uk_defaults().scene.loop;
    assert_int_equal(loop_from_snapshot(&loop, file, cs_snapshot_length(file, n)), 6);
    assert_true(loop.time_scale == 2.5f && loop.seed == 7 && loop.auto_drop_interval == 0.75f);
    assert_true(loop.auto_drop_max == 3 && loop.checkpoint_interval == 17 && loop.max_speed == 1);
    cs_sim *sim = uk_engine(3, 3);
    size_t len = cs_snapshot_size(sim);
    unsigned char *b = malloc(len);
    assert_int_equal(cs_snapshot_save(sim, b, len, &len), CS_OK);
    loop_settings now = uk_defaults().scene.loop, before = now;
    assert_int_equal(loop_from_snapshot(&now, b, len), 0);
    assert_memory_equal(&now, &before, sizeof now);
    free(b);
    cs_sim_destroy(sim);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_one_table),
        cmocka_unit_test(test_defaults),
        cmocka_unit_test(test_backend_defaults),
        cmocka_unit_test(test_config_text),
        cmocka_unit_test(test_precedence),
        cmocka_unit_test(test_markdown),
        cmocka_unit_test(test_schema),
        cmocka_unit_test(test_loop_from_snapshot),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
