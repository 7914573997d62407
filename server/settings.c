/* settings.c - the startup settings table, and setting any item (startup setting or engine
 * parameter) from text: config file lines, CLOTHD_* variables, command-line flags. */
#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "settings.h"

typedef enum { T_STR, T_INT, T_BOOL, T_ENUM } stype;

typedef struct srow {
    setting_info info;
    stype type;
    size_t offset, size;
} srow;

#define ROW_STR(name, def, lo, hi, choices, help)                                                      \
    {{#name, "string", help, choices, lo, hi, def, 0}, T_STR, offsetof(clothd_settings, name),         \
     sizeof(((clothd_settings *)0)->name)},
#define ROW_INT(name, def, lo, hi, choices, help)                                                      \
    {{#name, "int", help, choices, lo, hi, NULL, def}, T_INT, offsetof(clothd_settings, name), 4},
#define ROW_BOOL(name, def, lo, hi, choices, help)                                                     \
    {{#name, "bool", help, choices, lo, hi, NULL, def}, T_BOOL, offsetof(clothd_settings, name), 4},
#define ROW_ENUM(name, def, lo, hi, choices, help)                                                     \
    {{#name, "enum", help, choices, lo, hi, NULL, def}, T_ENUM, offsetof(clothd_settings, name), 4},
#define ROW(name, type, def, lo, hi, choices, help) ROW_##type(name, def, lo, hi, choices, help)

static const srow rows[] = {CLOTHD_SETTINGS(ROW)};
#define NROWS (sizeof rows / sizeof rows[0])

size_t settings_count(void) { return NROWS; }
const setting_info *settings_at(size_t i) { return i < NROWS ? &rows[i].info : NULL; }

/* The index of word in "a|b|c", or -1. */
static int choice_index(const char *choices, const char *word)
{
    int k = 0;
    for (const char *s = choices; s && *s; k++) {
        const char *bar = strchr(s, '|');
        const size_t len = bar ? (size_t)(bar - s) : strlen(s);
        if (strlen(word) == len && strncmp(s, word, len) == 0) return k;
        s = bar ? bar + 1 : s + len;
    }
    return -1;
}

void settings_default(clothd_config *c)
{
    memset(c, 0, sizeof *c);
    for (size_t i = 0; i < NROWS; i++) {
        char *field = (char *)&c->set + rows[i].offset;
        if (rows[i].type == T_STR) snprintf(field, rows[i].size, "%s", rows[i].info.def_text);
        else *(int32_t *)field = (int32_t)rows[i].info.def_number;
    }
    cs_scene_default(&c->scene);
    cs_params_default(&c->params);
}

static int parse_bool(const char *t, double *out)
{
    static const char *const yes[] = {"true", "1", "yes", "on"}, *const no[] = {"false", "0", "no", "off"};
    for (int k = 0; k < 4; k++) {
        if (strcasecmp(t, yes[k]) == 0) return *out = 1, 0;
        if (strcasecmp(t, no[k]) == 0) return *out = 0, 0;
    }
    return -1;
}

static int parse_number(const char *t, double *out)
{
    char *end;
    errno = 0;
    const double v = strtod(t, &end);
    while (isspace((unsigned char)*end)) end++;
    if (end == t || *end || errno == ERANGE || !isfinite(v)) return -1;
    *out = v;
    return 0;
}

static const srow *find_row(const char *name)
{
    for (size_t i = 0; i < NROWS; i++)
        if (strcmp(rows[i].info.name, name) == 0) return &rows[i];
    return NULL;
}

static int set_startup(clothd_config *c, const srow *r, const char *text, char *why, size_t why_len)
{
    char *field = (char *)&c->set + r->offset;
    double v;
    switch (r->type) {
    case T_STR:
        if (strlen(text) >= r->size) {
            snprintf(why, why_len, "%s is longer than %zu characters", r->info.name, r->size - 1);
            return -1;
        }
        snprintf(field, r->size, "%s", text);
        return 0;
    case T_ENUM: {
        const int k = choice_index(r->info.choices, text);
        if (k < 0) {
            snprintf(why, why_len, "%s must be one of %s (got '%s')", r->info.name, r->info.choices, text);
            return -1;
        }
        *(int32_t *)field = k;
        return 0;
    }
    case T_BOOL:
        if (parse_bool(text, &v) != 0) {
            snprintf(why, why_len, "%s must be true or false (got '%s')", r->info.name, text);
            return -1;
        }
        *(int32_t *)field = (int32_t)v;
        return 0;
    case T_INT:
        if (parse_number(text, &v) != 0 || v != floor(v) || v < r->info.min || v > r->info.max) {
            snprintf(why, why_len, "%s must be a whole number from %g to %g (got '%s')", r->info.name, r->info.min,
                     r->info.max, text);
            return -1;
        }
        *(int32_t *)field = (int32_t)v;
        return 0;
    }
    return -1;
}

static int set_engine(clothd_config *c, const cs_param_info *p, const char *text, char *why, size_t why_len)
{
    double v[3] = {0, 0, 0};
    if (p->type == CS_T_ENUM) {
        const int k = cs_param_choice(p, text);
        if (k < 0) {
            snprintf(why, why_len, "%s: unknown choice '%s'", p->name, text);
            return -1;
        }
        v[0] = k;
    } else if (p->type == CS_T_BOOL) {
        if (parse_bool(text, &v[0]) != 0) {
            snprintf(why, why_len, "%s must be true or false (got '%s')", p->name, text);
            return -1;
        }
    } else if (p->type == CS_T_VEC3) {
        char buf[256];
        if (strlen(text) >= sizeof buf) { /* cut, its tail would go unread: "1,2,3<spaces>,4" */
            snprintf(why, why_len, "%s must be three numbers 'x,y,z' (got %zu characters)", p->name, strlen(text));
            return -1;
        }
        snprintf(buf, sizeof buf, "%s", text);
        char *save = NULL, *tok = strtok_r(buf, ",", &save);
        int k = 0;
        for (; tok && k < 3; k++, tok = strtok_r(NULL, ",", &save))
            if (parse_number(tok, &v[k]) != 0) break;
        if (k != 3 || tok) {
            snprintf(why, why_len, "%s must be three numbers 'x,y,z' (got '%s')", p->name, text);
            return -1;
        }
    } else if (parse_number(text, &v[0]) != 0) {
        snprintf(why, why_len, "%s must be a number (got '%s')", p->name, text);
        return -1;
    }
    if (cs_param_set(p, CS_PARAM_BASE(p, &c->scene, &c->params), v, why, why_len) != 0) return -1;
    if (strcmp(p->name, "nx") == 0 || strcmp(p->name, "ny") == 0) c->scene_size_given = 1;
    return 0;
}

int settings_set_text(clothd_config *c, const char *name, const char *text, char *why, size_t why_len)
{
    char key[128];
    snprintf(key, sizeof key, "%s", name);
    for (char *k = key; *k; k++) *k = *k == '-' ? '_' : (char)tolower((unsigned char)*k);
    const srow *r = find_row(key);
    if (r) return set_startup(c, r, text, why, why_len);
    const cs_param_info *p = cs_param_find(key);
    if (p) return set_engine(c, p, text, why, why_len);
    snprintf(why, why_len, "unknown setting '%s' (clothd --help lists them)", name);
    return -1;
}

static char *trim(char *s)
{
    while (isspace((unsigned char)*s)) s++;
    char *e = s + strlen(s);
    while (e > s && isspace((unsigned char)e[-1])) *--e = '\0';
    return s;
}

int settings_parse_config(clothd_config *c, const char *text, size_t len, const char *name, char *why,
                          size_t why_len)
{
    /* One NUL-terminated copy to cut into lines in place: a line may be of any length. */
    char *copy = malloc(len + 1);
    if (!copy) {
        snprintf(why, why_len, "%s: out of memory", name);
        return -1;
    }
    if (len) memcpy(copy, text, len);
    copy[len] = '\0';
    char inner[512];
    int lineno = 0, rc = 0;
    for (char *line = copy, *end = copy + len; rc == 0 && line < end;) {
        char *nl = memchr(line, '\n', (size_t)(end - line));
        char *next = nl ? nl + 1 : end;
        if (nl) *nl = '\0';
        lineno++;
        if (strlen(line) != (size_t)((nl ? nl : end) - line)) {
            snprintf(why, why_len, "%s:%d: holds a NUL byte", name, lineno);
            rc = -1;
            break;
        }
        line[strcspn(line, "#")] = '\0';
        char *s = trim(line);
        line = next;
        if (!*s) continue;
        char *eq = strchr(s, '=');
        if (!eq) {
            snprintf(why, why_len, "%s:%d: expected 'name = value'", name, lineno);
            rc = -1;
            break;
        }
        *eq = '\0';
        if (settings_set_text(c, trim(s), trim(eq + 1), inner, sizeof inner) != 0) {
            snprintf(why, why_len, "%s:%d: %s", name, lineno, inner);
            rc = -1;
        }
    }
    free(copy);
    return rc;
}

static int load_file(clothd_config *c, const char *path, char *why, size_t why_len)
{
    FILE *f = fopen(path, "r");
    if (!f) {
        snprintf(why, why_len, "config file %s: %s", path, strerror(errno));
        return -1;
    }
    /* Read whole (up to a bound no config file comes near), then parsed as text. */
    char *text = malloc(CONFIG_MAX_BYTES + 1);
    const size_t len = text ? fread(text, 1, CONFIG_MAX_BYTES + 1, f) : 0;
    const int bad = !text || ferror(f);
    fclose(f);
    int rc = -1;
    if (bad) snprintf(why, why_len, "config file %s: could not read it", path);
    else if (len > CONFIG_MAX_BYTES) snprintf(why, why_len, "config file %s: larger than %d bytes", path, CONFIG_MAX_BYTES);
    else rc = settings_parse_config(c, text, len, path, why, why_len);
    free(text);
    return rc;
}

/* What a command-line name is: -1 unknown, 1 a boolean (may go without a value), 0 other. */
static int kind_of(const char *name)
{
    char key[128];
    snprintf(key, sizeof key, "%s", name);
    for (char *k = key; *k; k++) *k = *k == '-' ? '_' : *k;
    const srow *r = find_row(key);
    if (r) return r->type == T_BOOL;
    const cs_param_info *p = cs_param_find(key);
    return p ? p->type == CS_T_BOOL : -1;
}

int settings_load(clothd_config *c, int argc, char **argv, char **env, char *why, size_t why_len)
{
    const char *config = NULL;
    for (char **e = env; e && *e; e++)
        if (strncmp(*e, "CLOTHD_CONFIG=", 14) == 0) config = *e + 14;
    for (int i = 0; i < argc; i++) {
        if (strcmp(argv[i], "--config") == 0 && i + 1 < argc) config = argv[i + 1];
        else if (strncmp(argv[i], "--config=", 9) == 0) config = argv[i] + 9;
    }
    if (config && *config) {
        if (load_file(c, config, why, why_len) != 0) return -1;
        snprintf(c->set.config, sizeof c->set.config, "%s", config);
    }
    char inner[512];
    for (char **e = env; e && *e; e++) {
        if (strncmp(*e, "CLOTHD_", 7) != 0) continue;
        const char *eq = strchr(*e, '=');
        if (!eq) continue;
        char name[128];
        const size_t len = (size_t)(eq - (*e + 7));
        if (len == 0 || len >= sizeof name) continue;
        memcpy(name, *e + 7, len);
        name[len] = '\0';
        if (strcmp(name, "CONFIG") == 0) continue;
#ifdef CLOTHD_TEST_HOOKS
        if (strncmp(name, "TEST_", 5) == 0) continue; /* the test daemon's hooks (testhooks.h) */
#endif
        char key[128];
        snprintf(key, sizeof key, "%s", name);
        for (char *k = key; *k; k++) *k = (char)tolower((unsigned char)*k);
        if (!find_row(key) && !cs_param_find(key)) {
            /* Not ours (another tool's variable, or a typo): said, not fatal. */
            fprintf(stderr, "clothd: ignoring environment variable CLOTHD_%s: no such setting\n", name);
            continue;
        }
        if (settings_set_text(c, name, eq + 1, inner, sizeof inner) != 0) {
            snprintf(why, why_len, "environment CLOTHD_%s: %s", name, inner);
            return -1;
        }
    }
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        if (strncmp(a, "--", 2) != 0 || !a[2]) {
            snprintf(why, why_len, "unexpected argument '%s'", a);
            return -1;
        }
        char name[128];
        const char *value;
        const char *eq = strchr(a, '=');
        if (eq) {
            snprintf(name, sizeof name, "%.*s", (int)(eq - a - 2), a + 2);
            value = eq + 1;
        } else {
            snprintf(name, sizeof name, "%s", a + 2);
            const int kind = kind_of(name);
            if (kind < 0) {
                snprintf(why, why_len, "unknown setting '%s' (clothd --help lists them)", name);
                return -1;
            }
            if (i + 1 < argc && strncmp(argv[i + 1], "--", 2) != 0) value = argv[++i];
            else if (kind == 1) value = "true";
            else {
                snprintf(why, why_len, "--%s needs a value", name);
                return -1;
            }
        }
        if (settings_set_text(c, name, value, inner, sizeof inner) != 0) {
            snprintf(why, why_len, "--%s: %s", name, inner);
            return -1;
        }
    }
    return 0;
}

void settings_usage(FILE *out)
{
    fprintf(out, "Startup settings (flag, CLOTHD_<NAME> variable, or 'name = value' in the config file):\n");
    for (size_t i = 0; i < NROWS; i++) {
        const setting_info *s = &rows[i].info;
        char flag[64];
        snprintf(flag, sizeof flag, "--%s", s->name);
        for (char *k = flag + 2; *k; k++) *k = *k == '_' ? '-' : *k;
        if (s->choices) fprintf(out, "  %-22s %s (%s)\n", flag, s->help, s->choices);
        else fprintf(out, "  %-22s %s\n", flag, s->help);
    }
    fprintf(out, "\nEngine parameters, the same ways (see GET /v1/params/schema):\n");
    for (size_t i = 0; i < cs_param_count(); i++) {
        const cs_param_info *p = cs_param_at(i);
        char flag[64];
        snprintf(flag, sizeof flag, "--%s", p->name);
        for (char *k = flag + 2; *k; k++) *k = *k == '_' ? '-' : *k;
        fprintf(out, "  %-22s %s [%s, %s]\n", flag, p->help, p->unit, cs_param_kind_name(p->kind));
    }
}

/* The startup settings as a Markdown table, for README's "Configuration" section (a test diffs the
 * two). The web_root default is the build tree's own path, so it is named, not printed. Help texts
 * are escaped for a table cell (| < >). */
static void md_text(FILE *out, const char *s)
{
    for (; *s; s++) {
        if (*s == '|') fputs("\\|", out);
        else if (*s == '<') fputs("&lt;", out);
        else if (*s == '>') fputs("&gt;", out);
        else fputc(*s, out);
    }
}

void settings_markdown(FILE *out)
{
    fprintf(out, "| setting | flag, variable | default | range | meaning |\n|---|---|---|---|---|\n");
    for (size_t i = 0; i < NROWS; i++) {
        const srow *r = &rows[i];
        const setting_info *s = &r->info;
        char flag[64], var[64];
        snprintf(flag, sizeof flag, "--%s", s->name);
        for (char *k = flag + 2; *k; k++) *k = *k == '_' ? '-' : *k;
        snprintf(var, sizeof var, "CLOTHD_%s", s->name);
        for (char *k = var + 7; *k; k++) *k = (char)toupper((unsigned char)*k);
        fprintf(out, "| `%s` | `%s`, `%s` | ", s->name, flag, var);
        switch (r->type) {
        case T_STR:
            if (strcmp(s->name, "web_root") == 0) fprintf(out, "the build's `web/`");
            else if (s->def_text[0]) fprintf(out, "`%s`", s->def_text);
            else fprintf(out, "-");
            fprintf(out, " | - | ");
            break;
        case T_INT: fprintf(out, "%.0f | %.0f .. %.0f | ", s->def_number, s->min, s->max); break;
        case T_BOOL: fprintf(out, "%s | true, false | ", s->def_number != 0 ? "true" : "false"); break;
        case T_ENUM: {
            const char *c = s->choices;
            for (int k = 0; k < (int)s->def_number && strchr(c, '|'); k++) c = strchr(c, '|') + 1;
            fprintf(out, "%.*s | ", (int)(strchr(c, '|') ? (size_t)(strchr(c, '|') - c) : strlen(c)), c);
            for (c = s->choices; *c; c++) {
                if (*c == '|') fputs(", ", out);
                else fputc(*c, out);
            }
            fprintf(out, " | ");
            break;
        }
        }
        md_text(out, s->help);
        fprintf(out, " |\n");
    }
}
