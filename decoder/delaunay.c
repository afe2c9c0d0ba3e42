/* delaunay.c -- the exact 3-D Delaunay tetrahedralization of integer points, unique under a fixed symbolic
 * perturbation (formats/README.md, "The exact Delaunay (byte 12 bit 6)"); stage 2 of tw_decode.
 *
 *   tw_delaunay(cells, n, out, err) (internal.h): cells n * 3 int32 in [0, 2^23 - 1] -> out->tets (T, 4) and
 *       out->hull (H, 3) int32 indices into the caller's cells, in the canonical order of rule 5 below. Errors:
 *       TW_ERROR_ARGUMENT (a coordinate outside [0, 2^23), n > 2^26, a NULL pointer), TW_ERROR_MEMORY (an
 *       allocation failed), TW_ERROR_LIMIT (more than max(64 N + 4096, 2^22) tets: a degenerate set whose
 *       tetrahedralization grows quadratically, e.g. points on two skew lines), TW_ERROR_INTERNAL with a message
 *       starting "flat tet" (a tet with no volume: an internal inconsistency, never expected) or "walk" (point
 *       location did not end).
 *   tw_snap_to_lattice(points, n, cells, err): geometry/delaunay.py snap_to_lattice, float points -> cells.
 *
 * The Python extension tetweave_codec/geometry/_delaunay_native.c is a binding over this file (the same arrays,
 * widened to int64); geometry/delaunay.py `tetrahedralize_cells` calls it.
 *
 * Portability: C99 plus two GNU C extensions that gcc, clang and zig cc (wasm32 included) provide: __int128
 * (the exact fallback of the predicates) and __builtin_ctz / __builtin_ctzll / __builtin_expect. Transparent huge
 * pages (posix_memalign + madvise) only under __linux__. No global mutable state.
 *
 * DEFINITION (the specification; geometry/delaunay.py's docstring states the same in the same words)
 *
 * Input: N integer points p_i = (x_i, y_i, z_i), i = 0..N-1, with 0 <= x_i, y_i, z_i < 2^MAX_BITS, MAX_BITS = 23.
 *
 * 1. Duplicates. Of points with equal coordinates only the one with the lowest index i is a vertex; the others
 *    appear in no tet and no hull face.
 * 2. Ranks and perturbation. The M distinct points are ranked r = 0..M-1 in ascending lexicographic order of
 *    (x, y, z). Each point is lifted to h(p) = x^2 + y^2 + z^2 + delta_r, where the delta_r are positive
 *    infinitesimals with delta_{M-1} >> delta_{M-2} >> ... >> delta_0 > 0 (e.g. delta_r = eps^(M - r), eps -> 0+):
 *    the point of larger rank is raised more, and its term dominates. The tetrahedralization is the regular
 *    triangulation of the points with these lifts (the projection of the lower convex hull of the lifted points):
 *    the Delaunay tetrahedralization where the points are in general position, unique for every input with at
 *    least 4 affinely independent points. Every distinct point is a vertex (a perturbation this small hides none).
 * 3. Predicates, exact.
 *    orient3d(a, b, c, d) = sign det[b - a, c - a, d - a] (rows), no perturbation. A tet (a, b, c, d) is
 *    positively oriented when orient3d(a, b, c, d) > 0.
 *    Conflict of a point e with a positively oriented tet (a, b, c, d) (e inside its perturbed circumsphere):
 *    with O = det[b - a, c - a, d - a] (> 0) and the lifts h,
 *        Phi = O h(e) - o_a h(a) - o_b h(b) - o_c h(c) - o_d h(d),
 *        o_a = det3(e, b, c, d), o_b = det3(a, e, c, d), o_c = det3(a, b, e, d), o_d = det3(a, b, c, e),
 *    det3(.) being the determinant orient3d takes the sign of (o_v / O are e's barycentric coordinates, so
 *    Phi / O = h(e) - the lifted plane through a, b, c, d at e). e conflicts iff Phi < 0. Phi = Phi_0 +
 *    O delta(e) - o_a delta(a) - o_b delta(b) - o_c delta(c) - o_d delta(d), Phi_0 the same with |p|^2 for h.
 *    If Phi_0 != 0 its sign decides (Phi_0 < 0: e strictly inside the circumsphere). Else go through the five
 *    points in descending rank: if the point is e, e does not conflict (its coefficient O > 0); if it is a vertex
 *    v, let o = orient3d of the tet with v replaced by e; if o != 0, e conflicts iff o > 0; if o = 0, go on (e
 *    itself is always reached: the sequence stops).
 *    Translated to e (A = a - e, ...; |A|^2 the squared length): Phi_0 = -W with
 *        W = |A|^2 det[B,C,D] - |B|^2 det[A,C,D] + |C|^2 det[A,B,D] - |D|^2 det[A,B,C]   (rows),
 *    so e is strictly inside iff W > 0.
 * 4. Convex hull. The infinite vertex closes the hull: a hull triangle (a, b, c), oriented outward, is the finite
 *    face of a "ghost tet". A point q conflicts with it iff orient3d(a, b, c, q) > 0 (q strictly outside the
 *    plane), or orient3d(a, b, c, q) = 0 and q is inside the perturbed circumcircle of (a, b, c): in any
 *    coordinate plane where the projection (a', b', c') of the triangle is not degenerate (this code drops the
 *    axis of the largest |component| of (b - a) x (c - a), the lowest axis on ties; the result does not depend
 *    on the choice), with O2 = orient2d(a', b', c') = det[b' - a', c' - a'] and the same 3-D lifts h,
 *        Phi2 = O2 h(q) - o'_a h(a) - o'_b h(b) - o'_c h(c),
 *        o'_a = det2(q', b', c'), o'_b = det2(a', q', c'), o'_c = det2(a', b', q'),
 *    q conflicts iff sign(O2) Phi2 < 0 (h(q) below the lifted plane through a, b, c, at q). Phi2 = Phi2_0 + the
 *    delta terms as above; if sign(O2) Phi2_0 != 0 it decides, else in descending rank over a, b, c, q: q -> no
 *    conflict; a vertex v with o' = orient2d(triangle with v replaced by q) != 0 -> conflict iff sign(o') = sign(O2);
 *    o' = 0: go on to the next point. orient2d = sign det2, det2(a', b', c') = (b'_0 - a'_0)(c'_1 - a'_1) -
 *    (b'_1 - a'_1)(c'_0 - a'_0) on the two kept axes in ascending order. This is the epsilon -> 0 limit of rule 3 restricted to the hull face's plane, so the hull triangulation is
 *    the regular triangulation's: the 2-D regular triangulation of the points on each planar hull face.
 * 5. Output. tets (T, 4): every tet positively oriented (orient3d > 0 exactly; none is flat), indices into the
 *    caller's array. Canonical order: each tet is permuted evenly (orientation kept) so that its smallest index
 *    comes first and the smallest of the remaining three second; the tets are sorted lexicographically. hull
 *    faces (H, 3): the hull triangles, oriented outward (the normal (b - a) x (c - a) points away from the points),
 *    rotated cyclically so that the smallest index comes first, sorted lexicographically. Fewer than 4 distinct
 *    points, or all distinct points coplanar: T = H = 0 (no error).
 *
 * EXACTNESS (the bounds that make 64-bit and 128-bit integers exact). Coordinates c satisfy 0 <= c <= 2^23 - 1:
 *  - differences: |d| <= 2^23 - 1 < 2^23;
 *  - products of two differences < 2^46; 2x2 minors |d1 d2 - d3 d4| < 2^47 (int64; also exact in binary64,
 *    whose integers are exact up to 2^53);
 *  - orient3d and every 3x3 determinant of differences: 3 products of a difference and a 2x2 minor,
 *    |det| < 3 * 2^23 * 2^47 = 3 * 2^70 < 2^72 (int128);
 *  - lifts |A|^2 = dx^2 + dy^2 + dz^2 < 3 * 2^46 < 2^48 (int64, exact in binary64);
 *  - insphere W: 4 products of a lift and a 3x3 determinant of differences:
 *    |W| < 4 * 3 * 2^46 * 3 * 2^70 = 36 * 2^116 < 2^122 < 2^127 (int128; each product < 9 * 2^116 < 2^120);
 *  - the 2-D conflict W2 = |A|^2 det2[B, C] - |B|^2 det2[A, C] + |C|^2 det2[A, B]: |W2| < 3 * 3 * 2^46 * 2^47
 *    < 2^97 (int128); the hull plane normal (b - a) x (c - a): components < 2^47 (int64).
 *
 * ALGORITHM (speed only; any correct algorithm gives the same arrays): duplicates are merged after a stable LSD
 * radix sort of the points by (x, y, z); the points are translated and divided by the largest power of two that
 * divides every coordinate difference (every predicate is a homogeneous polynomial of differences and the ranks
 * do not change, so no sign changes; grid-quantized points then have small coordinates and most predicates are
 * exact in binary64), and renumbered in insertion order (their ranks kept for the perturbation). Insertion order:
 * BRIO (rounds drawn from a fixed hash of the rank) with a 3-D Hilbert order inside each round. Bowyer-Watson: the
 * first tet from 4 affinely independent points plus 4 ghost tets; each point is located by a visibility walk from
 * the last created tet (the four orientations of a step at once; faces tried in a fixed pseudo-random order), the
 * cavity of conflicting tets grown by breadth-first search (outcomes counted rather than branched on), its
 * boundary starred from the point, the new tets linked to each other through a table of oriented boundary edges
 * on local vertex ids (a hash of the edges for cavities of more than 124 boundary faces).
 * Predicates: binary64 first, decided by a static error bound from the largest coordinate difference S (exact
 * as computed when the largest possible permanent, 6 S^3 for orient3d and 72 S^5 for insphere, is below 2^53:
 * grids of up to 16 bits for orient3d, 9 bits for insphere), then by a bound on the computed permanent
 * (Shewchuk-style semi-static filter), then 128-bit integers.
 * Flat arrays: tet vertices int32 x 4, neighbours int32 x 4 encoded as tet * 4 + face (the tet array in transparent
 * huge pages on Linux), a free list of deleted tets.
 */
