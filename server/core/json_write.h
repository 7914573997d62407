/* json_write.h - writing the API's JSON: floats as the shortest text that reads back the same,
 * client text that jansson would refuse made safe, and the dump flags every answer uses. */
#ifndef CLOTHD_JSON_WRITE_H
#define CLOTHD_JSON_WRITE_H

#include <jansson.h>

/* Floats print with 9 significant digits: enough to round-trip a float32, and short. */
#define JSON_DUMP_FLAGS (JSON_COMPACT | JSON_REAL_PRECISION(9))

/* A JSON string of s without the bytes that are not part of well-formed UTF-8 (jansson refuses
 * the whole string otherwise). Texts that quote a client's input are cut to a fixed size (a
 * problem's detail and param, "%.64s"), and a cut may fall inside a character. NULL only when
 * out of memory. */
json_t *json_text(const char *s);

/* A float as the shortest decimal that reads back as the same float (9.81f is 9.81, not
 * 9.81000042). */
json_t *json_float(float f);

#endif
