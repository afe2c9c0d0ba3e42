/*
 * core_range_harness.c -- ctypes entry points over decoder/range.c for tests/test_core_range.py (test-only code,
 * never part of the core): a heap-held tw_range and one call per batch kind of formats/entropy.py's Reader.
 * Every function returns a tw_status and fills err on failure.
 */
#include <stdlib.h>

#include "../decoder/internal.h"

/* A decoder on word_count little-endian words at `words` (the caller keeps them alive); NULL when out of memory. */
tw_range *h_open(const unsigned char *words, size_t word_count) {
    tw_range *rc = malloc(sizeof *rc);
    if (rc) tw_range_start(rc, words, word_count, "test");
    return rc;
}

void h_close(tw_range *rc) { free(rc); }

/* count symbols of the histogram model of bytes v[0..a). */
int h_histogram(tw_range *rc, const unsigned char *v, size_t a, size_t count, uint8_t *out, tw_error *err) {
    tw_model m;
    if (tw_model_histogram(&m, v, a, err)) return err->status;
    return tw_range_decode_symbols(rc, &m, count, out, err);
}

/* count symbols of the model of integer weights w[0..a). */
int h_weights(tw_range *rc, const int64_t *w, size_t a, size_t count, uint8_t *out, tw_error *err) {
    tw_model m;
    if (tw_model_weights(&m, w, a, err)) return err->status;
    return tw_range_decode_symbols(rc, &m, count, out, err);
}

/* count bits of binary model v. */
int h_bits(tw_range *rc, int v, size_t count, uint8_t *out, tw_error *err) {
    return tw_range_decode_bits(rc, v, count, out, err);
}

/* One bit per v[i] (entropy.Reader.decode_binary with binary_weight_rows(v)), through tw_range_decode_bit. */
int h_binary(tw_range *rc, const uint8_t *v, size_t count, uint8_t *out, tw_error *err) {
    for (size_t i = 0; i < count; i++) {
        int b;
        if (tw_range_decode_bit(rc, v[i], &b, err)) return err->status;
        out[i] = (uint8_t)b;
    }
    return TW_OK;
}

int h_raw(tw_range *rc, const uint8_t *nbits, size_t count, uint32_t *out, tw_error *err) {
    return tw_range_decode_raw(rc, nbits, count, out, err);
}

/* Grouped by ctx with model_count histogram models, model c being bytes hist[offset[c] .. offset[c + 1]). */
int h_grouped(tw_range *rc, const uint8_t *ctx, size_t count, const unsigned char *hist, const size_t *offset,
              int model_count, uint8_t *out, tw_error *err) {
    tw_model models[8];
    if (model_count < 0 || model_count > 8) return tw_fail(err, TW_ERROR_ARGUMENT, "too many models");
    for (int c = 0; c < model_count; c++)
        if (tw_model_histogram(&models[c], hist + offset[c], offset[c + 1] - offset[c], err)) return err->status;
    return tw_range_decode_grouped(rc, ctx, count, models, model_count, out, err);
}

/* The decoder's state, for the spec decoder's comparison: lower, range, point, words read. */
void h_state(const tw_range *rc, uint64_t *out) {
    out[0] = rc->lower;
    out[1] = rc->range;
    out[2] = rc->point;
    out[3] = rc->next;
}
