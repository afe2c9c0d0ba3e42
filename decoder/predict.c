/*
 * predict.c -- the s prediction of formats/README.md ("s section, predicted"): causal neighbours, predictor
 * weights and the sequential pass, bit for bit as formats/predict.py computes them.
 *
 * Two users share these kernels:
 *   - the decoder core (tw_predict_s: residuals in, s symbols out, one fused pass over the points);
 *   - the Python package's compiled fast path (formats/_native.c, a thin binding that hands numpy buffers to the
 *     row kernels below; formats/predict.py stays the reference and answers the work bound's rows itself).
 *
 * Every binary64 operation is rounded on its own in the written order: compile with -ffp-contract=off and never
 * -ffast-math, on a target without excess precision (FLT_EVAL_METHOD 0: SSE2 on x86, wasm32, aarch64).
 * Integer distances are exact int64. No global mutable state: every table lives in a tw_neighbor_search or
 * tw_point_tree the caller owns.
 */
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

#if !defined(FLT_EVAL_METHOD) || FLT_EVAL_METHOD != 0
#error "binary64 arithmetic without excess precision is required (e.g. SSE2 on x86)"
#endif

#define BIG_REACH ((int64_t)1 << 31) /* reach toward a side without cells (below coordinate 0): R*R < 2**62 */
#define EMPTY_KEY UINT64_MAX

/* ------------------------------------------------------------------------------------------------------------ */
/* Morton codes */

static uint64_t spread3(uint64_t v) { /* bit b -> bit 3b, 21 bits (no aliasing for coordinates up to 2**16) */
    v &= 0x1FFFFF;
    v = (v | (v << 32)) & 0x1F00000000FFFFULL;
    v = (v | (v << 16)) & 0x1F0000FF0000FFULL;
    v = (v | (v << 8)) & 0x100F00F00F00F00FULL;
    v = (v | (v << 4)) & 0x10C30C30C30C30C3ULL;
    v = (v | (v << 2)) & 0x1249249249249249ULL;
    return v;
}

uint64_t tw_morton_key(uint64_t x, uint64_t y, uint64_t z) {
    return (spread3(x) << 2) | (spread3(y) << 1) | spread3(z);
}

int tw_predict_first_level(const int64_t *morton, int64_t n) {
    /* predict.py _first_level: the finest level whose occupied cells hold GRID_POINTS_PER_CELL (4) points on
     * average, or a single cell. Terminates: Morton codes of 16-bit cells are below 2**48. */
    for (int level = 0;; level++) {
        int64_t occupied = n > 0 ? 1 : 0;
        for (int64_t i = 1; i < n; i++) occupied += (morton[i] >> (3 * level)) != (morton[i - 1] >> (3 * level));
        if (n >= 4 * occupied || occupied == 1) return level;
    }
}

/* ------------------------------------------------------------------------------------------------------------ */
/* neighbour search on the Morton-ordered cells (the rule of formats/README.md step 1, searched level by level) */

/* Occupied cells of one level: an open-addressing hash from the cell's Morton key (the points' codes >> 3 level)
 * to its range of point indices [start, end). Built on first use of the level: O(N) time and memory. */
typedef struct {
    uint64_t *key; /* EMPTY_KEY: empty slot */
    int64_t *start, *end;
    uint64_t mask;
    int shift;
} cell_table;

typedef struct { /* the 3x3x3 block of the last cell looked up at one level */
    int64_t cell[3];
    int64_t start[27], end[27];
    int64_t total;
    int valid;
} cell_block;

struct tw_neighbor_search {
    const int64_t *cells, *morton;
    int64_t n, k, bound_rank, cap;
    int first_level;
    int64_t *dist; /* min(n, cap) squared distances of one block */
    cell_table tables[TW_PREDICT_COORD_BITS + 1];
    cell_block blocks[TW_PREDICT_COORD_BITS + 1];
};

static uint64_t slot_of(const cell_table *t, uint64_t key) { return (key * 0x9E3779B97F4A7C15ULL) >> t->shift; }

