/*
 * intersect.c -- the decoder core's crossing check (geometry/intersections.py `self_intersecting_faces` is the
 * reference): which faces of a triangle mesh cross or touch another face, by the conservative predicate of
 * formats/README.md "Crossing faces", with every binary64 operation in the reference's order (compile with
 * -ffp-contract=off, no -ffast-math), so both flag the same faces.
 *
 * Entry points (declared in internal.h; vertices v (nv * 3 doubles), faces f (nf * 3 int32, every index in
 * [0, nv): tw_self_intersecting checks it, the three ways below trust their caller), only (nf bytes, nonzero: the
 * face is marked; only pairs with a marked face are tested), flags (nf bytes out, 1 = flagged)):
 *
 *   tw_crossings_grid    the full check: 0 done, 1 the candidate grid found no feasible cell size (the reference
 *                        raises RuntimeError there), -1 out of memory.
 *   tw_crossings_marked  for checks with few faces marked: 0 decided (exactly tw_crossings_grid's flags), 2
 *                        undecided (flags all 0: run tw_crossings_grid), -1 out of memory.
 *   tw_crossings_stars   for the first check of a Loop level's faces (runs of 4 children): 0 decided (the grid's
 *                        flags), 2 undecided, -1 out of memory.
 *   tw_self_intersecting intersections.self_intersecting_faces' compiled dispatch over the three (the Python
 *                        binding's order, so the same work): 0 done, 1 infeasible, -1 out of memory, -2 an index
 *                        out of range.
 *
 * Candidate pairs: every pair of valid faces whose bounding boxes overlap (closed intervals); the grid groups
 * faces by the cells their boxes cover (cells sorted lexicographically by (x, y, z)) and tests a pair only in the
 * cell of the larger of the two boxes' lower corners, so each pair once.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"
#include "radix.h"

/* Integer helpers: radix.h (bit length, the radix sort with a start bit). */

/* ------------------------------------------------------------------------------------------------------------
 * Threads. Every entry point takes a thread count. With 1 nothing here runs: each loop is one call over its whole
 * range on the calling thread, the single-threaded code. With more, the loops whose items are independent run in
 * chunks on pthreads (the caller's thread among them), and the answer is the same bytes: the flags are an OR over
 * the tested pairs (which thread tests a pair, and in which order, cannot change whether it crosses), written with
 * relaxed atomic stores of 1 (a face flagged twice stays flagged); a skip that reads the flags ("both faces
 * already flagged") only skips pairs that cannot add a flag. Sums are of integers (exact in any order), minima and
 * maxima are merged in the serial loop's order, so every decision that depends on them is the serial one. Built
 * with -DTW_NO_THREADS (wasm32) or on Windows, everything runs on the calling thread: same flags.
 * ------------------------------------------------------------------------------------------------------------ */
#if defined(TW_NO_THREADS) || defined(_WIN32)
#define TW_THREADS 0
#else
#include <pthread.h>
#define TW_THREADS 1
#endif
/* more workers than this are never started (a --threads far above the cores only adds start-up and contention) */
#define MAX_WORKERS 64

#if TW_THREADS
#define FLAG_GET(p) __atomic_load_n((p), __ATOMIC_RELAXED)
#define FLAG_SET(p) __atomic_store_n((p), (uint8_t)1, __ATOMIC_RELAXED)
#else
#define FLAG_GET(p) (*(p))
#define FLAG_SET(p) (*(p) = 1)
#endif

/* fn(ctx, begin, end, worker) over the chunks [begin, end) of [0, n) */
typedef void (*RangeFn)(void *ctx, int64_t begin, int64_t end, int worker);

typedef struct {
    RangeFn fn;
    void *ctx;
    int64_t n, chunk, next; /* next: the first item no worker has taken yet */
} ForJob;

typedef struct {
    ForJob *job;
    int worker;
} ForArg;

static void for_run(ForJob *job, int worker) {
    for (;;) {
#if TW_THREADS
        int64_t b = __atomic_fetch_add(&job->next, job->chunk, __ATOMIC_RELAXED);
#else
        int64_t b = job->next;
        job->next += job->chunk;
#endif
        if (b >= job->n) return;
        job->fn(job->ctx, b, b + job->chunk < job->n ? b + job->chunk : job->n, worker);
    }
}

#if TW_THREADS
static void *for_main(void *arg) {
    ForArg *a = (ForArg *)arg;
    for_run(a->job, a->worker);
    return NULL;
}
#endif

/* The workers a loop of n items in chunks of `chunk` gets from a thread count: at most one per chunk, at most
 * MAX_WORKERS, at least 1. */
static int workers_for(int threads, int64_t n, int64_t chunk) {
    int64_t chunks = chunk > 0 ? (n + chunk - 1) / chunk : 1;
    int64_t w = threads < 1 ? 1 : threads;
    if (w > MAX_WORKERS) w = MAX_WORKERS;
    if (w > chunks) w = chunks;
    return w < 1 ? 1 : (int)w;
}

/* fn over [0, n) in chunks of `chunk` items, each chunk once, on `workers` threads (this one as worker 0; see
 * workers_for), whichever is free taking the next chunk. One worker: fn(ctx, 0, n, 0), the serial loop. A thread
 * that cannot be started leaves its chunks to the others. */
static void parallel_for(int workers, int64_t n, int64_t chunk, RangeFn fn, void *ctx) {
    if (n <= 0) return;
    if (workers <= 1 || chunk <= 0 || n <= chunk) {
        fn(ctx, 0, n, 0);
        return;
    }
    ForJob job = {fn, ctx, n, chunk, 0};
#if TW_THREADS
    pthread_t tid[MAX_WORKERS];
    ForArg args[MAX_WORKERS];
    int started[MAX_WORKERS];
    for (int w = 1; w < workers && w < MAX_WORKERS; w++) {
        args[w].job = &job;
        args[w].worker = w;
        started[w] = pthread_create(&tid[w], NULL, for_main, &args[w]) == 0;
    }
    for_run(&job, 0);
    for (int w = 1; w < workers && w < MAX_WORKERS; w++)
        if (started[w]) pthread_join(tid[w], NULL);
#else
    for_run(&job, 0);
#endif
}

/* The chunk that splits n items into `workers` contiguous blocks (block b = [b chunk, (b + 1) chunk)): loops whose
 * per-block results are merged in block order afterwards. */
static int64_t block_chunk(int64_t n, int workers) {
    return workers > 1 ? (n + workers - 1) / workers : (n > 0 ? n : 1);
}

#define MAX_CANDIDATE_PAIRS 30000000LL
/* `marked` counts the faces per cell of the first grid in a dense array of at most this many cells (2 bytes each) */
#define MAX_DENSE_CELLS (1LL << 25)

static int cmp_double(const void *a, const void *b) {
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* The k-th smallest of a[0..n) (0-based), moving every smaller value before position k: Hoare's selection, O(n)
 * expected instead of a full qsort (30 ms of a 320K-face check). After 64 rounds (an adversarial order) the rest
 * is sorted, so the worst case stays O(n log n). */
static double kth_smallest(double *a, int64_t n, int64_t k) {
    int64_t lo = 0, hi = n - 1;
    for (int round = 0; lo < hi; round++) {
        if (round == 64) {
            qsort(a + lo, (size_t)(hi - lo + 1), sizeof(double), cmp_double);
            return a[k];
        }
        double pivot = a[lo + (hi - lo) / 2];
        int64_t i = lo, j = hi;
        while (i <= j) {
            while (a[i] < pivot) i++;
            while (a[j] > pivot) j--;
            if (i <= j) {
                double t = a[i];
                a[i] = a[j];
                a[j] = t;
                i++;
                j--;
            }
        }
        if (k <= j)
            hi = j;
        else if (k >= i)
            lo = i;
        else
            return a[k];
    }
    return a[k];
}

/* The k-th smallest (0-based) of a[0..n) into *out, when every a[i] is +0, positive or +inf: 1. Else (a negative
 * value, -0 or a NaN) 0 and nothing written: the caller selects by comparisons (kth_smallest). For such values the
 * bit patterns, read as unsigned integers, are in the order of the values and equal values have equal bits, so a
 * radix selection on the bits gives the value kth_smallest gives. buf: scratch of n doubles (a is not changed).
 * Digits of TW_RADIX_BITS bits from the highest bit where the values differ: each level counts the candidates' digits
 * and keeps those of the digit that holds rank k (2 passes over a, then over far fewer): ~1 ms for 320K extents
 * where Hoare's selection took ~8. */
static int radix_kth(const double *a, int64_t n, int64_t k, double *buf, double *out) {
    const uint64_t inf = 0x7ff0000000000000ull, mask = (1u << TW_RADIX_BITS) - 1;
    uint64_t low = UINT64_MAX, high = 0;
    for (int64_t i = 0; i < n; i++) {
        uint64_t b;
        memcpy(&b, a + i, sizeof b);
        if (b > inf) return 0; /* sign bit (negative, -0) or NaN */
        if (b < low) low = b;
        if (b > high) high = b;
    }
    if (n <= 0 || k < 0 || k >= n) return 0;
    if (low == high) {
        *out = a[0];
        return 1;
    }
    int shift = tw_bit_length(low ^ high) - TW_RADIX_BITS; /* every value has the bits above the top differing bit */
    if (shift < 0) shift = 0;
    const double *src = a;
    int64_t m = n;
    for (;;) {
        int64_t count[1 << TW_RADIX_BITS];
        memset(count, 0, sizeof count);
        for (int64_t i = 0; i < m; i++) {
            uint64_t b;
            memcpy(&b, src + i, sizeof b);
            count[(b >> shift) & mask]++;
        }
        uint64_t d = 0;
        while (k >= count[d]) k -= count[d++]; /* the digit of rank k; k becomes its rank among them */
        int64_t w = 0;
        for (int64_t i = 0; i < m; i++) { /* in place from the second level on: w <= i */
            uint64_t b;
            memcpy(&b, src + i, sizeof b);
            if (((b >> shift) & mask) == d) buf[w++] = src[i];
        }
        src = buf;
        m = w;
        if (shift == 0) { /* the candidates now agree on every bit */
            *out = buf[0];
            return 1;
        }
        if (m <= 64) {
            *out = kth_smallest(buf, m, k);
            return 1;
        }
        shift = shift > TW_RADIX_BITS ? shift - TW_RADIX_BITS : 0;
    }
}

/* The k-th smallest of a[0..n) (0 <= k < n), a clobbered: radix_kth through a scratch copy where its values allow
 * and the scratch can be had, else kth_smallest in place (the same value either way). */
static double kth_value(double *a, int64_t n, int64_t k) {
    double *buf = (double *)malloc(sizeof(double) * (size_t)(n > 0 ? n : 1)), out;
    int done = buf && radix_kth(a, n, k, buf, &out);
    free(buf);
    return done ? out : kth_smallest(a, n, k);
}

/* The reference's first cell size: 2 * median(ext[0..n)) (numpy's median: the mean of the two middle values for
 * even n), or the largest extent where that is not > 0, or 1. n >= 1. Clobbers `sorted` (n items). ranks: NULL,
 * or 3 doubles out: ranks[0] = 1 when the size is 2 * median > 0 of extents in a total order (no NaN, no sign bit)
 * -- then it is a function of the multiset of extents and of ranks[1], ranks[2], the (n - 1) / 2-th and n / 2-th
 * smallest (tw_check_state keeps them) -- else 0. */
static double first_cell(const double *ext, double *sorted, int64_t n, double *ranks) {
    double upper, median, cell;
    if (ranks) ranks[0] = 0;
    if (radix_kth(ext, n, n / 2, sorted, &upper)) { /* no NaN, no sign bit: comparisons are a total order */
        median = upper;
        if (n % 2 == 0) {
            /* the (n/2 - 1)-th smallest: upper when at most n/2 - 1 values lie below it, else the largest of those */
            int64_t below = 0;
            double lower = upper;
            for (int64_t i = 0; i < n; i++)
                if (ext[i] < upper && (below++ == 0 || ext[i] > lower)) lower = ext[i];
            if (below <= n / 2 - 1) lower = upper;
            median = (lower + upper) / 2.0;
            if (ranks) ranks[1] = lower;
        } else if (ranks) {
            ranks[1] = upper;
        }
        cell = 2.0 * median;
        if (ranks) {
            ranks[0] = cell > 0;
            ranks[2] = upper;
        }
        if (!(cell > 0)) {
            cell = ext[0];
            for (int64_t i = 1; i < n; i++)
                if (ext[i] > cell) cell = ext[i];
            if (cell == 0) cell = 1.0;
        }
        return cell;
    }
    memcpy(sorted, ext, sizeof(double) * (size_t)n);
    upper = kth_smallest(sorted, n, n / 2);
    median = upper;
    if (n % 2 == 0) { /* the largest value before position n / 2 is the (n / 2 - 1)-th smallest */
        double lower = sorted[0];
        for (int64_t i = 1; i < n / 2; i++)
            if (sorted[i] > lower) lower = sorted[i];
        median = (lower + upper) / 2.0;
    }
    cell = 2.0 * median;
    if (!(cell > 0)) {
        cell = sorted[0];
        for (int64_t i = 1; i < n; i++)
            if (sorted[i] > cell) cell = sorted[i];
        if (cell == 0) cell = 1.0;
    }
    return cell;
}

static inline void sub3(const double *a, const double *b, double *r) {
    r[0] = a[0] - b[0];
    r[1] = a[1] - b[1];
    r[2] = a[2] - b[2];
}

static inline void cross3(const double *u, const double *w, double *r) {
    r[0] = u[1] * w[2] - u[2] * w[1];
    r[1] = u[2] * w[0] - u[0] * w[2];
    r[2] = u[0] * w[1] - u[1] * w[0];
}

static inline double dot3(const double *u, const double *w) { return (u[0] * w[0] + u[1] * w[1]) + u[2] * w[2]; }

static inline double orient(const double *a, const double *b, const double *c, const double *d) {
    double u[3], w[3], x[3], n[3];
    sub3(b, a, u);
    sub3(c, a, w);
    sub3(d, a, x);
    cross3(u, w, n);
    return dot3(n, x);
}

static inline double cross2(const double *o, const double *a, const double *b) {
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);
}

/* The contact tolerances (the reference's TOUCH_3D, TOUCH_2D): with m the pair's scale, an orientation within
 * TOUCH_3D m^3 and a 2-D cross product within TOUCH_2D m^2 count as zero (contact); see intersections.py. */
#define TOUCH_3D 0x1p-43
#define TOUCH_2D 0x1p-46

/* Point p in the closed triangle t, up to tol2 on each 2-D cross product (the reference's _point_in_closed_2d). */
static int point_in_closed_2d(const double *p, const double t[3][2], double tol2) {
    int pos = 0, neg = 0;
    for (int i = 0; i < 3; i++) {
        double d = cross2(t[i], t[(i + 1) % 3], p);
        pos |= d > tol2;
        neg |= d < -tol2;
    }
    return !(pos && neg);
}

/* Closed segments pq and rs meet, up to tol2, and their boxes overlap (the reference's _segments_touch_2d). */
static int segments_touch_2d(const double *p, const double *q, const double *r, const double *s, double tol2) {
    double d1 = cross2(p, q, r), d2 = cross2(p, q, s);
    if ((d1 > tol2 && d2 > tol2) || (d1 < -tol2 && d2 < -tol2)) return 0;
    double d3 = cross2(r, s, p), d4 = cross2(r, s, q);
    if ((d3 > tol2 && d4 > tol2) || (d3 < -tol2 && d4 < -tol2)) return 0;
    for (int k = 0; k < 2; k++) { /* and the boxes overlap on both axes (settles nearly collinear segments) */
        double lo = fmax(fmin(p[k], q[k]), fmin(r[k], s[k]));
        double hi = fmin(fmax(p[k], q[k]), fmax(r[k], s[k]));
        if (!(lo <= hi)) return 0;
    }
    return 1;
}

