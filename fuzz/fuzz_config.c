/* fuzz_config.c - the config file's text (settings_parse_config: 'name = value' lines, what
 * --config and CLOTHD_CONFIG read).
 *
 * Besides what ASan and UBSan catch, it checks what settings.h promises: a refusal names the
 * file and line; whatever was applied, every startup setting is within its range (strings
 * NUL-terminated in their fields) and every engine parameter passes the table's check. */
#include <stdint.h>

#include "fuzz_common.h"
#include "settings.h"

int LLVMFuzzerInitialize(int *argc, char ***argv)
{
    (void)argc, (void)argv;
    return 0;
}

/* Each startup setting against its row of the table (settings.h's X-macro). */
#define CHECK_STR(name, lo, hi)                                                                               \
    if (!memchr(c->set.name, '\0', sizeof c->set.name)) fuzz_fail(#name " is not NUL-terminated");
#define CHECK_NUM(name, lo, hi)                                                                               \
    if (c->set.name < (lo) || c->set.name > (hi)) fuzz_fail(#name " = %d is outside [%g, %g]", (int)c->set.name, (double)(lo), (double)(hi));
#define CHECK_INT(name, lo, hi) CHECK_NUM(name, lo, hi)
#define CHECK_BOOL(name, lo, hi) CHECK_NUM(name, lo, hi)
#define CHECK_ENUM(name, lo, hi) CHECK_NUM(name, lo, hi)
#define CHECK(name, type, def, lo, hi, choices, help) CHECK_##type(name, lo, hi)

static void check(const clothd_config *c)
{
    CLOTHD_SETTINGS(CHECK)
    for (size_t i = 0; i < cs_param_count(); i++) {
        const cs_param_info *p = cs_param_at(i);
        const void *base = CS_PARAM_BASE(p, &c->scene, &c->params);
        for (int k = 0; k < (p->type == CS_T_VEC3 ? 3 : 1); k++) {
            const double v = cs_param_get(p, base, k);
            if (!(v >= p->min && v <= p->max)) fuzz_fail("%s[%d] = %g is outside [%g, %g]", p->name, k, v, p->min, p->max);
        }
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    clothd_config c;
    settings_default(&c);
    char why[600];
    why[0] = '\0';
    const int rc = settings_parse_config(&c, (const char *)data, size, "fuzz.conf", why, sizeof why);
    if (rc != 0 && rc != -1) fuzz_fail("settings_parse_config returned %d", rc);
    if (!memchr(why, '\0', sizeof why)) fuzz_fail("the reason is not NUL-terminated");
    if (rc == -1 && strncmp(why, "fuzz.conf:", 10) != 0) fuzz_fail("a refusal that names no line: %s", why);
    if (rc == 0 && why[0]) fuzz_fail("an accepted file with a reason: %s", why);
    check(&c);
    return 0;
}