static int build_table(cell_table *t, const int64_t *morton, int64_t n, int level) {
    int64_t cells = n > 0 ? 1 : 0;
    for (int64_t i = 1; i < n; i++) cells += (morton[i] >> (3 * level)) != (morton[i - 1] >> (3 * level));
    int bits = 4;
    while (((int64_t)1 << bits) < 2 * cells) bits++;
    uint64_t size = (uint64_t)1 << bits;
    if (size > SIZE_MAX / sizeof(uint64_t)) return -1; /* a 32-bit target (wasm32) with a huge n */
    t->key = (uint64_t *)malloc((size_t)size * sizeof(uint64_t));
    t->start = (int64_t *)malloc((size_t)size * sizeof(int64_t));
    t->end = (int64_t *)malloc((size_t)size * sizeof(int64_t));
    if (!t->key || !t->start || !t->end) return -1;
    t->mask = size - 1;
    t->shift = 64 - bits;
    for (uint64_t s = 0; s < size; s++) t->key[s] = EMPTY_KEY;
    for (int64_t a = 0; a < n;) {
        uint64_t key = (uint64_t)(morton[a] >> (3 * level));
        int64_t e = a + 1;
        while (e < n && (uint64_t)(morton[e] >> (3 * level)) == key) e++;
        uint64_t s = slot_of(t, key);
        while (t->key[s] != EMPTY_KEY) s = (s + 1) & t->mask;
        t->key[s] = key;
        t->start[s] = a;
        t->end[s] = e;
        a = e;
    }
    return 0;
}

static void free_table(cell_table *t) {
    free(t->key);
    free(t->start);
    free(t->end);
    t->key = NULL;
    t->start = t->end = NULL;
}

static void fill_block(cell_block *b, const cell_table *t, const int64_t c[3]) {
    int s = 0;
    b->total = 0;
    for (int dx = -1; dx <= 1; dx++)
        for (int dy = -1; dy <= 1; dy++)
            for (int dz = -1; dz <= 1; dz++, s++) {
                int64_t x = c[0] + dx, y = c[1] + dy, z = c[2] + dz;
                b->start[s] = b->end[s] = 0;
                if (x < 0 || y < 0 || z < 0) continue;
                uint64_t key = tw_morton_key((uint64_t)x, (uint64_t)y, (uint64_t)z);
                for (uint64_t h = slot_of(t, key); t->key[h] != EMPTY_KEY; h = (h + 1) & t->mask)
                    if (t->key[h] == key) {
                        b->start[s] = t->start[h];
                        b->end[s] = t->end[h];
                        b->total += t->end[h] - t->start[h];
                        break;
                    }
            }
    memcpy(b->cell, c, sizeof b->cell);
    b->valid = 1;
}

/* The 27 cells of a block (index (dx + 1) * 9 + (dy + 1) * 3 + dz + 1) by |dx| + |dy| + |dz|: own cell, faces,
 * edges, corners; cell_delta: the offsets of each index. */
static const int near_first[27] = {13, 4, 10, 12, 14, 16, 22, 1, 3, 5, 7, 9, 11, 15, 17, 19, 21, 23, 25,
                                   0, 2, 6, 8, 18, 20, 24, 26};
static const int cell_delta[27][3] = {
    {-1, -1, -1}, {-1, -1, 0}, {-1, -1, 1}, {-1, 0, -1}, {-1, 0, 0}, {-1, 0, 1}, {-1, 1, -1}, {-1, 1, 0}, {-1, 1, 1},
    {0, -1, -1},  {0, -1, 0},  {0, -1, 1},  {0, 0, -1},  {0, 0, 0},  {0, 0, 1},  {0, 1, -1},  {0, 1, 0},  {0, 1, 1},
    {1, -1, -1},  {1, -1, 0},  {1, -1, 1},  {1, 0, -1},  {1, 0, 0},  {1, 0, 1},  {1, 1, -1},  {1, 1, 0},  {1, 1, 1}};

/* Is (d, j) before (topd[m], topj[m]) in the (D, index) order? */
#define BEFORE(d, j, m) ((d) < topd[m] || ((d) == topd[m] && (j) < topj[m]))

