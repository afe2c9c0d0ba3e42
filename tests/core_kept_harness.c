/* core_kept_harness.c -- decoder/intersect.c's kept crossing check (tw_check_state) with its state readable, for
 * tests/test_core_kept.py: the whole file is included, so the tests run the code the restore rounds run. */
#include "intersect.c"

/* What the last call left in st: out[0] seeded, out[1] dirty faces, out[2] the extents' window kept, out[3] the
 * valid faces. Returns the cell size (0 when not seeded). */
double tw_test_kept_info(const tw_check_state *st, int64_t *out) {
    out[0] = st->seeded;
    out[1] = st->ndirty;
    out[2] = st->win != NULL;
    out[3] = st->n;
    return st->seeded ? st->cell : 0.0;
}