#if defined(__linux__) && !defined(_DEFAULT_SOURCE)
#define _DEFAULT_SOURCE /* posix_memalign and MADV_HUGEPAGE under -std=c99 */
#endif

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#ifdef __linux__
#include <sys/mman.h>
#endif

#include "internal.h"
#include "radix.h"

#ifndef __SIZEOF_INT128__
#error "delaunay.c needs __int128 (gcc, clang, zig cc): the exact predicates evaluate 128-bit integers"
#endif

#define MAX_BITS 23
#define MAX_POINTS (1 << 26)
/* tets (ghosts included) allowed per distinct point, beyond a constant: ~7 for ordinary sets */
#define TETS_PER_POINT 64
#define TETS_EXTRA 4096
/* ... but never fewer than this many (128 MB of records): small sets whose tetrahedralization is quadratic, such
 * as points on two skew lines, still come out */
#define TETS_FLOOR (1 << 22)

typedef __int128 i128;


/* Forward error bounds of the binary64 filters, relative to the computed permanent. orient3d: differences and 2x2
 * minors are exact, 3 roundings remain (<= 3.01 u, u = 2^-53); insphere: lifts, differences and 2x2 minors are
 * exact, at most 7 roundings on any path (<= 7.1 u). Both with a margin of ~3x. */
#define ORIENT_BOUND 1e-15
#define INSPHERE_BOUND 2.5e-15
#define EXACT_DOUBLE 9007199254740992.0 /* 2^53: a permanent below it means every operation was exact */

enum { OK = 0, ERR_MEMORY = 1, ERR_FLAT = 2, ERR_WALK = 3, ERR_TOO_MANY = 4 };

/* Faces: face k of a tet is opposite its vertex k. Hull face of a ghost tet whose infinite vertex is at slot k,
 * oriented outward (the reverse of the face's orientation in a positively oriented tet). */
static const int HULL_FACE[4][3] = {{1, 3, 2}, {0, 2, 3}, {0, 3, 1}, {0, 1, 2}};

/* ----------------------------------------------------------------------------------------------------------- */
/* predicates on the (translated, scaled) coordinates; a vertex is a pointer to 3 doubles holding integers */

static int orient_exact(const double *a, const double *b, const double *c, const double *d) {
    int64_t bx = (int64_t)b[0] - (int64_t)a[0], by = (int64_t)b[1] - (int64_t)a[1], bz = (int64_t)b[2] - (int64_t)a[2];
    int64_t cx = (int64_t)c[0] - (int64_t)a[0], cy = (int64_t)c[1] - (int64_t)a[1], cz = (int64_t)c[2] - (int64_t)a[2];
    int64_t dx = (int64_t)d[0] - (int64_t)a[0], dy = (int64_t)d[1] - (int64_t)a[1], dz = (int64_t)d[2] - (int64_t)a[2];
    i128 det = (i128)bx * (cy * dz - cz * dy) + (i128)by * (cz * dx - cx * dz) + (i128)bz * (cx * dy - cy * dx);
    return (det > 0) - (det < 0);
}

/* Static filters from the largest coordinate difference S of the input (after scaling): every orient3d
 * permanent is at most 3 * S * 2 S^2 = 6 S^3, every insphere permanent at most 4 * 3 S^2 * 3 * S * 2 S^2 = 72 S^5.
 * A computed value above bound * that maximum has a certain sign; below 2^53 every operation is exact (the
 * bound is then -1: any computed value, 0 included, is the exact one). */
typedef struct {
    double orient, insphere;
} Filter;

static void filter_init(Filter *fl, double span) {
    double o = 6.0 * span * span * span, i = 72.0 * span * span * span * span * span;
    fl->orient = o < EXACT_DOUBLE ? -1.0 : ORIENT_BOUND * o;
    fl->insphere = i < EXACT_DOUBLE ? -1.0 : INSPHERE_BOUND * i;
}

/* orient3d past the static filter: the semi-static filter on the computed permanent, then exact */
static __attribute__((noinline)) int orient_slow(const double *a, const double *b, const double *c, const double *d) {
    double bx = b[0] - a[0], by = b[1] - a[1], bz = b[2] - a[2];
    double cx = c[0] - a[0], cy = c[1] - a[1], cz = c[2] - a[2];
    double dx = d[0] - a[0], dy = d[1] - a[1], dz = d[2] - a[2];
    double t1 = bx * (cy * dz - cz * dy), t2 = by * (cz * dx - cx * dz), t3 = bz * (cx * dy - cy * dx);
    double det = t1 + t2 + t3;
    double perm = fabs(t1) + fabs(t2) + fabs(t3);
    double bound = ORIENT_BOUND * perm;
    if (det > bound) return 1;
    if (-det > bound) return -1;
    if (perm < EXACT_DOUBLE) return (det > 0) - (det < 0);
    return orient_exact(a, b, c, d);
}

/* sign det[b - a, c - a, d - a] */
static inline int orient3d(const Filter *fl, const double *a, const double *b, const double *c, const double *d) {
    double bx = b[0] - a[0], by = b[1] - a[1], bz = b[2] - a[2];
    double cx = c[0] - a[0], cy = c[1] - a[1], cz = c[2] - a[2];
    double dx = d[0] - a[0], dy = d[1] - a[1], dz = d[2] - a[2];
    double det = bx * (cy * dz - cz * dy) + by * (cz * dx - cx * dz) + bz * (cx * dy - cy * dx);
    if (fabs(det) > fl->orient) return (det > 0) - (det < 0);
    return orient_slow(a, b, c, d);
}

static int insphere_exact(const double *a, const double *b, const double *c, const double *d, const double *e) {
    int64_t ax = (int64_t)a[0] - (int64_t)e[0], ay = (int64_t)a[1] - (int64_t)e[1], az = (int64_t)a[2] - (int64_t)e[2];
    int64_t bx = (int64_t)b[0] - (int64_t)e[0], by = (int64_t)b[1] - (int64_t)e[1], bz = (int64_t)b[2] - (int64_t)e[2];
    int64_t cx = (int64_t)c[0] - (int64_t)e[0], cy = (int64_t)c[1] - (int64_t)e[1], cz = (int64_t)c[2] - (int64_t)e[2];
    int64_t dx = (int64_t)d[0] - (int64_t)e[0], dy = (int64_t)d[1] - (int64_t)e[1], dz = (int64_t)d[2] - (int64_t)e[2];
    int64_t ab = ax * by - bx * ay, ac = ax * cy - cx * ay, ad = ax * dy - dx * ay;
    int64_t bc = bx * cy - cx * by, bd = bx * dy - dx * by, cd = cx * dy - dx * cy;
    i128 abc = (i128)az * bc - (i128)bz * ac + (i128)cz * ab;
    i128 bcd = (i128)bz * cd - (i128)cz * bd + (i128)dz * bc;
    i128 acd = (i128)az * cd - (i128)cz * ad + (i128)dz * ac;
    i128 abd = (i128)az * bd - (i128)bz * ad + (i128)dz * ab;
    int64_t la = ax * ax + ay * ay + az * az, lb = bx * bx + by * by + bz * bz;
    int64_t lc = cx * cx + cy * cy + cz * cz, ld = dx * dx + dy * dy + dz * dz;
    i128 w = la * bcd - lb * acd + lc * abd - ld * abc;
    return (w > 0) - (w < 0);
}

