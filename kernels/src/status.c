/* status.c - status names and messages, and how a refused call records its reason. */
#include <stdarg.h>
#include <stdio.h>

#include "sim_internal.h"

static const struct {
    cs_status st;
    const char *name, *message;
} cs_statuses[] = {
    {CS_OK, "ok", "success"},
    {CS_E_INVALID, "invalid", "an argument is malformed (missing, not finite or of the wrong size)"},
    {CS_E_RANGE, "range", "a value is outside its allowed range"},
    {CS_E_NOT_FOUND, "not_found", "no rock has that id"},
    {CS_E_UNSTABLE, "unstable", "the change would make the simulation unstable"},
    {CS_E_LIMIT, "limit", "a size limit would be exceeded"},
    {CS_E_NOMEM, "nomem", "out of memory"},
    {CS_E_NONFINITE, "nonfinite", "the state holds a NaN or an infinity"},
    {CS_E_FORMAT, "format", "the snapshot is truncated, corrupted or not a snapshot"},
    {CS_E_VERSION, "version", "the snapshot was written by another format version"},
    {CS_E_BACKEND, "backend", "the backend is unavailable or failed"},
    {CS_E_DEVICE, "device", "the device failed and its state is lost"},
    {CS_E_OVERLAP, "overlap", "a rock would overlap another rock or the cloth"},
};

static int find(cs_status st)
{
    for (size_t i = 0; i < sizeof cs_statuses / sizeof cs_statuses[0]; i++)
        if (cs_statuses[i].st == st) return (int)i;
    return -1;
}

const char *cs_status_name(cs_status st)
{
    const int i = find(st);
    return i < 0 ? "unknown" : cs_statuses[i].name;
}

const char *cs_status_message(cs_status st)
{
    const int i = find(st);
    return i < 0 ? "unknown status" : cs_statuses[i].message;
}

cs_status cs_fail(cs_sim *sim, cs_status st, const char *param, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(sim->err, sizeof sim->err, fmt, ap);
    va_end(ap);
    sim->err_param = param ? param : "";
    return st;
}

void cs_ok(cs_sim *sim)
{
    sim->err[0] = '\0';
    sim->err_param = "";
}
