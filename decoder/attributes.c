/*
 * attributes.c -- the s and c sections of `.tw` version 2 (formats/README.md "s section", "s section, predicted",
 * "c section"; reference formats/attributes.py, whose symbols these functions reproduce exactly).
 *
 * Every count is checked before use: model bytes against the section length, the stream's word part against
 * whole words, the symbol counts against size_t (wasm32) before any allocation; allocations are O(count).
 */
#include <stdint.h>
#include <stdlib.h>

#include "internal.h"

#define S_BUCKETS 21 /* bit_length(m) for s magnitudes m < 2^20 */
#define R_BUCKETS 23 /* bit_length(|r|) for prediction residuals |r| < 2^21 + 1 */
#define C_BUCKETS 17 /* bit_length(|k|) for c symbols |k| <= 2^15 */
#define SIGN_MODEL_MIN 8
#define SIGN_MODEL_MAX 248
#define S_MAGNITUDE_MAX (((uint32_t)1 << 20) - 1) /* s symbols lie in [-2^20, 2^20 - 1] */
#define C_SYMBOL_LIMIT ((uint32_t)1 << 15)        /* c symbols lie in [-2^15, 2^15] */
#define FAIR 128 /* the binary-model byte of a fair bit */

/* ---- model bytes ----------------------------------------------------------------------------------------- */

/* tw_models_take -- the next `count` model bytes into *bytes; TW_ERROR_INVALID when fewer remain. */
int tw_models_take(tw_models *c, size_t count, const unsigned char **bytes, tw_error *err) {
    if (count > c->size - c->pos) {
        tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: the %s models are truncated", c->what);
        return TW_ERROR_INVALID;
    }
    *bytes = c->data + c->pos;
    c->pos += count;
    return TW_OK;
}

/* tw_models_histogram -- one stored histogram (length byte A in 2..max_alphabet, A bytes) as model m. */
int tw_models_histogram(tw_models *c, size_t max_alphabet, tw_model *m, tw_error *err) {
    const unsigned char *p;
    if (tw_models_take(c, 1, &p, err)) return TW_ERROR_INVALID;
    size_t a = p[0];
    if (a < 2 || a > max_alphabet)
        return tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: bad %s histogram size %d", c->what, (int)a);
    if (tw_models_take(c, a, &p, err)) return TW_ERROR_INVALID;
    return tw_model_histogram(m, p, a, err);
}

/* ---- shared decoding steps ------------------------------------------------------------------------------- */

/* Work buffers of one batch of `count` symbols: bucket (low 7 bits) and sign (bit 7) per symbol, raw bit
 * counts, raw values. */
typedef struct batch {
    uint8_t *e, *nbits;
    uint32_t *raw;
} batch;

static int batch_alloc(batch *b, size_t count, const char *what, tw_error *err) {
    b->e = b->nbits = NULL;
    b->raw = NULL;
    if (count > SIZE_MAX / sizeof(uint32_t))
        return tw_fail(err, TW_ERROR_LIMIT, "the %s section has too many symbols for this platform", what);
    b->e = malloc(count ? count : 1);
    b->nbits = malloc(count ? count : 1);
    b->raw = malloc(count ? count * sizeof(uint32_t) : 1);
    if (!b->e || !b->nbits || !b->raw)
        return tw_fail(err, TW_ERROR_MEMORY, "out of memory decoding the %s section", what);
    return TW_OK;
}

static void batch_free(batch *b) {
    free(b->e);
    free(b->nbits);
    free(b->raw);
}

/* The raw bits below each bucket's leading one (nbits = max(e - 1, 0)), then the magnitudes into b->raw:
 * m = 2^(e - 1) + rest for e >= 1, 0 for e = 0 (attributes._from_raw). Buckets are <= 32 (the callers' models
 * have at most 33 symbols), so m < 2^32. */
