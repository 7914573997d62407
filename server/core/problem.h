/* problem.h - an error as the API answers it: an RFC 9457 problem (application/problem+json)
 * with the HTTP status, a type slug (urn:clothd:problem:<slug>), a title, the detail, and the
 * offending parameter when there is one; and the mapping of the engine's statuses to them. */
#ifndef CLOTHD_PROBLEM_H
#define CLOTHD_PROBLEM_H

#include "clothsim/clothsim.h"

typedef struct problem {
    int status;
    const char *slug;
    char detail[300];
    char param[64];
} problem;

/* Fills a problem and returns -1 (for `return problem_set(...)`). */
int problem_set(problem *pr, int status, const char *slug, const char *param, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 5, 6)))
#endif
    ;
/* The title of a slug ("Malformed JSON" for invalid-json, ...; "Error" for one it does not know). */
const char *problem_title(const char *slug);
/* The problem+json body (malloc'd). */
char *problem_body(const problem *pr);
/* The problem for a refused engine call (its status, error text and parameter). */
int problem_from_engine(problem *pr, cs_status st, const char *error, const char *param);

#endif