/* insphere past the static filter: the semi-static filter on the computed permanent, then exact */
static __attribute__((noinline)) int insphere_slow(const double *a, const double *b, const double *c, const double *d,
                                                   const double *e) {
    double ax = a[0] - e[0], ay = a[1] - e[1], az = a[2] - e[2];
    double bx = b[0] - e[0], by = b[1] - e[1], bz = b[2] - e[2];
    double cx = c[0] - e[0], cy = c[1] - e[1], cz = c[2] - e[2];
    double dx = d[0] - e[0], dy = d[1] - e[1], dz = d[2] - e[2];
    double ab = ax * by - bx * ay, ac = ax * cy - cx * ay, ad = ax * dy - dx * ay;
    double bc = bx * cy - cx * by, bd = bx * dy - dx * by, cd = cx * dy - dx * cy;
    double abc = az * bc - bz * ac + cz * ab;
    double bcd = bz * cd - cz * bd + dz * bc;
    double acd = az * cd - cz * ad + dz * ac;
    double abd = az * bd - bz * ad + dz * ab;
    double pabc = fabs(az * bc) + fabs(bz * ac) + fabs(cz * ab);
    double pbcd = fabs(bz * cd) + fabs(cz * bd) + fabs(dz * bc);
    double pacd = fabs(az * cd) + fabs(cz * ad) + fabs(dz * ac);
    double pabd = fabs(az * bd) + fabs(bz * ad) + fabs(dz * ab);
    double la = ax * ax + ay * ay + az * az, lb = bx * bx + by * by + bz * bz;
    double lc = cx * cx + cy * cy + cz * cz, ld = dx * dx + dy * dy + dz * dz;
    double w = la * bcd - lb * acd + lc * abd - ld * abc;
    double perm = la * pbcd + lb * pacd + lc * pabd + ld * pabc;
    double bound = INSPHERE_BOUND * perm;
    if (w > bound) return 1;
    if (-w > bound) return -1;
    if (perm < EXACT_DOUBLE) return (w > 0) - (w < 0);
    return insphere_exact(a, b, c, d, e);
}

/* sign of W (module docstring, rule 3): > 0 iff e is strictly inside the sphere through a, b, c, d (for a
 * positively oriented tet) */
static inline int insphere_w(const Filter *fl, const double *a, const double *b, const double *c, const double *d,
                             const double *e) {
    double ax = a[0] - e[0], ay = a[1] - e[1], az = a[2] - e[2];
    double bx = b[0] - e[0], by = b[1] - e[1], bz = b[2] - e[2];
    double cx = c[0] - e[0], cy = c[1] - e[1], cz = c[2] - e[2];
    double dx = d[0] - e[0], dy = d[1] - e[1], dz = d[2] - e[2];
    double ab = ax * by - bx * ay, ac = ax * cy - cx * ay, ad = ax * dy - dx * ay;
    double bc = bx * cy - cx * by, bd = bx * dy - dx * by, cd = cx * dy - dx * cy;
    double abc = az * bc - bz * ac + cz * ab;
    double bcd = bz * cd - cz * bd + dz * bc;
    double acd = az * cd - cz * ad + dz * ac;
    double abd = az * bd - bz * ad + dz * ab;
    double la = ax * ax + ay * ay + az * az, lb = bx * bx + by * by + bz * bz;
    double lc = cx * cx + cy * cy + cz * cz, ld = dx * dx + dy * dy + dz * dz;
    double w = la * bcd - lb * acd + lc * abd - ld * abc;
    if (fabs(w) > fl->insphere) return (w > 0) - (w < 0);
    return insphere_slow(a, b, c, d, e);
}

/* ----------------------------------------------------------------------------------------------------------- */
/* the triangulation */

typedef struct {
    uint64_t key;
    int32_t val;
    uint32_t stamp;
} HashSlot;

typedef struct {
    int32_t n;      /* distinct points; vertex n is the infinite vertex */
    double *x;      /* 3 n coordinates, translated and scaled */
    int32_t *rank;  /* lexicographic rank of each vertex (vertices are numbered in insertion order) */
    int32_t *tt;    /* 8 per tet: its 4 vertices (TV; the first -1: a deleted tet), then its 4 neighbours (TN:
                       u * 4 + g, face g of tet u), one cache line per two tets */
    int64_t cap, count, max_tets;
    int32_t *free_list;
    int64_t nfree, free_cap;
    /* per insertion scratch */
    int32_t *stack;
    int64_t stack_cap;
    int32_t *bnd; /* boundary records: cavity tet, face: 2 ints each */
    int64_t bnd_cap;
    HashSlot *hash;
    int64_t hcap;
    int32_t *vloc; /* n + 1: a boundary vertex's local id during one insertion, else -1 */
    int32_t *ltab; /* LOCAL_V x LOCAL_V: new tet face code by oriented local edge (a, b), else -1 */
    uint32_t stamp;
    uint64_t rng;
    int32_t last; /* a finite tet created by the last insertion */
    int32_t dummy;
    Filter fl;
} DT;

#define TV(dt, t) ((dt)->tt + 8 * (int64_t)(t))
#define TN(dt, t, f) ((dt)->tt[8 * (int64_t)(t) + 4 + (f)])

static int grow(void **p, int64_t *cap, int64_t need, size_t item) {
    if (need <= *cap) return OK;
    int64_t c = *cap ? *cap : 64;
    while (c < need) c *= 2;
    void *q = realloc(*p, (size_t)c * item);
    if (!q) return ERR_MEMORY;
    *p = q;
    *cap = c;
    return OK;
}

/* The tet array is accessed at random: on Linux ask for transparent huge pages (fewer TLB misses and page
 * faults; the kernel may ignore it). Freed with free(); a later realloc may drop the alignment (harmless). */
#define HUGE_PAGE ((size_t)2 << 20)
static void *alloc_huge(size_t bytes) {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
    if (bytes >= HUGE_PAGE) {
        void *p = NULL;
        size_t rounded = (bytes + HUGE_PAGE - 1) & ~(HUGE_PAGE - 1);
        if (posix_memalign(&p, HUGE_PAGE, rounded)) return NULL;
        madvise(p, rounded, MADV_HUGEPAGE);
        return p;
    }
#endif
    return malloc(bytes);
}

static inline int new_tet(DT *dt, int32_t *out) {
    if (dt->nfree) {
        *out = dt->free_list[--dt->nfree];
        return OK;
    }
    if (dt->count >= dt->max_tets) return ERR_TOO_MANY;
    if (dt->count >= dt->cap) {
        int64_t c = dt->cap ? dt->cap * 2 : 1024;
        if (c > dt->max_tets) c = dt->max_tets;
        int32_t *tt = realloc(dt->tt, (size_t)c * 8 * sizeof(int32_t));
        if (!tt) return ERR_MEMORY;
        dt->tt = tt;
        dt->cap = c;
    }
    *out = (int32_t)dt->count++;
    return OK;
}

static inline uint64_t xorshift(uint64_t *s) {
    uint64_t x = *s;
    x ^= x << 13;
    x ^= x >> 7;
    x ^= x << 17;
    *s = x;
    return x;
}

static inline const double *P(const DT *dt, int32_t v) { return dt->x + 3 * (int64_t)v; }

/* Does q conflict with the finite, positively oriented tet t? (rule 3) */
static __attribute__((noinline)) int conflict_perturbed(const DT *dt, const int32_t *v, int32_t q);

