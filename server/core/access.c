/* access.c - tokens, Host and Origin checks (see access.h). */
#include <arpa/inet.h>
#include <ctype.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>

#include "core/access.h"

#define TOKEN_MIN 16
#define TOKEN_MAX 512

struct access_policy {
    char control[TOKEN_MAX + 1], view[TOKEN_MAX + 1]; /* "" when not set */
    char hosts[512], origins[512];                    /* comma-separated lists */
};

/* Characters a token may hold: those of base64url and hex, which also pass as a WebSocket
 * subprotocol name (the stream takes the token there). */
static int token_char(int c) { return isalnum(c) || c == '-' || c == '_' || c == '.' || c == '~'; }

static int load_token(const char *path, const char *what, char *out, char *err, size_t err_len)
{
    out[0] = '\0';
    if (!path[0]) return 0;
    FILE *f = fopen(path, "rb");
    if (!f) {
        snprintf(err, err_len, "%s %s: %s", what, path, strerror(errno));
        return -1;
    }
    struct stat st;
    if (fstat(fileno(f), &st) == 0 && (st.st_mode & 077))
        fprintf(stderr, "clothd: warning: %s %s is readable by others (chmod 600 it)\n", what, path);
    char buf[TOKEN_MAX + 2];
    const size_t n = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    buf[n] = '\0';
    size_t len = n;
    while (len && isspace((unsigned char)buf[len - 1])) buf[--len] = '\0';
    if (len < TOKEN_MIN || len > TOKEN_MAX) {
        snprintf(err, err_len, "%s %s: a token is %d to %d characters (it has %zu%s); make one with: openssl rand -hex 32",
                 what, path, TOKEN_MIN, TOKEN_MAX, len, n == sizeof buf - 1 ? " or more" : "");
        return -1;
    }
    for (size_t k = 0; k < len; k++) {
        if (!token_char((unsigned char)buf[k])) {
            snprintf(err, err_len, "%s %s: a token holds only letters, digits and - _ . ~ (character %zu is not one)",
                     what, path, k + 1);
            return -1;
        }
    }
    memcpy(out, buf, len + 1);
    return 0;
}

/* 1 loopback, 0 another address, -1 not a numeric address at all. */
static int is_loopback(const char *addr)
{
    unsigned char a[16];
    if (inet_pton(AF_INET, addr, a) == 1) return a[0] == 127;
    if (inet_pton(AF_INET6, addr, a) == 1) {
        static const unsigned char one[16] = {[15] = 1};
        return memcmp(a, one, 16) == 0;
    }
    return -1;
}

access_policy *access_load(const clothd_settings *set, char *err, size_t err_len)
{
    access_policy *p = calloc(1, sizeof *p);
    if (!p) {
        snprintf(err, err_len, "out of memory");
        return NULL;
    }
    if (load_token(set->token_file, "token_file", p->control, err, err_len) != 0 ||
        load_token(set->view_token_file, "view_token_file", p->view, err, err_len) != 0) {
        free(p);
        return NULL;
    }
    if (p->view[0] && !p->control[0]) {
        snprintf(err, err_len, "view_token_file needs token_file too: a view token limits readers only where "
                               "a control token guards the rest");
        free(p);
        return NULL;
    }
    if (p->view[0] && strcmp(p->view, p->control) == 0) {
        snprintf(err, err_len, "the view token and the control token are the same: give them different ones");
        free(p);
        return NULL;
    }
    const int loopback = is_loopback(set->listen);
    if (loopback < 0) {
        snprintf(err, err_len, "listen address '%s': not a numeric IPv4 or IPv6 address (give one, e.g. 127.0.0.1)",
                 set->listen);
        free(p);
        return NULL;
    }
    if (!loopback && !p->control[0] && !set->insecure) {
        snprintf(err, err_len,
                 "refusing to listen on %s without a token: anyone who can reach it could control the "
                 "simulation. Set --token-file FILE (clients then send 'Authorization: Bearer <token>'; make "
                 "one with: openssl rand -hex 32 > FILE), or pass --insecure if this network is yours alone",
                 set->listen);
        free(p);
        return NULL;
    }
    snprintf(p->hosts, sizeof p->hosts, "%s", set->allowed_hosts);
    snprintf(p->origins, sizeof p->origins, "%s", set->allowed_origins);
    return p;
}

void access_free(access_policy *p) { free(p); }

int access_required(const access_policy *p) { return p->control[0] != '\0'; }

/* Equal in a time that depends on the secret's length only, not on where the first difference is. */
static int same_secret(const char *given, const char *secret)
{
    const size_t gl = strlen(given), sl = strlen(secret);
    volatile unsigned char d = (unsigned char)(gl != sl);
    for (size_t k = 0; k < sl; k++) d |= (unsigned char)(secret[k] ^ (k < gl ? given[k] : 0));
    return d == 0;
}

