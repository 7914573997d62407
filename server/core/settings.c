/* settings.c - the one settings table (see settings.h) and setting any row from text: config file
 * lines, CLOTHD_* variables, command-line flags. */
#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "clothsim/clothsim.h"
#include "core/settings.h"

static const char *const ch_BACKEND[] = {CLOTHD_CHOICES_BACKEND, NULL};
static const char *const ch_STATE_FILE_INVALID[] = {CLOTHD_CHOICES_STATE_FILE_INVALID, NULL};
static const char *const ch_LOG_FORMAT[] = {CLOTHD_CHOICES_LOG_FORMAT, NULL};
static const char *const ch_LOG_LEVEL[] = {CLOTHD_CHOICES_LOG_LEVEL, NULL};
#define CH_NONE NULL
#define CH_BACKEND ch_BACKEND
#define CH_STATE_FILE_INVALID ch_STATE_FILE_INVALID
#define CH_LOG_FORMAT ch_LOG_FORMAT
#define CH_LOG_LEVEL ch_LOG_LEVEL

#define STARTUP_ROW_OF(name, type, unit, def_number, def_text, lo, hi, ch, help)                      \
    {#name, type, unit, {def_number, 0, 0}, def_text, lo, hi, CH_##ch, SET_STARTUP, help, IN_SETTINGS,     \
     offsetof(clothd_settings, name)},
#define STARTUP_ROW_STR(name, unit, def, lo, hi, ch, help) STARTUP_ROW_OF(name, SET_STR, unit, 0, def, lo, hi, ch, help)
#define STARTUP_ROW_INT(name, unit, def, lo, hi, ch, help) STARTUP_ROW_OF(name, SET_INT, unit, def, NULL, lo, hi, ch, help)
#define STARTUP_ROW_FLOAT(name, unit, def, lo, hi, ch, help) STARTUP_ROW_OF(name, SET_FLOAT, unit, def, NULL, lo, hi, ch, help)
#define STARTUP_ROW_BOOL(name, unit, def, lo, hi, ch, help) STARTUP_ROW_OF(name, SET_BOOL, unit, def, NULL, lo, hi, ch, help)
#define STARTUP_ROW_ENUM(name, unit, def, lo, hi, ch, help) STARTUP_ROW_OF(name, SET_ENUM, unit, def, NULL, lo, hi, ch, help)
#define STARTUP_ROW(name, type, unit, def, lo, hi, ch, help) STARTUP_ROW_##type(name, unit, def, lo, hi, ch, help)

static const setting startup_rows[] = {CLOTHD_SETTINGS(STARTUP_ROW)};
#define N_STARTUP (sizeof startup_rows / sizeof startup_rows[0])

#define LOOP_DEF_INT(d) {(double)(d), 0, 0}
#define LOOP_DEF_FLOAT(d) {(double)(d), 0, 0}
#define LOOP_DEF_BOOL(d) {(double)(d), 0, 0}
#define LOOP_ROW(name, type, unit, def, lo, hi, ch, help)                                              \
    {#name, SET_##type, unit, LOOP_DEF_##type(def), NULL, lo, hi, CH_##ch, SET_LIVE, help, IN_LOOP,        \
     offsetof(loop_settings, name)},
static const setting loop_rows[] = {CLOTHD_LOOP_SETTINGS(LOOP_ROW)};
#define N_LOOP (sizeof loop_rows / sizeof loop_rows[0])

/* The engine's rows (read from its table at first use), then the daemon's: loop, startup. */
static setting rows[256];
static size_t n_rows;
static pthread_once_t rows_once = PTHREAD_ONCE_INIT;

static void build_rows(void)
{
    for (size_t i = 0; i < cs_param_count() && n_rows < sizeof rows / sizeof rows[0]; i++) {
        const cs_param_info *p = cs_param_at(i);
        const int scene = p->kind == CS_KIND_SCENE;
        rows[n_rows++] = (setting){p->name, (setting_type)p->type, p->unit, {p->def[0], p->def[1], p->def[2]}, NULL,
                                   p->min, p->max, p->choices, scene ? SET_SCENE : SET_LIVE, p->help,
                                   scene ? IN_FIELDS : IN_PARAMS, p->offset};
    }
    for (size_t i = 0; i < N_LOOP && n_rows < sizeof rows / sizeof rows[0]; i++) rows[n_rows++] = loop_rows[i];
    for (size_t i = 0; i < N_STARTUP && n_rows < sizeof rows / sizeof rows[0]; i++) rows[n_rows++] = startup_rows[i];
}