static inline int conflict_finite(const DT *dt, const int32_t *v, int32_t q) {
    int s = insphere_w(&dt->fl, P(dt, v[0]), P(dt, v[1]), P(dt, v[2]), P(dt, v[3]), P(dt, q));
    if (__builtin_expect(s != 0, 1)) return s > 0;
    return conflict_perturbed(dt, v, q);
}

/* rule 3 where the unperturbed W is 0 */
static __attribute__((noinline)) int conflict_perturbed(const DT *dt, const int32_t *v, int32_t q) {
    const double *pq = P(dt, q);
    /* symbolic perturbation: the five points in descending rank */
    const int32_t *rk = dt->rank;
    int32_t ids[5] = {rk[v[0]], rk[v[1]], rk[v[2]], rk[v[3]], rk[q]};
    int slot[5] = {0, 1, 2, 3, 4};
    for (int i = 1; i < 5; i++) /* insertion sort, descending id */
        for (int j = i; j > 0 && ids[slot[j]] > ids[slot[j - 1]]; j--) {
            int t = slot[j];
            slot[j] = slot[j - 1];
            slot[j - 1] = t;
        }
    for (int i = 0; i < 5; i++) {
        int k = slot[i];
        if (k == 4) return 0;
        const double *p[4] = {P(dt, v[0]), P(dt, v[1]), P(dt, v[2]), P(dt, v[3])};
        p[k] = pq;
        int o = orient3d(&dt->fl, p[0], p[1], p[2], p[3]);
        if (o) return o > 0;
    }
    return 0; /* not reached */
}

/* q on the plane of the triangle (a, b, c) (ids): inside its perturbed circumcircle? (rule 4) */
static int conflict_coplanar(const DT *dt, int32_t ia, int32_t ib, int32_t ic, int32_t iq) {
    const double *a = P(dt, ia), *b = P(dt, ib), *c = P(dt, ic), *q = P(dt, iq);
    int64_t ux = (int64_t)b[0] - (int64_t)a[0], uy = (int64_t)b[1] - (int64_t)a[1], uz = (int64_t)b[2] - (int64_t)a[2];
    int64_t vx = (int64_t)c[0] - (int64_t)a[0], vy = (int64_t)c[1] - (int64_t)a[1], vz = (int64_t)c[2] - (int64_t)a[2];
    int64_t n[3] = {uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx};
    int64_t an[3] = {n[0] < 0 ? -n[0] : n[0], n[1] < 0 ? -n[1] : n[1], n[2] < 0 ? -n[2] : n[2]};
    int drop = 0;
    if (an[1] > an[drop]) drop = 1;
    if (an[2] > an[drop]) drop = 2;
    int i = drop == 0 ? 1 : 0, j = drop == 2 ? 1 : 2;
    const double *pts[4] = {a, b, c, q};
    int64_t du[3], dv[3], lift[3];
    for (int k = 0; k < 3; k++) {
        int64_t dx = (int64_t)pts[k][0] - (int64_t)q[0], dy = (int64_t)pts[k][1] - (int64_t)q[1];
        int64_t dz = (int64_t)pts[k][2] - (int64_t)q[2];
        int64_t d3[3] = {dx, dy, dz};
        du[k] = d3[i];
        dv[k] = d3[j];
        lift[k] = dx * dx + dy * dy + dz * dz;
    }
    int64_t o2 = (int64_t)(b[i] - a[i]) * (int64_t)(c[j] - a[j]) - (int64_t)(b[j] - a[j]) * (int64_t)(c[i] - a[i]);
    int so2 = (o2 > 0) - (o2 < 0);
    if (!so2) return 0; /* not reached: a hull triangle is never degenerate */
    i128 w = (i128)lift[0] * (du[1] * dv[2] - du[2] * dv[1]) - (i128)lift[1] * (du[0] * dv[2] - du[2] * dv[0]) +
             (i128)lift[2] * (du[0] * dv[1] - du[1] * dv[0]);
    int sw = (w > 0) - (w < 0);
    if (sw) return sw * so2 > 0;
    int32_t ids[4] = {dt->rank[ia], dt->rank[ib], dt->rank[ic], dt->rank[iq]};
    int slot[4] = {0, 1, 2, 3};
    for (int s = 1; s < 4; s++)
        for (int t = s; t > 0 && ids[slot[t]] > ids[slot[t - 1]]; t--) {
            int u = slot[t];
            slot[t] = slot[t - 1];
            slot[t - 1] = u;
        }
    for (int s = 0; s < 4; s++) {
        int k = slot[s];
        if (k == 3) return 0;
        const double *p[3] = {a, b, c};
        p[k] = q;
        int64_t o = (int64_t)(p[1][i] - p[0][i]) * (int64_t)(p[2][j] - p[0][j]) -
                    (int64_t)(p[1][j] - p[0][j]) * (int64_t)(p[2][i] - p[0][i]);
        int so = (o > 0) - (o < 0);
        if (so) return so == so2;
    }
    return 0; /* not reached */
}

static __attribute__((noinline)) int conflict_ghost(const DT *dt, const int32_t *v, int32_t q);

/* Does q conflict with tet t (finite or ghost)? */
static inline int conflict(const DT *dt, int32_t t, int32_t q) {
    const int32_t *v = TV(dt, t);
    const int32_t inf = dt->n;
    if (__builtin_expect(v[0] != inf && v[1] != inf && v[2] != inf && v[3] != inf, 1))
        return conflict_finite(dt, v, q);
    return conflict_ghost(dt, v, q);
}

/* conflict() for a ghost tet (rule 4) */
static __attribute__((noinline)) int conflict_ghost(const DT *dt, const int32_t *v, int32_t q) {
    const int32_t inf = dt->n;
    int k = v[0] == inf ? 0 : v[1] == inf ? 1 : v[2] == inf ? 2 : 3;
    const double *p[4];
    for (int i = 0; i < 4; i++) p[i] = i == k ? P(dt, q) : P(dt, v[i]);
    int o = orient3d(&dt->fl, p[0], p[1], p[2], p[3]);
    if (o) return o > 0;
    int32_t f[3], m = 0;
    for (int i = 0; i < 4; i++)
        if (i != k) f[m++] = v[i];
    return conflict_coplanar(dt, f[0], f[1], f[2], q);
}

static inline int is_ghost(const DT *dt, int32_t t) {
    const int32_t *v = TV(dt, t);
    return v[0] == dt->n || v[1] == dt->n || v[2] == dt->n || v[3] == dt->n;
}

/* A tet in conflict with q: a visibility walk from the last created tet to the tet containing q, or to the ghost
 * tet of a hull face q is strictly outside of. */
static int locate(DT *dt, int32_t q, int32_t *found) {
    int32_t t = dt->last;
    int came = -1;
    const double *pq = P(dt, q);
    const double qx = pq[0], qy = pq[1], qz = pq[2], bound = dt->fl.orient;
    for (int64_t steps = 0; steps < 4 * dt->count + 64; steps++) {
        const int32_t *v = TV(dt, t);
        int r = (int)(xorshift(&dt->rng) & 3);
        /* the four orientations with q in place of each vertex, from the vertices translated to q (shared 2x2
         * minors; the same expression shape as orient3d's, so its static filter holds): o[f] = orient3d of the
         * tet with vertex f replaced by q = det[B, C, D], -det[A, C, D], det[A, B, D], -det[A, B, C] */
        const double *pa = P(dt, v[0]), *pb = P(dt, v[1]), *pc = P(dt, v[2]), *pd = P(dt, v[3]);
        double ax = pa[0] - qx, ay = pa[1] - qy, az = pa[2] - qz;
        double bx = pb[0] - qx, by = pb[1] - qy, bz = pb[2] - qz;
        double cx = pc[0] - qx, cy = pc[1] - qy, cz = pc[2] - qz;
        double dx = pd[0] - qx, dy = pd[1] - qy, dz = pd[2] - qz;
        double ab = ax * by - bx * ay, ac = ax * cy - cx * ay, ad = ax * dy - dx * ay;
        double bc = bx * cy - cx * by, bd = bx * dy - dx * by, cd = cx * dy - dx * cy;
        double o[4] = {bz * cd - cz * bd + dz * bc, -(az * cd - cz * ad + dz * ac), az * bd - bz * ad + dz * ab,
                       -(az * bc - bz * ac + cz * ab)};
        unsigned neg = 0;
        for (int f = 0; f < 4; f++) {
            if (__builtin_expect(fabs(o[f]) > bound, 1)) {
                neg |= (unsigned)(o[f] < 0) << f;
            } else if (f != came) {
                const double *p[4] = {pa, pb, pc, pd};
                p[f] = pq;
                neg |= (unsigned)(orient3d(&dt->fl, p[0], p[1], p[2], p[3]) < 0) << f;
            }
        }
        if (came >= 0) neg &= ~(1u << came);
        if (!neg) {
            *found = t;
            return OK;
        }
        /* the first face with q strictly beyond it in the order r, r + 1, ... (mod 4) */
        unsigned rot = ((neg >> r) | (neg << (4 - r))) & 15u;
        int f = (r + __builtin_ctz(rot)) & 3;
        int32_t code = TN(dt, t, f);
        t = code >> 2;
        came = code & 3;
        if (is_ghost(dt, t)) {
            *found = t;
            return OK;
        }
    }
    return ERR_WALK;
}

