/* test_access.c - who may use clothd (core/access.c): tokens and their levels, the listen rule,
 * Host (DNS rebinding), a page's Origin, and the cross-site rule for changing requests. */
#include <unistd.h>

#include "core/access.h"
#include "unitkit.h"

static char dir[64];

static const char *token_file(const char *name, const char *text)
{
    static char path[2][128];
    static int k;
    char *p = path[k++ % 2];
    snprintf(p, 128, "%s/%s", dir, name);
    FILE *f = fopen(p, "w");
    assert_non_null(f);
    fputs(text, f);
    fclose(f);
    return p;
}

static access_policy *load(clothd_config *c, char *err)
{
    return access_load(&c->set, err, 300);
}

static void test_no_token(void **unused)
{
    (void)unused;
    clothd_config c = uk_defaults();
    char err[300];
    access_policy *p = load(&c, err);
    assert_non_null(p);
    assert_false(access_required(p));
    assert_int_equal(access_token(p, NULL), ACCESS_CONTROL); /* loopback, no token: everyone controls */
    assert_int_equal(access_bearer(p, NULL), ACCESS_CONTROL);
    access_free(p);
    /* Beyond loopback without a token: refused, unless insecure. */
    snprintf(c.set.listen, sizeof c.set.listen, "0.0.0.0");
    assert_null(load(&c, err));
    assert_non_null(strstr(err, "refusing to listen on 0.0.0.0 without a token"));
    c.set.insecure = 1;
    p = load(&c, err);
    assert_non_null(p);
    access_free(p);
    snprintf(c.set.listen, sizeof c.set.listen, "localhost");
    assert_null(load(&c, err));
    assert_non_null(strstr(err, "not a numeric IPv4 or IPv6 address"));
}

static void test_tokens(void **unused)
{
    (void)unused;
    clothd_config c = uk_defaults();
    char err[300];
    snprintf(c.set.token_file, sizeof c.set.token_file, "%s", token_file("control", "0123456789abcdef0123\n"));
    snprintf(c.set.view_token_file, sizeof c.set.view_token_file, "%s", token_file("view", "viewviewviewview"));
    access_policy *p = load(&c, err);
    assert_non_null(p);
    assert_true(access_required(p));
    assert_int_equal(access_token(p, "0123456789abcdef0123"), ACCESS_CONTROL); /* the newline is not the token's */
    assert_int_equal(access_token(p, "viewviewviewview"), ACCESS_VIEW);
    assert_int_equal(access_token(p, "0123456789abcdef012"), ACCESS_NONE);
    assert_int_equal(access_token(p, ""), ACCESS_NONE);
    assert_int_equal(access_token(p, NULL), ACCESS_NONE);
    assert_int_equal(access_bearer(p, "Bearer  0123456789abcdef0123 "), ACCESS_CONTROL);
    assert_int_equal(access_bearer(p, "bearer viewviewviewview"), ACCESS_VIEW);
    assert_int_equal(access_bearer(p, "Basic 0123456789abcdef0123"), ACCESS_NONE);
    assert_int_equal(access_bearer(p, NULL), ACCESS_NONE);
    access_free(p);
    /* Too short, a character no token holds, the same token twice, a view token alone. */
    snprintf(c.set.token_file, sizeof c.set.token_file, "%s", token_file("control", "short"));
    assert_null(load(&c, err));
    assert_non_null(strstr(err, "a token is 16 to 512 characters"));
    snprintf(c.set.token_file, sizeof c.set.token_file, "%s", token_file("control", "0123456789abcdef!"));
    assert_null(load(&c, err));
    assert_non_null(strstr(err, "character 17 is not one"));
    snprintf(c.set.token_file, sizeof c.set.token_file, "%s", token_file("control", "viewviewviewview"));
    assert_null(load(&c, err));
    assert_non_null(strstr(err, "are the same"));
    c.set.token_file[0] = '\0';
    assert_null(load(&c, err));
    assert_non_null(strstr(err, "view_token_file needs token_file too"));
}

static void test_host_and_origin(void **unused)
{
    (void)unused;
    clothd_config c = uk_defaults();
    char err[300];
    snprintf(c.set.allowed_hosts, sizeof c.set.allowed_hosts, "cloth.example, other.example");
    snprintf(c.set.allowed_origins, sizeof c.set.allowed_origins, "https://app.example");
    access_policy *p = load(&c, err);
    assert_non_null(p);
    /* Host: an address, localhost, or a name of allowed_hosts; a port may follow. */
    assert_true(access_host_ok(p, NULL));
    assert_true(access_host_ok(p, "127.0.0.1:8080"));
    assert_true(access_host_ok(p, "[::1]:8080"));
    assert_true(access_host_ok(p, "LOCALHOST"));
    assert_true(access_host_ok(p, "other.example:99"));
    assert_false(access_host_ok(p, "evil.example"));
    assert_false(access_host_ok(p, "cloth.example:x"));
    assert_false(access_host_ok(p, ":8080"));
    /* A page's own origin: the host the request names, on the HTTP port. */
    assert_true(access_origin_ok(p, NULL, "127.0.0.1:8080", 8080));
    assert_true(access_origin_ok(p, "http://127.0.0.1:8080", "127.0.0.1:8080", 8080));
    assert_false(access_origin_ok(p, "http://127.0.0.1:9999", "127.0.0.1:8080", 8080));
    assert_false(access_origin_ok(p, "http://evil.example:8080", "evil.example:8080", 8080)); /* not an allowed host */
    assert_true(access_origin_ok(p, "http://localhost", "localhost", 80));
    assert_false(access_origin_ok(p, "null", "127.0.0.1:8080", 8080));
    assert_true(access_origin_ok(p, "https://app.example", "127.0.0.1:8080", 8080));
    assert_true(access_origin_listed(p, "https://app.example"));
    assert_false(access_origin_listed(p, "https://app.example.evil"));
    /* The cross-site rule: Sec-Fetch-Site: cross-site only from a listed origin. */
    assert_true(access_change_ok(p, NULL, NULL, "127.0.0.1:8080", 8080));
    assert_false(access_change_ok(p, NULL, "cross-site", "127.0.0.1:8080", 8080));
    assert_true(access_change_ok(p, "https://app.example", "cross-site", "127.0.0.1:8080", 8080));
    assert_true(access_change_ok(p, "http://127.0.0.1:8080", "same-origin", "127.0.0.1:8080", 8080));
    assert_false(access_change_ok(p, "http://127.0.0.1:8081", "same-site", "127.0.0.1:8080", 8080));
    access_free(p);
}

static int setup(void **unused)
{
    (void)unused;
    snprintf(dir, sizeof dir, "/tmp/clothd-access-XXXXXX");
    return mkdtemp(dir) ? 0 : -1;
}

static int teardown(void **unused)
{
    (void)unused;
    char cmd[128];
    snprintf(cmd, sizeof cmd, "rm -rf %s", dir);
    return system(cmd) == 0 ? 0 : -1;
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_no_token),
        cmocka_unit_test(test_tokens),
        cmocka_unit_test(test_host_and_origin),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
