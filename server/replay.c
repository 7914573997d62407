/* replay.c - clothd replay FILE: a journal bundle (GET /v1/journal with Accept:
 * application/octet-stream) rerun on an engine of the settings, its state hash printed. */
#include <stdio.h>
#include <stdlib.h>

#include <jansson.h>

#include "daemon.h"
#include "sim/commands.h"

int replay(const char *file, const clothd_config *cfg)
{
    char why[300];
    size_t len = 0;
    unsigned char *buf = read_file(file, &len, why, sizeof why);
    if (!buf) {
        fprintf(stderr, "clothd replay: %s\n", why);
        return 1;
    }
    /* The bundle: a snapshot (its header says how long it is) followed by the journal JSON. */
    const size_t snap_len = cs_snapshot_length(buf, len);
    if (snap_len == 0) {
        fprintf(stderr, "clothd replay: %s is not a journal bundle (GET /v1/journal with Accept: application/octet-stream)\n",
                file);
        free(buf);
        return 1;
    }
    json_error_t jerr;
    json_t *j = json_loadb((const char *)buf + snap_len, len - snap_len, JSON_REJECT_DUPLICATES, &jerr);
    cs_sim *sim = j ? make_engine(cfg) : NULL;
    int rc = 1;
    if (!j) {
        fprintf(stderr, "clothd replay: the journal in %s is not JSON: %s\n", file, jerr.text);
    } else if (sim && cs_snapshot_load(sim, buf, snap_len) != CS_OK) {
        fprintf(stderr, "clothd replay: the snapshot in %s is refused: %s\n", file, cs_sim_error(sim));
    } else if (sim) {
        cs_info info;
        size_t k;
        json_t *e;
        loop_settings loop = cfg->scene.loop; /* a params command sets them too; they change no state */
        rc = 0;
        json_array_foreach(json_object_get(j, "entries"), k, e)
        {
            const long long step = (long long)json_integer_value(json_object_get(e, "step"));
            cs_sim_info(sim, &info);
            json_t *journal = NULL, *result = NULL;
            problem pr;
            if (step < (long long)info.step || cs_sim_step(sim, step - (long long)info.step) != CS_OK ||
                command_apply(sim, &loop, json_object_get(e, "command"), &journal, &result, &pr) != 0) {
                fprintf(stderr, "clothd replay: entry %zu (step %lld) could not be replayed: %s\n", k, step,
                        pr.detail[0] ? pr.detail : cs_sim_error(sim));
                rc = 1;
                break;
            }
            json_decref(journal);
            json_decref(result);
        }
        const long long last = (long long)json_integer_value(json_object_get(j, "step"));
        cs_sim_info(sim, &info);
        if (rc == 0 && last > (long long)info.step && cs_sim_step(sim, last - (long long)info.step) != CS_OK) {
            fprintf(stderr, "clothd replay: stepping to %lld failed: %s\n", last, cs_sim_error(sim));
            rc = 1;
        }
        if (rc == 0) {
            char hex[17];
            cs_sim_info(sim, &info);
            cs_hash_hex(cs_state_hash(sim), hex);
            printf("%s\n", hex);
            fprintf(stderr, "clothd replay: step %llu, state hash %s\n", (unsigned long long)info.step, hex);
        }
    }
    json_decref(j);
    cs_sim_destroy(sim);
    free(buf);
    return rc;
}