static inline void glue(DT *dt, int32_t t, int f, int32_t code) {
    TN(dt, t, f) = code;
    TN(dt, code >> 2, code & 3) = t * 4 + f;
}

/* OTHER[f][g]: the two slots other than f and g (f != g) */
static const int8_t OTHER[4][4][2] = {
    {{-1, -1}, {2, 3}, {1, 3}, {1, 2}},
    {{2, 3}, {-1, -1}, {0, 3}, {0, 2}},
    {{1, 3}, {0, 3}, {-1, -1}, {0, 1}},
    {{1, 2}, {0, 2}, {0, 1}, {-1, -1}},
};

/* The three slots other than f, ascending. */
static const int8_t REST[4][3] = {{1, 2, 3}, {0, 2, 3}, {0, 1, 3}, {0, 1, 2}};

/* EDGE[f][g]: in a new tet with q at slot f, face g (g != f) is (q, r[EDGE[f][g][0]], r[EDGE[f][g][1]]) in the
 * cyclic order of the face oriented outward (HULL_FACE[g] rotated to start at f). The tet across that face is
 * also new and sees the face oriented the other way: the same edge reversed. Tets (ghosts included) are
 * oriented consistently, so matching (a, b) with (b, a) links the new tets. */
static const int8_t EDGE[4][4][2] = {
    {{-1, -1}, {2, 3}, {3, 1}, {1, 2}},
    {{3, 2}, {-1, -1}, {0, 3}, {2, 0}},
    {{1, 3}, {3, 0}, {-1, -1}, {0, 1}},
    {{2, 1}, {0, 2}, {1, 0}, {-1, -1}},
};

/* Cavities with at most LOCAL_NB boundary faces link their new tets through an edge table on local vertex ids
 * (the boundary is a triangulated sphere: nb = 2 V - 4 faces on V <= LOCAL_V vertices); larger ones through the
 * hash. */
#define LOCAL_V 64
#define LOCAL_NB (2 * LOCAL_V - 4)

/* Flags in a tet's record during one insertion: IN_CAVITY on v[0] (the tet is deleted at the end), TESTED_OUT on
 * v[1] (cleared at the end). Vertex ids are below 2^26 + 1. */
#define IN_CAVITY 0x40000000
#define TESTED_OUT 0x40000000

/* The new tet of the i-th cavity boundary face: its cavity tet with the vertex opposite the face replaced by q,
 * glued to the tet across the face; *t its index, *f the face (q's slot). The cavity tets stay intact until all
 * new tets are made (the free list holds only earlier insertions' tets). */
static inline int star_tet(DT *dt, int64_t i, int32_t q, int32_t inf, int32_t *t_out, int32_t *f_out) {
    int32_t ct = dt->bnd[2 * i], f = dt->bnd[2 * i + 1];
    int32_t t;
    int err = new_tet(dt, &t);
    if (err) return err;
    int32_t *r = TV(dt, t);
    memcpy(r, TV(dt, ct), 4 * sizeof(int32_t));
    r[0] &= ~IN_CAVITY;
    r[f] = q;
    int32_t out = TN(dt, ct, f);
    TV(dt, out >> 2)[1] &= ~TESTED_OUT;
    glue(dt, t, f, out);
    if (r[0] != inf && r[1] != inf && r[2] != inf && r[3] != inf) dt->last = t;
    *t_out = t;
    *f_out = f;
    return OK;
}

static int insert(DT *dt, int32_t q) {
    int32_t seed;
    int err = locate(dt, q, &seed);
    if (err) return err;
    dt->stamp++;
    int64_t ns = 0, nb = 0, top = 0;
    TV(dt, seed)[0] |= IN_CAVITY;
    dt->stack[ns++] = seed;
    /* breadth-first over the conflicting tets; stack[0..ns) is the cavity, top the next one to expand;
     * bnd[2 i], bnd[2 i + 1]: cavity tet and face of the i-th boundary face */
    while (top < ns) {
        int32_t t = dt->stack[top++];
        if (grow((void **)&dt->stack, &dt->stack_cap, ns + 4, sizeof(int32_t))) return ERR_MEMORY;
        if (grow((void **)&dt->bnd, &dt->bnd_cap, 2 * (nb + 4), sizeof(int32_t))) return ERR_MEMORY;
        /* each neighbour: in the cavity already (skip), tested before and outside (a boundary face), or tested
         * now; the outcomes are data-dependent, so they are counted, not branched on */
        for (int f = 0; f < 4; f++) {
            int32_t u = TN(dt, t, f) >> 2;
            int32_t *uv = TV(dt, u);
            int32_t in = (uv[0] & IN_CAVITY) != 0, c = 0;
            if (!((uv[0] | uv[1]) & (IN_CAVITY | TESTED_OUT))) {
                c = conflict(dt, u, q);
                uv[0] |= -c & IN_CAVITY;
                uv[1] |= (c - 1) & TESTED_OUT;
            }
            dt->stack[ns] = u;
            ns += c;
            dt->bnd[2 * nb] = t;
            dt->bnd[2 * nb + 1] = f;
            nb += 1 - (in | c);
        }
    }
    const int32_t inf = dt->n;
    if (nb <= LOCAL_NB) {
        /* new tets (star_tet), linked to each other through a local table of their edges */
        int32_t *vloc = dt->vloc, *ltab = dt->ltab, vlist[LOCAL_V];
        int nv = 0;
        for (int64_t i = 0; i < nb; i++) {
            int32_t t, f;
            if ((err = star_tet(dt, i, q, inf, &t, &f))) return err;
            const int32_t *r = TV(dt, t);
            int lid[4];
            for (int k = 0; k < 3; k++) {
                int s = REST[f][k];
                int32_t id = vloc[r[s]];
                if (id < 0) {
                    if (nv == LOCAL_V) return ERR_FLAT; /* not a sphere: never expected */
                    id = nv;
                    vloc[r[s]] = id;
                    vlist[nv++] = r[s];
                }
                lid[s] = id;
            }
            for (int k = 0; k < 3; k++) {
                int g = REST[f][k];
                int a = lid[EDGE[f][g][0]], b = lid[EDGE[f][g][1]];
                int32_t *ba = ltab + b * LOCAL_V + a;
                int32_t partner = *ba;
                int32_t code = t * 4 + g;
                /* each oriented edge comes once and its reverse once: the second links both and clears the
                 * first's entry, so the table is empty again after the insertion */
                *ba = -1;
                if (partner >= 0) {
                    TN(dt, partner >> 2, partner & 3) = code;
                    TN(dt, t, g) = partner;
                } else {
                    ltab[a * LOCAL_V + b] = code;
                }
            }
        }
        for (int k = 0; k < nv; k++) vloc[vlist[k]] = -1;
    } else {
        /* a large cavity: the same through a hash table of the edges */
        int64_t need = 16;
        while (need < 4 * nb) need *= 2;
        if (need > dt->hcap) {
            free(dt->hash);
            dt->hash = calloc((size_t)need, sizeof(HashSlot));
            dt->hcap = dt->hash ? need : 0;
            if (!dt->hash) return ERR_MEMORY;
        }
        const uint64_t hmask = (uint64_t)dt->hcap - 1;
        const uint32_t hs = dt->stamp; /* never 0: stamps start at 1 */
        HashSlot *hash = dt->hash;
        for (int64_t i = 0; i < nb; i++) {
            int32_t t, f;
            if ((err = star_tet(dt, i, q, inf, &t, &f))) return err;
            const int32_t *r = TV(dt, t);
            for (int k = 0; k < 3; k++) {
                int g = REST[f][k];
                /* face g holds q and the two vertices at the slots other than f and g */
                uint32_t e0 = (uint32_t)r[OTHER[f][g][0]], e1 = (uint32_t)r[OTHER[f][g][1]];
                uint32_t lo = e0 < e1 ? e0 : e1, hi = e0 ^ e1 ^ lo;
                uint64_t key = ((uint64_t)lo << 32) | hi;
                uint64_t h = (key * 0x9E3779B97F4A7C15ull) >> 32;
                HashSlot *sl = hash + (h & hmask);
                while (sl->stamp == hs && sl->key != key) sl = hash + (++h & hmask);
                /* each key comes exactly twice: the first stores itself, the second links both */
                int32_t partner = sl->stamp == hs ? sl->val : -1;
                int32_t *back = partner >= 0 ? &TN(dt, partner >> 2, partner & 3) : &dt->dummy;
                *back = t * 4 + g;
                TN(dt, t, g) = partner;
                sl->stamp = hs;
                sl->key = key;
                sl->val = t * 4 + g;
            }
        }
    }
    /* free the cavity */
    if (grow((void **)&dt->free_list, &dt->free_cap, dt->nfree + ns, sizeof(int32_t))) return ERR_MEMORY;
    for (int64_t i = 0; i < ns; i++) {
        int32_t t = dt->stack[i];
        TV(dt, t)[0] = -1;
        dt->free_list[dt->nfree++] = t;
    }
    return OK;
}

