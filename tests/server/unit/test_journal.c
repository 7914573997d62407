/* test_journal.c - the journal (core/journal.c): entries as PROTOCOL.md shows GET /v1/journal,
 * the bundle clothd replay reads (the base snapshot's bytes, then the JSON), its caps, and a
 * rebase that starts it afresh. */
#include "core/journal.h"
#include "unitkit.h"

static void append(journal *j, uint64_t step, const char *command)
{
    json_t *c = json_loads(command, 0, NULL);
    assert_non_null(c);
    assert_int_equal(journal_append(j, step, c), 0);
    json_decref(c);
}

static void test_entries_and_bundle(void **unused)
{
    (void)unused;
    journal *j = journal_new(100, 1 << 20);
    assert_int_equal(journal_rebase(j, "BASE", 4, 30), 0);
    size_t len;
    char *text = journal_json(j, &len);
    assert_string_equal(text, "{\"base_step\":30,\"entries\":[]}");
    assert_int_equal(len, strlen(text));
    free(text);
    append(j, 31, "{\"op\":\"reset\"}");
    append(j, 45, "{\"op\":\"grab\",\"vertex\":3,\"target\":[0,0,1.5]}");
    text = journal_json(j, &len);
    assert_string_equal(text, "{\"base_step\":30,\"entries\":[{\"step\":31,\"command\":{\"op\":\"reset\"}},"
                              "{\"step\":45,\"command\":{\"op\":\"grab\",\"vertex\":3,\"target\":[0,0,1.5]}}]}");
    free(text);
    unsigned char *b = journal_bundle(j, 60, &len);
    const char *tail = "{\"base_step\":30,\"step\":60,\"entries\":[{\"step\":31,\"command\":{\"op\":\"reset\"}},"
                       "{\"step\":45,\"command\":{\"op\":\"grab\",\"vertex\":3,\"target\":[0,0,1.5]}}]}";
    assert_int_equal(len, 4 + strlen(tail));
    assert_memory_equal(b, "BASE", 4);
    assert_memory_equal(b + 4, tail, strlen(tail));
    free(b);
    /* A rebase: a new base, no entries. */
    assert_int_equal(journal_rebase(j, "NEXT!", 5, 90), 0);
    text = journal_json(j, &len);
    assert_string_equal(text, "{\"base_step\":90,\"entries\":[]}");
    free(text);
    journal_free(j);
}

static void test_caps(void **unused)
{
    (void)unused;
    journal *j = journal_new(2, 1 << 20);
    journal_rebase(j, "", 0, 0);
    append(j, 1, "{\"op\":\"release\"}");
    assert_false(journal_full(j));
    append(j, 2, "{\"op\":\"release\"}");
    assert_true(journal_full(j)); /* two entries: the cap */
    journal_free(j);
    /* Bytes: an entry's text and its index pointer count. */
    const char *one = "{\"step\":1,\"command\":{\"op\":\"release\"}}";
    j = journal_new(100, strlen(one) + 1 + sizeof(char *));
    journal_rebase(j, "", 0, 0);
    assert_false(journal_full(j));
    append(j, 1, "{\"op\":\"release\"}");
    assert_true(journal_full(j));
    journal_free(j);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_entries_and_bundle),
        cmocka_unit_test(test_caps),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
