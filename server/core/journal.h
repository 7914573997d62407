/* journal.h - the commands applied since a base snapshot, each with the step it applied at.
 *
 * The sim thread appends; HTTP threads read. Entries are kept serialized, so a read is a copy
 * under a short lock. When the cloth is rebuilt, a snapshot restored, a rollback made, or the
 * journal reaches one of its caps (entries, bytes), it starts afresh from a new base snapshot. A bundle - the base
 * snapshot followed by the journal as JSON - is what `clothd replay` reruns. */
#ifndef CLOTHD_JOURNAL_H
#define CLOTHD_JOURNAL_H

#include <stddef.h>
#include <stdint.h>

#include <jansson.h>

typedef struct journal journal;

/* Caps: max_entries entries, max_bytes bytes of entries (their text and its index). */
journal *journal_new(size_t max_entries, size_t max_bytes);
void journal_free(journal *j);
/* Starts afresh from a snapshot (copied) of the state at base_step. */
int journal_rebase(journal *j, const void *snapshot, size_t len, uint64_t base_step);
/* Appends a command applied at step (the command is serialized; the caller keeps it). */
int journal_append(journal *j, uint64_t step, const json_t *command);
/* Whether the journal has reached a cap (the sim thread then rebases it). */
int journal_full(journal *j);
/* {"base_step": S, "entries": [{"step": N, "command": {...}}, ...]} (malloc'd). */
char *journal_json(journal *j, size_t *len);
/* The base snapshot followed by {"base_step", "step": step, "entries"} (malloc'd). */
unsigned char *journal_bundle(journal *j, uint64_t step, size_t *len);

#endif
