/* test_implicit.c - the multigrid level functions of clothsim/implicit.h: the written-out fast
 * paths give the same bits as the general functions they restate. */
#include <string.h>

#include "clothsim/implicit.h"
#include "testkit.h"

/* splitmix64, for reproducible blocks */
static uint64_t next_u64(uint64_t *s)
{
    uint64_t z = (*s += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

/* A float of either sign over several magnitudes, now and then a zero of either sign (which
 * catches a select that adds where the general code skips). */
static float draw(uint64_t *s)
{
    const uint64_t u = next_u64(s);
    if (u % 11 == 0) return (u & 16) ? -0.0f : 0.0f;
    const float mag = (float)((u >> 11) & 0xffff) / 65536.0f * powf(10.0f, (float)((u >> 40) % 7) - 3.0f);
    return (u & 1) ? -mag : mag;
}

/* cs_im_galerkin_inner against cs_im_galerkin on every inner coarse vertex of random fine levels
 * (blocks, and masks with pinned vertices): the same bits in D, the four forward blocks and the
 * mask. */
static void test_galerkin_inner_is_the_general_product(void **unused)
{
    (void)unused;
    const int32_t sizes[][2] = {{5, 5}, {9, 7}, {10, 10}, {17, 12}, {33, 9}};
    uint64_t seed = 12345;
    int checked = 0;
    for (size_t k = 0; k < sizeof sizes / sizeof sizes[0]; k++) {
        const int32_t nx = sizes[k][0], ny = sizes[k][1], n = nx * ny;
        const size_t S = cs_im_stride((size_t)n);
        float *blk = malloc(sizeof(float) * 5 * CS_IM_SYM * S), *mask = malloc(sizeof(float) * (size_t)n);
        assert_non_null(blk);
        assert_non_null(mask);
        for (size_t e = 0; e < 5 * CS_IM_SYM * S; e++) blk[e] = draw(&seed);
        for (int32_t v = 0; v < n; v++) mask[v] = next_u64(&seed) % 4 == 0 ? 0.0f : 1.0f;
        cs_im_level L;
        memset(&L, 0, sizeof L);
        L.nx = nx, L.ny = ny, L.S = S, L.mask = mask, L.D = blk;
        for (int t = 0; t < 4; t++) L.F[t] = blk + (size_t)(t + 1) * CS_IM_SYM * S;
        const int32_t cnx = cs_im_coarse(nx), cny = cs_im_coarse(ny);
        for (int32_t J = 0; J < cny; J++)
            for (int32_t I = 0; I < cnx; I++) {
                if (!cs_im_galerkin_is_inner(nx, ny, I, J)) continue;
                float a[5][CS_IM_SYM], b[5][CS_IM_SYM], ma = -1.0f, mb = -2.0f;
                float *Fa[4] = {a[1], a[2], a[3], a[4]}, *Fb[4] = {b[1], b[2], b[3], b[4]};
                /* stride 1: each output is one coarse vertex's six elements in a row */
                cs_im_galerkin(&L, I, J, a[0], Fa, 1, &ma);
                cs_im_galerkin_inner(&L, I, J, b[0], Fb, 1, &mb);
                if (memcmp(a, b, sizeof a) != 0 || memcmp(&ma, &mb, sizeof ma) != 0)
                    fail_msg("%d x %d, coarse (%d, %d): the inner product differs from the general one", nx, ny, I, J);
                checked++;
            }
        free(blk);
        free(mask);
    }
    print_message("%d inner coarse vertices checked\n", checked);
    assert_true(checked > 100);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_galerkin_inner_is_the_general_product),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