/* Offer candidate (d, j) to the list topd/topj of the *found (at most k) nearest so far, kept sorted by (D, index). */
static inline void offer(int64_t *topd, int64_t *topj, int64_t *found, int64_t k, int64_t d, int64_t j) {
    if (*found == k && !BEFORE(d, j, *found - 1)) return;
    int64_t m = *found < k ? (*found)++ : k - 1;
    while (m > 0 && BEFORE(d, j, m - 1)) {
        topd[m] = topd[m - 1];
        topj[m] = topj[m - 1];
        m--;
    }
    topd[m] = d;
    topj[m] = j;
}

static void write_row(int64_t *idx, int64_t *d2, int64_t k, const int64_t *topj, const int64_t *topd, int64_t keep) {
    for (int64_t m = 0; m < k; m++) {
        idx[m] = m < keep ? topj[m] : -1;
        d2[m] = m < keep ? topd[m] : 0;
    }
}

int tw_neighbors_begin(tw_neighbor_search **out, const int64_t *cells, const int64_t *morton, int64_t n, int64_t k,
                       int64_t bound_rank, int first_level, int64_t cap) {
    *out = NULL;
    if (n < 0 || k < 1 || k > TW_PREDICT_MAX_K || bound_rank < 1 || first_level < 0 ||
        first_level > TW_PREDICT_COORD_BITS || cap < 1)
        return TW_ERROR_ARGUMENT;
    for (int64_t i = 0; i < 3 * n; i++)
        if (cells[i] < 0 || cells[i] >= ((int64_t)1 << TW_PREDICT_COORD_BITS)) return TW_ERROR_ARGUMENT;
    for (int64_t i = 1; i < n; i++)
        if (morton[i] <= morton[i - 1]) return TW_ERROR_ARGUMENT;
    tw_neighbor_search *s = (tw_neighbor_search *)calloc(1, sizeof *s);
    if (!s) return TW_ERROR_MEMORY;
    int64_t buf_len = n < cap ? n : cap;
    s->dist = (int64_t *)malloc((size_t)(buf_len > 0 ? buf_len : 1) * sizeof(int64_t));
    if (!s->dist) {
        free(s);
        return TW_ERROR_MEMORY;
    }
    s->cells = cells;
    s->morton = morton;
    s->n = n;
    s->k = k;
    s->bound_rank = bound_rank;
    s->cap = cap;
    s->first_level = first_level;
    *out = s;
    return TW_OK;
}

void tw_neighbors_end(tw_neighbor_search *s) {
    if (!s) return;
    for (int l = 0; l <= TW_PREDICT_COORD_BITS; l++) free_table(&s->tables[l]);
    free(s->dist);
    free(s);
}

