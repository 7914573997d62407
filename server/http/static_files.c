/* static_files.c - the viewer's files (see static_files.h). */
#include <fcntl.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "http/static_files.h"

static const char *content_type(const char *path)
{
    static const struct {
        const char *ext, *type;
    } types[] = {{".html", "text/html; charset=utf-8"}, {".js", "text/javascript; charset=utf-8"},
                 {".mjs", "text/javascript; charset=utf-8"}, {".css", "text/css; charset=utf-8"},
                 {".json", "application/json"}, {".map", "application/json"}, {".svg", "image/svg+xml"},
                 {".png", "image/png"}, {".ico", "image/x-icon"}, {".wasm", "application/wasm"},
                 {".txt", "text/plain; charset=utf-8"}};
    const char *dot = strrchr(path, '.');
    for (size_t i = 0; dot && i < sizeof types / sizeof types[0]; i++)
        if (strcmp(dot, types[i].ext) == 0) return types[i].type;
    return "application/octet-stream";
}

static const char placeholder[] =
    "<!doctype html><meta charset=utf-8><title>clothd</title>"
    "<h1>clothd is running</h1><p>The viewer is not built yet. The API is at <a href=/v1/sim>/v1/sim</a>; "
    "see proto/PROTOCOL.md.</p>\n";

struct MHD_Response *static_file(const char *web_root, const char *url, int *status)
{
    const char *path = strcmp(url, "/") == 0 ? "/index.html" : url;
    int safe = path[0] == '/' && !strchr(path, '\\') && strlen(path) < 400;
    for (const char *p = path; safe && (p = strstr(p, "..")); p += 2)
        if ((p == path || p[-1] == '/') && (p[2] == '/' || p[2] == '\0')) safe = 0;
    if (safe && web_root[0]) {
        char full[PATH_MAX + 512], real[PATH_MAX];
        snprintf(full, sizeof full, "%s%s", web_root, path);
        const size_t rl = strlen(web_root);
        if (realpath(full, real) && strncmp(real, web_root, rl) == 0 && real[rl] == '/') {
            const int fd = open(real, O_RDONLY | O_CLOEXEC);
            struct stat st;
            if (fd >= 0 && fstat(fd, &st) == 0 && S_ISREG(st.st_mode)) {
                struct MHD_Response *resp = MHD_create_response_from_fd((uint64_t)st.st_size, fd);
                if (resp) {
                    MHD_add_response_header(resp, MHD_HTTP_HEADER_CONTENT_TYPE, content_type(real));
                    *status = 200;
                    return resp;
                }
            }
            if (fd >= 0) close(fd);
        }
    }
    if (safe && strcmp(path, "/index.html") == 0) {
        struct MHD_Response *resp =
            MHD_create_response_from_buffer(sizeof placeholder - 1, (void *)placeholder, MHD_RESPMEM_PERSISTENT);
        MHD_add_response_header(resp, MHD_HTTP_HEADER_CONTENT_TYPE, "text/html; charset=utf-8");
        *status = 200;
        return resp;
    }
    return NULL;
}