/* Segment pq and triangle abc (normal n) projected to the coordinate plane that drops the first axis of largest
 * |n|: they meet there, up to tol2 (the reference's _segment_touches_in_plane). */
static int segment_touches_in_plane(const double *p, const double *q, const double *a, const double *b,
                                    const double *c, const double *n, double tol2) {
    static const int KEEP[3][2] = {{1, 2}, {0, 2}, {0, 1}};
    int axis = 0;
    double m = fabs(n[0]);
    if (fabs(n[1]) > m) {
        axis = 1;
        m = fabs(n[1]);
    }
    if (fabs(n[2]) > m) axis = 2;
    const int *keep = KEEP[axis];
    double p2[2] = {p[keep[0]], p[keep[1]]}, q2[2] = {q[keep[0]], q[keep[1]]};
    double t[3][2] = {{a[keep[0]], a[keep[1]]}, {b[keep[0]], b[keep[1]]}, {c[keep[0]], c[keep[1]]}};
    if (point_in_closed_2d(p2, t, tol2) || point_in_closed_2d(q2, t, tol2)) return 1;
    for (int j = 0; j < 3; j++)
        if (segments_touch_2d(p2, q2, t[j], t[(j + 1) % 3], tol2)) return 1;
    return 0;
}

/* The closed segment pq meets the closed triangle abc (normal n) or comes within the tolerances of it, given
 * sp = orient(a, b, c, p) and sq = orient(a, b, c, q) (the reference's _segment_touches_triangle). */
static int segment_touches(double sp, double sq, double tol, double tol2, const double *p, const double *q,
                           const double *a, const double *b, const double *c, const double *n) {
    if ((sp > tol && sq > tol) || (sp < -tol && sq < -tol)) return 0;
    if (!(fabs(sp) <= tol && fabs(sq) <= tol)) {
        double s1 = orient(p, q, a, b), s2 = orient(p, q, b, c), s3 = orient(p, q, c, a);
        int pos = s1 > tol || s2 > tol || s3 > tol, neg = s1 < -tol || s2 < -tol || s3 < -tol;
        if (pos && neg) return 0;
    }
    /* a common point projects to a common point: the 2-D test decides what the orientations leave open */
    return segment_touches_in_plane(p, q, a, b, c, n, tol2);
}

/* The largest span of the two boxes (min x, y, z, max x, y, z) on one axis: every |coordinate difference| of the
 * pair is at most that (rounding is monotone), so a bound from it is at least the reference's. */
static inline double pair_span(const double *box_a, const double *box_b) {
    double span = 0;
    for (int k = 0; k < 3; k++) {
        double hi = box_a[3 + k] > box_b[3 + k] ? box_a[3 + k] : box_b[3 + k];
        double lo = box_a[k] < box_b[k] ? box_a[k] : box_b[k];
        if (hi - lo > span) span = hi - lo;
    }
    return span;
}

/* The reference's scale of a pair: the largest |coordinate difference| of the six vertices from b0. */
static double pair_scale(const double *a[3], const double *b[3]) {
    double scale_a = 0, scale_b = 0;
    for (int i = 0; i < 3; i++)
        for (int k = 0; k < 3; k++) {
            double x = fabs(a[i][k] - b[0][k]), y = fabs(b[i][k] - b[0][k]);
            if (x > scale_a) scale_a = x;
            if (y > scale_b) scale_b = y;
        }
    return scale_a > scale_b ? scale_a : scale_b;
}

/* The reference's _pairs_intersect for one pair of faces fa < fb (their vertex indices; ta, tb their corners, 9
 * coordinates each) with normals na, nb, each (x1 - x0) x (x2 - x0); box_a, box_b their boxes. orient(x0, x1, x2,
 * y) is computed as n_x . (y - x0): the same operations in the same order as the reference's. nlen_a, nlen_b are
 * not used (the tolerances are the pair's, not the faces'). */
/* Whether one face's free corners (orientations o against the other face's plane) all lie beyond `limit` on one
 * side of it, for either face: the pair is then apart. */
static inline int one_side_apart(const double *oa, const double *ob, const int *free_a, const int *free_b,
                                 double limit) {
    /* branch-free: a corner that is not free passes both tests */
    int apart = 0;
    for (int side = 0; side < 2; side++) {
        const double *o = side ? ob : oa;
        const int *fr = side ? free_b : free_a;
        int above = 1, below = 1;
        for (int i = 0; i < 3; i++) {
            above &= !fr[i] | (o[i] > limit);
            below &= !fr[i] | (o[i] < -limit);
        }
        apart |= above | below;
    }
    return apart;
}

static int pair_intersects(const double *ta, const double *tb, const int64_t *fa, const int64_t *fb,
                           const double *na, const double *nb, const double *box_a, const double *box_b,
                           double nlen_a, double nlen_b) {
    (void)nlen_a;
    (void)nlen_b;
    /* bit j of m[i]: vertex i of a is vertex j of b (branch-free: most pairs are neighbours in a fan) */
    int m0 = (fa[0] == fb[0]) | (fa[0] == fb[1]) << 1 | (fa[0] == fb[2]) << 2;
    int m1 = (fa[1] == fb[0]) | (fa[1] == fb[1]) << 1 | (fa[1] == fb[2]) << 2;
    int m2 = (fa[2] == fb[0]) | (fa[2] == fb[1]) << 1 | (fa[2] == fb[2]) << 2;
    int free_a[3] = {m0 == 0, m1 == 0, m2 == 0}, used = m0 | m1 | m2;
    int free_b[3] = {!(used & 1), !(used >> 1 & 1), !(used >> 2 & 1)};
    if (free_a[0] + free_a[1] + free_a[2] < 2 || free_b[0] + free_b[1] + free_b[2] < 2) return 0;
    const double *a[3], *b[3];
    for (int i = 0; i < 3; i++) {
        a[i] = ta + 3 * i;
        b[i] = tb + 3 * i;
    }
    double d[3], oa[3], ob[3];
    for (int i = 0; i < 3; i++) {
        sub3(a[i], b[0], d);
        oa[i] = dot3(nb, d); /* orient(b0, b1, b2, a_i) */
        sub3(b[i], a[0], d);
        ob[i] = dot3(na, d); /* orient(a0, a1, a2, b_i) */
    }
    /* apart when one face's free corners lie beyond tol on one side of the other's plane: first against the
     * bound from the boxes' span (at least the pair's scale, so at least tol: the same decision), which settles
     * most pairs without the scale */
    double span = pair_span(box_a, box_b);
    double wide = TOUCH_3D * span * span * span;
    if (one_side_apart(oa, ob, free_a, free_b, wide)) return 0;
    double scale = pair_scale(a, b);
    double tol = TOUCH_3D * scale * scale * scale, tol2 = TOUCH_2D * scale * scale;
    if (one_side_apart(oa, ob, free_a, free_b, tol)) return 0;
    for (int i = 0; i < 3; i++) {
        int j = (i + 1) % 3;
        if (free_a[i] && free_a[j] && segment_touches(oa[i], oa[j], tol, tol2, a[i], a[j], b[0], b[1], b[2], nb))
            return 1;
    }
    for (int i = 0; i < 3; i++) {
        int j = (i + 1) % 3;
        if (free_b[i] && free_b[j] && segment_touches(ob[i], ob[j], tol, tol2, b[i], b[j], a[0], a[1], a[2], na))
            return 1;
    }
    return 0;
}

/* The reference's _grid_pairs decision for cell size `cell`: 0 feasible, 1 "coarser", 2 "finer", -1 out of memory,
 * 3 the cell keys do not fit 64 bits (a degenerate spread of sizes; the caller treats it as a failure).
 * On success *keys holds the sorted entries (cell key << face_bits | face), *count their number, c0 (n,3) the
 * lower cell of each box. */
static int grid(const double *lo, const double *hi, int64_t n, double cell, const double *origin, int64_t *c0,
                uint64_t **keys, int64_t *count, int *face_bits, int64_t *dims) {
    double limit = 64.0 * (double)n + 1000000.0, total_cells = 0;
    dims[0] = dims[1] = dims[2] = 1;
    /* one pass: the entries' count (stopping where it crosses the limit), the lower cells and the dimensions */
    for (int64_t i = 0; i < n; i++) {
        double span = 1, a[3], b[3];
        for (int k = 0; k < 3; k++) {
            a[k] = floor((lo[3 * i + k] - origin[k]) / cell);
            b[k] = floor((hi[3 * i + k] - origin[k]) / cell);
            span *= b[k] - a[k] + 1;
        }
        total_cells += span;
        if (total_cells > limit) return 1;
        for (int k = 0; k < 3; k++) { /* converted only under the limit, as a separate pass would */
            c0[3 * i + k] = (int64_t)a[k];
            if ((int64_t)b[k] + 1 > dims[k]) dims[k] = (int64_t)b[k] + 1;
        }
    }
    int fb = tw_bit_length((uint64_t)n);
    int cb = tw_bit_length((uint64_t)dims[0]) + tw_bit_length((uint64_t)dims[1]) + tw_bit_length((uint64_t)dims[2]);
    if (fb + cb > 63) return 3;
    int64_t m = (int64_t)total_cells, t = 0;
    uint64_t *e = (uint64_t *)malloc(sizeof(uint64_t) * (size_t)(m > 0 ? m : 1));
    if (!e) return -1;
    for (int64_t i = 0; i < n; i++) {
        int64_t c1[3];
        for (int k = 0; k < 3; k++) c1[k] = (int64_t)floor((hi[3 * i + k] - origin[k]) / cell);
        for (int64_t x = c0[3 * i]; x <= c1[0]; x++)
            for (int64_t y = c0[3 * i + 1]; y <= c1[1]; y++)
                for (int64_t z = c0[3 * i + 2]; z <= c1[2]; z++)
                    e[t++] = ((((uint64_t)x * (uint64_t)dims[1] + (uint64_t)y) * (uint64_t)dims[2] + (uint64_t)z)
                              << fb) | (uint64_t)i;
    }
    uint64_t *tmp = (uint64_t *)malloc(sizeof(uint64_t) * (size_t)(t > 0 ? t : 1));
    if (!tmp) {
        free(e);
        return -1;
    }
    /* the entries were written face by face: in ascending order of their low fb bits, so only the cell bits are
     * sorted (stable: a cell's faces stay ascending) */
    tw_radix_sort(e, tmp, t, fb, fb + cb);
    free(tmp);
    long long pairs = 0;
    for (int64_t s = 0; s < t;) {
        int64_t r = s + 1;
        while (r < t && (e[r] >> fb) == (e[s] >> fb)) r++;
        long long size = r - s;
        pairs += size * (size - 1) / 2;
        if (pairs > MAX_CANDIDATE_PAIRS) {
            free(e);
            return 2;
        }
        s = r;
    }
    *keys = e;
    *count = t;
    *face_bits = fb;
    return 0;
}

/* The closed box lo (3,), hi (3,) of triangle p0 p1 p2 and its extent, the longest side of the box: the grid's
 * entries of `faces` and `marked_flags` alike. */
static double face_box(const double *p0, const double *p1, const double *p2, double *lo, double *hi) {
    double x = 0;
    for (int k = 0; k < 3; k++) {
        double a = p0[k], b = p1[k], d = p2[k];
        double mn = a, mx = a;
        if (b < mn) mn = b;
        if (d < mn) mn = d;
        if (b > mx) mx = b;
        if (d > mx) mx = d;
        lo[k] = mn;
        hi[k] = mx;
        if (k == 0 || mx - mn > x) x = mx - mn;
    }
    return x;
}

/* `faces`' first pass, over faces [begin, end): the valid ones' indices, normals, boxes and extents, written
 * compacted from position `begin` of each array (block b's count in count[b]); the caller closes the gaps in
 * block order, which gives the serial pass's arrays. */
typedef struct {
    const double *v;
    const int32_t *f;
    int64_t *valid, *count, chunk;
    double *lo, *hi, *ext, *normal;
} FacesPass;

static void faces_pass(void *ctx, int64_t begin, int64_t end, int worker) {
    (void)worker;
    FacesPass *c = (FacesPass *)ctx;
    const double *v = c->v;
    const int32_t *f = c->f;
    int64_t n = begin;
    for (int64_t i = begin; i < end; i++) {
        const double *p0 = v + 3 * f[3 * i], *p1 = v + 3 * f[3 * i + 1], *p2 = v + 3 * f[3 * i + 2];
        double e1[3], e2[3], x[3];
        sub3(p1, p0, e1);
        sub3(p2, p0, e2);
        cross3(e1, e2, x);
        if (!(dot3(x, x) > 0)) continue;
        c->valid[n] = i;
        c->normal[3 * n] = x[0];
        c->normal[3 * n + 1] = x[1];
        c->normal[3 * n + 2] = x[2];
        c->ext[n] = face_box(p0, p1, p2, c->lo + 3 * n, c->hi + 3 * n);
        n++;
    }
    c->count[begin / c->chunk] = n - begin;
}

/* `faces`' pair loop over the grid's cells [begin, end) (cell k: entries cstart[k] .. cstart[k + 1] of e); each
 * worker gathers a cell's boxes into its own scratch (lbox, lat, lid: `most` entries each per worker), and the
 * corners, normal and vertex indices of a face (lcorner: 12 doubles, lids: 4 per entry) only when a pair of it
 * passes the box test (most entries never do). */
typedef struct {
    const double *v, *lo, *hi, *normal;
    const int32_t *f;
    const int64_t *valid, *c0, *cstart;
    const uint64_t *e;
    const uint8_t *only;
    uint8_t *flags;
    uint64_t mask, dims_y, dims_z;
    int fb;
    int64_t most;
    double *lbox, *lcorner;
    uint8_t *lat;
    int64_t *lids;
    int32_t *lkeep;
} FacesCells;

