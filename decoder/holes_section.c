/*
 * holes_section.c -- the holes section of `.tw` version 2, flags bit 7 (formats/README.md "Holes"; reference
 * formats/holes.py decode_holes, whose ranks this reproduces exactly).
 *
 * K is bounded by 64 * max(N, 1), and by the surface's face count when the caller knows it, before anything is
 * allocated; the allocation is then 14 bytes per listed face (buckets, raw bit counts, gaps, ranks).
 */
#include <stdint.h>
#include <stdlib.h>

#include "internal.h"

#define GAP_BUCKETS 33                  /* bit_length(g) for gaps g < 2^32 */
#define MAX_RANK 0xffffffffu            /* ranks are < 2^32 */
#define MAX_HOLE_FACES_PER_POINT 64u    /* K <= 64 * max(N, 1) (formats/holes.py max_hole_faces) */

/* Whether `count` elements of `size` bytes are addressable (a 32-bit size_t on wasm32 bounds K). */
static int fits(uint64_t count, size_t size) {
    return count <= (uint64_t)(SIZE_MAX / size);
}

/* The section's framing, read without allocating: K (1..64 max(n, 1), and <= max_faces when that is not 0), the
 * gap histogram, and a range decoder opened on the words (a whole number of 32-bit words). TW_ERROR_INVALID with
 * formats/holes.py decode_holes' messages, in its order. */
static int holes_frame(const unsigned char *section, size_t size, uint32_t n, uint64_t max_faces, uint32_t *k,
                       tw_model *hist, tw_range *rc, tw_error *err) {
    if (size < 4) return tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: the holes section is truncated");
    *k = (uint32_t)section[0] | (uint32_t)section[1] << 8 | (uint32_t)section[2] << 16 | (uint32_t)section[3] << 24;
    uint64_t bound = (uint64_t)MAX_HOLE_FACES_PER_POINT * (n ? n : 1);
    if (*k < 1 || *k > bound)
        return tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: %lu hole faces for %lu points",
                       (unsigned long)*k, (unsigned long)n);
    /* ranks are strictly increasing and each must be < F0: more than F0 of them cannot all be (checked before the
     * allocation, which F0 then bounds) */
    if (max_faces && *k > max_faces)
        return tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: %lu hole faces for a surface of %llu faces",
                       (unsigned long)*k, (unsigned long long)max_faces);
    tw_models mc = {section + 4, size - 4, 0, "holes"};
    if (tw_models_histogram(&mc, GAP_BUCKETS, hist, err)) return TW_ERROR_INVALID;
    if (tw_range_open(rc, section + 4 + mc.pos, size - 4 - mc.pos, "holes", err)) return TW_ERROR_INVALID;
    return TW_OK;
}

/*
 * tw_check_holes_section -- the holes section's framing (`size` bytes at `section`, a file of n points) without
 * decoding its words: what tw_parse checks when the decoder defers the ranks until the surface's face count is
 * known. TW_OK, or TW_ERROR_INVALID (truncated, K outside 1..64 max(n, 1), a bad histogram, words not a whole
 * number of 32-bit words). Allocates nothing.
 */
int tw_check_holes_section(const unsigned char *section, size_t size, uint32_t n, tw_error *err) {
    uint32_t k;
    tw_model hist;
    tw_range rc;
    return holes_frame(section, size, n, 0, &k, &hist, &rc, err);
}

/*
 * tw_decode_holes_bounded -- the holes section (`size` bytes at `section`) of a file of n points: uint32 K, a
 * histogram (A <= 33), then the words: K gap buckets, the raw bits below each leading one. r_0 = g_0,
 * r_i = r_{i-1} + 1 + g_i. max_faces: 0, or the extracted surface's face count F0 when the caller knows it
 * (every rank must be < F0, so K <= F0: a decoder that reads the section after marching tets bounds the
 * allocation by its own surface instead of 64 N). On success *ranks is a malloc'ed array of *count = K ranks (the
 * caller frees it). Errors: TW_ERROR_INVALID (truncated, K outside 1..64 max(n, 1) or above max_faces, bad
 * model, a stream that does not decode, a rank >= 2^32; then the last rank >= max_faces, with geometry/holes.py
 * open_holes' message), TW_ERROR_MEMORY / TW_ERROR_LIMIT (allocation); *ranks is then NULL and *count 0.
 */
int tw_decode_holes_bounded(const unsigned char *section, size_t size, uint32_t n, uint64_t max_faces,
                            int64_t **ranks, size_t *count, tw_error *err) {
    *ranks = NULL;
    *count = 0;
    uint32_t k;
    tw_model hist;
    tw_range rc;
    if (holes_frame(section, size, n, max_faces, &k, &hist, &rc, err)) return TW_ERROR_INVALID;
    if (!fits(k, sizeof(int64_t)))
        return tw_fail(err, TW_ERROR_LIMIT, "the holes section lists too many faces for this platform");

    size_t kk = k;
    uint8_t *e = malloc(kk), *nbits = malloc(kk);
    uint32_t *gap = malloc(kk * sizeof *gap);
    int64_t *r = malloc(kk * sizeof *r);
    int status = TW_OK;
    if (!e || !nbits || !gap || !r) {
        status = tw_fail(err, TW_ERROR_MEMORY, "out of memory decoding the holes section");
        goto done;
    }
    if ((status = tw_range_decode_symbols(&rc, &hist, kk, e, err))) goto done;
    for (size_t i = 0; i < kk; i++) nbits[i] = (uint8_t)(e[i] > 1 ? e[i] - 1 : 0);
    if ((status = tw_range_decode_raw(&rc, nbits, kk, gap, err))) goto done;
    int64_t rank = -1;
    for (size_t i = 0; i < kk; i++) {
        /* e <= 32: the gap 2^(e-1) + rest is < 2^32; the ranks only grow, so checking each is checking the last */
        uint64_t g = e[i] >= 1 ? ((uint64_t)1 << (e[i] - 1)) + gap[i] : 0;
        rank += (int64_t)g + 1;
        if (rank > (int64_t)MAX_RANK) {
            status = tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: hole face rank out of range");
            goto done;
        }
        r[i] = rank;
    }
    /* geometry/holes.py's check when F0 is known, on the last (largest) rank as it reports it */
    if (max_faces && (uint64_t)r[kk - 1] >= max_faces)
        status = tw_fail(err, TW_ERROR_INVALID, "invalid .tw file: hole face rank %lld but the surface has %llu faces",
                         (long long)r[kk - 1], (unsigned long long)max_faces);
done:
    free(e);
    free(nbits);
    free(gap);
    if (status) {
        free(r);
        return status;
    }
    *ranks = r;
    *count = kk;
    return TW_OK;
}

/* tw_decode_holes -- tw_decode_holes_bounded without a face count (K bounded by 64 max(n, 1) only). */
int tw_decode_holes(const unsigned char *section, size_t size, uint32_t n, int64_t **ranks, size_t *count,
                    tw_error *err) {
    return tw_decode_holes_bounded(section, size, n, 0, ranks, count, err);
}
