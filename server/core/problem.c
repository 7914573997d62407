/* problem.c - RFC 9457 problems (see problem.h). */
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "core/json_write.h"
#include "core/problem.h"

static const struct {
    const char *slug, *title;
} titles[] = {
    {"invalid-json", "Malformed JSON"},
    {"unknown-field", "Unknown field"},
    {"wrong-type", "Wrong type"},
    {"out-of-range", "Value out of range"},
    {"unstable", "Change would be unstable"},
    {"limit", "Limit reached"},
    {"not-found", "Not found"},
    {"method-not-allowed", "Method not allowed"},
    {"wrong-state", "Wrong state"},
    {"too-large", "Request body too large"},
    {"bad-snapshot", "Bad snapshot"},
    {"unavailable", "Service unavailable"},
    {"busy", "Too busy"},
    {"internal", "Internal error"},
    {"unauthorized", "Unauthorized"},
    {"forbidden", "Forbidden"},
    {"rate-limited", "Too many requests"},
    {"host-not-allowed", "Host not allowed"},
    {"cross-site", "Cross-site request refused"},
    {"bad-request", "Malformed request"},
    {"uri-too-long", "Request target too long"},
    {"not-implemented", "Not implemented"},
    {"too-many-clients", "Too many clients"},
    {"upgrade-required", "Upgrade required"},
};

const char *problem_title(const char *slug)
{
    for (size_t i = 0; i < sizeof titles / sizeof titles[0]; i++)
        if (strcmp(titles[i].slug, slug) == 0) return titles[i].title;
    return "Error";
}

int problem_set(problem *pr, int status, const char *slug, const char *param, const char *fmt, ...)
{
    pr->status = status;
    pr->slug = slug;
    snprintf(pr->param, sizeof pr->param, "%s", param ? param : "");
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(pr->detail, sizeof pr->detail, fmt, ap);
    va_end(ap);
    return -1;
}

char *problem_body(const problem *pr)
{
    char type[96];
    snprintf(type, sizeof type, "urn:clothd:problem:%s", pr->slug);
    json_t *o = json_pack("{s:s, s:s, s:i, s:o}", "type", type, "title", problem_title(pr->slug), "status",
                          pr->status, "detail", json_text(pr->detail));
    if (pr->param[0]) json_object_set_new(o, "param", json_text(pr->param));
    char *s = json_dumps(o, JSON_DUMP_FLAGS);
    json_decref(o);
    return s;
}

int problem_from_engine(problem *pr, cs_status st, const char *error, const char *param)
{
    switch (st) {
    case CS_E_NOT_FOUND: return problem_set(pr, 404, "not-found", param, "%s", error);
    case CS_E_UNSTABLE: return problem_set(pr, 422, "unstable", param, "%s", error);
    case CS_E_LIMIT: return problem_set(pr, 422, "limit", param, "%s", error);
    case CS_E_INVALID:
    case CS_E_RANGE: return problem_set(pr, 422, "out-of-range", param, "%s", error);
    case CS_E_FORMAT:
    case CS_E_VERSION: return problem_set(pr, 400, "bad-snapshot", param, "%s", error);
    case CS_E_BACKEND:
    case CS_E_DEVICE: return problem_set(pr, 503, "unavailable", param, "%s", error);
    default: return problem_set(pr, 500, "internal", param, "%s", error);
    }
}

