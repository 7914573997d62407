/* static_files.h - the viewer's static files at /, from web_root: a file under it, or the
 * placeholder page at / when the viewer is not built. A path may not leave web_root: no '..'
 * segment, no backslash or NUL, and the resolved real path (links followed) must lie under it. */
#ifndef CLOTHD_STATIC_FILES_H
#define CLOTHD_STATIC_FILES_H

#include <microhttpd.h>

/* The answer for url (with its Content-Type; *status 200), or NULL for 404. web_root is resolved
 * (realpath), or empty when the directory does not exist. */
struct MHD_Response *static_file(const char *web_root, const char *url, int *status);

#endif
