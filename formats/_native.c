/* Compiled fast path of the s prediction's decoder loops (formats/predict.py is the reference and the fallback).
 *
 * Two functions, each giving bit for bit what the reference gives:
 *
 *   neighbors(cells, morton, idx, d2, over, k, bound_rank, first_level, cap) -> number of rows in `over`
 *       The causal neighbour rule of formats/README.md ("s section, predicted", step 1): per point i the k points
 *       j < i with the smallest (D_ij, j) among those with D_ij < B_i (the bound_rank-th smallest D_ij over all
 *       points, i itself included; no bound when N <= bound_rank). Exact int64 arithmetic. Points whose search
 *       would scan more than `cap` points at one level are not answered: their rows go to `over` (ascending), for
 *       the reference's k-d tree (the same work bound as the reference).
 *   reconstruct(idx, beta, residual, out, lo, hi, residual_bound[, pred])
 *       The sequential pass (step 3): a = ((b0 u0 + b1 u1) + b2 u2) + ... in binary64, floor of a clamped to
 *       [lo, hi], plus the residual (clamped to +-residual_bound, as the reference does). ValueError on a NaN
 *       (as Python's math.floor) or on a neighbour index that is not an earlier point. `pred` (optional, float64)
 *       receives every sum a, for tests.
 *
 * Build flags (setup.py): -O2 -ffp-contract=off, never -ffast-math: every binary64 operation rounded on its own,
 * in the written order, so the results equal numpy's and Python's. All arrays are C-contiguous buffers (int64 'q'
 * or 'l' of 8 bytes, float64 'd') checked for size; every index the file controls is bounds-checked.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#if !defined(FLT_EVAL_METHOD) || FLT_EVAL_METHOD != 0
#error "binary64 arithmetic without excess precision is required (e.g. SSE2 on x86); the Python path is used"
#endif

#define MAX_K 64
#define COORD_BITS 16 /* formats/quantize.morton_keys interleaves the low 16 bits of each coordinate */
#define BIG_REACH ((int64_t)1 << 31) /* reach toward a side without cells (below coordinate 0): R*R < 2**62 */

/* ------------------------------------------------------------------------------------------------------------ */
/* buffers */

static int get_buffer(PyObject *obj, Py_buffer *view, char kind, Py_ssize_t count, int writable, const char *name) {
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) != 0) return -1;
    const char *f = view->format ? view->format : "B";
    if (*f == '<' || *f == '=' || *f == '@') f++;
    int ok = view->itemsize == 8 && f[1] == '\0' &&
             (kind == 'd' ? f[0] == 'd' : (f[0] == 'q' || f[0] == 'l'));
    if (!ok || (count >= 0 && view->len != count * 8)) {
        PyBuffer_Release(view);
        PyErr_Format(PyExc_ValueError, "_native: %s must be a C-contiguous %s array of %zd items", name,
                     kind == 'd' ? "float64" : "int64", count);
        return -1;
    }
    return 0;
}

/* ------------------------------------------------------------------------------------------------------------ */
/* neighbour search */

static uint64_t spread3(uint64_t v) { /* bit b -> bit 3b, 21 bits (no aliasing for coordinates up to 2**16) */
    v &= 0x1FFFFF;
    v = (v | (v << 32)) & 0x1F00000000FFFFULL;
    v = (v | (v << 16)) & 0x1F0000FF0000FFULL;
    v = (v | (v << 8)) & 0x100F00F00F00F00FULL;
    v = (v | (v << 4)) & 0x10C30C30C30C30C3ULL;
    v = (v | (v << 2)) & 0x1249249249249249ULL;
    return v;
}

/* Occupied cells of one level: an open-addressing hash from the cell's Morton key (the points' codes >> 3 level)
 * to its range of point indices [start, end). Built on first use of the level: O(N) time and memory. */
typedef struct {
    uint64_t *key; /* UINT64_MAX: empty slot */
    int64_t *start, *end;
    uint64_t mask;
    int shift;
} CellTable;

#define EMPTY_KEY UINT64_MAX

static uint64_t slot_of(const CellTable *t, uint64_t key) { return (key * 0x9E3779B97F4A7C15ULL) >> t->shift; }