int tw_neighbors_row(tw_neighbor_search *s, int64_t i, int64_t *idx, int64_t *d2) {
    const int64_t *cells = s->cells, *p = s->cells + 3 * i;
    const int64_t n = s->n, k = s->k, bound_rank = s->bound_rank;
    const int bounded = n > bound_rank; /* else every earlier point is a candidate */
    int64_t topd[TW_PREDICT_MAX_K], topj[TW_PREDICT_MAX_K];
    int64_t need = i < k ? i : k, found = 0;
    for (int level = s->first_level; level <= TW_PREDICT_COORD_BITS; level++) {
        const int64_t side = (int64_t)1 << level;
        int64_t c[3], reach = BIG_REACH;
        for (int a = 0; a < 3; a++) {
            c[a] = p[a] >> level;
            int64_t off = p[a] & (side - 1);
            int64_t below = c[a] == 0 ? BIG_REACH : side + off; /* no cells below coordinate 0 */
            int64_t above = 2 * side - 1 - off;
            if (below < reach) reach = below;
            if (above < reach) reach = above;
        }
        const int64_t r2 = reach * reach;
        cell_block *b = &s->blocks[level];
        if (!s->tables[level].key && build_table(&s->tables[level], s->morton, n, level)) {
            free_table(&s->tables[level]);
            return -TW_ERROR_MEMORY;
        }
        if (!b->valid || b->cell[0] != c[0] || b->cell[1] != c[1] || b->cell[2] != c[2])
            fill_block(b, &s->tables[level], c);
        if (b->total > s->cap) return 1; /* work bound: the caller's fallback answers this point */
        const int everything = b->total == n;
        found = 0;
        if (!bounded || b->total < bound_rank) {
            /* Fewer than bound_rank points in the block: fewer than that lie within any settled neighbour's
             * distance, so the bound cuts nothing and only earlier points matter. Cells nearest first; once k are
             * found, a cell whose box lies farther than the k-th is skipped. */
            int64_t gaps[3][3]; /* per axis, the distance from the point to the cells below, its own, above */
            for (int ax = 0; ax < 3; ax++) {
                const int64_t off = p[ax] & (side - 1);
                gaps[ax][0] = off + 1;
                gaps[ax][1] = 0;
                gaps[ax][2] = side - off;
            }
            for (int q = 0; q < 27; q++) {
                const int sl = near_first[q];
                const int64_t a = b->start[sl], e = b->end[sl] < i ? b->end[sl] : i;
                if (a >= e) continue;
                if (found == k) {
                    int64_t lb = 0;
                    for (int ax = 0; ax < 3; ax++) {
                        const int64_t gap = gaps[ax][cell_delta[sl][ax] + 1];
                        lb += gap * gap;
                    }
                    if (lb > topd[k - 1]) continue;
                }
                for (int64_t j = a; j < e; j++) {
                    const int64_t *q3 = cells + 3 * j;
                    int64_t dx = q3[0] - p[0], dy = q3[1] - p[1], dz = q3[2] - p[2];
                    offer(topd, topj, &found, k, dx * dx + dy * dy + dz * dz, j);
                }
            }
            if (!(everything || (found >= need && (need == 0 || topd[need - 1] <= r2)))) continue;
            write_row(idx, d2, k, topj, topd, found);
            return 0;
        }
        /* every point of the block: its distance, and the k nearest earlier ones by (D, index) */
        int64_t *dist = s->dist, t = 0;
        for (int sl = 0; sl < 27; sl++) {
            for (int64_t j = b->start[sl]; j < b->end[sl]; j++) {
                const int64_t *q = cells + 3 * j;
                int64_t dx = q[0] - p[0], dy = q[1] - p[1], dz = q[2] - p[2];
                int64_t d = dx * dx + dy * dy + dz * dz; /* < 3 * 2**32 */
                dist[t++] = d;
                if (j < i) offer(topd, topj, &found, k, d, j);
            }
        }
        /* Settled when the block holds every point, or the min(i, k) nearest earlier points lie within the reach
         * (every point within it is in the block), or bound_rank points do (then B_i <= reach^2 and every
         * candidate below B_i is in the block). */
        int settled = everything || (found >= need && (need == 0 || topd[need - 1] <= r2));
        if (!settled && bounded) {
            int64_t within = 0;
            for (int64_t u = 0; u < t; u++) within += dist[u] <= r2;
            settled = within >= bound_rank;
        }
        if (!settled) continue;
        /* D < B_i  <=>  fewer than bound_rank points at distance <= D; exact from the block in every settled case
         * (D within the reach, or the block's count already reaches the rank). Monotone in slot order. */
        int64_t keep = found;
        if (bounded && found > 0) {
            int64_t count = 0;
            for (int64_t u = 0; u < t; u++) count += dist[u] <= topd[found - 1];
            if (count >= bound_rank) {
                keep = 0;
                while (keep < found) {
                    count = 0;
                    for (int64_t u = 0; u < t; u++) count += dist[u] <= topd[keep];
                    if (count >= bound_rank) break;
                    keep++;
                }
            }
        }
        write_row(idx, d2, k, topj, topd, keep);
        return 0;
    }
    return 1; /* unreachable: at level 16 the block holds every point */
}

/* ------------------------------------------------------------------------------------------------------------ */
/* the work bound's fallback: an exact search over a bounding-box hierarchy of the Morton-ordered points */

#define TREE_LEAF 8 /* points per leaf: a contiguous range of the Morton order */