access_level access_token(const access_policy *p, const char *token)
{
    if (!p->control[0]) return ACCESS_CONTROL;
    if (!token || !token[0] || strlen(token) > TOKEN_MAX) return ACCESS_NONE;
    const int control = same_secret(token, p->control);
    const int view = p->view[0] && same_secret(token, p->view);
    return control ? ACCESS_CONTROL : view ? ACCESS_VIEW : ACCESS_NONE;
}

access_level access_bearer(const access_policy *p, const char *authorization)
{
    if (!p->control[0]) return ACCESS_CONTROL;
    if (!authorization || strncasecmp(authorization, "Bearer ", 7) != 0) return ACCESS_NONE;
    const char *t = authorization + 7;
    while (*t == ' ') t++;
    char token[TOKEN_MAX + 1];
    size_t n = strlen(t);
    while (n && t[n - 1] == ' ') n--;
    if (n > TOKEN_MAX) return ACCESS_NONE;
    memcpy(token, t, n);
    token[n] = '\0';
    return access_token(p, token);
}

/* Splits "host", "host:port", "[v6]" or "[v6]:port" into the host (brackets off) and the port (-1
 * when none). 0 when it is not of that shape. */
static int split_host(const char *in, char *host, size_t cap, int *port)
{
    *port = -1;
    const char *end;
    if (in[0] == '[') {
        const char *close = strchr(in, ']');
        if (!close || (size_t)(close - in - 1) >= cap) return 0;
        memcpy(host, in + 1, (size_t)(close - in - 1));
        host[close - in - 1] = '\0';
        end = close + 1;
    } else {
        end = strchr(in, ':');
        if (!end) end = in + strlen(in);
        if ((size_t)(end - in) >= cap || end == in) return 0;
        memcpy(host, in, (size_t)(end - in));
        host[end - in] = '\0';
    }
    if (*end == ':') {
        char *stop;
        const long v = strtol(end + 1, &stop, 10);
        if (stop == end + 1 || *stop || v < 0 || v > 65535) return 0;
        *port = (int)v;
    } else if (*end) {
        return 0;
    }
    return 1;
}

static int in_list(const char *list, const char *item)
{
    for (const char *s = list; *s;) {
        while (*s == ' ' || *s == ',') s++;
        const char *e = s;
        while (*e && *e != ',') e++;
        size_t n = (size_t)(e - s);
        while (n && s[n - 1] == ' ') n--;
        if (n && ((n == 1 && s[0] == '*') || (strlen(item) == n && strncasecmp(s, item, n) == 0))) return 1;
        s = e;
    }
    return 0;
}

static int host_name_ok(const access_policy *p, const char *host)
{
    unsigned char a[16];
    /* An address is no DNS name: a page cannot rebind it to this machine. */
    if (inet_pton(AF_INET, host, a) == 1 || inet_pton(AF_INET6, host, a) == 1) return 1;
    return strcasecmp(host, "localhost") == 0 || in_list(p->hosts, host);
}

int access_host_ok(const access_policy *p, const char *host)
{
    if (!host) return 1;
    char name[256];
    int port;
    return split_host(host, name, sizeof name, &port) && host_name_ok(p, name);
}

int access_origin_listed(const access_policy *p, const char *origin)
{
    return origin && in_list(p->origins, origin);
}

int access_origin_ok(const access_policy *p, const char *origin, const char *host, int http_port)
{
    if (!origin) return 1; /* not a browser: the token (where one is set) decides */
    if (in_list(p->origins, origin)) return 1;
    int default_port;
    const char *rest;
    if (strncasecmp(origin, "http://", 7) == 0) rest = origin + 7, default_port = 80;
    else if (strncasecmp(origin, "https://", 8) == 0) rest = origin + 8, default_port = 443;
    else return 0; /* "null" (a sandboxed or file page) and anything else */
    char oname[256], hname[256];
    int oport, hport;
    if (!host || !split_host(rest, oname, sizeof oname, &oport) || !split_host(host, hname, sizeof hname, &hport))
        return 0;
    if (oport < 0) oport = default_port;
    return strcasecmp(oname, hname) == 0 && host_name_ok(p, hname) && oport == http_port;
}

int access_change_ok(const access_policy *p, const char *origin, const char *fetch_site, const char *host, int http_port)
{
    if (fetch_site && strcasecmp(fetch_site, "cross-site") == 0 && !access_origin_listed(p, origin)) return 0;
    return access_origin_ok(p, origin, host, http_port);
}