static void faces_cells(void *ctx, int64_t begin, int64_t end, int worker) {
    FacesCells *c = (FacesCells *)ctx;
    const uint64_t *e = c->e, mask = c->mask, dims_y = c->dims_y, dims_z = c->dims_z;
    const int64_t *valid = c->valid;
    const int32_t *f = c->f;
    const uint8_t *only = c->only;
    double *lbox = c->lbox + 6 * c->most * worker;       /* box: lo xyz, hi xyz */
    double *lcorner = c->lcorner + 12 * c->most * worker; /* corners 9, normal 3 */
    uint8_t *lat = c->lat + c->most * worker;           /* bit d: the box's lower cell is this cell in d; bit 3: loaded */
    int64_t *lids = c->lids + 4 * c->most * worker;       /* face, its 3 vertex indices */
    int32_t *lkeep = c->lkeep + c->most * worker;         /* the entries whose box passes with the current one */
    for (int64_t k = begin; k < end; k++) {
        int64_t s = c->cstart[k], r = c->cstart[k + 1];
        uint64_t key = e[s] >> c->fb;
        int any = 0; /* a cell without a face of interest has no pair to test */
        for (int64_t i = s; i < r && !any; i++) any = only[valid[(int64_t)(e[i] & mask)]];
        if (!any) continue;
        /* the pair is tested once, in the cell of the larger of the two lower corners (floor is monotone). Every
         * box here covers this cell, so its lower corner is at or below the cell in each coordinate, and the larger
         * corner is this cell exactly when, in each coordinate, one of the two is */
        uint64_t cz = key % dims_z, cy = key / dims_z % dims_y, cx = key / dims_z / dims_y;
        for (int64_t i = s; i < r; i++) {
            int64_t p = (int64_t)(e[i] & mask), o = i - s;
            double *box = lbox + 6 * o;
            for (int d = 0; d < 3; d++) {
                box[d] = c->lo[3 * p + d];
                box[3 + d] = c->hi[3 * p + d];
            }
            const int64_t *cp = c->c0 + 3 * p;
            lat[o] = (uint8_t)(((uint64_t)cp[0] == cx) | ((uint64_t)cp[1] == cy) << 1 | ((uint64_t)cp[2] == cz) << 2);
            lids[4 * o] = p;
        }
        for (int64_t i = s; i < r; i++) {
            int64_t oi = i - s, kept = 0;
            const double *bp = lbox + 6 * oi;
            const int at = lat[oi] & 7;
            /* branch-free: these tests go either way unpredictably, and most pairs fail one; the pairs that pass
             * are listed (the list grows by 0 or 1), then tested */
            for (int64_t oj = oi + 1; oj < r - s; oj++) {
                const double *bq = lbox + 6 * oj;
                int keep = (((at | lat[oj]) & 7) == 7) & (bp[0] <= bq[3]) & (bq[0] <= bp[3]) & (bp[1] <= bq[4]) &
                           (bq[1] <= bp[4]) & (bp[2] <= bq[5]) & (bq[2] <= bp[5]);
                lkeep[kept] = (int32_t)oj;
                kept += keep;
            }
            for (int64_t x = 0; x < kept; x++) {
                int64_t oj = lkeep[x];
                const double *bq = lbox + 6 * oj;
                /* a cell's entries are sorted by face: i's face is the lower one */
                int64_t fa = valid[lids[4 * oi]], fz = valid[lids[4 * oj]];
                if (!only[fa] && !only[fz]) continue;
                int64_t both[2] = {oi, oj};
                for (int w = 0; w < 2; w++) {
                    int64_t o = both[w];
                    if (lat[o] & 8) continue;
                    int64_t p = lids[4 * o], face = valid[p];
                    double *corner = lcorner + 12 * o;
                    for (int d = 0; d < 3; d++) {
                        int32_t vid = f[3 * face + d];
                        lids[4 * o + 1 + d] = vid;
                        for (int q = 0; q < 3; q++) corner[3 * d + q] = c->v[3 * vid + q];
                        corner[9 + d] = c->normal[3 * p + d];
                    }
                    lat[o] |= 8;
                }
                const double *ca = lcorner + 12 * oi, *cb = lcorner + 12 * oj;
                if (pair_intersects(ca, cb, lids + 4 * oi + 1, lids + 4 * oj + 1, ca + 9, cb + 9, bp, bq, 0, 0)) {
                    FLAG_SET(c->flags + fa);
                    FLAG_SET(c->flags + fz);
                }
            }
        }
    }
}

/* Faces per chunk of the first passes, and grid cells per chunk of the pair loops (small enough that the workers
 * share the uneven cells evenly, large enough that taking a chunk costs nothing) */
#define PASS_CHUNK 4096
#define CELL_CHUNK 256
#define PATCH_CHUNK 1024 /* vertices per chunk of `stars`' patches */

/* tw_crossings_grid (`faces`): the full check, the reference's grid and pair predicate. v (nv * 3), f (nf * 3, indices
 * trusted), only (nf), flags (nf, out). 0 done, 1 no feasible cell size (the reference's RuntimeError), -1 out of
 * memory. */
int tw_crossings_grid(const double *v, size_t nv_, const int32_t *f, size_t nf_, const uint8_t *only, int threads,
                      uint8_t *flags) {
    (void)nv_;
    int64_t nf = (int64_t)nf_;
    memset(flags, 0, (size_t)nf);
    int status = 0;
    int64_t *valid = NULL, *counts = NULL, *cstart = NULL;
    double *lo = NULL, *hi = NULL, *ext = NULL;
    uint64_t *e = NULL;
    uint8_t *lat = NULL;
    int32_t *lkeep = NULL;
    int64_t *c0 = NULL, *lids = NULL;
    double *local = NULL, *normal = NULL;
    size_t cap = (size_t)(nf > 0 ? nf : 1);
    int pass_workers = workers_for(threads, nf, PASS_CHUNK);
    int64_t chunk = block_chunk(nf, pass_workers);
    valid = (int64_t *)malloc(sizeof(int64_t) * cap);
    lo = (double *)malloc(sizeof(double) * 3 * cap);
    hi = (double *)malloc(sizeof(double) * 3 * cap);
    ext = (double *)malloc(sizeof(double) * cap);
    normal = (double *)malloc(sizeof(double) * 3 * cap);
    counts = (int64_t *)malloc(sizeof(int64_t) * (size_t)pass_workers);
    if (!valid || !lo || !hi || !ext || !normal || !counts) {
        status = -1;
        goto done;
    }
    FacesPass pass = {.v = v, .f = f, .valid = valid, .count = counts, .chunk = chunk, .lo = lo, .hi = hi, .ext = ext,
                      .normal = normal};
    parallel_for(pass_workers, nf, chunk, faces_pass, &pass);
    int64_t n = 0;
    for (int64_t b = 0; b * chunk < nf; b++) { /* close the gaps between the blocks, in block order */
        int64_t from = b * chunk, m = counts[b];
        if (from != n) {
            memmove(valid + n, valid + from, sizeof(int64_t) * (size_t)m);
            memmove(normal + 3 * n, normal + 3 * from, sizeof(double) * 3 * (size_t)m);
            memmove(lo + 3 * n, lo + 3 * from, sizeof(double) * 3 * (size_t)m);
            memmove(hi + 3 * n, hi + 3 * from, sizeof(double) * 3 * (size_t)m);
            memmove(ext + n, ext + from, sizeof(double) * (size_t)m);
        }
        n += m;
    }
    if (nf < 2 || n < 2) goto done;
    /* cell = 2 median(extent); not > 0: max extent, or 1 */
    double *sorted = (double *)malloc(sizeof(double) * (size_t)n);
    if (!sorted) {
        status = -1;
        goto done;
    }
    double cell = first_cell(ext, sorted, n, NULL);
    free(sorted);
    double origin[3];
    for (int k = 0; k < 3; k++) {
        origin[k] = lo[k];
        for (int64_t i = 1; i < n; i++)
            if (lo[3 * i + k] < origin[k]) origin[k] = lo[3 * i + k];
    }
    c0 = (int64_t *)malloc(sizeof(int64_t) * 3 * (size_t)n);
    if (!c0) {
        status = -1;
        goto done;
    }
    int tried_coarser = 0, tried_finer = 0, fb = 0;
    int64_t t = 0, dims[3];
    for (;;) {
        int r = grid(lo, hi, n, cell, origin, c0, &e, &t, &fb, dims);
        if (r == 0) break;
        if (r < 0) {
            status = -1;
            goto done;
        }
        if (r == 3) {
            status = 1;
            goto done;
        }
        if (r == 1) tried_coarser = 1;
        if (r == 2) tried_finer = 1;
        if (tried_coarser && tried_finer) {
            status = 1;
            goto done;
        }
        cell *= (r == 1) ? 2.0 : 0.5;
    }
    /* the cells: runs of one key in the sorted entries, and the largest of them */
    cstart = (int64_t *)malloc(sizeof(int64_t) * (size_t)(t + 1));
    if (!cstart) {
        status = -1;
        goto done;
    }
    int64_t ncells = 0, most = 0;
    for (int64_t s = 0; s < t;) {
        int64_t r = s + 1;
        while (r < t && (e[r] >> fb) == (e[s] >> fb)) r++;
        if (r - s > most) most = r - s;
        cstart[ncells++] = s;
        s = r;
    }
    cstart[ncells] = t;
    int cell_workers = workers_for(threads, ncells, CELL_CHUNK);
    /* per cell, its boxes gathered contiguously (the pair loop is memory bound) */
    local = (double *)malloc(sizeof(double) * 18 * (size_t)most * (size_t)cell_workers);
    lat = (uint8_t *)malloc((size_t)most * (size_t)cell_workers);
    lids = (int64_t *)malloc(sizeof(int64_t) * 4 * (size_t)most * (size_t)cell_workers);
    lkeep = (int32_t *)malloc(sizeof(int32_t) * (size_t)most * (size_t)cell_workers);
    if (!local || !lat || !lids || !lkeep) {
        status = -1;
        goto done;
    }
    FacesCells cells = {.v = v, .lo = lo, .hi = hi, .normal = normal, .f = f, .valid = valid, .c0 = c0,
                        .cstart = cstart, .e = e, .only = only, .flags = flags, .mask = (((uint64_t)1) << fb) - 1,
                        .dims_y = (uint64_t)dims[1], .dims_z = (uint64_t)dims[2], .fb = fb, .most = most,
                        .lbox = local, .lcorner = local + 6 * (size_t)most * (size_t)cell_workers, .lat = lat,
                        .lids = lids, .lkeep = lkeep};
    parallel_for(cell_workers, ncells, CELL_CHUNK, faces_cells, &cells);
done:
    free(valid);
    free(counts);
    free(cstart);
    free(lo);
    free(hi);
    free(ext);
    free(e);
    free(c0);
    free(local);
    free(lat);
    free(lids);
    free(lkeep);
    free(normal);
    return status;
}

/* The faces of one check. Boxes and normals are computed where they are needed, not stored: storing them for
 * 320K faces cost more in fresh pages than computing them three times. */
typedef struct {
    const double *v;
    const int32_t *f;
    const uint8_t *valid, *only;
    uint8_t *flags;
} CheckFaces;

/* Face i's corners (9 coordinates) and closed box (lo xyz, hi xyz), as `faces` computes them. */
static inline void face_corners_box(const CheckFaces *s, int64_t i, double *corners, double *box) {
    const int32_t *ids = s->f + 3 * i;
    for (int k = 0; k < 3; k++)
        for (int c = 0; c < 3; c++) corners[3 * k + c] = s->v[3 * ids[k] + c];
    face_box(corners, corners + 3, corners + 6, box, box + 3);
}

/* Face i's normal (x1 - x0) x (x2 - x0) from its corners, as `faces` computes it. */
static inline void face_normal(const double *corners, double *normal) {
    double e1[3], e2[3];
    sub3(corners + 3, corners, e1);
    sub3(corners + 6, corners, e2);
    cross3(e1, e2, normal);
}

/* pair_intersects of faces a, b (the lower first, as `faces`), when both are valid, one is marked and their closed
 * boxes overlap: flags both when it accepts. */
static void test_pair(const CheckFaces *s, int64_t a, int64_t b) {
    if (a > b) {
        int64_t t = a;
        a = b;
        b = t;
    }
    if (a == b || !s->valid[a] || !s->valid[b] || !(s->only[a] || s->only[b]) ||
        (FLAG_GET(s->flags + a) && FLAG_GET(s->flags + b)))
        return;
    double ta[9], tb[9], na[3], nb[3], ba[6], bb[6];
    face_corners_box(s, a, ta, ba);
    face_corners_box(s, b, tb, bb);
    if (!(ba[0] <= bb[3] && bb[0] <= ba[3] && ba[1] <= bb[4] && bb[1] <= ba[4] && ba[2] <= bb[5] && bb[2] <= ba[5]))
        return;
    face_normal(ta, na);
    face_normal(tb, nb);
    int64_t ia[3] = {s->f[3 * a], s->f[3 * a + 1], s->f[3 * a + 2]};
    int64_t ib[3] = {s->f[3 * b], s->f[3 * b + 1], s->f[3 * b + 2]};
    if (pair_intersects(ta, tb, ia, ib, na, nb, ba, bb, sqrt(dot3(na, na)), sqrt(dot3(nb, nb)))) {
        FLAG_SET(s->flags + a);
        FLAG_SET(s->flags + b);
    }
}

/* test_pair(group pa + g, group pb + h) for every child g of parent pa and h of parent pb (pa != pb, group <= 4),
 * in that order, with the same tests: each child's corners, box and normal computed once, not once per pair. */
static void test_parents(const CheckFaces *s, int group, int64_t pa, int64_t pb) {
    double t[2][4][9], box[2][4][6], nrm[2][4][3];
    const int64_t base[2] = {group * pa, group * pb};
    for (int w = 0; w < 2; w++)
        for (int g = 0; g < group; g++)
            if (s->valid[base[w] + g]) {
                face_corners_box(s, base[w] + g, t[w][g], box[w][g]);
                face_normal(t[w][g], nrm[w][g]);
            }
    const int lo = pa < pb ? 0 : 1, hi = 1 - lo; /* the lower parent's children are the lower faces */
    for (int g = 0; g < group; g++)
        for (int h = 0; h < group; h++) {
            const int ka = lo == 0 ? g : h, kb = lo == 0 ? h : g; /* child of the lower, of the higher */
            const int64_t a = base[lo] + ka, b = base[hi] + kb;
            if (!s->valid[a] || !s->valid[b] || !(s->only[a] || s->only[b]) ||
                (FLAG_GET(s->flags + a) && FLAG_GET(s->flags + b)))
                continue;
            const double *ba = box[lo][ka], *bb = box[hi][kb];
            if (!(ba[0] <= bb[3] && bb[0] <= ba[3] && ba[1] <= bb[4] && bb[1] <= ba[4] && ba[2] <= bb[5] &&
                  bb[2] <= ba[5]))
                continue;
            int64_t ia[3] = {s->f[3 * a], s->f[3 * a + 1], s->f[3 * a + 2]};
            int64_t ib[3] = {s->f[3 * b], s->f[3 * b + 1], s->f[3 * b + 2]};
            if (pair_intersects(t[lo][ka], t[hi][kb], ia, ib, nrm[lo][ka], nrm[hi][kb], ba, bb, 0, 0)) {
                FLAG_SET(s->flags + a);
                FLAG_SET(s->flags + b);
            }
        }
}

/* The cells c (6: lower x y z, upper x y z) that the closed box lo (3,), hi (3,) covers on the lattice of side
 * `cell` from `origin`: every quotient is >= 0, where truncation is floor (the reference's floor of the same
 * quotient). Returns the number of cells, summed as the reference's grid sums it. */
static inline double cell_range(const double *lo, const double *hi, const double *origin, double cell, int64_t *c) {
    double span = 1;
    for (int k = 0; k < 3; k++) {
        c[k] = (int64_t)((lo[k] - origin[k]) / cell);
        c[3 + k] = (int64_t)((hi[k] - origin[k]) / cell);
        span *= (double)c[3 + k] - (double)c[k] + 1;
    }
    return span;
}

/* The count of first_grid_feasible over faces [begin, end): grid entries and pairs in cells, into the worker's
 * sums. Shared counts (more than one worker) are atomic increments; whichever order they come in, a cell's
 * increments see 0, 1, ..., its size - 1, so the pairs and the overflow test are those of the serial count. */
typedef struct {
    const CheckFaces *s;
    const double *lo, *hi, *origin;
    double cell, limit;
    int64_t dims_y, dims_z;
    uint16_t *counts;
    int32_t *rng; /* NULL, or 6 int32 per face: its cells (tw_check_state keeps them) */
    int shared, failed; /* failed: a bound is crossed (shared: read and set atomically) */
    double total[MAX_WORKERS];
    long long pairs[MAX_WORKERS];
} GridCount;