struct tw_point_tree {
    const int64_t *cells;
    int64_t n, leaves, size; /* size: leaves rounded up to a power of two; nodes 1 .. 2 size - 1 */
    int32_t *box;            /* per node: min x, y, z, max x, y, z; min > max for a node without points */
    int64_t *heap;           /* the bound_rank smallest distances of one query (a max-heap) */
    int64_t heap_cap;
};

int tw_point_tree_build(tw_point_tree **out, const int64_t *cells, int64_t n) {
    *out = NULL;
    tw_point_tree *t = (tw_point_tree *)calloc(1, sizeof *t);
    if (!t) return TW_ERROR_MEMORY;
    t->cells = cells;
    t->n = n;
    t->leaves = (n + TREE_LEAF - 1) / TREE_LEAF;
    t->size = 1;
    while (t->size < t->leaves) t->size *= 2;
    t->box = (int32_t *)malloc((size_t)(2 * t->size) * 6 * sizeof(int32_t));
    if (!t->box) {
        free(t);
        return TW_ERROR_MEMORY;
    }
    for (int64_t v = 0; v < 2 * t->size; v++) {
        int32_t *b = t->box + 6 * v;
        b[0] = b[1] = b[2] = INT32_MAX;
        b[3] = b[4] = b[5] = INT32_MIN;
    }
    for (int64_t j = 0; j < n; j++) { /* cells are below 2**16 (checked by the caller's search) */
        int32_t *b = t->box + 6 * (t->size + j / TREE_LEAF);
        for (int a = 0; a < 3; a++) {
            int32_t x = (int32_t)cells[3 * j + a];
            if (x < b[a]) b[a] = x;
            if (x > b[3 + a]) b[3 + a] = x;
        }
    }
    for (int64_t v = t->size - 1; v >= 1; v--) {
        int32_t *b = t->box + 6 * v, *l = t->box + 12 * v, *r = t->box + 12 * v + 6;
        for (int a = 0; a < 3; a++) {
            b[a] = l[a] < r[a] ? l[a] : r[a];
            b[3 + a] = l[3 + a] > r[3 + a] ? l[3 + a] : r[3 + a];
        }
    }
    *out = t;
    return TW_OK;
}

void tw_point_tree_free(tw_point_tree *t) {
    if (!t) return;
    free(t->box);
    free(t->heap);
    free(t);
}

/* Squared distance from p to node v's box (0 inside); INT64_MAX for a node without points. */
static int64_t box_distance(const tw_point_tree *t, int64_t v, const int64_t *p) {
    const int32_t *b = t->box + 6 * v;
    if (b[0] > b[3]) return INT64_MAX;
    int64_t lb = 0;
    for (int a = 0; a < 3; a++) {
        int64_t g = p[a] < b[a] ? b[a] - p[a] : p[a] > b[3 + a] ? p[a] - b[3 + a] : 0;
        lb += g * g;
    }
    return lb;
}

static void heap_push(int64_t *heap, int64_t *count, int64_t cap, int64_t d) {
    /* max-heap of the cap smallest distances seen */
    if (*count == cap) {
        if (d >= heap[0]) return;
        int64_t m = 0; /* replace the root and sift down */
        for (;;) {
            int64_t l = 2 * m + 1, r = l + 1, big = m;
            int64_t vbig = d;
            if (l < cap && heap[l] > vbig) big = l, vbig = heap[l];
            if (r < cap && heap[r] > vbig) big = r, vbig = heap[r];
            if (big == m) break;
            heap[m] = heap[big];
            m = big;
        }
        heap[m] = d;
        return;
    }
    int64_t m = (*count)++;
    while (m > 0 && heap[(m - 1) / 2] < d) {
        heap[m] = heap[(m - 1) / 2];
        m = (m - 1) / 2;
    }
    heap[m] = d;
}