size_t settings_count(void)
{
    pthread_once(&rows_once, build_rows);
    return n_rows;
}

const setting *settings_at(size_t i) { return i < settings_count() ? &rows[i] : NULL; }

const setting *settings_find(const char *name)
{
    for (size_t i = 0; name && i < settings_count(); i++)
        if (strcmp(rows[i].name, name) == 0) return &rows[i];
    return NULL;
}

const char *setting_type_name(setting_type t) { return t == SET_STR ? "string" : cs_param_type_name((cs_param_type)t); }

const char *setting_kind_name(setting_kind k)
{
    static const char *const names[] = {"scene", "live", "startup"};
    return (unsigned)k < 3 ? names[k] : "?";
}

void *setting_field(const setting *s, clothd_settings *set, scene_config *scene)
{
    switch (s->home) {
    case IN_SETTINGS: return set ? (char *)set + s->offset : NULL;
    case IN_FIELDS: return scene ? (char *)&scene->fields + s->offset : NULL;
    case IN_PARAMS: return scene ? (char *)&scene->params + s->offset : NULL;
    case IN_LOOP: return scene ? (char *)&scene->loop + s->offset : NULL;
    }
    return NULL;
}

/* A number row as the engine's table describes one, at offset 0 of its field: the engine's own
 * reads, checks and writes then serve every number row. */
static cs_param_info engine_view(const setting *s)
{
    cs_param_info p = {s->name, (cs_param_type)s->type, s->unit, {s->def[0], s->def[1], s->def[2]}, s->min, s->max,
                       s->choices, s->kind == SET_SCENE ? CS_KIND_SCENE : CS_KIND_LIVE, s->help, 0};
    return p;
}

double setting_get(const setting *s, const void *field, int i)
{
    const cs_param_info p = engine_view(s);
    return cs_param_get(&p, field, i);
}

int setting_set(const setting *s, void *field, const double *v, char *why, size_t why_len)
{
    const cs_param_info p = engine_view(s);
    return cs_param_set(&p, field, v, why, why_len);
}

int setting_choice(const setting *s, const char *name)
{
    for (int k = 0; s->choices && name && s->choices[k]; k++)
        if (strcmp(s->choices[k], name) == 0) return k;
    return -1;
}

int loop_from_snapshot(loop_settings *loop, const void *snapshot, size_t len)
{
    int found = 0;
    char why[8];
    for (size_t i = 0; i < settings_count(); i++) {
        const setting *s = &rows[i];
        double v[3];
        if (s->home != IN_LOOP || cs_snapshot_value(snapshot, len, s->name, v) != CS_OK) continue;
        found += setting_set(s, (char *)loop + s->offset, v, why, sizeof why) == 0;
    }
    return found;
}

/* "a|b|c", the way --help and the errors name an enum's choices. */
static void choice_list(const setting *s, const char *sep, char *out, size_t cap)
{
    out[0] = '\0';
    for (int k = 0; s->choices && s->choices[k]; k++)
        snprintf(out + strlen(out), cap - strlen(out), "%s%s", k ? sep : "", s->choices[k]);
}