static int magnitudes(tw_range *rc, batch *b, size_t count, tw_error *err) {
    for (size_t i = 0; i < count; i++) {
        int e = b->e[i] & 0x7f;
        b->nbits[i] = (uint8_t)(e > 1 ? e - 1 : 0);
    }
    int status = tw_range_decode_raw(rc, b->nbits, count, b->raw, err);
    if (status) return status;
    for (size_t i = 0; i < count; i++) {
        int e = b->e[i] & 0x7f;
        b->raw[i] = e >= 1 ? ((uint32_t)1 << (e - 1)) + b->raw[i] : 0;
    }
    return TW_OK;
}

/*
 * Signed values of one batch (attributes._decode_signed): `count` buckets with model m, the sign of every nonzero
 * bucket as a fair bit (1 = negative) in order, the raw bits. Leaves bucket | sign << 7 in b->e and the
 * magnitudes in b->raw (each < 2^(A - 1) for A buckets <= 23 here, so they fit int32 with their sign).
 */
static int decode_signed(tw_range *rc, const tw_model *m, size_t count, batch *b, tw_error *err) {
    if (tw_range_decode_symbols(rc, m, count, b->e, err)) return TW_ERROR_INVALID;
    for (size_t i = 0; i < count; i++) {
        if (!b->e[i]) continue;
        int neg;
        if (tw_range_decode_bit(rc, FAIR, &neg, err)) return TW_ERROR_INVALID;
        b->e[i] |= (uint8_t)(neg << 7);
    }
    return magnitudes(rc, b, count, err);
}

static int32_t signed_value(const batch *b, size_t i) {
    int32_t m = (int32_t)b->raw[i];
    return (b->e[i] & 0x80) ? -m : m;
}

/* ---- s --------------------------------------------------------------------------------------------------- */

static int no_points(size_t size, const char *what, tw_error *err) {
    if (size) return tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: %s", what);
    return TW_OK;
}

/*
 * tw_decode_s -- the s section without prediction (`size` bytes at `section`, n points) into k[0..n):
 * 4 sign-model bytes (8..248), a histogram (A <= 21), the words: signs of the even indices with v_even, signs of
 * the odd indices grouped by the context t[i-1] + t[i+1] (2 t[i-1] for the last index of an even n) with
 * v_odd[ctx], the buckets, the raw bits. k = m for t = 0, -m - 1 for t = 1. Errors: TW_ERROR_INVALID (malformed),
 * TW_ERROR_MEMORY / TW_ERROR_LIMIT (allocation).
 */
int tw_decode_s(const unsigned char *section, size_t size, uint32_t n, int32_t *k, tw_error *err) {
    if (n == 0) return no_points(size, "s data for zero points", err);
    tw_models mc = {section, size, 0, "s"};
    const unsigned char *sign;
    if (tw_models_take(&mc, 4, &sign, err)) return TW_ERROR_INVALID;
    for (int i = 0; i < 4; i++)
        if (sign[i] < SIGN_MODEL_MIN || sign[i] > SIGN_MODEL_MAX)
            return tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: bad s sign model");
    tw_model hist, odd[3];
    if (tw_models_histogram(&mc, S_BUCKETS, &hist, err)) return TW_ERROR_INVALID;
    for (int c = 0; c < 3; c++)
        if (tw_model_binary(&odd[c], sign[1 + c], err)) return TW_ERROR_INVALID;
    tw_range rc;
    if (tw_range_open(&rc, section + mc.pos, size - mc.pos, "s", err)) return TW_ERROR_INVALID;

    size_t count = n, n_even = (count + 1) / 2, n_odd = count / 2;
    batch b;
    uint8_t *t = NULL;
    int status = batch_alloc(&b, count, "s", err);
    if (!status && !(t = malloc(count))) status = tw_fail(err, TW_ERROR_MEMORY, "out of memory decoding the s section");
    if (status) goto done;
    /* t[0..n_even) = even signs, then t[n_even..n) = odd signs; b.nbits holds the odd contexts meanwhile. */
    if ((status = tw_range_decode_bits(&rc, sign[0], n_even, t, err))) goto done;
    for (size_t j = 0; j < n_odd; j++) {
        uint8_t left = t[j], right = j + 1 < n_even ? t[j + 1] : t[j];
        b.nbits[j] = (uint8_t)(left + right);
    }
    if ((status = tw_range_decode_grouped(&rc, b.nbits, n_odd, odd, 3, t + n_even, err))) goto done;
    if ((status = tw_range_decode_symbols(&rc, &hist, count, b.e, err))) goto done;
    if ((status = magnitudes(&rc, &b, count, err))) goto done;
    for (size_t i = 0; i < count; i++) {
        uint32_t m = b.raw[i];
        if (m > S_MAGNITUDE_MAX) { /* cannot happen with <= 21 buckets; kept as the reference's guard */
            status = tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: s symbol out of range");
            goto done;
        }
        int neg = (i % 2 == 0) ? t[i / 2] : t[n_even + i / 2];
        k[i] = neg ? -(int32_t)m - 1 : (int32_t)m;
    }
done:
    free(t);
    batch_free(&b);
    return status;
}

