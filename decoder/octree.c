/*
 * octree.c -- the positions section of `.tw` version 2 (formats/README.md "Positions section" and "Positions
 * section, context-coded"; formats/octree.py decode is the reference).
 *
 * Breadth first from the root: each level's nodes (Morton keys with 3L bits, ascending) get an 8-bit occupancy
 * code, coded either as population count + rank (8 histogram bytes per level) or, with flags bit 2 and the
 * level's bit in the mask, bit by bit with 12 binary models chosen by the occupied face neighbours on the child's
 * side and the children already decoded. The occupied children of a level are the next level's nodes; after level
 * b - 1 they are the N leaf cells, in canonical order.
 *
 * Untrusted input: the model bytes are checked against the section before use, a level that announces more than
 * N children is refused before any child is stored (so no buffer exceeds the N of the header), and the range
 * decoder never reads past the section's words.
 */
#include <stdlib.h>
#include <string.h>

#include "internal.h"

#define MODEL_BYTES_PER_LEVEL 8 /* population-count histogram */
#define LEVEL_MASK_BYTES 2      /* uint16 mask of the bit-coded levels (flags bit 2) */
#define CONTEXTS 12             /* binary models of a bit-coded level: 3 a + min(o, 2) */

static int popcount8(unsigned v) {
    int c = 0;
    for (; v; v &= v - 1) c++;
    return c;
}

/* Every third bit of v from bit 0, packed (octree._compact3): the coordinate of one axis of a Morton key. */
static uint32_t compact3(uint64_t v) {
    v &= 0x9249249249249249ULL;
    v = (v | (v >> 2)) & 0x30C30C30C30C30C3ULL;
    v = (v | (v >> 4)) & 0xF00F00F00F00F00FULL;
    v = (v | (v >> 8)) & 0x00FF0000FF0000FFULL;
    v = (v | (v >> 16)) & 0x0000FFFF0000FFFFULL;
    return (uint32_t)(v & 0xFFFF);
}

/* Whether `key` is among keys[0..n) (ascending): a dense bitmap over every key of the level when it has one
 * (levels <= DENSE_LEVEL_MAX, as octree.face_neighbours), else a binary search. */
static int has_key(const uint64_t *keys, size_t n, const uint8_t *bitmap, uint64_t key) {
    if (bitmap) return (bitmap[key >> 3] >> (key & 7)) & 1;
    size_t lo = 0, hi = n;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (keys[mid] < key)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo < n && keys[lo] == key;
}

#define DENSE_LEVEL_MAX 7 /* a bitmap of 8^level bits: 256 KiB at level 7 */

/*
 * face_neighbours -- octree.face_neighbours: for each node of `level` (keys ascending, 3 level bits), bit s of
 * out[i] says whether its face neighbour s (-x, +x, -y, +y, -z, +z) is a node too (never outside the grid).
 * A +-1 step along one axis of a Morton code borrows or carries through that axis' bits only. Returns TW_OK or
 * TW_ERROR_MEMORY (the bitmap).
 */
static int face_neighbours(const uint64_t *keys, size_t n, int level, uint8_t *out) {
    uint8_t *bitmap = NULL;
    if (level <= DENSE_LEVEL_MAX) {
        bitmap = (uint8_t *)calloc(((size_t)1 << (3 * level)) / 8 + 1, 1);
        if (!bitmap) return TW_ERROR_MEMORY;
        for (size_t i = 0; i < n; i++) bitmap[keys[i] >> 3] |= (uint8_t)(1u << (keys[i] & 7));
    }
    for (size_t i = 0; i < n; i++) out[i] = 0;
    for (int axis = 0; axis < 3; axis++) {
        const int shift = 2 - axis; /* x, y, z sit at key bits 3j + 2, 3j + 1, 3j */
        uint64_t bits = 0;
        for (int j = 0; j < level; j++) bits |= (uint64_t)1 << (3 * j + shift);
        for (size_t i = 0; i < n; i++) {
            const uint64_t key = keys[i], coord = key & bits, rest = key & ~bits;
            if (coord != 0 && has_key(keys, n, bitmap, ((coord - 1) & bits) | rest))
                out[i] |= (uint8_t)(1u << (2 * axis));
            if (coord != bits && has_key(keys, n, bitmap, (((key | ~bits) + 1) & bits) | rest))
                out[i] |= (uint8_t)(1u << (2 * axis + 1));
        }
    }
    free(bitmap);
    return TW_OK;
}

