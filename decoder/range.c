/*
 * range.c -- the range decoder of `.tw` version 2 and its integer models (formats/README.md, "Entropy coder").
 *
 * The encoder writes its streams with constriction's queue range coder at the default preset (32-bit words,
 * 64-bit state, 24-bit probabilities); this is that decoder, written from the specification: 64-bit lower /
 * range / point, one renormalization by a whole word per symbol at most, missing words read as zero. Every
 * operation is unsigned 64-bit integer arithmetic (subtraction and addition wrap modulo 2^64), so the symbols are
 * the same on every platform. No allocation happens here.
 */
#include <string.h>

#include "internal.h"

#define TOTAL ((uint32_t)1 << TW_RANGE_PRECISION)
#define WORD_BITS 32
#define RANGE_MIN ((uint64_t)1 << WORD_BITS) /* range >= 2^32 between symbols */

/* Word i of the stream (little-endian, no alignment assumed), or 0 past the end. */
static uint64_t read_word(tw_range *rc) {
    if (rc->next >= rc->word_count) return 0;
    const unsigned char *p = rc->words + 4 * rc->next++;
    return (uint64_t)p[0] | (uint64_t)p[1] << 8 | (uint64_t)p[2] << 16 | (uint64_t)p[3] << 24;
}

/*
 * tw_range_start -- a decoder at the start of word_count words at `words` (NULL is fine when word_count is 0).
 * lower = 0, range = 2^64 - 1, point = the first two words, the first the more significant.
 */
void tw_range_start(tw_range *rc, const unsigned char *words, size_t word_count, const char *what) {
    rc->words = words;
    rc->word_count = words ? word_count : 0;
    rc->next = 0;
    rc->what = what ? what : "entropy";
    rc->lower = 0;
    rc->range = UINT64_MAX;
    uint64_t hi = read_word(rc);
    rc->point = hi << WORD_BITS | read_word(rc);
}

/*
 * tw_range_open -- tw_range_start on a section's word part: `size` bytes at `bytes`, which must be whole words
 * (formats/entropy.py Reader), else TW_ERROR_INVALID.
 */
int tw_range_open(tw_range *rc, const unsigned char *bytes, size_t size, const char *what, tw_error *err) {
    if (size % 4)
        return tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: %s stream is not a whole number of 32-bit words",
                       what ? what : "entropy");
    tw_range_start(rc, bytes, size / 4, what);
    return TW_OK;
}

/*
 * The quantile of the next symbol: (point - lower) / (range >> 24), which must be below 2^24 (a stream whose
 * point lies past the last symbol's interval was not written by an encoder: TW_ERROR_INVALID).
 */
static int quantile(tw_range *rc, uint64_t *scale, uint32_t *q, tw_error *err) {
    uint64_t s = rc->range >> TW_RANGE_PRECISION; /* >= 2^8 since range >= 2^32 */
    uint64_t x = (rc->point - rc->lower) / s;
    if (x >= TOTAL) {
        tw_fail(err, TW_ERROR_INVALID, "corrupted .tw file: the %s stream does not decode", rc->what);
        return TW_ERROR_INVALID;
    }
    *scale = s;
    *q = (uint32_t)x;
    return TW_OK;
}

/* Narrow the interval to the decoded symbol's [left, left + probability) and renormalize by one word at most:
 * range >= scale >= 2^8 after the narrowing, so one shift by 32 bits restores range >= 2^32. */
static void advance(tw_range *rc, uint64_t scale, uint32_t left, uint32_t probability) {
    rc->lower += scale * left;
    rc->range = scale * probability;
    if (rc->range < RANGE_MIN) {
        rc->lower <<= WORD_BITS;
        rc->range <<= WORD_BITS;
        rc->point = rc->point << WORD_BITS | read_word(rc);
    }
}

/* Symbol of quantile q under m: the i with cum[i] <= q < cum[i + 1] (binary search; cum strictly increasing). */
static int lookup(const tw_model *m, uint32_t q) {
    int lo = 0, hi = m->size; /* cum[lo] <= q < cum[hi] */
    while (hi - lo > 1) {
        int mid = lo + (hi - lo) / 2;
        if (m->cum[mid] <= q)
            lo = mid;
        else
            hi = mid;
    }
    return lo;
}