/*
 * tw_decode_s_residuals -- the residual part of the predicted s section (n points) into r[0..n): a histogram
 * (A <= 23), then the words of one signed batch (buckets, signs of the nonzero ones, raw bits). The prediction
 * and the final range check belong to predict.c. Errors as tw_decode_s.
 */
int tw_decode_s_residuals(const unsigned char *section, size_t size, uint32_t n, int32_t *r, tw_error *err) {
    if (n == 0) return no_points(size, "s data for zero points", err);
    tw_models mc = {section, size, 0, "s"};
    tw_model hist;
    if (tw_models_histogram(&mc, R_BUCKETS, &hist, err)) return TW_ERROR_INVALID;
    tw_range rc;
    if (tw_range_open(&rc, section + mc.pos, size - mc.pos, "s", err)) return TW_ERROR_INVALID;
    batch b;
    int status = batch_alloc(&b, n, "s", err);
    if (!status) status = decode_signed(&rc, &hist, n, &b, err);
    if (!status)
        for (size_t i = 0; i < n; i++) r[i] = signed_value(&b, i);
    batch_free(&b);
    return status;
}

/* ---- c --------------------------------------------------------------------------------------------------- */

/*
 * tw_decode_c -- the c section (n points, SH degree sh_degree in -1..3) into k[0..n*q) row-major (n, q): one
 * histogram (A <= 17) per band l = 0..d, then per band the signed batch of its 2l + 1 coefficients in
 * coefficient-major order (all points of coefficient l^2, then l^2 + 1, ...). |k| > 2^15 is TW_ERROR_INVALID.
 */
int tw_decode_c(const unsigned char *section, size_t size, uint32_t n, int sh_degree, int32_t *k, tw_error *err) {
    if (sh_degree < -1 || sh_degree > 3) return tw_fail(err, TW_ERROR_ARGUMENT, "SH degree %d", sh_degree);
    size_t q = (size_t)(sh_degree + 1) * (size_t)(sh_degree + 1);
    if (n == 0 || q == 0) return no_points(size, "c data without coefficients", err);
    tw_models mc = {section, size, 0, "c"};
    tw_model hist[4];
    for (int l = 0; l <= sh_degree; l++)
        if (tw_models_histogram(&mc, C_BUCKETS, &hist[l], err)) return TW_ERROR_INVALID;
    tw_range rc;
    if (tw_range_open(&rc, section + mc.pos, size - mc.pos, "c", err)) return TW_ERROR_INVALID;
    size_t widest = (size_t)(2 * sh_degree + 1);
    if (n > SIZE_MAX / sizeof(uint32_t) / widest)
        return tw_fail(err, TW_ERROR_LIMIT, "the c section has too many symbols for this platform");
    batch b;
    int status = batch_alloc(&b, (size_t)n * widest, "c", err);
    for (int l = 0; l <= sh_degree && !status; l++) {
        size_t j0 = (size_t)l * (size_t)l, width = (size_t)(2 * l + 1), count = (size_t)n * width;
        if ((status = decode_signed(&rc, &hist[l], count, &b, err))) break;
        for (size_t t = 0; t < count; t++) {
            if (b.raw[t] > C_SYMBOL_LIMIT) {
                status = tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: c symbol out of range");
                break;
            }
            size_t coefficient = t / n, point = t % n;
            k[point * q + j0 + coefficient] = signed_value(&b, t);
        }
    }
    batch_free(&b);
    return status;
}