/* One bit-coded level: occ[i] of each node from 8 child passes (octree._decode_bitwise). */
static int decode_bitwise(tw_range *rc, const unsigned char *table, const uint64_t *keys, size_t n, int level,
                          uint8_t *occ, uint8_t *neighbours, tw_error *err) {
    for (int c = 0; c < CONTEXTS; c++) /* binary_weight_rows rejects a zero byte whether or not it is used */
        if (table[c] == 0) return tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: bad binary model");
    if (face_neighbours(keys, n, level, neighbours))
        return tw_fail(err, TW_ERROR_MEMORY, "out of memory for the octree's neighbour table");
    for (size_t i = 0; i < n; i++) occ[i] = 0;
    for (int child = 0; child < 8; child++) {
        const int bx = (child >> 2) & 1, by = (child >> 1) & 1, bz = child & 1;
        for (size_t i = 0; i < n; i++) {
            const unsigned nb = neighbours[i];
            const int side = ((nb >> bx) & 1) + ((nb >> (2 + by)) & 1) + ((nb >> (4 + bz)) & 1);
            const int before = popcount8(occ[i]);
            int bit = 1;
            if (child < 7 || before > 0) { /* child 7 of a node with no other child is occupied: not coded */
                const int ctx = 3 * side + (before < 2 ? before : 2);
                if (tw_range_decode_bit(rc, table[ctx], &bit, err)) return TW_ERROR_INVALID;
            }
            occ[i] |= (uint8_t)(bit << child);
        }
    }
    return TW_OK;
}

/* One level of population count + rank (octree._decode_popcount). patterns[k][r]: the r-th code with k bits set;
 * pop: n bytes of scratch. */
static int decode_popcount(tw_range *rc, const unsigned char *hist, size_t n, const tw_model *uniform,
                           const uint8_t patterns[9][70], uint8_t *occ, uint8_t *pop, tw_error *err) {
    tw_model model;
    if (tw_model_histogram(&model, hist, MODEL_BYTES_PER_LEVEL, err)) return TW_ERROR_INVALID;
    for (size_t i = 0; i < n; i++) {
        int symbol;
        if (tw_range_decode(rc, &model, &symbol, err)) return TW_ERROR_INVALID;
        pop[i] = (uint8_t)(symbol + 1);
        occ[i] = 255; /* k = 8: code 255, which codes nothing */
    }
    for (int k = 1; k <= 7; k++) /* ranks grouped by population k = 1..7, nodes in level order */
        for (size_t i = 0; i < n; i++) {
            if (pop[i] != k) continue;
            int rank;
            if (tw_range_decode(rc, &uniform[k], &rank, err)) return TW_ERROR_INVALID;
            occ[i] = patterns[k][rank];
        }
    return TW_OK;
}

