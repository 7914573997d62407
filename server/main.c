/* main.c - clothd: the simulation daemon.
 *
 *   clothd [serve] [--flag value ...]   run the simulation and its HTTP API (default)
 *   clothd replay FILE [--flag value]   rerun a journal bundle, print the final state hash
 *   clothd routes                       print the HTTP route table
 *   clothd --help | --help-markdown | --version
 *
 * serve: settings from the config file, CLOTHD_* variables and flags; the engine on the chosen
 * backend, resumed from --state-file when it exists (a corrupt or foreign file is refused, or
 * moved aside with --state-file-invalid fresh), paused if it was saved paused; the sim thread;
 * the HTTP server. SIGTERM or SIGINT stops accepting, stops the sim thread (within a quarter
 * second of compute, whatever it runs: a long step, a long frame), saves the state file (statefile.h: temp
 * file, fsync, rename, fsync of the directory) and exits 0. A backend failure (SIGUSR1 from the sim thread) keeps
 * answering - /v1/health 503 - while it saves the last checkpoint, then exits 3, for a supervisor
 * to restart from the state file. Exit statuses are in EXIT_STATUSES (daemon.h).
 *
 * This file reads the command line and runs the subcommand it names: serve.c, persist.c (the state
 * file) and replay.c hold the subcommands (daemon.h lists what they share). */
#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "clothsim/clothsim.h"
#include "core/log.h"
#include "core/settings.h"
#include "daemon.h"
#include "sim/commands.h"
#include "sim/scene.h"
#include "stream/stream.h"

static const char *const backend_names[] = {"auto", "cuda", "cpu"};

static void usage(FILE *out)
{
    fprintf(out,
            "clothd %s - a cloth-and-rock simulation service\n\n"
            "usage: clothd [serve] [--flag value ...]   run the simulation and its HTTP API\n"
            "       clothd replay FILE [--backend B]    rerun a journal bundle (GET /v1/journal with\n"
            "                                           Accept: application/octet-stream); print the hash\n"
            "       clothd routes                       print the HTTP routes\n"
            "       clothd --help | --version\n"
            "       clothd --help-markdown              the startup settings as a Markdown table\n\n" EXIT_STATUSES,
            CLOTHD_VERSION);
    settings_usage(out);
}

unsigned char *read_file(const char *path, size_t *len, char *why, size_t why_len)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        snprintf(why, why_len, "%s: %s", path, strerror(errno));
        return NULL;
    }
    size_t cap = 1 << 16, n = 0;
    unsigned char *buf = malloc(cap);
    while (buf) {
        const size_t got = fread(buf + n, 1, cap - n, f);
        n += got;
        if (n < cap) break;
        unsigned char *g = realloc(buf, cap *= 2);
        if (!g) free(buf);
        buf = g;
    }
    const int bad = ferror(f) ? errno : 0; /* fread sets errno when it fails (EISDIR, EIO) */
    fclose(f);
    if (!buf || bad) {
        snprintf(why, why_len, "%s: could not read it (%s)", path, buf ? strerror(bad) : "out of memory");
        free(buf);
        return NULL;
    }
    *len = n;
    return buf;
}

cs_sim *make_engine_on(const clothd_config *cfg, const char *backend)
{
    char err[300];
    cs_status st;
    void *sink = (void *)&stream_sink_ops; /* what the stream holds is part of a scene's cost */
    cs_sim *sim = scene_engine_new(&cfg->scene, &cfg->set, backend, sink, &st, err, sizeof err);
    if (!sim) log_at(LOG_ERROR, NULL, NULL, "cannot start the simulation: %s", err);
    return sim;
}

cs_sim *make_engine(const clothd_config *cfg) { return make_engine_on(cfg, backend_names[cfg->set.backend]); }

int main(int argc, char **argv, char **envp)
{
    signal(SIGPIPE, SIG_IGN);
    /* Past a file size limit (RLIMIT_FSIZE) a write fails with EFBIG, and the save says so,
     * instead of the signal killing the daemon mid-save. */
    signal(SIGXFSZ, SIG_IGN);
    const char *sub = "serve";
    int first = 1;
    if (argc > 1 && argv[1][0] != '-') {
        sub = argv[1];
        first = 2;
    }
    if (argc > 1 && (strcmp(argv[1], "--help") == 0 || strcmp(argv[1], "-h") == 0)) {
        usage(stdout);
        return 0;
    }
    if (argc > 1 && strcmp(argv[1], "--help-markdown") == 0) {
        settings_markdown(stdout);
        return 0;
    }
    if (argc > 1 && strcmp(argv[1], "--version") == 0) {
        printf("clothd %s (libclothsim %s)\n", CLOTHD_VERSION, CS_VERSION);
        return 0;
    }
    if (strcmp(sub, "routes") == 0) {
        command_print_routes(stdout);
        return 0;
    }
    const char *file = NULL;
    if (strcmp(sub, "replay") == 0) {
        if (argc <= first) {
            fprintf(stderr, "clothd replay: which file? (clothd --help)\n");
            return EXIT_USAGE;
        }
        file = argv[first++];
    } else if (strcmp(sub, "serve") != 0) {
        fprintf(stderr, "clothd: unknown command '%s' (clothd --help)\n", sub);
        return EXIT_USAGE;
    }
    clothd_config cfg;
    settings_default(&cfg);
    char why[600];
#ifdef CLOTHD_TEST_HOOKS
    const char *skip = "TEST_"; /* the test daemon's hooks (testhooks.h) */
#else
    const char *skip = NULL;
#endif
    if (settings_load(&cfg, argc - first, argv + first, envp, skip, why, sizeof why) != 0) {
        fprintf(stderr, "clothd: %s\n", why);
        return EXIT_USAGE;
    }
    log_setup(cfg.set.log_format, cfg.set.log_level);
    return file ? replay(file, &cfg) : serve(&cfg);
}