static void grid_count(void *ctx, int64_t begin, int64_t end, int worker) {
    GridCount *g = (GridCount *)ctx;
    const CheckFaces *s = g->s;
    double total = g->total[worker];
    long long pairs = g->pairs[worker];
    int ok = 1;
    for (int64_t i = begin; i < end && ok; i++) {
        if (!s->valid[i]) continue;
#if TW_THREADS
        if (g->shared && __atomic_load_n(&g->failed, __ATOMIC_RELAXED)) break;
#endif
        double corners[9], b[6];
        if (g->lo) {
            memcpy(b, g->lo + 3 * i, 3 * sizeof(double));
            memcpy(b + 3, g->hi + 3 * i, 3 * sizeof(double));
        } else {
            face_corners_box(s, i, corners, b);
        }
        int64_t c[6];
        total += cell_range(b, b + 3, g->origin, g->cell, c);
        if (g->rng)
            for (int k = 0; k < 6; k++) g->rng[6 * i + k] = (int32_t)c[k]; /* dims < 2^25 (MAX_DENSE_CELLS) */
        if (total > g->limit) {
            ok = 0;
            break;
        }
        for (int64_t x = c[0]; x <= c[3] && ok; x++)
            for (int64_t y = c[1]; y <= c[4] && ok; y++)
                for (int64_t z = c[2]; z <= c[5]; z++) {
                    uint16_t *cnt = g->counts + (x * g->dims_y + y) * g->dims_z + z, before;
#if TW_THREADS
                    if (g->shared)
                        before = __atomic_fetch_add(cnt, (uint16_t)1, __ATOMIC_RELAXED);
                    else
#endif
                        before = (*cnt)++;
                    if (before == UINT16_MAX) { /* a cell of 65536 faces (the dense count's limit) */
                        ok = 0;
                        break;
                    }
                    pairs += before;
                }
        if (pairs > MAX_CANDIDATE_PAIRS) ok = 0;
    }
    g->total[worker] = total;
    g->pairs[worker] = pairs;
    if (!ok) {
#if TW_THREADS
        __atomic_store_n(&g->failed, 1, __ATOMIC_RELAXED);
#else
        g->failed = 1;
#endif
    }
}

/* 1 when the reference's grid is feasible at its first cell size (`faces` then answers with the pair set; *cell
 * and dims (3,) are that lattice's), 0 when that is not known here, -1 out of memory. n valid faces, ext their
 * extents in face order, origin and top the corners of their boxes; lo, hi (F,3) the boxes when the caller keeps
 * them, else NULL (computed from the corners). Why the count decides: see `marked` below. With several threads the
 * faces are counted in chunks: the entries and pairs are sums of integers, and every bound is crossed by the
 * total when it is crossed by a prefix of the serial loop (the increments are positive), so the answer is the
 * serial one. */
/* What first_grid_feasible hands to a caller that keeps its count (tw_check_state): first_cell's ranks, and when
 * the answer is 1, the dense count (counts: dims[0] dims[1] dims[2] cells, malloc'd, the caller's), the grid's
 * entries and its pairs in cells. */
typedef struct {
    double ranks[3];
    uint16_t *counts;
    int32_t *rng; /* in: 6 int32 per face for the faces' cells (when the answer is 1), or NULL */
    int64_t total;
    long long pairs;
} GridKeep;

static int first_grid_feasible(const CheckFaces *s, const double *lo, const double *hi, int64_t nf, int64_t n,
                               const double *ext, const double *origin, const double *top, double *cell_out,
                               int64_t *dims, int threads, GridKeep *keep) {
    double *sorted = (double *)malloc(sizeof(double) * (size_t)n);
    if (!sorted) return -1;
    double cell = first_cell(ext, sorted, n, keep ? keep->ranks : NULL);
    free(sorted);
    *cell_out = cell;
    /* floor is monotone: the largest upper cell is that of the largest upper coordinate */
    for (int k = 0; k < 3; k++) {
        double q = (top[k] - origin[k]) / cell;
        if (!(q < 1e9)) return 0; /* also NaN: a lattice this fine is never counted densely */
        dims[k] = (int64_t)q + 1;
    }
    int cb = tw_bit_length((uint64_t)dims[0]) + tw_bit_length((uint64_t)dims[1]) + tw_bit_length((uint64_t)dims[2]);
    if (tw_bit_length((uint64_t)n) + cb > 63) return 0;
    if ((double)dims[0] * (double)dims[1] * (double)dims[2] > (double)MAX_DENSE_CELLS) return 0;
    GridCount *g = (GridCount *)calloc(1, sizeof(GridCount));
    if (!g) return -1;
    g->counts = (uint16_t *)calloc((size_t)(dims[0] * dims[1] * dims[2]), sizeof(uint16_t));
    if (!g->counts) {
        free(g);
        return -1;
    }
    int workers = workers_for(threads, nf, PASS_CHUNK);
    g->s = s;
    g->lo = lo;
    g->hi = hi;
    g->origin = origin;
    g->cell = cell;
    g->limit = 64.0 * (double)n + 1000000.0;
    g->dims_y = dims[1];
    g->dims_z = dims[2];
    g->shared = workers > 1;
    g->rng = keep ? keep->rng : NULL;
    parallel_for(workers, nf, PASS_CHUNK, grid_count, g);
    double total = 0;
    long long pairs = 0;
    for (int w = 0; w < workers; w++) {
        total += g->total[w];
        pairs += g->pairs[w];
    }
    int ok = !g->failed && total <= g->limit && pairs <= MAX_CANDIDATE_PAIRS;
    if (keep && ok) { /* total: a sum of integers below 2^53, exact */
        keep->counts = g->counts;
        keep->total = (int64_t)total;
        keep->pairs = pairs;
    } else {
        free(g->counts);
    }
    free(g);
    return ok;
}

/* One face's corners, normal (x1 - x0) x (x2 - x0), its length, box and vertex indices, as `faces` gathers them. */
typedef struct {
    double corners[9], normal[3], box[6], nlen;
    int64_t ids[3], face, c0[3], c1[3]; /* c0, c1: the lower and upper cells of its box */
} FaceData;

static void face_data(const double *v, const int32_t *f, int64_t face, const double *lo, const double *hi,
                      FaceData *d) {
    d->face = face;
    for (int k = 0; k < 3; k++) {
        d->ids[k] = f[3 * face + k];
        d->box[k] = lo[3 * face + k];
        d->box[3 + k] = hi[3 * face + k];
        for (int c = 0; c < 3; c++) d->corners[3 * k + c] = v[3 * f[3 * face + k] + c];
    }
    double e1[3], e2[3];
    sub3(d->corners + 3, d->corners, e1);
    sub3(d->corners + 6, d->corners, e2);
    cross3(e1, e2, d->normal);
    d->nlen = sqrt(dot3(d->normal, d->normal));
}

/* A block of a first pass: its valid faces, marked ones among them, and the corners of their boxes. */
typedef struct {
    int64_t n, marked;
    double origin[3], top[3];
} BlockSum;

/* Add a face's box to a block's sums (the serial pass's rule: the first valid face's corners, then strictly
 * smaller / larger ones). */
static inline void block_add(BlockSum *b, const double *lo, const double *hi) {
    for (int k = 0; k < 3; k++) {
        if (b->n == 0 || lo[k] < b->origin[k]) b->origin[k] = lo[k];
        if (b->n == 0 || hi[k] > b->top[k]) b->top[k] = hi[k];
    }
    b->n++;
}

/* The blocks' sums merged in block order, which is the serial pass's result: the valid faces' extents moved
 * together (block b's n values start at ext + b * stride), origin and top (the same rule), the total of valid and
 * of marked faces. Returns the valid faces. */
static int64_t merge_blocks(const BlockSum *sums, int64_t blocks, int64_t stride, double *ext, double *origin,
                            double *top, int64_t *marked) {
    int64_t n = 0;
    *marked = 0;
    for (int64_t b = 0; b < blocks; b++) {
        const BlockSum *x = sums + b;
        if (x->n == 0) continue;
        if (b * stride != n) memmove(ext + n, ext + b * stride, sizeof(double) * (size_t)x->n);
        for (int k = 0; k < 3; k++) {
            if (n == 0 || x->origin[k] < origin[k]) origin[k] = x->origin[k];
            if (n == 0 || x->top[k] > top[k]) top[k] = x->top[k];
        }
        n += x->n;
        *marked += x->marked;
    }
    return n;
}

/* `marked`'s first pass over faces [begin, end) (one block): as `faces`, the valid faces, boxes and extents */
typedef struct {
    const double *v;
    const int32_t *f;
    const uint8_t *only;
    uint8_t *valid;
    double *lo, *hi, *ext;
    int64_t chunk;
    BlockSum *sums;
} MarkedPass;

static void marked_pass(void *ctx, int64_t begin, int64_t end, int worker) {
    (void)worker;
    MarkedPass *c = (MarkedPass *)ctx;
    const double *v = c->v;
    const int32_t *f = c->f;
    BlockSum *b = c->sums + begin / c->chunk;
    b->n = b->marked = 0;
    for (int64_t i = begin; i < end; i++) {
        const double *p0 = v + 3 * f[3 * i], *p1 = v + 3 * f[3 * i + 1], *p2 = v + 3 * f[3 * i + 2];
        double e1[3], e2[3], x[3];
        sub3(p1, p0, e1);
        sub3(p2, p0, e2);
        cross3(e1, e2, x);
        c->valid[i] = dot3(x, x) > 0;
        if (!c->valid[i]) continue;
        c->ext[begin + b->n] = face_box(p0, p1, p2, c->lo + 3 * i, c->hi + 3 * i);
        block_add(b, c->lo + 3 * i, c->hi + 3 * i);
        b->marked += c->only[i] != 0;
    }
}

/* `marked`'s pair loop over faces [begin, end): each face's box scans the marked faces listed in its cells */
typedef struct {
    const double *v, *lo, *hi, *origin;
    const int32_t *f;
    const int64_t *dims;
    const uint8_t *valid, *only;
    uint8_t *flags;
    const uint64_t *hot;
    const int32_t *head, *next, *who;
    const FaceData *mk;
    double cell;
} MarkedLoop;

/* Valid face i's box scans the marked faces listed in its cells (marked_loop's body). */
static void marked_scan(const MarkedLoop *c, int64_t i) {
    const int64_t *dims = c->dims;
    const uint8_t *only = c->only;
    uint8_t *flags = c->flags;
    FaceData q;
    const double *ql = c->lo + 3 * i, *qh = c->hi + 3 * i;
    int64_t r[6];
    cell_range(ql, qh, c->origin, c->cell, r);
    int have = 0;
    for (int64_t x = r[0]; x <= r[3]; x++)
        for (int64_t y = r[1]; y <= r[4]; y++)
            for (int64_t z = r[2]; z <= r[5]; z++) {
                int64_t at = (x * dims[1] + y) * dims[2] + z;
                if (!(c->hot[at >> 6] >> (at & 63) & 1)) continue;
                for (int32_t e = c->head[at]; e > 0; e = c->next[e - 1]) {
                    const FaceData *p = c->mk + c->who[e - 1];
                    if (p->face == i || (only[i] && i > p->face)) continue; /* a marked pair from its lower face */
                    int64_t mx = p->c0[0] > r[0] ? p->c0[0] : r[0], my = p->c0[1] > r[1] ? p->c0[1] : r[1];
                    int64_t mz = p->c0[2] > r[2] ? p->c0[2] : r[2];
                    if (mx != x || my != y || mz != z) continue; /* the pair's own cell */
                    const double *pb = p->box;
                    if (!(pb[0] <= qh[0] && ql[0] <= pb[3] && pb[1] <= qh[1] && ql[1] <= pb[4] && pb[2] <= qh[2] &&
                          ql[2] <= pb[5]))
                        continue;
                    /* nothing left to learn from this pair */
                    if (FLAG_GET(flags + i) && FLAG_GET(flags + p->face)) continue;
                    if (!have) {
                        face_data(c->v, c->f, i, c->lo, c->hi, &q);
                        have = 1;
                    }
                    const FaceData *a = i < p->face ? &q : p, *b = i < p->face ? p : &q;
                    if (pair_intersects(a->corners, b->corners, a->ids, b->ids, a->normal, b->normal, a->box,
                                        b->box, a->nlen, b->nlen)) {
                        FLAG_SET(flags + i);
                        FLAG_SET(flags + p->face);
                    }
                }
            }
}

static void marked_loop(void *ctx, int64_t begin, int64_t end, int worker) {
    (void)worker;
    const MarkedLoop *c = (const MarkedLoop *)ctx;
    for (int64_t i = begin; i < end; i++)
        if (c->valid[i]) marked_scan(c, i);
}

/* tw_crossings_marked(v, nv, f, nf, only, threads, flags) -> 0: decided, flags are exactly what
 * tw_crossings_grid (`faces` below) writes; 2: undecided (flags all 0: the caller runs `faces`); -1 out of memory.
 *
 * For checks that mark few faces (geometry.surface_filter.restore_crossings after its first check): `faces`
 * rebuilds and sorts the whole grid for them; this does O(F) passes and the marked faces' pairs only.
 *
 * Why the answers agree. `faces` flags both faces of every pair of valid faces with overlapping closed boxes, at
 * least one marked, that pair_intersects accepts (its grid only lists candidates: every overlapping pair shares
 * the cell of its larger lower corner) -- unless no cell size is feasible (status 1). It starts from first_cell()
 * of the extents and tries another size only when that one is infeasible: more than 64 n + 10^6 grid entries, keys
 * over 63 bits, or more than MAX_CANDIDATE_PAIRS pairs in cells. This computes the same first size and origin,
 * sums the entries in the same order, and counts every cell's faces (a dense array over the lattice; undecided
 * when that has more than MAX_DENSE_CELLS cells or a cell 65535 faces) to get the exact pair count: when the
 * first size is feasible, the answer is the pair set, computed here from lists of the marked faces per cell (the
 * same dense lattice) that every valid face's box scans, each pair once (in the cell of its larger lower corner; a
 * pair of two marked faces from its lower face), the lower face first as in `faces`. */