int tw_point_tree_neighbors(tw_point_tree *t, int64_t i, int64_t k, int64_t bound_rank, int64_t *idx, int64_t *d2) {
    /* predict.py _tree_rows: q = min(bound_rank, n); B = the q-th smallest D_ij over all points j (i itself
     * included, as 0) when q < n, else no bound; the k earlier points j < i with D_ij < B, by (D, j). */
    const int64_t n = t->n, *p = t->cells + 3 * i;
    if (k < 1 || k > TW_PREDICT_MAX_K || bound_rank < 1 || i < 0 || i >= n) return TW_ERROR_ARGUMENT;
    int64_t stack[2 * 64], top;
    int64_t bound = INT64_MAX;
    const int64_t q = bound_rank < n ? bound_rank : n;
    if (q < n) {
        if (t->heap_cap < q) {
            free(t->heap);
            t->heap = (int64_t *)malloc((size_t)q * sizeof(int64_t));
            t->heap_cap = t->heap ? q : 0;
            if (!t->heap) return TW_ERROR_MEMORY;
        }
        int64_t count = 0;
        top = 0;
        stack[top++] = 1;
        while (top) {
            int64_t v = stack[--top];
            int64_t lb = box_distance(t, v, p);
            if (lb == INT64_MAX || (count == q && lb >= t->heap[0])) continue;
            if (v >= t->size) {
                int64_t a = (v - t->size) * TREE_LEAF, e = a + TREE_LEAF < n ? a + TREE_LEAF : n;
                for (int64_t j = a; j < e; j++) {
                    const int64_t *c = t->cells + 3 * j;
                    int64_t dx = c[0] - p[0], dy = c[1] - p[1], dz = c[2] - p[2];
                    heap_push(t->heap, &count, q, dx * dx + dy * dy + dz * dz);
                }
                continue;
            }
            /* the nearer child last, so that it is searched first */
            int64_t l = 2 * v, r = 2 * v + 1;
            if (box_distance(t, l, p) < box_distance(t, r, p)) {
                stack[top++] = r;
                stack[top++] = l;
            } else {
                stack[top++] = l;
                stack[top++] = r;
            }
        }
        bound = t->heap[0]; /* count == q: the tree holds n > q points */
    }
    int64_t topd[TW_PREDICT_MAX_K], topj[TW_PREDICT_MAX_K], found = 0;
    top = 0;
    stack[top++] = 1;
    while (top) {
        int64_t v = stack[--top];
        /* the first point of node v: nodes of the deepest level hold TREE_LEAF points each */
        int64_t depth_size = 1;
        while (depth_size * 2 <= v) depth_size *= 2;
        int64_t first = (v - depth_size) * (t->size / depth_size) * TREE_LEAF;
        if (first >= i) continue; /* no earlier point below */
        int64_t lb = box_distance(t, v, p);
        if (lb >= bound || (found == k && lb > topd[k - 1])) continue;
        if (v >= t->size) {
            int64_t e = first + TREE_LEAF < i ? first + TREE_LEAF : i;
            for (int64_t j = first; j < e; j++) {
                const int64_t *c = t->cells + 3 * j;
                int64_t dx = c[0] - p[0], dy = c[1] - p[1], dz = c[2] - p[2];
                int64_t d = dx * dx + dy * dy + dz * dz;
                if (d < bound) offer(topd, topj, &found, k, d, j);
            }
            continue;
        }
        int64_t l = 2 * v, r = 2 * v + 1;
        if (box_distance(t, l, p) < box_distance(t, r, p)) {
            stack[top++] = r;
            stack[top++] = l;
        } else {
            stack[top++] = l;
            stack[top++] = r;
        }
    }
    write_row(idx, d2, k, topj, topd, found);
    return TW_OK;
}

/* ------------------------------------------------------------------------------------------------------------ */
/* weights and the sequential pass */