/* ----------------------------------------------------------------------------------------------------------- */
/* ordering */

/* Stable LSD radix sort of perm[0..m) by key(perm[i]) (a 32-bit key with `bits` significant bits). */
static int radix_perm(uint32_t *perm, uint32_t *tmp, int64_t m, const uint32_t *key, int bits) {
    enum { D = 12 };
    int64_t *count = malloc(sizeof(int64_t) << D);
    if (!count) return ERR_MEMORY;
    uint32_t *src = perm, *dst = tmp;
    for (int shift = 0; shift < bits; shift += D) {
        memset(count, 0, sizeof(int64_t) << D);
        for (int64_t i = 0; i < m; i++) count[(key[src[i]] >> shift) & ((1u << D) - 1)]++;
        int64_t sum = 0;
        for (int d = 0; d < (1 << D); d++) {
            int64_t c = count[d];
            count[d] = sum;
            sum += c;
        }
        for (int64_t i = 0; i < m; i++) dst[count[(key[src[i]] >> shift) & ((1u << D) - 1)]++] = src[i];
        uint32_t *t = src;
        src = dst;
        dst = t;
    }
    if (src != perm) memcpy(perm, src, (size_t)m * sizeof(uint32_t));
    free(count);
    return OK;
}

/* Skilling's 3-D Hilbert index of (x, y, z), `b` bits each (J. Skilling, AIP Conf. Proc. 707, 2004); the
 * data-dependent branches of the reference are written as masks (they mispredicted about half the time) */
static uint64_t hilbert3(uint32_t x0, uint32_t x1, uint32_t x2, int b) {
    uint32_t X[3] = {x0, x1, x2};
    uint32_t M = 1u << (b - 1), P_, Q, t;
    for (Q = M; Q > 1; Q >>= 1) {
        P_ = Q - 1;
        for (int i = 0; i < 3; i++) {
            /* bit Q of X[i] set: invert the low bits of X[0]; else exchange them between X[0] and X[i] */
            uint32_t m = 0u - ((X[i] & Q) != 0);
            t = (X[0] ^ X[i]) & P_ & ~m;
            X[0] ^= (P_ & m) ^ t;
            X[i] ^= t;
        }
    }
    X[1] ^= X[0];
    X[2] ^= X[1];
    t = 0;
    for (Q = M; Q > 1; Q >>= 1) t ^= (Q - 1) & (0u - ((X[2] & Q) != 0));
    for (int i = 0; i < 3; i++) X[i] ^= t;
    uint64_t key = 0;
    for (int bit = b - 1; bit >= 0; bit--)
        for (int i = 0; i < 3; i++) key = (key << 1) | ((X[i] >> bit) & 1u);
    return key;
}