int tw_crossings_marked(const double *v, size_t nv_, const int32_t *f, size_t nf_, const uint8_t *only, int threads,
                        uint8_t *flags) {
    (void)nv_;
    int64_t nf = (int64_t)nf_;
    int status = 2;
    double *lo = NULL, *hi = NULL, *ext = NULL;
    uint8_t *valid = NULL;
    uint64_t *hot = NULL; /* one bit per cell: some marked face covers it (fits a cache where head does not) */
    int32_t *head = NULL, *next = NULL, *who = NULL;
    FaceData *mk = NULL;
    BlockSum *sums = NULL;
    memset(flags, 0, (size_t)nf);
    size_t cap = (size_t)(nf > 0 ? nf : 1);
    lo = (double *)malloc(sizeof(double) * 3 * cap);
    hi = (double *)malloc(sizeof(double) * 3 * cap);
    ext = (double *)malloc(sizeof(double) * cap);
    valid = (uint8_t *)malloc(cap);
    if (!lo || !hi || !ext || !valid) {
        status = -1;
        goto done;
    }
    int pass_workers = workers_for(threads, nf, PASS_CHUNK);
    int64_t chunk = block_chunk(nf, pass_workers), k_marked = 0;
    sums = (BlockSum *)calloc((size_t)pass_workers, sizeof(BlockSum));
    if (!sums) {
        status = -1;
        goto done;
    }
    MarkedPass pass = {.v = v, .f = f, .only = only, .valid = valid, .lo = lo, .hi = hi, .ext = ext, .chunk = chunk,
                       .sums = sums};
    parallel_for(pass_workers, nf, chunk, marked_pass, &pass);
    double origin[3] = {0, 0, 0}, top[3] = {0, 0, 0};
    int64_t n = merge_blocks(sums, nf > 0 ? (nf + chunk - 1) / chunk : 0, chunk, ext, origin, top, &k_marked);
    if (nf < 2 || n < 2) { /* `faces` flags nothing */
        status = 0;
        goto done;
    }
    CheckFaces s = {v, f, valid, only, flags};
    double cell;
    int64_t dims[3];
    int feasible = first_grid_feasible(&s, lo, hi, nf, n, ext, origin, top, &cell, dims, threads, NULL);
    if (feasible < 0) status = -1;
    if (feasible <= 0) goto done;
    int64_t ncells = dims[0] * dims[1] * dims[2];
    head = (int32_t *)calloc((size_t)ncells, sizeof(int32_t)); /* 1 + first marked entry of a cell, 0: none */
    hot = (uint64_t *)calloc((size_t)(ncells / 64 + 1), sizeof(uint64_t));
    mk = (FaceData *)malloc(sizeof(FaceData) * (size_t)(k_marked > 0 ? k_marked : 1));
    if (!head || !hot || !mk) {
        status = -1;
        goto done;
    }
    /* the marked faces' lists per cell */
    int64_t m = 0, t = 0, t_cap = 0;
    for (int64_t i = 0; i < nf; i++) {
        if (!valid[i] || !only[i]) continue;
        int64_t c[6];
        double span = cell_range(lo + 3 * i, hi + 3 * i, origin, cell, c);
        int64_t need = t + (int64_t)span;
        if (need > t_cap) {
            t_cap = 2 * need + 64;
            int32_t *nn = (int32_t *)realloc(next, sizeof(int32_t) * (size_t)t_cap);
            if (nn) next = nn;
            int32_t *nw = (int32_t *)realloc(who, sizeof(int32_t) * (size_t)t_cap);
            if (nw) who = nw;
            if (!nn || !nw) {
                status = -1;
                goto done;
            }
        }
        FaceData *d = mk + m;
        face_data(v, f, i, lo, hi, d);
        for (int k = 0; k < 3; k++) {
            d->c0[k] = c[k];
            d->c1[k] = c[3 + k];
        }
        for (int64_t x = c[0]; x <= c[3]; x++)
            for (int64_t y = c[1]; y <= c[4]; y++)
                for (int64_t z = c[2]; z <= c[5]; z++) {
                    int64_t at = (x * dims[1] + y) * dims[2] + z;
                    int32_t *h = head + at;
                    hot[at >> 6] |= (uint64_t)1 << (at & 63);
                    who[t] = (int32_t)m;
                    next[t] = *h;
                    *h = (int32_t)(++t);
                }
        m++;
    }
    /* decided: the first cell size is feasible, the answer is the pair set */
    status = 0;
    if (m == 0) goto done;
    MarkedLoop loop = {.v = v, .lo = lo, .hi = hi, .origin = origin, .f = f, .dims = dims, .valid = valid,
                       .only = only, .flags = flags, .hot = hot, .head = head, .next = next, .who = who, .mk = mk,
                       .cell = cell};
    parallel_for(workers_for(threads, nf, PASS_CHUNK), nf, PASS_CHUNK, marked_loop, &loop);
done:
    if (status == 2) memset(flags, 0, (size_t)nf);
    free(sums);
    free(lo);
    free(hi);
    free(ext);
    free(valid);
    free(hot);
    free(head);
    free(next);
    free(who);
    free(mk);
    return status;
}

/* ------------------------------------------------------------------------------------------------------------
 * tw_crossings_stars(v, nv, f, nf, only, children, threads, flags) -> 0: decided, flags are exactly what
 * tw_crossings_grid (`faces`) writes; 2: undecided (flags all 0: the
 * caller runs `faces`).
 *
 * The first check of a filtered surface, without a grid over its faces. `children` is 1, or 4 when the faces come
 * in runs of four, the children of one face of the level before (geometry.subdivision.loop_level: the corner
 * children (a, m_ab, m_ca), (m_ab, b, m_bc), (m_ca, m_bc, c) and the middle one (m_ab, m_bc, m_ca)); "parents" are
 * those faces (children 1: the faces themselves). Every pair of valid faces with overlapping closed boxes and a
 * face marked in `only` is either tested with pair_intersects, the lower face first, as `faces` tests it, or
 * shown not to cross:
 *
 * - Parents that share no vertex: their children share no vertex either; a grid over the parents' boxes (the
 *   union of their children's) lists the parent pairs whose boxes overlap, and each pair of their children whose
 *   boxes overlap is tested.
 * - Parents that share a vertex u: both lie in u's patch, the children of the parents around u. The patch is a
 *   disk (a closed fan of parents, checked, refined as loop_level refines it). Projected along N, the sum of its
 *   faces' normals, every face of the patch has twice its area at least STAR_MARGIN times its longest edge squared
 *   (shown for each parent's children at once, from the cone of their normals: ParentRec), and
 *   its boundary turns around u by at least STAR_MARGIN (sine of the angle) at every step and once in all: the
 *   projection of a disk whose faces all keep their orientation and whose boundary is a simple closed curve is
 *   one-to-one (each point inside the curve has one preimage, counted with orientation), so no two faces of the
 *   patch meet outside the vertices and edges they share, and faces sharing only u stay apart by at least
 *   ~STAR_MARGIN of their edges, far above the contact tolerances of pair_intersects (TOUCH_3D m^3: faces within
 *   ~2^-43 m), which therefore answers 0 for each of the patch's pairs (tests: stars == faces on Loop levels with
 *   folds and crossings). A patch that fails this has all its pairs tested.
 *
 * `faces` answers with that pair set unless its grid fails at its first cell size; first_grid_feasible() proves
 * it does not (as `marked` does), else this is undecided. Undecided also when the runs are not Loop children or
 * the parents' grid would be too large: the caller then runs `faces`.
 * ------------------------------------------------------------------------------------------------------------ */
#define STAR_MARGIN 1e-6
#define MAX_STAR 64 /* parents around one vertex that a patch takes; more: its pairs are tested */
#define MAX_PARENT_PAIRS 64000000LL

/* A parent as the patches read it (one record, so that a patch touches a few cache lines, not its 24 faces): its
 * corners and edge midpoints, the sum of its children's normals, and a cone that holds their unit normals: every
 * child's unit normal is within angle t of `axis` (cos_t, sin_t), and `need` = the largest of STAR_MARGIN (longest
 * edge)^2 / |normal| over the children. ok: every child valid and the cone narrower than a half-space. */
typedef struct {
    int32_t ids[3], mid[3]; /* mid: m01, m12, m20 (children 4), the middle child's corners (vertex indices) */
    double nsum[3], axis[3], cos_t, sin_t, need;
    uint8_t ok, marked;
} ParentRec;

/* Rounding allowance of the cone test (its inputs are unit vectors; the test's margin is STAR_MARGIN) */
#define CONE_SLACK 1e-9

/* One vertex's patch: 1 when it is shown free of crossings (see above), 0 when its pairs must be tested. pf: the
 * k parents around u; group: children per parent. */
static int patch_certified(const CheckFaces *s, const ParentRec *recs, int group, int64_t u, const int32_t *pf,
                           int64_t k) {
    if (k < 3 || k > MAX_STAR) return 0;
    int64_t a[MAX_STAR], b[MAX_STAR], mid[MAX_STAR], spoke_a[MAX_STAR], spoke_b[MAX_STAR], order[MAX_STAR];
    uint8_t used[MAX_STAR];
    for (int64_t t = 0; t < k; t++) {
        const ParentRec *r = recs + pf[t];
        const int32_t *p = r->ids;
        if (!r->ok || p[0] == p[1] || p[1] == p[2] || p[2] == p[0]) return 0;
        int at = p[0] == u ? 0 : p[1] == u ? 1 : 2;
        a[t] = p[(at + 1) % 3];
        b[t] = p[(at + 2) % 3];
        if (group == 4) { /* the middle child (m01, m12, m20): edge (x_e, x_e+1) has its midpoint at e */
            const int32_t *m = r->mid;
            mid[t] = m[(at + 1) % 3];
            spoke_a[t] = m[at];           /* midpoint of (u, a) */
            spoke_b[t] = m[(at + 2) % 3]; /* midpoint of (b, u) */
        }
        used[t] = 0;
    }
    /* the parents in fan order: each starts where the last ended, one cycle through all */
    order[0] = 0;
    used[0] = 1;
    for (int64_t t = 1; t < k; t++) {
        int64_t prev = order[t - 1], next = -1, found = 0, want = b[prev];
        for (int64_t c = 0; c < k; c++) { /* branch-free: which parent matches is unpredictable */
            int hit = !used[c] & (a[c] == want);
            found += hit;
            next = hit ? c : next;
        }
        if (found != 1) return 0; /* none, or two candidates: not a manifold fan */
        order[t] = next;
        used[next] = 1;
    }
    if (b[order[k - 1]] != a[order[0]]) return 0;
    /* a disk: distinct boundary vertices, spoke midpoints shared by neighbouring parents and distinct */
    for (int64_t t = 0; t < k; t++)
        for (int64_t c = t + 1; c < k; c++) {
            if (a[t] == a[c]) return 0;
            if (group == 4 && (mid[t] == mid[c] || spoke_a[t] == spoke_a[c] || mid[t] == a[c] || mid[c] == a[t]))
                return 0;
        }
    if (group == 4)
        for (int64_t t = 0; t < k; t++) {
            int64_t x = order[t], y = order[t + 1 < k ? t + 1 : 0]; /* (t + 1) mod k without a division */
            if (spoke_b[x] != spoke_a[y]) return 0;
            if (spoke_a[x] == u || mid[x] == u) return 0;
            for (int64_t c = 0; c < k; c++)
                if (spoke_a[x] == a[c] || spoke_a[x] == mid[c]) return 0;
        }
    /* N: the sum of the children's normals */
    double nrm[3] = {0, 0, 0};
    for (int64_t t = 0; t < k; t++)
        for (int c = 0; c < 3; c++) nrm[c] += recs[pf[t]].nsum[c];
    double len = sqrt(dot3(nrm, nrm));
    if (!(len > 0)) return 0;
    for (int c = 0; c < 3; c++) nrm[c] /= len;
    /* every child keeps its orientation with area to spare, (projected double area) >= margin (longest edge)^2:
     * its unit normal is within t of the cone's axis, the axis within a of N, so their angle is at most a + t and
     * the projected share of its area at least cos(a + t) >= need */
    for (int64_t t = 0; t < k; t++) {
        const ParentRec *r = recs + pf[t];
        double d = dot3(r->axis, nrm);
        if (!(d > 0)) return 0;
        double sin_a = sqrt(d < 1 ? 1 - d * d : 0);
        if (!(d * r->cos_t - sin_a * r->sin_t >= r->need + CONE_SLACK)) return 0;
    }
    /* the boundary, projected on a basis (e1, e2) of the plane normal to N, turns around u once, each step by a
     * positive angle with margin */
    double e1[3], e2[3], axis[3] = {0, 0, 0};
    int small = fabs(nrm[0]) <= fabs(nrm[1]) ? (fabs(nrm[0]) <= fabs(nrm[2]) ? 0 : 2)
                                             : (fabs(nrm[1]) <= fabs(nrm[2]) ? 1 : 2);
    axis[small] = 1;
    cross3(nrm, axis, e1);
    double l1 = sqrt(dot3(e1, e1));
    for (int c = 0; c < 3; c++) e1[c] /= l1;
    cross3(nrm, e1, e2);
    const double *pu = s->v + 3 * u;
    int64_t nb = group == 4 ? 2 * k : k;
    double q[2 * MAX_STAR][2];
    for (int64_t t = 0; t < k; t++) {
        int64_t x = order[t];
        int64_t ids[2] = {a[x], group == 4 ? mid[x] : -1};
        for (int j = 0; j < (group == 4 ? 2 : 1); j++) {
            double d[3];
            sub3(s->v + 3 * ids[j], pu, d);
            double *qq = q[(group == 4 ? 2 : 1) * t + j];
            qq[0] = dot3(d, e1);
            qq[1] = dot3(d, e2);
        }
    }
    int winding = 0;
    for (int64_t i = 0; i < nb; i++) {
        const double *p = q[i], *r = q[i + 1 < nb ? i + 1 : 0];
        double cr = p[0] * r[1] - p[1] * r[0];
        double lp = p[0] * p[0] + p[1] * p[1], lr = r[0] * r[0] + r[1] * r[1];
        if (!(cr > 0 && cr * cr >= STAR_MARGIN * STAR_MARGIN * lp * lr)) return 0; /* cr > 0: lp, lr > 0 */
        winding += p[1] < 0 && r[1] >= 0;
    }
    return winding == 1;
}

/* `stars`' pass over parents [begin, end) (one block): as `faces`, the valid faces, their boxes and extents (the
 * reference's grid, merged by merge_blocks); each parent's record (runs checked to be Loop children) and box (its
 * valid children's) */
typedef struct {
    const CheckFaces *s;
    int group;
    int64_t chunk;
    uint8_t *valid, *interest, *runs;
    ParentRec *recs;
    double *gbox, *ext;
    BlockSum *sums;
} StarsPass;

static void stars_pass(void *ctx, int64_t begin, int64_t end, int worker) {
    (void)worker;
    StarsPass *sp = (StarsPass *)ctx;
    const CheckFaces *s = sp->s;
    const int group = sp->group;
    uint8_t *valid = sp->valid, *interest = sp->interest;
    ParentRec *recs = sp->recs;
    double *gbox = sp->gbox, *ext = sp->ext;
    BlockSum *sum = sp->sums + begin / sp->chunk;
    int runs = 1;
    sum->n = sum->marked = 0;
    for (int64_t j = begin; j < end; j++) {
        const int32_t *c = s->f + 3 * group * j;
        ParentRec *r = recs + j;
        if (group == 1) {
            r->ids[0] = c[0], r->ids[1] = c[1], r->ids[2] = c[2];
            r->mid[0] = r->mid[1] = r->mid[2] = -1;
        } else {
            int64_t m01 = c[1], m20 = c[2], m12 = c[5];
            r->ids[0] = c[0], r->ids[1] = c[4], r->ids[2] = c[8];
            r->mid[0] = m01, r->mid[1] = m12, r->mid[2] = m20;
            if (c[3] != m01 || c[6] != m20 || c[7] != m12 || c[9] != m01 || c[10] != m12 || c[11] != m20) runs = 0;
        }
        double unit[4][3], sum_u[3] = {0, 0, 0}, *gb = gbox + 6 * j;
        r->nsum[0] = r->nsum[1] = r->nsum[2] = 0;
        r->need = 0;
        r->ok = 1;
        r->marked = 0;
        interest[j] = 2; /* no valid child: never a candidate of the parents' grid */
        for (int g = 0; g < group; g++) {
            int64_t face = group * j + g;
            const double *p0 = s->v + 3 * s->f[3 * face], *p1 = s->v + 3 * s->f[3 * face + 1];
            const double *p2 = s->v + 3 * s->f[3 * face + 2];
            double e1[3], e2[3], e3[3], nrm[3], b[6];
            sub3(p1, p0, e1);
            sub3(p2, p0, e2);
            cross3(e1, e2, nrm);
            double nn = dot3(nrm, nrm);
            valid[face] = nn > 0;
            r->marked |= s->only[face];
            if (!valid[face]) {
                r->ok = 0;
                continue;
            }
            double x = face_box(p0, p1, p2, b, b + 3);
            for (int k = 0; k < 3; k++) {
                if (interest[j] == 2 || b[k] < gb[k]) gb[k] = b[k];
                if (interest[j] == 2 || b[3 + k] > gb[3 + k]) gb[3 + k] = b[3 + k];
            }
            ext[group * begin + sum->n] = x;
            block_add(sum, b, b + 3);
            interest[j] = (interest[j] == 2 ? 0 : interest[j]) | s->only[face];
            /* the cone of the children's unit normals and the margin they need (patch_certified) */
            sub3(p2, p1, e3);
            double nl = sqrt(nn), l1 = dot3(e1, e1), l2 = dot3(e2, e2), l3 = dot3(e3, e3);
            double longest = l1 > l2 ? (l1 > l3 ? l1 : l3) : (l2 > l3 ? l2 : l3);
            double need = STAR_MARGIN * longest / nl;
            if (need > r->need) r->need = need;
            for (int k = 0; k < 3; k++) {
                r->nsum[k] += nrm[k];
                unit[g][k] = nrm[k] / nl;
                sum_u[k] += unit[g][k];
            }
        }
        double sl = sqrt(dot3(sum_u, sum_u));
        r->cos_t = -1;
        if (r->ok && sl > 0) {
            for (int k = 0; k < 3; k++) r->axis[k] = sum_u[k] / sl;
            double lowest = 1;
            for (int g = 0; g < group; g++) {
                double d = dot3(unit[g], r->axis);
                if (d < lowest) lowest = d;
            }
            r->cos_t = lowest;
        }
        if (!(r->cos_t > 0)) r->ok = 0;
        r->sin_t = r->ok ? sqrt(1 - r->cos_t * r->cos_t) : 1;
    }
    sp->runs[begin / sp->chunk] = (uint8_t)runs;
}