int tw_predict_weights_row(const int64_t *cells, int64_t n, int64_t i, const int64_t *row, const int64_t *rd,
                           int64_t k, double ridge_factor, double *beta) {
    /* The weights of formats/predict.py predictor_weights, every binary64 operation in its order. Its numpy code
     * adds the terms of missing slots (idx -1) too, but each such term is +-0.0 and a sum that starts at +0.0
     * never becomes -0.0, so adding it leaves the sum's bits unchanged: skipping them is exact. */
    const int64_t *p = cells + 3 * i;
    double d[TW_PREDICT_MAX_K][3], w[TW_PREDICT_MAX_K], e[TW_PREDICT_MAX_K][3];
    int64_t have[TW_PREDICT_MAX_K], h = 0;
    if (k < 0 || k > TW_PREDICT_MAX_K) return -1;
    for (int64_t m = 0; m < k; m++) {
        int64_t j = row[m];
        beta[m] = 0.0;
        if (j < 0) continue;
        if (j >= n || rd[m] <= 0) return -1;
        have[h] = m;
        for (int a = 0; a < 3; a++) d[h][a] = (double)(cells[3 * j + a] - p[a]); /* exact: |x| < 2**17 */
        w[h] = 1.0 / (double)rd[m];
        h++;
    }
    double sw = 0.0, mm[3] = {0.0, 0.0, 0.0};
    for (int64_t s = 0; s < h; s++) sw = sw + w[s];
    double safe_sw = sw > 0 ? sw : 1.0;
    for (int a = 0; a < 3; a++) {
        double acc = 0.0;
        for (int64_t s = 0; s < h; s++) acc = acc + w[s] * d[s][a];
        mm[a] = acc / safe_sw;
    }
    for (int64_t s = 0; s < h; s++)
        for (int a = 0; a < 3; a++) e[s][a] = d[s][a] - mm[a];
    double c[3][3];
    for (int a = 0; a < 3; a++)
        for (int b = a; b < 3; b++) {
            double acc = 0.0;
            for (int64_t s = 0; s < h; s++) acc = acc + w[s] * (e[s][a] * e[s][b]);
            c[a][b] = acc;
        }
    double ridge = ridge_factor * sw;
    double m00 = c[0][0] + ridge, m01 = c[0][1], m02 = c[0][2];
    double m11 = c[1][1] + ridge, m12 = c[1][2], m22 = c[2][2] + ridge;
    double a00 = m11 * m22 - m12 * m12;
    double a01 = m02 * m12 - m01 * m22;
    double a02 = m01 * m12 - m02 * m11;
    double a11 = m00 * m22 - m02 * m02;
    double a12 = m01 * m02 - m00 * m12;
    double a22 = m00 * m11 - m01 * m01;
    double det = (m00 * a00 + m01 * a01) + m02 * a02;
    double safe_det = sw > 0 ? det : 1.0;
    double h0 = ((a00 * mm[0] + a01 * mm[1]) + a02 * mm[2]) / safe_det;
    double h1 = ((a01 * mm[0] + a11 * mm[1]) + a12 * mm[2]) / safe_det;
    double h2 = ((a02 * mm[0] + a12 * mm[1]) + a22 * mm[2]) / safe_det;
    double inv_w = 1.0 / safe_sw;
    for (int64_t s = 0; s < h; s++) {
        double he = (h0 * e[s][0] + h1 * e[s][1]) + h2 * e[s][2];
        beta[have[s]] = w[s] * (inv_w - he);
    }
    return 0;
}

int tw_predict_symbol(int64_t i, const int64_t *row, const double *b, int64_t k, const double *u, double lo,
                      double hi, int64_t residual, int64_t bound, int64_t *sym, double *sum) {
    /* a = ((b0 u0 + b1 u1) + b2 u2) + ...: the first term alone, then each next one added, as the reference's
     * Python expression evaluates it; a missing neighbour (-1, beta 0) reads u = 0.0 as the reference does. */
    double a = 0.0;
    for (int64_t m = 0; m < k; m++) {
        int64_t j = row[m];
        if (j < -1 || j >= i) return 2;
        double term = b[m] * (j >= 0 ? u[j] : 0.0);
        a = m == 0 ? term : a + term;
    }
    if (sum) *sum = a;
    if (isnan(a)) return 1;
    double clamped = a < lo ? lo : a > hi ? hi : a;
    int64_t r = residual < -bound ? -bound : residual > bound ? bound : residual;
    *sym = (int64_t)floor(clamped) + r; /* |sym| < 2**51 for the bounds the callers pass: u = sym + 1/2 exact */
    return 0;
}