int tw_decode_octree(const unsigned char *section, size_t size, int bits, uint32_t n, int contexts, int32_t *cells,
                     tw_error *err) {
    if (bits < 6 || bits > 16) return tw_fail(err, TW_ERROR_ARGUMENT, "octree: %d position bits", bits);
    if (n == 0) return TW_OK;
    /* octree.model_size */
    unsigned mask = 0;
    size_t pos = 0, models = (size_t)bits * MODEL_BYTES_PER_LEVEL;
    static const char *const short_models = "invalid .tw payload: the positions section is shorter than its models";
    if (contexts) {
        if (size < LEVEL_MASK_BYTES) return tw_fail(err, TW_ERROR_INVALID, "%s", short_models);
        mask = (unsigned)section[0] | (unsigned)section[1] << 8;
        if (mask >> bits)
            return tw_fail(err, TW_ERROR_INVALID,
                           "invalid .tw payload: bit-coded octree levels beyond the position bits");
        models = LEVEL_MASK_BYTES + models + (size_t)popcount8(mask & 0xFF) * (CONTEXTS - MODEL_BYTES_PER_LEVEL) +
                 (size_t)popcount8(mask >> 8) * (CONTEXTS - MODEL_BYTES_PER_LEVEL);
        pos = LEVEL_MASK_BYTES;
    }
    if (size < models) return tw_fail(err, TW_ERROR_INVALID, "%s", short_models);
    tw_range rc;
    if (tw_range_open(&rc, section + models, size - models, "positions", err)) return TW_ERROR_INVALID;

    /* the codes with k bits set, ascending (octree.PATTERNS), and the uniform models of their ranks */
    uint8_t patterns[9][70];
    int found[9] = {0};
    for (int code = 0; code < 256; code++) {
        int k = popcount8((unsigned)code);
        patterns[k][found[k]++] = (uint8_t)code;
    }
    tw_model uniform[8];
    for (int k = 1; k <= 7; k++)
        if (tw_model_uniform(&uniform[k], (size_t)found[k], err)) return TW_ERROR_INTERNAL;

    int status = TW_OK;
    uint64_t *keys = (uint64_t *)malloc((size_t)n * sizeof(uint64_t));
    uint64_t *next = (uint64_t *)malloc((size_t)n * sizeof(uint64_t));
    uint8_t *occ = (uint8_t *)malloc((size_t)n);
    uint8_t *scratch = (uint8_t *)malloc((size_t)n); /* face neighbours or population counts */
    if (!keys || !next || !occ || !scratch) {
        status = tw_fail(err, TW_ERROR_MEMORY, "out of memory for an octree of %u points", n);
        goto done;
    }
    size_t count = 1; /* the root: one node, key 0 */
    keys[0] = 0;
    for (int level = 0; level < bits; level++) {
        const int bitwise = (mask >> level) & 1;
        const unsigned char *table = section + pos;
        pos += bitwise ? CONTEXTS : MODEL_BYTES_PER_LEVEL;
        if (bitwise)
            status = decode_bitwise(&rc, table, keys, count, level, occ, scratch, err);
        else
            status = decode_popcount(&rc, table, count, uniform, (const uint8_t(*)[70])patterns, occ, scratch, err);
        if (status) goto done;
        uint64_t total = 0;
        for (size_t i = 0; i < count; i++) total += (uint64_t)popcount8(occ[i]);
        if (total > n) {
            status = tw_fail(err, TW_ERROR_INVALID, "corrupted .tw file: the octree has more than %u points", n);
            goto done;
        }
        size_t m = 0;
        for (size_t i = 0; i < count; i++)
            for (int child = 0; child < 8; child++)
                if ((occ[i] >> child) & 1) next[m++] = keys[i] << 3 | (uint64_t)child;
        uint64_t *swap = keys;
        keys = next;
        next = swap;
        count = m;
    }
    if (count != n) {
        status = tw_fail(err, TW_ERROR_INVALID, "corrupted .tw file: the octree has %zu points, the header says %u",
                         count, n);
        goto done;
    }
    for (size_t i = 0; i < count; i++) /* octree._cells_from_keys: x at key bits 3j + 2, y 3j + 1, z 3j */
        for (int axis = 0; axis < 3; axis++) cells[3 * i + (size_t)axis] = (int32_t)compact3(keys[i] >> (2 - axis));
done:
    free(keys);
    free(next);
    free(occ);
    free(scratch);
    return status;
}