/* `stars`' patches of vertices [begin, end) (see patch_certified) */
typedef struct {
    const CheckFaces *s;
    const ParentRec *recs;
    const int32_t *vstart, *vfaces;
    int group;
} StarsPatches;

static void stars_patches(void *ctx, int64_t begin, int64_t end, int worker) {
    (void)worker;
    const StarsPatches *c = (const StarsPatches *)ctx;
    const ParentRec *recs = c->recs;
    const int group = c->group;
    for (int64_t u = begin; u < end; u++) {
        const int32_t *pf = c->vfaces + c->vstart[u];
        int64_t k = c->vstart[u + 1] - c->vstart[u], any = 0;
        for (int64_t t = 0; t < k && !any; t++) any |= recs[pf[t]].marked;
        if (!any || patch_certified(c->s, recs, group, u, pf, k)) continue;
        for (int64_t t = 0; t < k; t++)
            for (int g = 0; g < group; g++)
                for (int64_t w = t; w < k; w++)
                    for (int h = (w == t ? g + 1 : 0); h < group; h++)
                        test_pair(c->s, (int64_t)group * pf[t] + g, (int64_t)group * pf[w] + h);
    }
}

/* A parent as the grid's pair loop reads it: box (lo xyz, hi xyz), vertex indices (int32, as the faces'), where
 * its lower cell is the cell's (bit d: in coordinate d) and whether it has a marked child (interest). */
typedef struct {
    double box[6];
    int32_t ids[3];
    uint8_t at, interest;
} CellParent;

/* `stars`' pair loop over the parents' grid, cells [begin, end) (cell (x, y, z) is number (x dims_y + y) dims_z
 * + z); each worker gathers a cell's parents into its own scratch (`most` entries per worker, local and lpid) */
typedef struct {
    const CheckFaces *s;
    const ParentRec *recs;
    const double *gbox;
    const int32_t *gc, *bucket;
    const int64_t *dims;
    const int32_t *cstart;
    const uint8_t *interest;
    int group;
    int64_t most;
    CellParent *local;
    int64_t *lpid;
    int32_t *lkeep;
} StarsCells;

static void stars_cells(void *ctx, int64_t begin, int64_t end, int worker) {
    const StarsCells *c = (const StarsCells *)ctx;
    const int group = c->group;
    const int64_t *dims = c->dims;
    CellParent *local = c->local + c->most * worker;
    int64_t *lpid = c->lpid + c->most * worker;   /* each entry's parent */
    int32_t *lkeep = c->lkeep + c->most * worker; /* the entries that pass with the current one */
    for (int64_t cid = begin; cid < end; cid++) {
        int64_t s0 = c->cstart[cid], m = c->cstart[cid + 1] - s0;
        if (m < 2) continue;
        int64_t x = cid / (dims[1] * dims[2]), y = cid / dims[2] % dims[1], z = cid % dims[2];
        for (int64_t i = 0; i < m; i++) {
            int64_t p = c->bucket[s0 + i];
            CellParent *l = local + i;
            const int32_t *g = c->gc + 6 * p;
            lpid[i] = p;
            l->interest = c->interest[p] != 0;
            /* the pair is tested once, in the cell of the larger of the two lower corners: every box here covers
             * this cell (lower corner at or below it), so the larger is this cell when in each coordinate one is */
            l->at = (uint8_t)((g[0] == x) | (g[1] == y) << 1 | (g[2] == z) << 2);
            for (int k = 0; k < 3; k++) {
                l->box[k] = c->gbox[6 * p + k];
                l->box[3 + k] = c->gbox[6 * p + 3 + k];
                l->ids[k] = (int32_t)c->recs[p].ids[k];
            }
        }
        for (int64_t i = 0; i < m; i++) {
            const CellParent *lp = local + i;
            const double *bp = lp->box;
            const int32_t v0 = lp->ids[0], v1 = lp->ids[1], v2 = lp->ids[2];
            int64_t kept = 0;
            /* branch-free (the tests go either way unpredictably): the pairs whose boxes overlap, one of which has
             * a marked child, and which share no vertex (a shared vertex makes it a patch's pair) are listed (the
             * list grows by 0 or 1 each), then tested */
            for (int64_t j = i + 1; j < m; j++) {
                const CellParent *lr = local + j;
                const double *br = lr->box;
                const int32_t *vr = lr->ids;
                int touch = (v0 == vr[0]) | (v0 == vr[1]) | (v0 == vr[2]) | (v1 == vr[0]) | (v1 == vr[1]) |
                            (v1 == vr[2]) | (v2 == vr[0]) | (v2 == vr[1]) | (v2 == vr[2]);
                int keep = ((lp->at | lr->at) == 7) & (bp[0] <= br[3]) & (br[0] <= bp[3]) & (bp[1] <= br[4]) &
                           (br[1] <= bp[4]) & (bp[2] <= br[5]) & (br[2] <= bp[5]) & (lp->interest | lr->interest) &
                           !touch;
                lkeep[kept] = (int32_t)j;
                kept += keep;
            }
            for (int64_t t = 0; t < kept; t++) test_parents(c->s, group, lpid[i], lpid[lkeep[t]]);
        }
    }
}

int tw_crossings_stars(const double *v, size_t nv_, const int32_t *f, size_t nf_, const uint8_t *only, int group,
                       int threads, uint8_t *flags) {
    int64_t nf = (int64_t)nf_;
    if (group != 1 && group != 4) return 2;
    CheckFaces s;
    s.v = v;
    s.f = f;
    s.only = only;
    s.flags = flags;
    int status = 2;
    uint8_t *valid = NULL, *interest = NULL;
    double *ext = NULL, *gbox = NULL, *gext = NULL;
    ParentRec *recs = NULL;
    int32_t *vstart = NULL, *vfaces = NULL, *gc = NULL, *bucket = NULL; /* int32: see the guard below */
    int32_t *cstart = NULL;
    CellParent *local = NULL;
    int64_t *lpid = NULL;
    int32_t *lkeep = NULL;
    BlockSum *sums = NULL;
    uint8_t *runs = NULL;
    memset(s.flags, 0, (size_t)nf);
    size_t cap = (size_t)(nf > 0 ? nf : 1);
    valid = (uint8_t *)malloc(cap);
    ext = (double *)malloc(sizeof(double) * cap);
    if (!valid || !ext) {
        status = -1;
        goto done;
    }
    s.valid = valid;
    int64_t n = 0, nv = (int64_t)nv_, np = nf / group;
    if (nf % group) goto done;
    recs = (ParentRec *)malloc(sizeof(ParentRec) * (size_t)(np > 0 ? np : 1));
    gbox = (double *)malloc(sizeof(double) * 6 * (size_t)(np > 0 ? np : 1));
    interest = (uint8_t *)malloc((size_t)(np > 0 ? np : 1));
    if (!recs || !gbox || !interest) {
        status = -1;
        goto done;
    }
    /* one pass over the faces, parent by parent (stars_pass) */
    int pass_workers = workers_for(threads, np, PASS_CHUNK / 4);
    int64_t chunk = block_chunk(np, pass_workers), blocks = np > 0 ? (np + chunk - 1) / chunk : 0, k_marked;
    sums = (BlockSum *)calloc((size_t)pass_workers, sizeof(BlockSum));
    runs = (uint8_t *)malloc((size_t)pass_workers);
    if (!sums || !runs) {
        status = -1;
        goto done;
    }
    StarsPass pass = {.s = &s, .group = group, .chunk = chunk, .valid = valid, .interest = interest, .runs = runs,
                      .recs = recs, .gbox = gbox, .ext = ext, .sums = sums};
    parallel_for(pass_workers, np, chunk, stars_pass, &pass);
    double origin[3] = {0, 0, 0}, top[3] = {0, 0, 0};
    n = merge_blocks(sums, blocks, group * chunk, ext, origin, top, &k_marked);
    int loop_runs = 1;
    for (int64_t b = 0; b < blocks; b++) loop_runs &= runs[b];
    if (nf < 2 || n < 2) { /* `faces` flags nothing */
        status = 0;
        goto done;
    }
    if (!loop_runs) goto done;
    double fine_cell;
    int64_t fine_dims[3];
    int feasible = first_grid_feasible(&s, NULL, NULL, nf, n, ext, origin, top, &fine_cell, fine_dims, threads,
                                       NULL);
    if (feasible < 0) status = -1;
    if (feasible <= 0) goto done;
    /* the parents around each vertex */
    /* int32 indices (half the fresh pages of int64): parent numbers, vertex indices (int32 faces) and cell
     * coordinates (dims <= 1e9) fit, and 3 np counts when it is below 2^31, else undecided (never so at the
     * decoder's face limit) */
    if (3 * (uint64_t)np > (uint64_t)INT32_MAX) goto done;
    vstart = (int32_t *)calloc((size_t)nv + 1, sizeof(int32_t));
    vfaces = (int32_t *)malloc(sizeof(int32_t) * 3 * (size_t)np);
    if (!vstart || !vfaces) {
        status = -1;
        goto done;
    }
    for (int64_t j = 0; j < np; j++)
        for (int c = 0; c < 3; c++) vstart[recs[j].ids[c] + 1]++;
    for (int64_t u = 0; u < nv; u++) vstart[u + 1] += vstart[u];
    for (int64_t j = 0; j < np; j++)
        for (int c = 0; c < 3; c++) vfaces[vstart[recs[j].ids[c]]++] = (int32_t)j;
    for (int64_t u = nv; u > 0; u--) vstart[u] = vstart[u - 1];
    vstart[0] = 0;
    /* patches */
    StarsPatches patches = {.s = &s, .recs = recs, .vstart = vstart, .vfaces = vfaces, .group = group};
    parallel_for(workers_for(threads, nv, PATCH_CHUNK), nv, PATCH_CHUNK, stars_patches, &patches);
    /* parents sharing no vertex: a grid over their boxes */
    gext = (double *)malloc(sizeof(double) * (size_t)np);
    gc = (int32_t *)malloc(sizeof(int32_t) * 6 * (size_t)np);
    if (!gext || !gc) {
        status = -1;
        goto done;
    }
    int64_t ng = 0;
    double go[3] = {0, 0, 0}, gt[3] = {0, 0, 0};
    for (int64_t j = 0; j < np; j++) {
        if (interest[j] == 2) continue;
        const double *b = gbox + 6 * j;
        double x = 0;
        for (int k = 0; k < 3; k++) {
            if (b[3 + k] - b[k] > x) x = b[3 + k] - b[k];
            if (ng == 0 || b[k] < go[k]) go[k] = b[k];
            if (ng == 0 || b[3 + k] > gt[k]) gt[k] = b[3 + k];
        }
        gext[ng++] = x;
    }
    if (ng < 2) {
        status = 0;
        goto done;
    }
    double cell = 2.0 * kth_value(gext, ng, ng / 2);
    if (!(cell > 0)) cell = 1.0;
    int64_t dims[3], ncells = 0, entries = 0;
    for (int round = 0;; round++) {
        if (round == 64) goto done;
        double total = 1;
        for (int k = 0; k < 3; k++) {
            double q = (gt[k] - go[k]) / cell;
            dims[k] = q < 1e9 ? (int64_t)q + 1 : (int64_t)1e9;
            total *= (double)dims[k];
        }
        double spans = 0;
        if (total <= (double)MAX_DENSE_CELLS)
            for (int64_t j = 0; j < np; j++) {
                if (interest[j] == 2) continue;
                const double *b = gbox + 6 * j;
                double span = 1;
                for (int k = 0; k < 3; k++)
                    span *= (double)((int64_t)((b[3 + k] - go[k]) / cell) - (int64_t)((b[k] - go[k]) / cell) + 1);
                spans += span;
            }
        if (total <= (double)MAX_DENSE_CELLS && spans <= 64.0 * (double)ng + 1000000.0) {
            ncells = (int64_t)total;
            entries = (int64_t)spans;
            break;
        }
        cell *= 2.0;
    }
    cstart = (int32_t *)calloc((size_t)ncells + 1, sizeof(int32_t));
    bucket = (int32_t *)malloc(sizeof(int32_t) * (size_t)(entries > 0 ? entries : 1));
    if (!cstart || !bucket) {
        status = -1;
        goto done;
    }
    for (int64_t j = 0; j < np; j++) {
        if (interest[j] == 2) continue;
        const double *b = gbox + 6 * j;
        int32_t *c = gc + 6 * j;
        for (int k = 0; k < 3; k++) { /* below dims[k] (rounding is monotone), <= MAX_DENSE_CELLS */
            c[k] = (int32_t)(int64_t)((b[k] - go[k]) / cell);
            c[3 + k] = (int32_t)(int64_t)((b[3 + k] - go[k]) / cell);
        }
        for (int64_t x = c[0]; x <= c[3]; x++)
            for (int64_t y = c[1]; y <= c[4]; y++)
                for (int64_t z = c[2]; z <= c[5]; z++) cstart[(x * dims[1] + y) * dims[2] + z + 1]++;
    }
    long long in_cells = 0;
    for (int64_t i = 0; i < ncells; i++) {
        long long size = cstart[i + 1];
        in_cells += size * (size - 1) / 2;
        cstart[i + 1] += cstart[i];
    }
    if (in_cells > MAX_PARENT_PAIRS) goto done;
    for (int64_t j = 0; j < np; j++) {
        if (interest[j] == 2) continue;
        const int32_t *c = gc + 6 * j;
        for (int64_t x = c[0]; x <= c[3]; x++)
            for (int64_t y = c[1]; y <= c[4]; y++)
                for (int64_t z = c[2]; z <= c[5]; z++) bucket[cstart[(x * dims[1] + y) * dims[2] + z]++] = (int32_t)j;
    }
    for (int64_t i = ncells; i > 0; i--) cstart[i] = cstart[i - 1];
    cstart[0] = 0;
    /* per cell, its parents gathered contiguously (the pair loop is memory bound) */
    int64_t most = 0;
    for (int64_t i = 0; i < ncells; i++)
        if (cstart[i + 1] - cstart[i] > most) most = cstart[i + 1] - cstart[i];
    int cell_workers = workers_for(threads, ncells, CELL_CHUNK);
    size_t slots = (size_t)(most > 0 ? most : 1) * (size_t)cell_workers;
    local = (CellParent *)malloc(sizeof(CellParent) * slots);
    lpid = (int64_t *)malloc(sizeof(int64_t) * slots);
    lkeep = (int32_t *)malloc(sizeof(int32_t) * slots);
    if (!local || !lpid || !lkeep) {
        status = -1;
        goto done;
    }
    StarsCells cells = {.s = &s, .recs = recs, .gbox = gbox, .gc = gc, .bucket = bucket, .cstart = cstart,
                        .interest = interest, .dims = dims, .group = group, .most = most > 0 ? most : 1,
                        .local = local, .lpid = lpid, .lkeep = lkeep};
    parallel_for(cell_workers, ncells, CELL_CHUNK, stars_cells, &cells);
    status = 0;
done:
    if (status == 2) memset(s.flags, 0, (size_t)nf);
    free(valid);
    free(ext);
    free(recs);
    free(vstart);
    free(vfaces);
    free(gbox);
    free(gext);
    free(interest);
    free(gc);
    free(cstart);
    free(bucket);
    free(local);
    free(lpid);
    free(lkeep);
    free(sums);
    free(runs);
    return status;
}