/* ------------------------------------------------------------------------------------------------------------ */
/* the decoder core's s prediction */

int tw_predict_s(const int32_t *cells32, size_t count, const int32_t *residual, int32_t *symbols, tw_error *err) {
    const int64_t n = (int64_t)count, k = TW_PREDICT_K;
    if (n == 0) return TW_OK;
    int status = TW_OK;
    int64_t *cells = (int64_t *)malloc((size_t)n * 3 * sizeof(int64_t));
    int64_t *morton = (int64_t *)malloc((size_t)n * sizeof(int64_t));
    double *u = (double *)malloc((size_t)n * sizeof(double));
    tw_neighbor_search *search = NULL;
    tw_point_tree *tree = NULL;
    if (!cells || !morton || !u) {
        status = tw_fail(err, TW_ERROR_MEMORY, "out of memory for the s prediction of %lld points", (long long)n);
        goto done;
    }
    for (int64_t i = 0; i < n; i++) {
        for (int a = 0; a < 3; a++) cells[3 * i + a] = cells32[3 * i + a];
        const uint64_t *xyz = (const uint64_t *)(cells + 3 * i);
        morton[i] = (int64_t)tw_morton_key(xyz[0], xyz[1], xyz[2]);
    }
    if (n >= 2) {
        int rc = tw_neighbors_begin(&search, cells, morton, n, k, TW_PREDICT_BOUND_RANK,
                                    tw_predict_first_level(morton, n), TW_PREDICT_MAX_CANDIDATES);
        if (rc == TW_ERROR_MEMORY) {
            status = tw_fail(err, rc, "out of memory for the s prediction's neighbour search");
            goto done;
        }
        if (rc) { /* the octree yields unique 16-bit cells in Morton order: a broken caller */
            status = tw_fail(err, TW_ERROR_INTERNAL, "s prediction: cells out of range or not in canonical order");
            goto done;
        }
    }
    const double lo = -(double)TW_PREDICT_SYMBOL_LIMIT, hi = (double)(TW_PREDICT_SYMBOL_LIMIT - 1);
    for (int64_t i = 0; i < n; i++) {
        int64_t idx[TW_PREDICT_K], d2[TW_PREDICT_K];
        double beta[TW_PREDICT_K];
        if (n < 2) {
            write_row(idx, d2, k, NULL, NULL, 0);
        } else {
            int rc = tw_neighbors_row(search, i, idx, d2);
            if (rc == 1) { /* the work bound: the exact tree search answers this point (hostile files only) */
                if (!tree && tw_point_tree_build(&tree, cells, n)) rc = -TW_ERROR_MEMORY;
                else rc = tw_point_tree_neighbors(tree, i, k, TW_PREDICT_BOUND_RANK, idx, d2) ? -TW_ERROR_MEMORY : 0;
            }
            if (rc < 0) {
                status = tw_fail(err, TW_ERROR_MEMORY, "out of memory for the s prediction's neighbour search");
                goto done;
            }
        }
        if (tw_predict_weights_row(cells, n, i, idx, d2, k, TW_PREDICT_RIDGE, beta)) {
            status = tw_fail(err, TW_ERROR_INTERNAL, "s prediction: neighbour index or distance out of range");
            goto done;
        }
        int64_t sym;
        int rc = tw_predict_symbol(i, idx, beta, k, u, lo, hi, residual[i], TW_PREDICT_RESIDUAL_BOUND, &sym, NULL);
        if (rc == 1) {
            status = tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: the s prediction is not a number");
            goto done;
        }
        if (rc) {
            status = tw_fail(err, TW_ERROR_INTERNAL, "s prediction: a neighbour is not an earlier point");
            goto done;
        }
        if (sym < -TW_PREDICT_SYMBOL_LIMIT || sym > TW_PREDICT_SYMBOL_LIMIT - 1) {
            status = tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: s symbol out of range");
            goto done;
        }
        symbols[i] = (int32_t)sym;
        u[i] = (double)sym + 0.5;
    }
done:
    tw_neighbors_end(search);
    tw_point_tree_free(tree);
    free(cells);
    free(morton);
    free(u);
    return status;
}