void settings_default(clothd_config *c)
{
    memset(c, 0, sizeof *c);
    char why[8];
    for (size_t i = 0; i < settings_count(); i++) {
        const setting *s = &rows[i];
        void *field = setting_field(s, &c->set, &c->scene);
        if (s->type == SET_STR) snprintf(field, SETTING_TEXT_MAX, "%s", s->def_text);
        else setting_set(s, field, s->def, why, sizeof why);
    }
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

/* "x,y,z" into v[0..3); the whole text is read (a long one is refused, not cut). */
static int parse_vec3(const char *text, double v[3])
{
    char buf[256];
    if (strlen(text) >= sizeof buf) return -1; /* cut, its tail would go unread: "1,2,3<spaces>,4" */
    snprintf(buf, sizeof buf, "%s", text);
    char *save = NULL, *tok = strtok_r(buf, ",", &save);
    int k = 0;
    for (; tok && k < 3; k++, tok = strtok_r(NULL, ",", &save))
        if (parse_number(tok, &v[k]) != 0) return -1;
    return k == 3 && !tok ? 0 : -1;
}

/* One row from its text form, into its field. */
static int set_from_text(const setting *s, void *field, const char *text, char *why, size_t why_len)
{
    double v[3] = {0, 0, 0};
    char list[160];
    switch (s->type) {
    case SET_STR:
        if (strlen(text) >= SETTING_TEXT_MAX) {
            snprintf(why, why_len, "%s is longer than %d characters", s->name, SETTING_TEXT_MAX - 1);
            return -1;
        }
        snprintf(field, SETTING_TEXT_MAX, "%s", text);
        return 0;
    case SET_ENUM:
        if ((v[0] = setting_choice(s, text)) < 0) {
            choice_list(s, "|", list, sizeof list);
            snprintf(why, why_len, "%s must be one of %s (got '%s')", s->name, list, text);
            return -1;
        }
        break;
    case SET_BOOL:
        if (parse_bool(text, &v[0]) != 0) {
            snprintf(why, why_len, "%s must be true or false (got '%s')", s->name, text);
            return -1;
        }
        break;
    case SET_INT:
        if (parse_number(text, &v[0]) != 0 || setting_set(s, field, v, why, why_len) != 0) {
            snprintf(why, why_len, "%s must be a whole number from %g to %g (got '%s')", s->name, s->min, s->max, text);
            return -1;
        }
        return 0;
    case SET_VEC3:
        if (parse_vec3(text, v) != 0) {
            if (strlen(text) >= 256) snprintf(why, why_len, "%s must be three numbers 'x,y,z' (got %zu characters)", s->name, strlen(text));
            else snprintf(why, why_len, "%s must be three numbers 'x,y,z' (got '%s')", s->name, text);
            return -1;
        }
        break;
    case SET_FLOAT:
        if (parse_number(text, &v[0]) != 0) {
            snprintf(why, why_len, "%s must be a number (got '%s')", s->name, text);
            return -1;
        }
        break;
    }
    return setting_set(s, field, v, why, why_len);
}

/* A name as the table spells it: dashes as underscores, lowercase. */
static void table_name(const char *name, char *key, size_t cap)
{
    snprintf(key, cap, "%s", name);
    for (char *k = key; *k; k++) *k = *k == '-' ? '_' : (char)tolower((unsigned char)*k);
}

int settings_set_text(clothd_config *c, const char *name, const char *text, char *why, size_t why_len)
{
    char key[128];
    table_name(name, key, sizeof key);
    const setting *s = settings_find(key);
    if (!s) {
        snprintf(why, why_len, "unknown setting '%s' (clothd --help lists them)", name);
        return -1;
    }
    if (set_from_text(s, setting_field(s, &c->set, &c->scene), text, why, why_len) != 0) return -1;
    if (strcmp(s->name, "nx") == 0 || strcmp(s->name, "ny") == 0) c->scene_size_given = 1;
    if (strcmp(s->name, "integrator") == 0) c->integrator_given = 1;
    return 0;
}

int settings_backend_defaults(clothd_config *cfg, const char *backend)
{
    cs_scene *f = &cfg->scene.fields;
    cs_params *p = &cfg->scene.params;
    const cs_integrator integrator = cs_params_default_integrator(backend);
    int changed = 0;
    if (strcmp(backend, "cuda") == 0 && !cfg->scene_size_given && (f->nx != 256 || f->ny != 256))
        f->nx = f->ny = 256, changed = 1;
    if (!cfg->integrator_given && p->integrator != (int32_t)integrator) p->integrator = integrator, changed = 1;
    return changed;
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

int settings_load(clothd_config *c, int argc, char **argv, char **env, const char *skip, char *why, size_t why_len)
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
    char inner[512], key[128];
    for (char **e = env; e && *e; e++) {
        if (strncmp(*e, "CLOTHD_", 7) != 0) continue;
        const char *eq = strchr(*e, '=');
        if (!eq) continue;
        char name[128];
        const size_t len = (size_t)(eq - (*e + 7));
        if (len == 0 || len >= sizeof name) continue;
        memcpy(name, *e + 7, len);
        name[len] = '\0';
        if (strcmp(name, "CONFIG") == 0 || (skip && strncmp(name, skip, strlen(skip)) == 0)) continue;
        table_name(name, key, sizeof key);
        if (!settings_find(key)) {
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
            table_name(name, key, sizeof key);
            const setting *s = settings_find(key);
            if (!s) {
                snprintf(why, why_len, "unknown setting '%s' (clothd --help lists them)", name);
                return -1;
            }
            if (i + 1 < argc && strncmp(argv[i + 1], "--", 2) != 0) value = argv[++i];
            else if (s->type == SET_BOOL) value = "true";
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

/* "--name" and "CLOTHD_NAME" of a row. */
static void flag_of(const setting *s, char *out, size_t cap)
{
    snprintf(out, cap, "--%s", s->name);
    for (char *k = out + 2; *k; k++) *k = *k == '_' ? '-' : *k;
}

void settings_usage(FILE *out)
{
    static const char *const headings[] = {
        [SET_SCENE] = "Scene fields (changing one rebuilds the cloth; PUT /v1/scene)",
        [SET_LIVE] = "Live parameters (PATCH /v1/params)",
        [SET_STARTUP] = "Startup settings",
    };
    fprintf(out, "Every row below is a flag, a CLOTHD_<NAME> variable and a 'name = value' line of the config\n"
                 "file alike (GET /v1/params/schema lists the same table).\n");
    for (size_t i = 0; i < settings_count(); i++) {
        const setting *s = &rows[i];
        if (i == 0 || rows[i - 1].kind != s->kind) fprintf(out, "\n%s:\n", headings[s->kind]);
        char flag[64], list[160];
        flag_of(s, flag, sizeof flag);
        choice_list(s, "|", list, sizeof list);
        if (s->kind != SET_STARTUP) fprintf(out, "  %-22s %s [%s]\n", flag, s->help, s->unit);
        else if (s->choices) fprintf(out, "  %-22s %s (%s)\n", flag, s->help, list);
        else fprintf(out, "  %-22s %s\n", flag, s->help);
    }
}

/* The startup settings as a Markdown table, for docs/operating.md's "Configuration" section (a
 * test diffs the two). The web_root default is the build tree's own path, so it is named, not printed. Help texts
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
    for (size_t i = 0; i < settings_count(); i++) {
        const setting *s = &rows[i];
        if (s->kind != SET_STARTUP) continue;
        char flag[64], var[64], list[160];
        flag_of(s, flag, sizeof flag);
        snprintf(var, sizeof var, "CLOTHD_%s", s->name);
        for (char *k = var + 7; *k; k++) *k = (char)toupper((unsigned char)*k);
        fprintf(out, "| `%s` | `%s`, `%s` | ", s->name, flag, var);
        switch (s->type) {
        case SET_STR:
            if (strcmp(s->name, "web_root") == 0) fprintf(out, "the build's `web/`");
            else if (s->def_text[0]) fprintf(out, "`%s`", s->def_text);
            else fprintf(out, "-");
            fprintf(out, " | - | ");
            break;
        case SET_BOOL: fprintf(out, "%s | true, false | ", s->def[0] != 0 ? "true" : "false"); break;
        case SET_ENUM:
            choice_list(s, ", ", list, sizeof list);
            fprintf(out, "%s | %s | ", s->choices[(int)s->def[0]], list);
            break;
        case SET_FLOAT: fprintf(out, "%g | %g .. %g %s | ", s->def[0], s->min, s->max, s->unit); break;
        default: fprintf(out, "%.0f | %.0f .. %.0f | ", s->def[0], s->min, s->max); break;
        }
        md_text(out, s->help);
        fprintf(out, " |\n");
    }
}