/* `only` marking at most 1/MARKED_SHARE of the faces: the short way of tw_crossings_marked first (as
 * intersections.MARKED_SHARE) */
#define MARKED_SHARE 8

/* tw_self_intersecting: intersections.self_intersecting_faces' compiled path (the same calls in the same order):
 * only NULL = every face marked; few marked: tw_crossings_marked, else with children 4 tw_crossings_stars, and
 * tw_crossings_grid when those leave it undecided. Every index is checked first. 0 done, 1 no feasible grid, -1
 * out of memory, -2 an index out of range. */
int tw_self_intersecting(const double *v, size_t nv, const int32_t *f, size_t nf, const uint8_t *only, int children,
                         int threads, uint8_t *flags) {
    for (size_t i = 0; i < 3 * nf; i++)
        if (f[i] < 0 || (size_t)f[i] >= nv) return -2;
    uint8_t *all = NULL;
    if (!only) {
        all = (uint8_t *)malloc(nf > 0 ? nf : 1);
        if (!all) return -1;
        memset(all, 1, nf);
    }
    int status = -3;
    if (only) {
        size_t marked = 0;
        for (size_t i = 0; i < nf; i++) marked += only[i] != 0;
        if (MARKED_SHARE * marked <= nf) status = tw_crossings_marked(v, nv, f, nf, only, threads, flags);
        else if (children == 4)
            status = tw_crossings_stars(v, nv, f, nf, only, 4, threads, flags);
    } else if (children == 4) {
        status = tw_crossings_stars(v, nv, f, nf, all, 4, threads, flags);
    }
    if (status != 0 && status != -1) status = tw_crossings_grid(v, nv, f, nf, only ? only : all, threads, flags);
    free(all);
    return status;
}

/* ------------------------------------------------------------------------------------------------------------
 * tw_check_state: `marked`'s work kept from one restore round's check to the next (filter.c's restore_crossings).
 * Between two checks of one surface only the vertices put back move, so only the faces around them (`changed`)
 * change their box; the rest of `marked` -- the valid faces' boxes, the first cell size, the dense count that
 * proves that size feasible, and the lists of the faces per cell -- is the last check's. A call is decided by the
 * same rule as tw_crossings_marked, and gives its flags, when the kept state is what a fresh pass would compute:
 *
 * - Boxes, validity: recomputed for the changed faces (the same face_box); their validity must not change.
 * - The first cell size 2 median(extents): kept when every changed face's old and new extent both lie strictly
 *   below the lower middle value L, or both strictly above the upper one U (the (n - 1) / 2-th and n / 2-th
 *   smallest; one value for odd n): the values in [L, U] and the count below L are then unchanged, so are the
 *   middle ranks. Only where first_cell() selected them by their bits (no NaN, no sign bit) and 2 median > 0.
 * - origin and top (the boxes' corners, which fix the lattice's dims): kept when no changed face's old box
 *   touched them (strictly inside) and its new box does not leave them.
 * - The count: the changed faces' old cells taken out, all of them first, then their new cells added, so a cell
 *   reaches 65536 only when its final count does; the entries and pairs are then exactly the fresh count's (sums
 *   of integers), and the decision (feasible, else undecided) is first_grid_feasible's.
 * - The pairs: `marked` has every valid face q scan the marked faces listed in q's cells. For a face whose box is
 *   the seed's (not dirty), the same (q, marked p) tuples are enumerated from p: each cell of p's range lists the
 *   faces whose seed box covers it (items), and the pair is taken in its own cell (the larger lower corner) as
 *   there; dirty faces scan the marked faces' lists as in `marked`. The flags are an OR over the same tested
 *   pairs, whatever the order (the skip of pairs whose faces are both flagged only skips pairs that add nothing).
 *
 * Anything else (a proof fails, other faces or sizes, too many dirty faces, no `changed`) computes the state
 * afresh: the cost of tw_crossings_marked. The state never changes the answer, only the work.
 * ------------------------------------------------------------------------------------------------------------ */
struct tw_check_state {
    const int32_t *f; /* the faces described (nf over nv vertices) */
    size_t nf, nv;
    int seeded;             /* 0: the next call computes afresh */
    uint8_t *valid, *dirty; /* nf each; dirty: the face's box is not its seed box (it is not in `items`) */
    double *lo, *hi, *ext;  /* nf * 3, nf * 3: the valid faces' boxes; ext: nf scratch (the selection's) */
    int32_t *rng;           /* nf * 6: each valid face's cells on the lattice (lower x y z, upper x y z) */
    int64_t n, ncells, ndirty, *dirty_list; /* n valid faces; dirty_list: nf / MARKED_SHARE + 1 */
    double origin[3], top[3], cell, ranks[3];
    int64_t dims[3], total;
    long long pairs;
    uint16_t *counts;           /* ncells: faces per cell (first_grid_feasible's dense count) */
    int32_t *start, *items;     /* the valid faces per cell at the seed: items[start[c] .. start[c + 1]) */
    int32_t *head, *next, *who; /* `marked`'s lists of the marked faces per cell (head 0 between calls) */
    uint64_t *hot;
    FaceData *mk;
    int64_t list_cap, mk_cap;
    /* the extents around the middle: every valid face's extent in [win_lo, win_hi], ascending (win_n of them),
     * below: how many are < win_lo. win NULL: not kept (the cell size is then recomputed afresh). */
    double *win, win_lo, win_hi;
    int64_t win_n, win_cap, below;
    int ext_fresh; /* ext holds the valid faces' extents (nothing moved since the seed) */
};

tw_check_state *tw_check_state_new(void) { return (tw_check_state *)calloc(1, sizeof(tw_check_state)); }

void tw_check_state_free(tw_check_state *st) {
    if (!st) return;
    free(st->valid);
    free(st->dirty);
    free(st->lo);
    free(st->hi);
    free(st->ext);
    free(st->rng);
    free(st->dirty_list);
    free(st->counts);
    free(st->start);
    free(st->items);
    free(st->head);
    free(st->next);
    free(st->who);
    free(st->hot);
    free(st->mk);
    free(st->win);
    free(st);
}

/* The extent of box lo, hi as face_box computes it from the corners (the same comparisons on the same values). */
static inline double box_extent(const double *lo, const double *hi) {
    double x = 0;
    for (int k = 0; k < 3; k++)
        if (k == 0 || hi[k] - lo[k] > x) x = hi[k] - lo[k];
    return x;
}

/* An extent radix_kth can order by its bits (+0, positive, +inf): first_cell's total order. */
static inline int clean_extent(double x) {
    uint64_t b;
    memcpy(&b, &x, sizeof b);
    return b <= 0x7ff0000000000000ull;
}

/* Take extent x out of (sign -1) or put it into (sign 1) the kept extents: 0, or -1 when it is not there / no
 * memory (the window is then dropped). */
static int window_move(tw_check_state *st, double x, int sign) {
    if (x < st->win_lo) {
        st->below += sign;
        return 0;
    }
    if (x > st->win_hi) return 0;
    int64_t a = 0, b = st->win_n; /* the first position whose value is >= x */
    while (a < b) {
        int64_t m = a + (b - a) / 2;
        if (st->win[m] < x) a = m + 1;
        else b = m;
    }
    if (sign < 0) {
        if (a >= st->win_n || st->win[a] != x) return -1;
        memmove(st->win + a, st->win + a + 1, sizeof(double) * (size_t)(st->win_n - a - 1));
        st->win_n--;
        return 0;
    }
    if (st->win_n == st->win_cap) {
        double *w = (double *)realloc(st->win, sizeof(double) * (size_t)(2 * st->win_cap + 16));
        if (!w) return -1;
        st->win = w;
        st->win_cap = 2 * st->win_cap + 16;
    }
    memmove(st->win + a + 1, st->win + a, sizeof(double) * (size_t)(st->win_n - a));
    st->win[a] = x;
    st->win_n++;
    return 0;
}

/* first_cell's size from the kept extents (n of them): 1 and *cell, or 0 when a middle rank is not kept or the
 * size would not be 2 median > 0 (computed afresh then). */
static int window_cell(const tw_check_state *st, int64_t n, double *cell, double *ranks) {
    int64_t a = (n - 1) / 2 - st->below, b = n / 2 - st->below;
    if (!st->win || a < 0 || b >= st->win_n) return 0;
    double lower = st->win[a], upper = st->win[b];
    double median = n % 2 == 0 ? (lower + upper) / 2.0 : upper;
    *cell = 2.0 * median;
    ranks[0] = 1;
    ranks[1] = lower;
    ranks[2] = upper;
    return *cell > 0;
}

/* The cells r (6) of box lo, hi on a lattice of the kept state's dims, into int32 (it has < 2^25 cells). */
static inline void kept_range(const double *lo, const double *hi, const double *origin, double cell, int32_t *r) {
    int64_t c[6];
    cell_range(lo, hi, origin, cell, c);
    for (int k = 0; k < 6; k++) r[k] = (int32_t)c[k];
}

/* Add (sign 1) or take out (sign -1) cells r (6) to the kept count: entries, pairs. 0, or 1 when a cell would
 * reach 65536 faces (first_grid_feasible's limit). */
static int kept_cells(tw_check_state *st, const int32_t *r, int sign) {
    int64_t span = 1;
    for (int k = 0; k < 3; k++) span *= (int64_t)r[3 + k] - r[k] + 1;
    st->total += sign * span;
    for (int64_t x = r[0]; x <= r[3]; x++)
        for (int64_t y = r[1]; y <= r[4]; y++)
            for (int64_t z = r[2]; z <= r[5]; z++) {
                uint16_t *cnt = st->counts + (x * st->dims[1] + y) * st->dims[2] + z;
                if (sign < 0) {
                    st->pairs -= --*cnt;
                } else {
                    if (*cnt == UINT16_MAX) return 1;
                    st->pairs += (*cnt)++;
                }
            }
    return 0;
}

/* The extents' window keeps at least KEPT_MARGIN ranks each side of the middle ones, at most KEPT_WINDOW values */
#define KEPT_MARGIN 64
#define KEPT_WINDOW 8192

/* The kept extents around the middle ranks, from st->ext[0..n) (the valid faces' extents as the seed computed
 * them), when first_cell's size came from them by their bits (ranks[0] == 1): the values within a relative band
 * around the upper middle value U, the band widened or narrowed until it holds the middle ranks with KEPT_MARGIN
 * to spare and at most KEPT_WINDOW values (one pass per try). 0 (st->win NULL when none is found), -1 memory. */
static int keep_window(tw_check_state *st) {
    int64_t n = st->n, need_lo = (n - 1) / 2 - KEPT_MARGIN, need_hi = n / 2 + KEPT_MARGIN;
    double U = st->ranks[2], eps = 1.0 / 256;
    free(st->win);
    st->win = NULL;
    if (!(st->ranks[0] == 1) || n < 2 || !(U > 0)) return 0;
    if (need_lo < 0) need_lo = 0;
    if (need_hi > n - 1) need_hi = n - 1;
    for (int tries = 0; tries < 12; tries++) {
        double lo = U - U * eps, hi = U + U * eps;
        int64_t below = 0, m = 0;
        for (int64_t i = 0; i < n; i++) {
            below += st->ext[i] < lo;
            m += st->ext[i] >= lo && st->ext[i] <= hi;
        }
        if (m > KEPT_WINDOW) {
            eps /= 4;
            continue;
        }
        if (below > need_lo || below + m <= need_hi) {
            eps *= 4;
            continue;
        }
        st->win = (double *)malloc(sizeof(double) * (size_t)(2 * m + 16));
        if (!st->win) return -1;
        st->win_cap = 2 * m + 16;
        st->win_n = 0;
        for (int64_t i = 0; i < n; i++)
            if (st->ext[i] >= lo && st->ext[i] <= hi) st->win[st->win_n++] = st->ext[i];
        qsort(st->win, (size_t)st->win_n, sizeof(double), cmp_double);
        st->win_lo = lo;
        st->win_hi = hi;
        st->below = below;
        return 0;
    }
    return 0;
}

/* The kept state moved to the current positions of the changed faces (changed: nf bytes). 1 done (kept), 0
 * compute afresh (a proof failed; the state may be half moved), 2 a cell of 65536 faces (undecided; the state is
 * dropped), -1 out of memory. */
static int kept_update(tw_check_state *st, const double *v, const int32_t *f, const uint8_t *changed) {
    int64_t nf = (int64_t)st->nf, m = 0, cap = nf / MARKED_SHARE + 1;
    for (int64_t i = 0; i < nf; i++) m += changed[i] != 0;
    if (m == 0) return 1;
    if (!st->win && st->ext_fresh && keep_window(st) < 0) return -1;
    st->ext_fresh = 0;
    if (!st->win) return 0;
    if (st->ndirty + m > cap) return 0; /* a long dirty list: cheaper afresh */
    /* the faces whose cells change: the changed ones, and others where the lattice moves (at most cap) */
    int64_t *list = (int64_t *)malloc(sizeof(int64_t) * (size_t)m);
    int64_t *moved = (int64_t *)malloc(sizeof(int64_t) * (size_t)cap);
    double *box = (double *)malloc(sizeof(double) * 6 * (size_t)m);
    int32_t *cells = (int32_t *)malloc(sizeof(int32_t) * 6 * (size_t)cap);
    int status = 1;
    if (!list || !moved || !box || !cells) {
        status = -1;
        goto out;
    }
    /* the changed faces' new boxes: validity kept, extents orderable, corners strictly inside the last ones */
    int64_t nc = 0;
    for (int64_t i = 0; i < nf && status == 1; i++) {
        if (!changed[i]) continue;
        const double *p0 = v + 3 * f[3 * i], *p1 = v + 3 * f[3 * i + 1], *p2 = v + 3 * f[3 * i + 2];
        double e1[3], e2[3], x[3], *b = box + 6 * nc;
        sub3(p1, p0, e1);
        sub3(p2, p0, e2);
        cross3(e1, e2, x);
        int now = dot3(x, x) > 0;
        if (now != st->valid[i]) status = 0;
        if (!now || status != 1) continue;
        double e_new = face_box(p0, p1, p2, b, b + 3);
        const double *ol = st->lo + 3 * i, *oh = st->hi + 3 * i;
        if (!clean_extent(e_new)) status = 0;
        for (int k = 0; k < 3; k++)
            if (!(ol[k] > st->origin[k] && oh[k] < st->top[k] && b[k] > st->origin[k] && b[3 + k] < st->top[k]))
                status = 0;
        list[nc++] = i;
    }
    if (status != 1) goto out;
    /* the first cell size from the kept extents */
    for (int64_t j = 0; j < nc && status == 1; j++) {
        int64_t i = list[j];
        if (window_move(st, box_extent(st->lo + 3 * i, st->hi + 3 * i), -1) ||
            window_move(st, box_extent(box + 6 * j, box + 6 * j + 3), 1))
            status = 0;
    }
    double cell, ranks[3];
    if (status != 1 || !window_cell(st, st->n, &cell, ranks)) {
        free(st->win); /* the kept extents are no longer the faces' */
        st->win = NULL;
        status = 0;
        goto out;
    }
    int64_t dims[3];
    for (int k = 0; k < 3; k++) { /* first_grid_feasible's dims; origin and top are kept (see above) */
        double q = (st->top[k] - st->origin[k]) / cell;
        if (!(q < 1e9)) status = 0;
        dims[k] = status ? (int64_t)q + 1 : 0;
        if (dims[k] != st->dims[k]) status = 0;
    }
    if (status != 1) goto out;
    /* the faces whose cells change, with their new cells */
    int64_t nl = 0;
    if (cell == st->cell) {
        for (int64_t j = 0; j < nc; j++) {
            kept_range(box + 6 * j, box + 6 * j + 3, st->origin, cell, cells + 6 * j);
            moved[j] = list[j];
        }
        nl = nc;
    } else {
        int32_t r[6];
        for (int64_t i = 0, j = 0; i < nf && status == 1; i++) {
            if (!st->valid[i]) continue;
            int now = j < nc && list[j] == i;
            const double *b = now ? box + 6 * j : NULL;
            if (now) j++;
            kept_range(b ? b : st->lo + 3 * i, b ? b + 3 : st->hi + 3 * i, st->origin, cell, r);
            if (!now && !memcmp(r, st->rng + 6 * i, sizeof r)) continue;
            if (st->ndirty + nl + 1 > cap) {
                status = 0;
                break;
            }
            memcpy(cells + 6 * nl, r, sizeof r);
            moved[nl++] = i;
        }
        if (status != 1) goto out;
    }
    /* the count moved: every old cell out, then every new cell in */
    int over = 0;
    for (int64_t j = 0; j < nl; j++) kept_cells(st, st->rng + 6 * moved[j], -1);
    for (int64_t j = 0; j < nl && !over; j++) over = kept_cells(st, cells + 6 * j, 1);
    if (over) {
        st->seeded = 0;
        status = 2;
        goto out;
    }
    for (int64_t j = 0, c = 0; j < nl; j++) {
        int64_t i = moved[j];
        memcpy(st->rng + 6 * i, cells + 6 * j, 6 * sizeof(int32_t));
        if (changed[i]) { /* the valid changed faces, in face order in both moved and box */
            memcpy(st->lo + 3 * i, box + 6 * c, 3 * sizeof(double));
            memcpy(st->hi + 3 * i, box + 6 * c + 3, 3 * sizeof(double));
            c++;
        }
        if (!st->dirty[i]) {
            st->dirty[i] = 1;
            st->dirty_list[st->ndirty++] = i;
        }
    }
    st->cell = cell;
    memcpy(st->ranks, ranks, sizeof ranks);
out:
    free(list);
    free(moved);
    free(box);
    free(cells);
    return status;
}