static int build_table(CellTable *t, const int64_t *morton, int64_t n, int level) {
    int64_t cells = n > 0 ? 1 : 0;
    for (int64_t i = 1; i < n; i++) cells += (morton[i] >> (3 * level)) != (morton[i - 1] >> (3 * level));
    int bits = 4;
    while (((int64_t)1 << bits) < 2 * cells) bits++;
    uint64_t size = (uint64_t)1 << bits;
    t->key = (uint64_t *)malloc(size * sizeof(uint64_t));
    t->start = (int64_t *)malloc(size * sizeof(int64_t));
    t->end = (int64_t *)malloc(size * sizeof(int64_t));
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

static void free_table(CellTable *t) {
    free(t->key);
    free(t->start);
    free(t->end);
    t->key = NULL;
    t->start = t->end = NULL;
}

typedef struct { /* the 3x3x3 block of the last cell looked up at one level */
    int64_t cell[3];
    int64_t start[27], end[27];
    int64_t total;
    int valid;
} Block;

static void fill_block(Block *b, const CellTable *t, const int64_t c[3]) {
    int s = 0;
    b->total = 0;
    for (int dx = -1; dx <= 1; dx++)
        for (int dy = -1; dy <= 1; dy++)
            for (int dz = -1; dz <= 1; dz++, s++) {
                int64_t x = c[0] + dx, y = c[1] + dy, z = c[2] + dz;
                b->start[s] = b->end[s] = 0;
                if (x < 0 || y < 0 || z < 0) continue;
                uint64_t key = (spread3((uint64_t)x) << 2) | (spread3((uint64_t)y) << 1) | spread3((uint64_t)z);
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

static PyObject *neighbors(PyObject *self, PyObject *args) {
    PyObject *o_cells, *o_morton, *o_idx, *o_d2, *o_over;
    Py_ssize_t k, bound_rank, first_level, cap;
    if (!PyArg_ParseTuple(args, "OOOOOnnnn", &o_cells, &o_morton, &o_idx, &o_d2, &o_over, &k, &bound_rank,
                          &first_level, &cap))
        return NULL;
    if (k < 1 || k > MAX_K || bound_rank < 1 || first_level < 0 || first_level > COORD_BITS || cap < 1) {
        PyErr_SetString(PyExc_ValueError, "_native.neighbors: parameter out of range");
        return NULL;
    }
    Py_buffer vm, vc, vi, vd, vo;
    if (get_buffer(o_morton, &vm, 'q', -1, 0, "morton")) return NULL;
    int64_t n = vm.len / 8;
    if (get_buffer(o_cells, &vc, 'q', 3 * n, 0, "cells")) goto fail_m;
    if (get_buffer(o_idx, &vi, 'q', k * n, 1, "idx")) goto fail_c;
    if (get_buffer(o_d2, &vd, 'q', k * n, 1, "d2")) goto fail_i;
    if (get_buffer(o_over, &vo, 'q', n, 1, "over")) goto fail_d;

    const int64_t *cells = (const int64_t *)vc.buf, *morton = (const int64_t *)vm.buf;
    int64_t *idx = (int64_t *)vi.buf, *d2 = (int64_t *)vd.buf, *over = (int64_t *)vo.buf;
    int64_t n_over = 0;
    int error = 0;
    for (int64_t i = 0; i < 3 * n; i++)
        if (cells[i] < 0 || cells[i] >= ((int64_t)1 << COORD_BITS)) error = 1;
    for (int64_t i = 1; i < n; i++)
        if (morton[i] <= morton[i - 1]) error = 1;
    int64_t buf_len = n < cap ? n : cap;
    int64_t *dist = error ? NULL : (int64_t *)malloc((size_t)(buf_len > 0 ? buf_len : 1) * sizeof(int64_t));
    if (error) {
        PyErr_SetString(PyExc_ValueError, "_native.neighbors: cells out of range or not in canonical order");
        goto done;
    }
    if (!dist) {
        PyErr_NoMemory();
        goto done;
    }
    Block blocks[COORD_BITS + 1];
    CellTable tables[COORD_BITS + 1];
    for (int l = 0; l <= COORD_BITS; l++) {
        blocks[l].valid = 0;
        tables[l].key = NULL;
        tables[l].start = tables[l].end = NULL;
    }
    int no_memory = 0;
    Py_BEGIN_ALLOW_THREADS;
    const int bounded = n > bound_rank; /* else every earlier point is a candidate */
    for (int64_t i = 0; i < n; i++) {
        const int64_t *p = cells + 3 * i;
        int64_t topd[MAX_K], topj[MAX_K];
        int64_t need = i < k ? i : k, found = 0;
        int answered = 0;
        for (int level = (int)first_level; level <= COORD_BITS && !answered; level++) {
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
            Block *b = &blocks[level];
            if (!tables[level].key && build_table(&tables[level], morton, n, level)) {
                no_memory = 1;
                break;
            }
            if (!b->valid || b->cell[0] != c[0] || b->cell[1] != c[1] || b->cell[2] != c[2])
                fill_block(b, &tables[level], c);
            if (b->total > cap) { /* work bound: the reference's k-d tree answers this point */
                over[n_over++] = i;
                answered = 1;
                break;
            }
            const int everything = b->total == n;
            found = 0;
            if (!bounded || b->total < bound_rank) {
                /* Fewer than bound_rank points in the block: fewer than that lie within any settled neighbour's
                 * distance, so the bound cuts nothing and only earlier points matter. Cells nearest first; once
                 * k are found, a cell whose box lies farther than the k-th is skipped. */
                int64_t gaps[3][3]; /* per axis, the distance from the point to the cells below, its own, above */
                for (int ax = 0; ax < 3; ax++) {
                    const int64_t off = p[ax] & (side - 1);
                    gaps[ax][0] = off + 1;
                    gaps[ax][1] = 0;
                    gaps[ax][2] = side - off;
                }
                for (int q = 0; q < 27; q++) {
                    const int s = near_first[q];
                    const int64_t a = b->start[s], e = b->end[s] < i ? b->end[s] : i;
                    if (a >= e) continue;
                    if (found == k) {
                        int64_t lb = 0;
                        for (int ax = 0; ax < 3; ax++) {
                            const int64_t gap = gaps[ax][cell_delta[s][ax] + 1];
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
                for (int64_t m = 0; m < k; m++) {
                    idx[i * k + m] = m < found ? topj[m] : -1;
                    d2[i * k + m] = m < found ? topd[m] : 0;
                }
                answered = 1;
                break;
            }
            /* every point of the block: its distance, and the k nearest earlier ones by (D, index) */
            int64_t t = 0;
            for (int s = 0; s < 27; s++) {
                for (int64_t j = b->start[s]; j < b->end[s]; j++) {
                    const int64_t *q = cells + 3 * j;
                    int64_t dx = q[0] - p[0], dy = q[1] - p[1], dz = q[2] - p[2];
                    int64_t d = dx * dx + dy * dy + dz * dz; /* < 3 * 2**32 */
                    dist[t++] = d;
                    if (j < i) offer(topd, topj, &found, k, d, j);
                }
            }
            /* Settled when the block holds every point, or the min(i, k) nearest earlier points lie within the
             * reach (every point within it is in the block), or bound_rank points do (then B_i <= reach^2 and
             * every candidate below B_i is in the block). */
            int settled = everything || (found >= need && (need == 0 || topd[need - 1] <= r2));
            if (!settled && bounded) {
                int64_t within = 0;
                for (int64_t u = 0; u < t; u++) within += dist[u] <= r2;
                settled = within >= bound_rank;
            }
            if (!settled) continue;
            /* D < B_i  <=>  fewer than bound_rank points at distance <= D; exact from the block in every settled
             * case (D within the reach, or the block's count already reaches the rank). Monotone in slot order. */
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
            for (int64_t m = 0; m < k; m++) {
                idx[i * k + m] = m < keep ? topj[m] : -1;
                d2[i * k + m] = m < keep ? topd[m] : 0;
            }
            answered = 1;
        }
        if (no_memory) break;
        if (!answered) over[n_over++] = i; /* unreachable: at level 16 the block holds every point */
    }
    Py_END_ALLOW_THREADS;
    for (int l = 0; l <= COORD_BITS; l++) free_table(&tables[l]);
    if (no_memory) PyErr_NoMemory();
done:
    free(dist);
    PyBuffer_Release(&vo);
fail_d:
    PyBuffer_Release(&vd);
fail_i:
    PyBuffer_Release(&vi);
fail_c:
    PyBuffer_Release(&vc);
fail_m:
    PyBuffer_Release(&vm);
    if (PyErr_Occurred()) return NULL;
    return PyLong_FromLongLong(n_over);
}

/* ------------------------------------------------------------------------------------------------------------ */
/* sequential pass */

static PyObject *reconstruct(PyObject *self, PyObject *args) {
    PyObject *o_idx, *o_beta, *o_res, *o_out, *o_pred = Py_None;
    double lo, hi;
    long long bound;
    if (!PyArg_ParseTuple(args, "OOOOddL|O", &o_idx, &o_beta, &o_res, &o_out, &lo, &hi, &bound, &o_pred))
        return NULL;
    Py_buffer vr, vi, vb, vo, vp;
    vp.buf = NULL;
    if (get_buffer(o_res, &vr, 'q', -1, 0, "residual")) return NULL;
    int64_t n = vr.len / 8;
    int64_t k = n ? -1 : 0;
    if (get_buffer(o_idx, &vi, 'q', -1, 0, "idx")) goto fail_r;
    if (n) k = (vi.len / 8) / n;
    if (k > MAX_K || vi.len != 8 * k * n) {
        PyErr_SetString(PyExc_ValueError, "_native.reconstruct: idx must be (N, K)");
        goto fail_i;
    }
    if (get_buffer(o_beta, &vb, 'd', k * n, 0, "beta")) goto fail_i;
    if (get_buffer(o_out, &vo, 'q', n, 1, "out")) goto fail_b;
    if (o_pred != Py_None && get_buffer(o_pred, &vp, 'd', n, 1, "pred")) goto fail_o;
    double *pred = (double *)vp.buf; /* optional: the sums a (tests compare them bit for bit) */
    if (!(bound >= 0 && bound <= ((long long)1 << 50) && lo <= hi && fabs(lo) < 0x1p50 && fabs(hi) < 0x1p50)) {
        PyErr_SetString(PyExc_ValueError, "_native.reconstruct: parameter out of range");
        goto done;
    }
    const int64_t *idx = (const int64_t *)vi.buf, *res = (const int64_t *)vr.buf;
    const double *beta = (const double *)vb.buf;
    int64_t *out = (int64_t *)vo.buf;
    double *u = (double *)malloc((size_t)(n > 0 ? n : 1) * sizeof(double));
    if (!u) {
        PyErr_NoMemory();
        goto done;
    }
    int64_t bad = -1;
    int nan = 0;
    Py_BEGIN_ALLOW_THREADS;
    for (int64_t i = 0; i < n && bad < 0; i++) {
        const int64_t *row = idx + i * k;
        const double *b = beta + i * k;
        double a = 0.0;
        for (int64_t m = 0; m < k; m++) {
            int64_t j = row[m];
            if (j < -1 || j >= i) {
                bad = i;
                break;
            }
            /* a missing neighbour (-1, beta 0) reads u = 0.0 as the reference does: the sum gains +0.0 */
            double term = b[m] * (j >= 0 ? u[j] : 0.0);
            a = m == 0 ? term : a + term;
        }
        if (bad >= 0) break;
        if (pred) pred[i] = a;
        if (isnan(a)) {
            nan = 1;
            bad = i;
            break;
        }
        double clamped = a < lo ? lo : a > hi ? hi : a;
        int64_t r = res[i] < -bound ? -bound : res[i] > bound ? bound : res[i];
        int64_t sym = (int64_t)floor(clamped) + r; /* |sym| < 2**51: u = sym + 1/2 is exact */
        out[i] = sym;
        u[i] = (double)sym + 0.5;
    }
    Py_END_ALLOW_THREADS;
    free(u);
    if (bad >= 0)
        PyErr_SetString(PyExc_ValueError, nan ? "cannot convert float NaN to integer"
                                              : "_native.reconstruct: neighbour index is not an earlier point");
done:
    if (vp.buf) PyBuffer_Release(&vp);
fail_o:
    PyBuffer_Release(&vo);
fail_b:
    PyBuffer_Release(&vb);
fail_i:
    PyBuffer_Release(&vi);
fail_r:
    PyBuffer_Release(&vr);
    if (PyErr_Occurred()) return NULL;
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------------------------------------------------ */
/* predictor weights */

/* The weights beta (N, K) of formats/predict.py predictor_weights, every binary64 operation in its order. Its
 * numpy code adds the terms of missing slots (idx -1) too, but each such term is +-0.0 and a sum that starts at
 * +0.0 never becomes -0.0, so adding it leaves the sum's bits unchanged: skipping them is exact. */
static PyObject *weights(PyObject *self, PyObject *args) {
    PyObject *o_cells, *o_idx, *o_d2, *o_beta;
    double ridge_factor;
    if (!PyArg_ParseTuple(args, "OOOOd", &o_cells, &o_idx, &o_d2, &o_beta, &ridge_factor)) return NULL;
    Py_buffer vc, vi, vd, vb;
    if (get_buffer(o_cells, &vc, 'q', -1, 0, "cells")) return NULL;
    int64_t n = vc.len / 24, k = 0;
    if (vc.len != 24 * n) {
        PyErr_SetString(PyExc_ValueError, "_native.weights: cells must be (N, 3)");
        goto fail_c;
    }
    if (get_buffer(o_idx, &vi, 'q', -1, 0, "idx")) goto fail_c;
    if (n) k = (vi.len / 8) / n;
    if (k > MAX_K || vi.len != 8 * k * n) {
        PyErr_SetString(PyExc_ValueError, "_native.weights: idx must be (N, K)");
        goto fail_i;
    }
    if (get_buffer(o_d2, &vd, 'q', k * n, 0, "d2")) goto fail_i;
    if (get_buffer(o_beta, &vb, 'd', k * n, 1, "beta")) goto fail_d;
    const int64_t *cells = (const int64_t *)vc.buf, *idx = (const int64_t *)vi.buf, *dd = (const int64_t *)vd.buf;
    double *beta = (double *)vb.buf;
    int bad = 0;
    Py_BEGIN_ALLOW_THREADS;
    for (int64_t i = 0; i < n && !bad; i++) {
        const int64_t *row = idx + i * k, *rd = dd + i * k;
        const int64_t *p = cells + 3 * i;
        double d[MAX_K][3], w[MAX_K], e[MAX_K][3];
        int64_t have[MAX_K], h = 0;
        for (int64_t m = 0; m < k; m++) {
            int64_t j = row[m];
            beta[i * k + m] = 0.0;
            if (j < 0) continue;
            if (j >= n || rd[m] <= 0) {
                bad = 1;
                break;
            }
            have[h] = m;
            for (int a = 0; a < 3; a++) d[h][a] = (double)(cells[3 * j + a] - p[a]); /* exact: |x| < 2**17 */
            w[h] = 1.0 / (double)rd[m];
            h++;
        }
        if (bad) break;
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
            beta[i * k + have[s]] = w[s] * (inv_w - he);
        }
    }
    Py_END_ALLOW_THREADS;
    if (bad) PyErr_SetString(PyExc_ValueError, "_native.weights: neighbour index or distance out of range");
    PyBuffer_Release(&vb);
fail_d:
    PyBuffer_Release(&vd);
fail_i:
    PyBuffer_Release(&vi);
fail_c:
    PyBuffer_Release(&vc);
    if (PyErr_Occurred()) return NULL;
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"neighbors", neighbors, METH_VARARGS, "Causal neighbour search (formats/predict.py causal_neighbors)."},
    {"weights", weights, METH_VARARGS, "Predictor weights (formats/predict.py predictor_weights)."},
    {"reconstruct", reconstruct, METH_VARARGS, "Sequential pass of the s prediction (formats/predict.py)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_native", "Compiled fast path of formats/predict.py.",
                                    -1, methods};

PyMODINIT_FUNC PyInit__native(void) { return PyModule_Create(&module); }