/*
 * tw_range_decode -- one symbol of model m into *symbol. TW_ERROR_INVALID when the stream does not decode;
 * the decoder is then unusable (callers stop).
 */
int tw_range_decode(tw_range *rc, const tw_model *m, int *symbol, tw_error *err) {
    uint64_t scale;
    uint32_t q;
    if (quantile(rc, &scale, &q, err)) return TW_ERROR_INVALID;
    int i = lookup(m, q);
    advance(rc, scale, m->cum[i], m->cum[i + 1] - m->cum[i]);
    *symbol = i;
    return TW_OK;
}

/* The binary model of byte v: symbol 0 covers [0, (256 - v) * 2^16), symbol 1 the rest. */
static int check_binary(int v, tw_error *err) {
    if (v < 1 || v > 255) return tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: bad binary model");
    return TW_OK;
}

static int decode_bit(tw_range *rc, uint32_t split, int *bit, tw_error *err) {
    uint64_t scale;
    uint32_t q;
    if (quantile(rc, &scale, &q, err)) return TW_ERROR_INVALID;
    if (q < split) {
        advance(rc, scale, 0, split);
        *bit = 0;
    } else {
        advance(rc, scale, split, TOTAL - split);
        *bit = 1;
    }
    return TW_OK;
}

/* tw_range_decode_bit -- one bit with the binary model of byte v (1..255, else TW_ERROR_INVALID). */
int tw_range_decode_bit(tw_range *rc, int v, int *bit, tw_error *err) {
    if (check_binary(v, err)) return TW_ERROR_INVALID;
    return decode_bit(rc, (uint32_t)(256 - v) << 16, bit, err);
}

/* tw_range_decode_symbols -- count symbols of model m into out[0..count) (symbols < 255 fit a byte). */
int tw_range_decode_symbols(tw_range *rc, const tw_model *m, size_t count, uint8_t *out, tw_error *err) {
    for (size_t i = 0; i < count; i++) {
        int s;
        if (tw_range_decode(rc, m, &s, err)) return TW_ERROR_INVALID;
        out[i] = (uint8_t)s;
    }
    return TW_OK;
}

/* tw_range_decode_bits -- count bits of binary model v (1..255) into out[0..count). */
int tw_range_decode_bits(tw_range *rc, int v, size_t count, uint8_t *out, tw_error *err) {
    if (check_binary(v, err)) return TW_ERROR_INVALID;
    uint32_t split = (uint32_t)(256 - v) << 16;
    for (size_t i = 0; i < count; i++) {
        int b;
        if (decode_bit(rc, split, &b, err)) return TW_ERROR_INVALID;
        out[i] = (uint8_t)b;
    }
    return TW_OK;
}

/*
 * tw_range_decode_raw -- values[0..count) from raw fair bits by bit plane (see internal.h). nbits[i] > 32 is
 * TW_ERROR_ARGUMENT (no stream of the format has more than 31). Work: count per plane, at most 32 planes.
 */
int tw_range_decode_raw(tw_range *rc, const uint8_t *nbits, size_t count, uint32_t *values, tw_error *err) {
    int top = 0;
    for (size_t i = 0; i < count; i++) {
        if (nbits[i] > 32) return tw_fail(err, TW_ERROR_ARGUMENT, "raw bits: %d bits per value", nbits[i]);
        if (nbits[i] > top) top = nbits[i];
        values[i] = 0;
    }
    const uint32_t half = TOTAL / 2;
    for (int plane = top - 1; plane >= 0; plane--) {
        for (size_t i = 0; i < count; i++) {
            if (nbits[i] <= plane) continue;
            int b;
            if (decode_bit(rc, half, &b, err)) return TW_ERROR_INVALID;
            values[i] = values[i] << 1 | (uint32_t)b;
        }
    }
    return TW_OK;
}

