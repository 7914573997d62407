/* fuzz_config.c - the config file's text (settings_parse_config: 'name = value' lines, what
 * --config and CLOTHD_CONFIG read).
 *
 * Besides what ASan and UBSan catch, it checks what settings.h promises: a refusal names the
 * file and line; whatever was applied, every startup setting is within its range (strings
 * NUL-terminated in their fields) and every engine parameter passes the table's check. */
#include <stdint.h>

#include "core/settings.h"
#include "fuzz_common.h"

int LLVMFuzzerInitialize(int *argc, char ***argv)
{
    (void)argc, (void)argv;
    return 0;
}

/* Whatever the file held, every row of the table holds a value it allows. */
static void check(clothd_config *c)
{
    for (size_t i = 0; i < settings_count(); i++) {
        const setting *s = settings_at(i);
        const void *field = setting_field(s, &c->set, &c->scene);
        if (s->type == SET_STR) {
            if (!memchr(field, '\0', SETTING_TEXT_MAX)) fuzz_fail("%s is not NUL-terminated", s->name);
            continue;
        }
        for (int k = 0; k < (s->type == SET_VEC3 ? 3 : 1); k++) {
            const double v = setting_get(s, field, k);
            if (!(v >= s->min && v <= s->max)) fuzz_fail("%s[%d] = %g is outside [%g, %g]", s->name, k, v, s->min, s->max);
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