/* The kept state computed afresh (tw_crossings_marked's first pass and count, the count and boxes kept, the
 * lists of faces per cell built): 1 seeded (feasible), 0 decided without a pair (fewer than 2 valid faces), 2
 * undecided (not seeded), -1 out of memory. */
static int kept_seed(tw_check_state *st, const double *v, size_t nv, const int32_t *f, size_t nf_,
                     const uint8_t *only, int threads) {
    int64_t nf = (int64_t)nf_;
    size_t cap = (size_t)(nf > 0 ? nf : 1);
    st->seeded = 0;
    if (st->nf != nf_ || !st->valid) { /* the per-face arrays: all of them, or none (valid NULL) */
        free(st->valid);
        free(st->dirty);
        free(st->lo);
        free(st->hi);
        free(st->ext);
        free(st->rng);
        free(st->dirty_list);
        st->rng = (int32_t *)malloc(sizeof(int32_t) * 6 * cap);
        st->valid = (uint8_t *)malloc(cap);
        st->dirty = (uint8_t *)malloc(cap);
        st->lo = (double *)malloc(sizeof(double) * 3 * cap);
        st->hi = (double *)malloc(sizeof(double) * 3 * cap);
        st->ext = (double *)malloc(sizeof(double) * cap);
        st->dirty_list = (int64_t *)malloc(sizeof(int64_t) * (cap / MARKED_SHARE + 1));
        st->nf = nf_;
        if (!st->valid || !st->dirty || !st->lo || !st->hi || !st->ext || !st->rng || !st->dirty_list) {
            free(st->valid);
            st->valid = NULL;
            return -1;
        }
    }
    st->f = f;
    st->nv = nv;
    st->ndirty = 0;
    memset(st->dirty, 0, cap);
    free(st->counts);
    st->counts = NULL;
    int pass_workers = workers_for(threads, nf, PASS_CHUNK);
    int64_t chunk = block_chunk(nf, pass_workers), k_marked = 0;
    BlockSum *sums = (BlockSum *)calloc((size_t)pass_workers, sizeof(BlockSum));
    if (!sums) return -1;
    MarkedPass pass = {.v = v, .f = f, .only = only, .valid = st->valid, .lo = st->lo, .hi = st->hi, .ext = st->ext,
                       .chunk = chunk, .sums = sums};
    parallel_for(pass_workers, nf, chunk, marked_pass, &pass);
    st->n = merge_blocks(sums, nf > 0 ? (nf + chunk - 1) / chunk : 0, chunk, st->ext, st->origin, st->top, &k_marked);
    free(sums);
    if (nf < 2 || st->n < 2) return 0;
    CheckFaces s = {v, f, st->valid, only, NULL};
    GridKeep keep = {{0, 0, 0}, NULL, st->rng, 0, 0};
    int feasible = first_grid_feasible(&s, st->lo, st->hi, nf, st->n, st->ext, st->origin, st->top, &st->cell,
                                       st->dims, threads, &keep);
    if (feasible <= 0) return feasible < 0 ? -1 : 2;
    memcpy(st->ranks, keep.ranks, sizeof st->ranks);
    st->counts = keep.counts;
    st->total = keep.total;
    st->pairs = keep.pairs;
    int64_t ncells = st->dims[0] * st->dims[1] * st->dims[2];
    if (ncells != st->ncells || !st->head || !st->hot) { /* head and hot: 0 between calls */
        free(st->start);
        free(st->head);
        free(st->hot);
        st->start = NULL;
        st->head = (int32_t *)calloc((size_t)ncells, sizeof(int32_t));
        st->hot = (uint64_t *)calloc((size_t)(ncells / 64 + 1), sizeof(uint64_t));
        st->ncells = ncells;
        if (!st->head || !st->hot) return -1;
    }
    /* the lists of faces per cell and the extents' window wait for the next call: one check alone needs neither */
    free(st->items);
    st->items = NULL;
    free(st->win);
    st->win = NULL;
    st->ext_fresh = 1;
    st->seeded = 1;
    return 1;
}

/* The lists of the valid faces per cell (items, start) from the kept count and cells, every face clean: 0, or -1
 * out of memory (the lists are then not there). */
static int kept_lists(tw_check_state *st) {
    int64_t nf = (int64_t)st->nf, ncells = st->ncells;
    free(st->items);
    free(st->start);
    st->items = NULL;
    st->start = (int32_t *)malloc(sizeof(int32_t) * (size_t)(ncells + 1));
    if (st->start) st->items = (int32_t *)malloc(sizeof(int32_t) * (size_t)(st->total > 0 ? st->total : 1));
    if (!st->items) return -1;
    int32_t *start = st->start;
    start[0] = 0;
    for (int64_t c = 0; c < ncells; c++) start[c + 1] = start[c] + st->counts[c];
    /* fill in face order, with start[c] as the cursor of cell c, then shift back */
    for (int64_t i = 0; i < nf; i++) {
        if (!st->valid[i]) continue;
        const int32_t *c = st->rng + 6 * i;
        for (int64_t x = c[0]; x <= c[3]; x++)
            for (int64_t y = c[1]; y <= c[4]; y++)
                for (int64_t z = c[2]; z <= c[5]; z++) st->items[start[(x * st->dims[1] + y) * st->dims[2] + z]++] =
                    (int32_t)i;
    }
    for (int64_t c = ncells; c > 0; c--) start[c] = start[c - 1];
    start[0] = 0;
    for (int64_t j = 0; j < st->ndirty; j++) st->dirty[st->dirty_list[j]] = 0;
    st->ndirty = 0;
    return 0;
}

/* `marked`'s pairs from the kept state (see above): 0, or -1 out of memory. */
static int kept_pairs(tw_check_state *st, const double *v, const int32_t *f, const uint8_t *only, int threads,
                      uint8_t *flags) {
    int64_t nf = (int64_t)st->nf, m = 0, t = 0;
    const int64_t *dims = st->dims;
    for (int64_t i = 0; i < nf; i++) m += st->valid[i] && only[i];
    if (m == 0) return 0;
    if (m > st->mk_cap) {
        FaceData *mk = (FaceData *)realloc(st->mk, sizeof(FaceData) * (size_t)m);
        if (!mk) return -1;
        st->mk = mk;
        st->mk_cap = m;
    }
    m = 0;
    for (int64_t i = 0; i < nf; i++) {
        if (!st->valid[i] || !only[i]) continue;
        FaceData *d = st->mk + m++;
        const int32_t *c = st->rng + 6 * i;
        face_data(v, f, i, st->lo, st->hi, d);
        int64_t span = 1;
        for (int k = 0; k < 3; k++) {
            d->c0[k] = c[k];
            d->c1[k] = c[3 + k];
            span *= (int64_t)c[3 + k] - c[k] + 1;
        }
        t += span;
    }
    /* faces with their seed box: from the marked faces' cells */
    FaceData q;
    for (int64_t j = 0; j < m && st->items; j++) {
        const FaceData *p = st->mk + j;
        const double *pb = p->box;
        for (int64_t x = p->c0[0]; x <= p->c1[0]; x++)
            for (int64_t y = p->c0[1]; y <= p->c1[1]; y++)
                for (int64_t z = p->c0[2]; z <= p->c1[2]; z++) {
                    int64_t at = (x * dims[1] + y) * dims[2] + z;
                    for (int32_t e = st->start[at]; e < st->start[at + 1]; e++) {
                        int64_t i = st->items[e];
                        if (st->dirty[i] || i == p->face || (only[i] && i > p->face)) continue;
                        const double *ql = st->lo + 3 * i, *qh = st->hi + 3 * i;
                        const int32_t *r = st->rng + 6 * i;
                        int64_t mx = p->c0[0] > r[0] ? p->c0[0] : r[0], my = p->c0[1] > r[1] ? p->c0[1] : r[1];
                        int64_t mz = p->c0[2] > r[2] ? p->c0[2] : r[2];
                        if (mx != x || my != y || mz != z) continue; /* the pair's own cell */
                        if (!(pb[0] <= qh[0] && ql[0] <= pb[3] && pb[1] <= qh[1] && ql[1] <= pb[4] && pb[2] <= qh[2] &&
                              ql[2] <= pb[5]))
                            continue;
                        if (flags[i] && flags[p->face]) continue;
                        face_data(v, f, i, st->lo, st->hi, &q);
                        const FaceData *a = i < p->face ? &q : p, *b = i < p->face ? p : &q;
                        if (pair_intersects(a->corners, b->corners, a->ids, b->ids, a->normal, b->normal, a->box,
                                            b->box, a->nlen, b->nlen))
                            flags[i] = flags[p->face] = 1;
                    }
                }
    }
    if (st->items && st->ndirty == 0) return 0;
    /* dirty faces (no lists of faces: every face): `marked`'s scan of the marked faces' lists */
    if (t > st->list_cap) {
        int32_t *nn = (int32_t *)realloc(st->next, sizeof(int32_t) * (size_t)t);
        if (nn) st->next = nn;
        int32_t *nw = (int32_t *)realloc(st->who, sizeof(int32_t) * (size_t)t);
        if (nw) st->who = nw;
        if (!nn || !nw) return -1;
        st->list_cap = t;
    }
    t = 0;
    for (int64_t j = 0; j < m; j++) {
        const FaceData *p = st->mk + j;
        for (int64_t x = p->c0[0]; x <= p->c1[0]; x++)
            for (int64_t y = p->c0[1]; y <= p->c1[1]; y++)
                for (int64_t z = p->c0[2]; z <= p->c1[2]; z++) {
                    int64_t at = (x * dims[1] + y) * dims[2] + z;
                    st->hot[at >> 6] |= (uint64_t)1 << (at & 63);
                    st->who[t] = (int32_t)j;
                    st->next[t] = st->head[at];
                    st->head[at] = (int32_t)(++t);
                }
    }
    MarkedLoop loop = {.v = v, .lo = st->lo, .hi = st->hi, .origin = st->origin, .f = f, .dims = dims,
                       .valid = st->valid, .only = only, .flags = flags, .hot = st->hot, .head = st->head,
                       .next = st->next, .who = st->who, .mk = st->mk, .cell = st->cell};
    if (!st->items)
        parallel_for(workers_for(threads, nf, PASS_CHUNK), nf, PASS_CHUNK, marked_loop, &loop);
    for (int64_t j = 0; j < st->ndirty && st->items; j++)
        if (st->valid[st->dirty_list[j]]) marked_scan(&loop, st->dirty_list[j]);
    for (int64_t j = 0; j < m; j++) { /* head and hot back to 0 */
        const FaceData *p = st->mk + j;
        for (int64_t x = p->c0[0]; x <= p->c1[0]; x++)
            for (int64_t y = p->c0[1]; y <= p->c1[1]; y++)
                for (int64_t z = p->c0[2]; z <= p->c1[2]; z++) {
                    int64_t at = (x * dims[1] + y) * dims[2] + z;
                    st->head[at] = 0;
                    st->hot[at >> 6] = 0;
                }
    }
    return 0;
}

/* tw_crossings_marked through the kept state: the same status and flags. changed: NULL (compute afresh) or nf
 * bytes, nonzero for each face with a vertex moved since the last call with this state. */
static int kept_marked(tw_check_state *st, const double *v, size_t nv, const int32_t *f, size_t nf,
                       const uint8_t *only, const uint8_t *changed, int threads, uint8_t *flags) {
    memset(flags, 0, nf);
    int status = 0;
    if (st->seeded && st->f == f && st->nf == nf && st->nv == nv && changed)
        status = kept_update(st, v, f, changed);
    if (status == 2 || status < 0) return status;
    if (status == 0) {
        status = kept_seed(st, v, nv, f, nf, only, threads);
        if (status != 1) return status;
    } else {
        double limit = 64.0 * (double)st->n + 1000000.0;
        if (!((double)st->total <= limit && st->pairs <= MAX_CANDIDATE_PAIRS)) return 2; /* kept, undecided */
        /* a second check: the lists of faces per cell pay from now on (beyond int32 entries: every face scans) */
        if (!st->items && st->total < INT32_MAX && kept_lists(st) < 0) return -1;
    }
    int r = kept_pairs(st, v, f, only, threads, flags);
    if (r < 0) memset(flags, 0, nf);
    return r;
}

/* tw_self_intersecting, the checks that mark few faces through the kept state `st` (tw_check_state_new; NULL:
 * tw_self_intersecting itself): the same status and flags. changed: NULL, or nf bytes, nonzero for each face with
 * a vertex moved since the last call with `st` (the faces, nf and nv the same as then; otherwise the state is
 * computed afresh). A call that does not go through the state drops it. */
int tw_self_intersecting_kept(tw_check_state *st, const double *v, size_t nv, const int32_t *f, size_t nf,
                              const uint8_t *only, const uint8_t *changed, int children, int threads,
                              uint8_t *flags) {
    if (!st) return tw_self_intersecting(v, nv, f, nf, only, children, threads, flags);
    size_t marked = 0;
    if (only)
        for (size_t i = 0; i < nf; i++) marked += only[i] != 0;
    if (!only || MARKED_SHARE * marked > nf) {
        st->seeded = 0;
        return tw_self_intersecting(v, nv, f, nf, only, children, threads, flags);
    }
    for (size_t i = 0; i < 3 * nf; i++)
        if (f[i] < 0 || (size_t)f[i] >= nv) return -2;
    int status = kept_marked(st, v, nv, f, nf, only, changed, threads, flags);
    if (status != 0 && status != -1) status = tw_crossings_grid(v, nv, f, nf, only, threads, flags);
    return status;
}