/* tw_range_decode_grouped -- symbols grouped by context (see internal.h); out[i] = 0 where ctx[i] has no model. */
int tw_range_decode_grouped(tw_range *rc, const uint8_t *ctx, size_t count, const tw_model *models,
                            int model_count, uint8_t *out, tw_error *err) {
    for (size_t i = 0; i < count; i++) out[i] = 0;
    for (int c = 0; c < model_count; c++) {
        for (size_t i = 0; i < count; i++) {
            if (ctx[i] != c) continue;
            int s;
            if (tw_range_decode(rc, &models[c], &s, err)) return TW_ERROR_INVALID;
            out[i] = (uint8_t)s;
        }
    }
    return TW_OK;
}

/* ---- models ---------------------------------------------------------------------------------------------- */

/*
 * tw_model_weights -- the model of integer weights w[0..a): symbol i has left cumulative sum(w[j], j < i) + i and
 * probability w[i] + 1. TW_ERROR_INVALID unless 2 <= a <= 255, every w >= 0 and sum(w) = 2^24 - a.
 */
int tw_model_weights(tw_model *m, const int64_t *w, size_t a, tw_error *err) {
    if (a < 2 || a > TW_MODEL_MAX_SYMBOLS)
        return tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: bad model size");
    int64_t sum = 0;
    for (size_t i = 0; i < a; i++) {
        if (w[i] < 0 || w[i] >= (int64_t)TOTAL)
            return tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: bad model");
        m->cum[i] = (uint32_t)(sum + (int64_t)i);
        sum += w[i];
    }
    if (sum != (int64_t)(TOTAL - a)) return tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: bad model");
    m->cum[a] = TOTAL;
    m->size = (int)a;
    return TW_OK;
}

/*
 * tw_model_histogram -- the model of a stored histogram v[0..a) (formats/entropy.py histogram_weights):
 * w_i = floor(v_i * (2^24 - a) / V), V = sum(v), the remainder to the first largest v_i.
 * TW_ERROR_INVALID when a is outside 2..255 or every byte is 0 ("bad histogram model").
 */
int tw_model_histogram(tw_model *m, const unsigned char *v, size_t a, tw_error *err) {
    if (a < 2 || a > TW_MODEL_MAX_SYMBOLS)
        return tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: bad histogram model");
    uint64_t total = 0;
    size_t top = 0;
    for (size_t i = 0; i < a; i++) {
        total += v[i];
        if (v[i] > v[top]) top = i; /* the first index of the largest byte (numpy argmax) */
    }
    if (total == 0) return tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: bad histogram model");
    const uint64_t free_weight = TOTAL - a;
    int64_t w[TW_MODEL_MAX_SYMBOLS];
    uint64_t sum = 0;
    for (size_t i = 0; i < a; i++) {
        w[i] = (int64_t)((uint64_t)v[i] * free_weight / total); /* < 2^8 * 2^24: exact in 64 bits */
        sum += (uint64_t)w[i];
    }
    w[top] += (int64_t)(free_weight - sum); /* sum <= free_weight: each term is rounded down */
    return tw_model_weights(m, w, a, err);
}

/* tw_model_binary -- the binary model of byte v: w = ((256 - v) * 2^16 - 1, v * 2^16 - 1); v outside 1..255 is
 * TW_ERROR_INVALID. */
int tw_model_binary(tw_model *m, int v, tw_error *err) {
    if (check_binary(v, err)) return TW_ERROR_INVALID;
    m->size = 2;
    m->cum[0] = 0;
    m->cum[1] = (uint32_t)(256 - v) << 16;
    m->cum[2] = TOTAL;
    return TW_OK;
}

/* tw_model_uniform -- the histogram model of a bytes equal to 1 (a in 2..255). */
int tw_model_uniform(tw_model *m, size_t a, tw_error *err) {
    unsigned char ones[TW_MODEL_MAX_SYMBOLS];
    if (a < 2 || a > TW_MODEL_MAX_SYMBOLS)
        return tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: bad model size");
    memset(ones, 1, a);
    return tw_model_histogram(m, ones, a, err);
}