static uint64_t splitmix64(uint64_t z) {
    z += 0x9E3779B97F4A7C15ull;
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

#define HILBERT_BITS 10 /* at most: 8 cells per point are enough (fewer bits, less work) */
#define BRIO_LEVELS 15

/* ----------------------------------------------------------------------------------------------------------- */
/* output */

typedef struct {
    uint32_t v[4]; /* indices into the caller's points (< 2^26) */
} Row;

/* row order after v[0]: (v[1], v[2], v[3]) */
static inline int row_less(const Row *a, const Row *b) {
    uint64_t ka = ((uint64_t)a->v[1] << 32) | a->v[2], kb = ((uint64_t)b->v[1] << 32) | b->v[2];
    return ka < kb || (ka == kb && a->v[3] < b->v[3]);
}

static int cmp_row3(const void *pa, const void *pb) {
    return row_less(pa, pb) ? -1 : row_less(pb, pa) ? 1 : 0;
}

/* Sort rows (v[0] the row's smallest entry, < n) lexicographically: a counting sort by v[0] into `out`, then each
 * group by the rest (insertion sort, qsort for large groups). */
static int sort_rows(const Row *rows, Row *out, int64_t m, int64_t n) {
    int64_t *start = calloc((size_t)n + 1, sizeof(int64_t));
    if (!start) return ERR_MEMORY;
    for (int64_t i = 0; i < m; i++) start[rows[i].v[0] + 1]++;
    for (int64_t k = 0; k < n; k++) start[k + 1] += start[k];
    for (int64_t i = 0; i < m; i++) out[start[rows[i].v[0]]++] = rows[i];
    int64_t lo = 0;
    for (int64_t k = 0; k < n; k++) {
        int64_t hi = start[k];
        if (hi - lo > 32)
            qsort(out + lo, (size_t)(hi - lo), sizeof(Row), cmp_row3);
        else
            for (int64_t i = lo + 1; i < hi; i++) {
                Row r = out[i];
                int64_t j = i;
                while (j > lo && row_less(&r, &out[j - 1])) {
                    out[j] = out[j - 1];
                    j--;
                }
                out[j] = r;
            }
        lo = hi;
    }
    free(start);
    return OK;
}

/* (a, b, c, d) positively oriented -> the even permutation with the smallest first, the next smallest second:
 * sort the four (distinct) indices with a 5-comparator network, counting swaps without branches; an odd count
 * swaps the last two back (the result is then an even permutation of the input, and the smallest two lead) */
#define CSWAP(x, y)                             \
    do {                                        \
        uint32_t sw_ = x > y, lo_ = sw_ ? y : x; \
        y = sw_ ? x : y;                        \
        x = lo_;                                \
        par ^= sw_;                             \
    } while (0)
static inline void canonical_tet(uint32_t *v) {
    uint32_t a = v[0], b = v[1], c = v[2], d = v[3], par = 0;
    CSWAP(a, b);
    CSWAP(c, d);
    CSWAP(a, c);
    CSWAP(b, d);
    CSWAP(b, c);
    v[0] = a;
    v[1] = b;
    v[2] = par ? d : c;
    v[3] = par ? c : d;
}
#undef CSWAP

static void canonical_tri(uint32_t *v) {
    int k = 0;
    if (v[1] < v[k]) k = 1;
    if (v[2] < v[k]) k = 2;
    uint32_t a = v[k], b = v[(k + 1) % 3], c = v[(k + 2) % 3];
    v[0] = a, v[1] = b, v[2] = c;
}

/* ----------------------------------------------------------------------------------------------------------- */
/* the whole computation */

typedef struct {
    Row *tets, *hull;
    int64_t nt, nh;
} Result;

static void dt_free(DT *dt) {
    free(dt->x);
    free(dt->tt);
    free(dt->rank);
    free(dt->free_list);
    free(dt->stack);
    free(dt->bnd);
    free(dt->hash);
    free(dt->vloc);
    free(dt->ltab);
}

static int run(const int32_t *cells, int64_t n_in, Result *res) {
    int err = OK;
    DT dt;
    memset(&dt, 0, sizeof dt);
    memset(res, 0, sizeof *res);
    uint32_t *perm = NULL, *tmp = NULL, *key = NULL, *orig = NULL;
    uint64_t *order = NULL, *otmp = NULL;
    if (n_in < 4) return OK;
    perm = malloc((size_t)n_in * sizeof(uint32_t));
    tmp = malloc((size_t)n_in * sizeof(uint32_t));
    key = malloc((size_t)n_in * sizeof(uint32_t));
    if (!perm || !tmp || !key) goto nomem;
    /* 1-2: lexicographic ranks (stable: of equal points the lowest index comes first) */
    for (int64_t i = 0; i < n_in; i++) perm[i] = (uint32_t)i;
    for (int axis = 2; axis >= 0; axis--) {
        for (int64_t i = 0; i < n_in; i++) key[i] = (uint32_t)cells[3 * i + axis];
        if (radix_perm(perm, tmp, n_in, key, MAX_BITS)) goto nomem;
    }
    free(key);
    key = NULL;
    int64_t m = 0;
    for (int64_t i = 0; i < n_in; i++) {
        const int32_t *c = cells + 3 * (int64_t)perm[i];
        if (m) {
            const int32_t *p = cells + 3 * (int64_t)perm[m - 1];
            if (p[0] == c[0] && p[1] == c[1] && p[2] == c[2]) continue;
        }
        perm[m++] = perm[i]; /* perm[0..m): original index of rank r */
    }
    orig = perm;
    perm = NULL;
    if (m < 4) goto done;
    dt.n = (int32_t)m;
    dt.x = malloc((size_t)(m + 1) * 3 * sizeof(double));
    if (!dt.x) goto nomem;
    int64_t lo[3], hi[3];
    for (int a = 0; a < 3; a++) lo[a] = hi[a] = cells[3 * (int64_t)orig[0] + a];
    uint64_t diff_bits = 0;
    for (int64_t r = 0; r < m; r++)
        for (int a = 0; a < 3; a++) {
            int64_t c = cells[3 * (int64_t)orig[r] + a];
            if (c < lo[a]) lo[a] = c;
            if (c > hi[a]) hi[a] = c;
            diff_bits |= (uint64_t)(c - cells[3 * (int64_t)orig[0] + a]);
        }
    int shift = 0;
    while (shift < MAX_BITS && !((diff_bits >> shift) & 1)) shift++;
    for (int64_t r = 0; r < m; r++)
        for (int a = 0; a < 3; a++) dt.x[3 * r + a] = (double)((cells[3 * (int64_t)orig[r] + a] - lo[a]) >> shift);
    dt.x[3 * m] = dt.x[3 * m + 1] = dt.x[3 * m + 2] = 0.0;
    /* insertion order: BRIO rounds, Hilbert order inside each */
    int64_t span = 1;
    for (int a = 0; a < 3; a++)
        if (((hi[a] - lo[a]) >> shift) + 1 > span) span = ((hi[a] - lo[a]) >> shift) + 1;
    filter_init(&dt.fl, (double)(span - 1));
    order = malloc((size_t)m * sizeof(uint64_t));
    otmp = malloc((size_t)m * sizeof(uint64_t));
    if (!order || !otmp) goto nomem;
    int hbits = tw_bit_length((uint64_t)m) / 3 + 1;
    if (hbits > HILBERT_BITS) hbits = HILBERT_BITS;
    if (hbits < 2) hbits = 2;
    /* the cell of a coordinate x is floor(x 2^hbits / span): both operands are exact in binary64 (< 2^33) and an
     * inexact quotient is at least 1 / span from an integer, so the rounded division floors to the same cell as
     * the integer division, without its latency */
    const double cells_per_unit = (double)((int64_t)1 << hbits), span_d = (double)span;
    for (int64_t r = 0; r < m; r++) {
        uint32_t h[3];
        for (int a = 0; a < 3; a++) h[a] = (uint32_t)(dt.x[3 * r + a] * cells_per_unit / span_d);
        uint64_t z = splitmix64((uint64_t)r);
        int tz = z ? __builtin_ctzll(z) : BRIO_LEVELS; /* trailing zero bits, at most BRIO_LEVELS */
        if (tz > BRIO_LEVELS) tz = BRIO_LEVELS;
        uint64_t round = (uint64_t)(BRIO_LEVELS - tz);
        order[r] = (round << 56) | (hilbert3(h[0], h[1], h[2], hbits) << 26) | (uint64_t)r;
    }
    tw_radix_sort(order, otmp, m, 0, 60);
    free(otmp);
    otmp = NULL;
    /* renumber the vertices in insertion order (nearby vertices near in memory); keep their ranks */
    {
        double *xn = malloc((size_t)(m + 1) * 3 * sizeof(double));
        dt.rank = malloc((size_t)m * sizeof(int32_t));
        uint32_t *ov = malloc((size_t)m * sizeof(uint32_t));
        if (!xn || !dt.rank || !ov) {
            free(xn);
            free(ov);
            goto nomem;
        }
        for (int64_t i = 0; i < m; i++) {
            int64_t r = (int64_t)(order[i] & ((1u << 26) - 1));
            memcpy(xn + 3 * i, dt.x + 3 * r, 3 * sizeof(double));
            dt.rank[i] = (int32_t)r;
            ov[i] = orig[r];
        }
        xn[3 * m] = xn[3 * m + 1] = xn[3 * m + 2] = 0.0;
        free(dt.x);
        dt.x = xn;
        free(orig);
        orig = ov;
    }
    /* first tet: 4 affinely independent points, in insertion order */
    int64_t pick[4] = {0, 1, -1, -1};
    {
        const double *a = dt.x, *b = dt.x + 3;
        int64_t ux = (int64_t)(b[0] - a[0]), uy = (int64_t)(b[1] - a[1]), uz = (int64_t)(b[2] - a[2]);
        for (int64_t i = 2; i < m && pick[2] < 0; i++) {
            const double *c = dt.x + 3 * i;
            int64_t vx = (int64_t)(c[0] - a[0]), vy = (int64_t)(c[1] - a[1]), vz = (int64_t)(c[2] - a[2]);
            if (uy * vz - uz * vy || uz * vx - ux * vz || ux * vy - uy * vx) pick[2] = i;
        }
        if (pick[2] < 0) goto done; /* collinear */
        const double *c = dt.x + 3 * pick[2];
        for (int64_t i = pick[2] + 1; i < m && pick[3] < 0; i++)
            if (orient3d(&dt.fl, a, b, c, dt.x + 3 * i)) pick[3] = i;
        if (pick[3] < 0) goto done; /* coplanar */
    }
    dt.max_tets = TETS_PER_POINT * m + TETS_EXTRA;
    if (dt.max_tets < TETS_FLOOR) dt.max_tets = TETS_FLOOR;
    if (dt.max_tets > (1 << 29)) dt.max_tets = 1 << 29; /* tet * 4 + face fits int32 */
    dt.rng = 0x2545F4914F6CDD1Dull;
    dt.stamp = 1;
    if (grow((void **)&dt.stack, &dt.stack_cap, 256, sizeof(int32_t))) goto nomem;
    dt.vloc = malloc((size_t)(m + 1) * sizeof(int32_t));
    dt.ltab = malloc((size_t)LOCAL_V * LOCAL_V * sizeof(int32_t));
    if (!dt.vloc || !dt.ltab) goto nomem;
    memset(dt.vloc, 0xff, (size_t)(m + 1) * sizeof(int32_t));
    memset(dt.ltab, 0xff, (size_t)LOCAL_V * LOCAL_V * sizeof(int32_t));
    {
        /* ~6.5 tets per point plus the hull's ghosts: reserve once instead of growing by copies */
        int64_t c = 8 * m + 64;
        if (c > dt.max_tets) c = dt.max_tets;
        dt.tt = alloc_huge((size_t)c * 8 * sizeof(int32_t));
        if (!dt.tt) goto nomem;
        dt.cap = c;
    }
    {
        int32_t v[4];
        for (int i = 0; i < 4; i++) v[i] = (int32_t)pick[i];
        if (orient3d(&dt.fl, P(&dt, v[0]), P(&dt, v[1]), P(&dt, v[2]), P(&dt, v[3])) < 0) {
            int32_t t = v[0];
            v[0] = v[1];
            v[1] = t;
        }
        int32_t ids[5];
        for (int i = 0; i < 5; i++)
            if ((err = new_tet(&dt, &ids[i]))) goto fail;
        memcpy(TV(&dt, 0), v, sizeof v);
        for (int i = 0; i < 4; i++) {
            int32_t *g = TV(&dt, ids[i + 1]);
            memcpy(g, v, sizeof v);
            g[i] = dt.n;
            int s0 = i == 0 ? 1 : 0, s1 = i <= 1 ? 2 : 1; /* the two lowest slots other than i: swap them */
            int32_t t = g[s0];
            g[s0] = g[s1];
            g[s1] = t;
        }
        /* link faces with equal vertex sets */
        for (int t = 0; t < 5; t++)
            for (int f = 0; f < 4; f++)
                for (int u = t + 1; u < 5; u++)
                    for (int g = 0; g < 4; g++) {
                        int32_t a[3], b[3], na = 0, nb2 = 0;
                        for (int s = 0; s < 4; s++) {
                            if (s != f) a[na++] = TV(&dt, t)[s];
                            if (s != g) b[nb2++] = TV(&dt, u)[s];
                        }
                        int same = 1;
                        for (int s = 0; s < 3 && same; s++)
                            same = a[s] == b[0] || a[s] == b[1] || a[s] == b[2];
                        if (same) glue(&dt, t, f, u * 4 + g);
                    }
        dt.last = 0;
    }
    for (int64_t i = 2; i < m; i++) {
        if (i == pick[2] || i == pick[3]) continue;
        if ((err = insert(&dt, (int32_t)i))) goto fail;
    }
    /* 5: output */
    {
        Row *rows = malloc((size_t)(dt.count ? dt.count : 1) * sizeof(Row));
        Row *tets = malloc((size_t)(dt.count ? dt.count : 1) * sizeof(Row));
        if (!rows || !tets) {
            free(rows);
            free(tets);
            goto nomem;
        }
        int64_t nt = 0, nh = dt.count; /* tets from the front of rows, hull faces from the back */
        for (int64_t t = 0; t < dt.count; t++) {
            const int32_t *v = TV(&dt, t);
            if (v[0] < 0) continue;
            int k = v[0] == dt.n ? 0 : v[1] == dt.n ? 1 : v[2] == dt.n ? 2 : v[3] == dt.n ? 3 : -1;
            if (k < 0) {
                /* rule 5: every tet positively oriented (Bowyer-Watson with exact predicates guarantees it) */
                if (orient3d(&dt.fl, P(&dt, v[0]), P(&dt, v[1]), P(&dt, v[2]), P(&dt, v[3])) <= 0) {
                    free(rows);
                    free(tets);
                    err = ERR_FLAT;
                    goto fail;
                }
                Row *r = rows + nt++;
                for (int i = 0; i < 4; i++) r->v[i] = orig[v[i]];
                canonical_tet(r->v);
            } else {
                Row *r = rows + --nh;
                for (int i = 0; i < 3; i++) r->v[i] = orig[v[HULL_FACE[k][i]]];
                canonical_tri(r->v);
                r->v[3] = r->v[2]; /* sorted by (v1, v2, v3): v3 = v2 orders by (v1, v2) */
            }
        }
        int64_t h = dt.count - nh;
        err = sort_rows(rows, tets, nt, n_in);
        if (!err) err = sort_rows(rows + nh, tets + nt, h, n_in);
        free(rows);
        if (err) {
            free(tets);
            goto fail;
        }
        res->tets = tets;
        res->nt = nt;
        res->hull = tets + nt; /* one allocation: free(res->tets) frees both */
        res->nh = h;
    }
    goto done;
nomem:
    err = ERR_MEMORY;
fail:
    free(res->tets);
    memset(res, 0, sizeof *res);
done:
    free(perm);
    free(tmp);
    free(key);
    free(orig);
    free(order);
    free(otmp);
    dt_free(&dt);
    return err;
}


/* ----------------------------------------------------------------------------------------------------------- */
/* entry points (internal.h) */

void tw_tets_free(tw_tets *tz) {
    if (!tz) return;
    free(tz->tets);
    free(tz->hull);
    memset(tz, 0, sizeof *tz);
}

int tw_delaunay(const int32_t *cells, size_t n, tw_tets *out, tw_error *err) {
    if (!out) return tw_fail(err, TW_ERROR_ARGUMENT, "tw_delaunay: out is NULL");
    memset(out, 0, sizeof *out);
    if (n > (size_t)MAX_POINTS)
        return tw_fail(err, TW_ERROR_ARGUMENT, "at most %d points can be tetrahedralized, got %llu", MAX_POINTS,
                       (unsigned long long)n);
    if (n && !cells) return tw_fail(err, TW_ERROR_ARGUMENT, "tw_delaunay: cells is NULL");
    for (size_t i = 0; i < 3 * n; i++)
        if (cells[i] < 0 || cells[i] >= (1 << MAX_BITS))
            return tw_fail(err, TW_ERROR_ARGUMENT, "cell coordinates must lie in [0, 2^%d), got %lld", MAX_BITS,
                           (long long)cells[i]);
    Result res;
    int e = run(cells, (int64_t)n, &res);
    switch (e) {
    case OK: break;
    case ERR_MEMORY: return tw_fail(err, TW_ERROR_MEMORY, "out of memory in the Delaunay tetrahedralization");
    case ERR_TOO_MANY:
        return tw_fail(err, TW_ERROR_LIMIT,
                       "the Delaunay tetrahedralization of %llu points needs more than max(%d per point, %d) tets "
                       "(a degenerate point set, e.g. points on two skew lines)",
                       (unsigned long long)n, TETS_PER_POINT, TETS_FLOOR);
    case ERR_FLAT:
        return tw_fail(err, TW_ERROR_INTERNAL, "flat tet: a new tet has no volume (inconsistent predicates)");
    default: return tw_fail(err, TW_ERROR_INTERNAL, "walk: point location did not terminate");
    }
    /* res.tets: nt rows of 4 (the tets) then nh rows of 4 (the hull faces, v[3] a copy of v[2]), one block */
    if (res.nt) {
        out->tets = malloc((size_t)res.nt * 4 * sizeof(int32_t));
        out->hull = malloc((size_t)res.nh * 3 * sizeof(int32_t));
        if (!out->tets || !out->hull) {
            free(res.tets);
            tw_tets_free(out);
            return tw_fail(err, TW_ERROR_MEMORY, "out of memory in the Delaunay tetrahedralization");
        }
        for (int64_t i = 0; i < res.nt; i++)
            for (int k = 0; k < 4; k++) out->tets[4 * i + k] = (int32_t)res.tets[i].v[k];
        for (int64_t i = 0; i < res.nh; i++)
            for (int k = 0; k < 3; k++) out->hull[3 * i + k] = (int32_t)res.hull[i].v[k];
        out->nt = (size_t)res.nt;
        out->nh = (size_t)res.nh;
    }
    free(res.tets);
    return TW_OK;
}

/* geometry/delaunay.py snap_to_lattice with quantize.GRID_BOUND = 1.2, one binary64 rounding per operation in the
 * Python's order: t = (x + B) / (2 B) * 2^23, K = clamp(floor(t + 0.5), 0, 2^23 - 1), where B = 1.2, or the power of
 * two 2^e > max |x| (frexp's e) when max |x| > 1.2. Points must be finite (else TW_ERROR_ARGUMENT). */
int tw_snap_to_lattice(const double *points, size_t n, int32_t *cells, tw_error *err) {
    const double grid_bound = 1.2, top = (double)((1 << MAX_BITS) - 1);
    if (n && (!points || !cells)) return tw_fail(err, TW_ERROR_ARGUMENT, "tw_snap_to_lattice: NULL array");
    double largest = 0.0;
    for (size_t i = 0; i < 3 * n; i++) {
        if (!isfinite(points[i])) return tw_fail(err, TW_ERROR_ARGUMENT, "points must be finite");
        if (fabs(points[i]) > largest) largest = fabs(points[i]);
    }
    double bound = grid_bound;
    if (largest > grid_bound) {
        int e;
        frexp(largest, &e);
        bound = ldexp(1.0, e);
    }
    const double width = 2.0 * bound, cells_per_axis = (double)(1 << MAX_BITS);
    for (size_t i = 0; i < 3 * n; i++) {
        double t = (points[i] + bound) / width * cells_per_axis;
        double k = floor(t + 0.5);
        cells[i] = (int32_t)(k < 0.0 ? 0.0 : k > top ? top : k);
    }
    return TW_OK;
}
