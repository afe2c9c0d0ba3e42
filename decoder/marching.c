/* marching.c -- directional marching tets (formats/README.md, "Decoding" steps 3-4); stage 3 of tw_decode.
 *
 * geometry/marching_tets.py `marching_tets_numpy` (with `_edge_vertices`, `_caps_numpy`, `check_manifold`) is the
 * reference; tw_marching_tets returns the same control surface bit for bit: vertices in the same order (unique
 * active edges by key min(i, j) * N + max(i, j), then the cap vertices by point index), every double by the same
 * binary64 operations in the same order (compile with -ffp-contract=off, no -ffast-math), faces in the same order
 * (by tet, then table order, then the hull caps by hull face).
 *
 * Parts:
 *   tw_tanh              the format's tanh (geometry/tanh.py states the algorithm; a library tanh is not the same
 *                        function on every platform, see there)
 *   tw_mt_tables_init    the case tables, derived and checked (the Python binding passes the tables it holds)
 *   tw_mt_topology       the integer topology: sorted unique active edges, faces, face tets
 *   tw_manifold_defect   check_manifold's three defects
 *   tw_marching_tets     the whole stage: topology, edge vertices with the SH, hull caps, the manifold check
 * The Python extension tetweave_codec/geometry/_mt_native.c is a binding over the first three.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"
#include "radix.h"

/* ----------------------------------------------------------------------------------------------------------- */
/* tanh (geometry/tanh.py: the same constants and the same sequence of operations) */

#define TANH_SATURATION 20.0
#define TANH_TINY 0x1p-27
#define INV_LN2 0x1.71547652b82fep+0
#define LN2_HI 0x1.62e42fefa0000p-1 /* 37 significant bits: k * LN2_HI is exact */
#define LN2_LO 0x1.cf79abc9e3b3ap-40

/* 1/n! rounded to binary64, n = 2..16 */
static const double EXPM1_COEFFS[15] = {
    0x1.0000000000000p-1,  0x1.5555555555555p-3,  0x1.5555555555555p-5,  0x1.1111111111111p-7,
    0x1.6c16c16c16c17p-10, 0x1.a01a01a01a01ap-13, 0x1.a01a01a01a01ap-16, 0x1.71de3a556c734p-19,
    0x1.27e4fb7789f5cp-22, 0x1.ae64567f544e4p-26, 0x1.1eed8eff8d898p-29, 0x1.6124613a86d09p-33,
    0x1.93974a8c07c9dp-37, 0x1.ae7f3e733b81fp-41, 0x1.ae7f3e733b81fp-45,
};

/* tanh(x) within 2 units in the last place, the same bits on every IEEE 754 platform: +-1 for |x| >= 20 and NaN,
 * x for |x| < 2^-27, else expm1(2|x|) / (expm1(2|x|) + 2) with the sign of x, expm1 by a reduction to
 * |r| <= ln2 / 2 and a degree-16 Taylor polynomial (Horner). */
double tw_tanh(double x) {
    const double a = fabs(x);
    if (!(a < TANH_SATURATION)) return copysign(1.0, x);
    if (a < TANH_TINY) return x;
    const double t = a + a;
    const double k = floor(t * INV_LN2 + 0.5);
    const double r = (t - k * LN2_HI) - k * LN2_LO;
    double q = EXPM1_COEFFS[14];
    for (int n = 13; n >= 0; n--) q = q * r + EXPM1_COEFFS[n];
    const double p = r + r * (r * q);
    const double scale = ldexp(1.0, (int)k);
    const double e = scale * p + (scale - 1.0);
    return copysign(e / (e + 2.0), x);
}

/* ----------------------------------------------------------------------------------------------------------- */
/* tables (geometry/marching_tets.py TET_EDGES, TRIANGLE_TABLE, ACTIVE_EDGE_TABLE, HULL_EDGES, CAP_TABLE) */

static const int TET_EDGE_A[6] = {0, 0, 0, 1, 1, 2}, TET_EDGE_B[6] = {1, 2, 3, 2, 3, 3};

static const int64_t TRIANGLE_TABLE[16 * 2 * 3] = {
    -1, -1, -1, -1, -1, -1, /* 0: all outside */
    0,  1,  2,  -1, -1, -1, /* 1 */
    0,  4,  3,  -1, -1, -1, /* 2 */
    1,  2,  4,  1,  4,  3,  /* 3 */
    1,  3,  5,  -1, -1, -1, /* 4 */
    3,  5,  2,  3,  2,  0,  /* 5 */
    0,  4,  5,  0,  5,  1,  /* 6 */
    2,  4,  5,  -1, -1, -1, /* 7 */
    2,  5,  4,  -1, -1, -1, /* 8 */
    0,  1,  5,  0,  5,  4,  /* 9 */
    2,  5,  3,  2,  3,  0,  /* 10 */
    1,  5,  3,  -1, -1, -1, /* 11 */
    1,  3,  4,  1,  4,  2,  /* 12 */
    0,  3,  4,  -1, -1, -1, /* 13 */
    0,  2,  1,  -1, -1, -1, /* 14 */
    -1, -1, -1, -1, -1, -1, /* 15: all inside */
};

/* hull triangle slots: 0-2 the cap vertices at a, b, c; 3-5 the edge vertices on (a, b), (b, c), (c, a) */
static const int HULL_EDGE_A[3] = {0, 1, 2}, HULL_EDGE_B[3] = {1, 2, 0};
static const int CAP_TABLE[8][2][3] = {
    {{-1, -1, -1}, {-1, -1, -1}}, {{0, 3, 5}, {-1, -1, -1}}, {{1, 4, 3}, {-1, -1, -1}}, {{0, 1, 4}, {0, 4, 5}},
    {{2, 5, 4}, {-1, -1, -1}},    {{2, 0, 3}, {2, 3, 4}},    {{1, 2, 5}, {1, 5, 3}},    {{0, 1, 2}, {-1, -1, -1}},
};

static const char *const MANIFOLD_ERRORS[3] = {
    "marching tets produced a degenerate triangle: the tetrahedralization is not proper",
    "marching tets used a directed edge twice: the tetrahedralization is not proper",
    "marching tets left an edge without its twin: the tetrahedralization is not proper",
};

/* Derive the per-case tables from active (16 x 6: nonzero = local edge e active in case code) and triangle
 * (16 x 2 x 3 local edges, -1 none), as the reference's arrays hold them. TW_ERROR_ARGUMENT when an entry is out of
 * range or a triangle uses an inactive edge. */
int tw_mt_tables_init(tw_mt_tables *tables, const int64_t *active, const int64_t *triangle, tw_error *err) {
    for (int i = 0; i < 16 * 2 * 3; i++)
        if (triangle[i] < -1 || triangle[i] > 5)
            return tw_fail(err, TW_ERROR_ARGUMENT, "marching tets: triangle table entry out of range");
    for (int code = 0; code < 16; code++) {
        tables->n_act[code] = tables->n_tri[code] = 0;
        for (int e = 0; e < 6; e++) {
            tables->pos[code][e] = active[6 * code + e] ? tables->n_act[code] : -1;
            if (active[6 * code + e]) tables->act[code][tables->n_act[code]++] = e;
        }
        for (int h = 0; h < 2; h++) {
            const int64_t *row = triangle + 6 * code + 3 * h;
            if (code == 0 || code == 15 || row[0] < 0) continue;
            for (int c = 0; c < 3; c++) {
                if (row[c] < 0 || tables->pos[code][row[c]] < 0)
                    return tw_fail(err, TW_ERROR_ARGUMENT, "marching tets: a table triangle on an inactive edge");
                tables->tri[code][tables->n_tri[code]][c] = (int)row[c];
            }
            tables->n_tri[code]++;
        }
    }
    return TW_OK;
}

/* The format's tables (ACTIVE_EDGE_TABLE: the edges whose two ends differ in the case code). */
static void default_tables(tw_mt_tables *tables) {
    int64_t active[16 * 6];
    for (int code = 0; code < 16; code++)
        for (int e = 0; e < 6; e++) active[6 * code + e] = ((code >> TET_EDGE_A[e]) & 1) != ((code >> TET_EDGE_B[e]) & 1);
    tw_mt_tables_init(tables, active, TRIANGLE_TABLE, NULL); /* valid by construction */
}

/* ----------------------------------------------------------------------------------------------------------- */
/* topology */

void tw_mt_topology_free(tw_mt_topo *topo) {
    if (!topo) return;
    free(topo->lo);
    free(topo->hi);
    free(topo->faces);
    free(topo->face_tets);
    memset(topo, 0, sizeof *topo);
}

/* Active edges and faces of marching tets (the reference's _topology_numpy). tets: nt * 4 indices (each checked
 * against n: TW_ERROR_ARGUMENT), inside: n bytes (nonzero: s < 0). out: nu unique active edges (lo < hi, sorted by
 * (lo, hi)), nf faces (3 indices into the edges each) and the tet of each face. TW_ERROR_LIMIT when n > 2^31 or the
 * active edge occurrences reach 2^32 (the Python binding then lets the reference decide); TW_ERROR_MEMORY. */
int tw_mt_topology(const int32_t *tets, size_t nt, const uint8_t *inside, size_t n, const tw_mt_tables *tables,
                   tw_mt_topo *out, tw_error *err) {
    memset(out, 0, sizeof *out);
    if (n > ((size_t)1 << 31))
        return tw_fail(err, TW_ERROR_LIMIT, "marching tets: more than 2^31 points");
    uint8_t *codes = malloc(nt ? nt : 1);
    if (!codes) return tw_fail(err, TW_ERROR_MEMORY, "out of memory in marching tets");
    /* pass 1: check the indices, the case code of every tet, count the active edge occurrences and faces */
    int64_t m = 0, f_count = 0;
    for (size_t t = 0; t < nt; t++) {
        int code = 0;
        for (int k = 0; k < 4; k++) {
            int32_t v = tets[4 * t + k];
            if (v < 0 || (size_t)v >= n) {
                free(codes);
                return tw_fail(err, TW_ERROR_ARGUMENT, "marching tets: tet vertex index out of range");
            }
            code |= (inside[v] != 0) << k;
        }
        codes[t] = (uint8_t)code;
        m += tables->n_act[code];
        f_count += tables->n_tri[code];
    }
    if (m >= ((int64_t)1 << 32)) { /* occurrences are numbered in 32 bits */
        free(codes);
        return tw_fail(err, TW_ERROR_LIMIT, "marching tets: 2^32 or more active edge occurrences");
    }
    const size_t mm = (size_t)(m > 0 ? m : 1);
    uint32_t *lo_of = malloc(mm * sizeof(uint32_t)), *hi_of = malloc(mm * sizeof(uint32_t));
    uint32_t *by_hi = malloc(mm * sizeof(uint32_t)), *by_key = malloc(mm * sizeof(uint32_t));
    int64_t *count = malloc((n + 1) * sizeof(int64_t));
    out->lo = malloc(mm * sizeof(uint32_t));
    out->hi = malloc(mm * sizeof(uint32_t));
    out->faces = malloc((size_t)(f_count ? f_count : 1) * 3 * sizeof(int32_t));
    out->face_tets = malloc((size_t)(f_count ? f_count : 1) * sizeof(int32_t));
    int status = TW_OK;
    if (!lo_of || !hi_of || !by_hi || !by_key || !count || !out->lo || !out->hi || !out->faces || !out->face_tets) {
        status = tw_fail(err, TW_ERROR_MEMORY, "out of memory in marching tets");
        tw_mt_topology_free(out);
        goto done;
    }
    /* pass 2: the end points lo < hi of every active edge, in tet-then-edge order */
    int64_t occ = 0;
    for (size_t t = 0; t < nt; t++) {
        const int32_t *v = tets + 4 * t;
        const int code = codes[t];
        for (int q = 0; q < tables->n_act[code]; q++) {
            const int e = tables->act[code][q];
            const int32_t a = v[TET_EDGE_A[e]], b = v[TET_EDGE_B[e]];
            lo_of[occ] = (uint32_t)(a < b ? a : b);
            hi_of[occ] = (uint32_t)(a < b ? b : a);
            occ++;
        }
    }
    /* the occurrences sorted by key (lo, hi): two stable counting sorts, by hi then by lo */
    memset(count, 0, (n + 1) * sizeof(int64_t));
    for (int64_t o = 0; o < m; o++) count[hi_of[o] + 1]++;
    for (size_t v = 1; v <= n; v++) count[v] += count[v - 1];
    for (int64_t o = 0; o < m; o++) by_hi[count[hi_of[o]]++] = (uint32_t)o;
    memset(count, 0, (n + 1) * sizeof(int64_t));
    for (int64_t o = 0; o < m; o++) count[lo_of[o] + 1]++;
    for (size_t v = 1; v <= n; v++) count[v] += count[v - 1];
    for (int64_t r = 0; r < m; r++) by_key[count[lo_of[by_hi[r]]]++] = by_hi[r];
    /* unique edges in order; inverse[occurrence] = rank of its edge, in the memory of by_hi (no longer needed) */
    uint32_t *inverse = by_hi;
    int64_t u = 0;
    for (int64_t r = 0; r < m; r++) {
        const uint32_t o = by_key[r];
        if (!u || out->lo[u - 1] != lo_of[o] || out->hi[u - 1] != hi_of[o]) {
            out->lo[u] = lo_of[o];
            out->hi[u] = hi_of[o];
            u++;
        }
        inverse[o] = (uint32_t)(u - 1);
    }
    out->nu = (size_t)u;
    /* pass 3: faces, per mixed tet its table triangles; local edge e is the tet's pos[code][e]-th occurrence */
    int64_t base = 0, f = 0;
    for (size_t t = 0; t < nt; t++) {
        const int code = codes[t];
        for (int q = 0; q < tables->n_tri[code]; q++) {
            for (int c = 0; c < 3; c++)
                out->faces[3 * f + c] = (int32_t)inverse[base + tables->pos[code][tables->tri[code][q][c]]];
            out->face_tets[f++] = (int32_t)t;
        }
        base += tables->n_act[code];
    }
    out->nf = (size_t)f;
done:
    free(codes);
    free(lo_of);
    free(hi_of);
    free(by_hi);
    free(by_key);
    free(count);
    return status;
}

/* ----------------------------------------------------------------------------------------------------------- */
/* manifold check */

/* check_manifold: *defect = 0 (every directed edge used once and, when closed, paired with its reverse), 1 (a
 * degenerate triangle), 2 (a directed edge used twice), 3 (closed only: an edge without its twin); the reference's
 * checks in its order. faces: nf * 3 indices < nv <= 2^31 (else TW_ERROR_ARGUMENT); TW_ERROR_MEMORY. */
int tw_manifold_defect(const int32_t *faces, size_t nf, size_t nv, int closed, int *defect, tw_error *err) {
    *defect = 0;
    const size_t m = 3 * nf;
    if (nv > ((size_t)1 << 31)) return tw_fail(err, TW_ERROR_ARGUMENT, "manifold check: more than 2^31 vertices");
    for (size_t i = 0; i < m; i++)
        if (faces[i] < 0 || (size_t)faces[i] >= nv)
            return tw_fail(err, TW_ERROR_ARGUMENT, "manifold check: face index out of range");
    for (size_t i = 0; i < m; i++) /* tail == head */
        if (faces[i] == faces[i % 3 == 2 ? i - 2 : i + 1]) {
            *defect = 1;
            return TW_OK;
        }
    if (m == 0) return TW_OK;
    uint64_t *packed = malloc(m * sizeof(uint64_t)), *tmp = malloc(m * sizeof(uint64_t));
    if (!packed || !tmp) {
        free(packed);
        free(tmp);
        return tw_fail(err, TW_ERROR_MEMORY, "out of memory in the manifold check");
    }
    /* each directed edge as (undirected key << 1) | direction; closed and oriented means every undirected key
     * appears exactly twice, once per direction: pairs (2k, 2k + 1) of the sorted array */
    for (size_t i = 0; i < m; i++) {
        uint64_t tail = (uint64_t)faces[i], head = (uint64_t)faces[i % 3 == 2 ? i - 2 : i + 1];
        uint64_t forward = tail * (uint64_t)nv + head, backward = head * (uint64_t)nv + tail;
        packed[i] = ((forward < backward ? forward : backward) << 1) | (forward > backward);
    }
    tw_radix_sort(packed, tmp, (int64_t)m, 0, tw_bit_length((uint64_t)nv * nv) + 1);
    for (size_t i = 1; i < m && !*defect; i++)
        if (packed[i] == packed[i - 1]) *defect = 2;
    if (!*defect && closed) {
        if (m % 2) *defect = 3;
        for (size_t i = 0; i + 1 < m && !*defect; i += 2)
            if ((packed[i] & 1) || (packed[i] | 1) != packed[i + 1]) *defect = 3;
    }
    free(packed);
    free(tmp);
    return TW_OK;
}

/* ----------------------------------------------------------------------------------------------------------- */
/* the stage */

/* The SH constants of geometry/sh.py (the same decimal literals: the same doubles). */
#define SH_C0 0.28209479177387814
#define SH_C1 0.4886025119029199
#define SH_C2_0 1.0925484305920792
#define SH_C2_1 0.31539156525252005
#define SH_C2_2 0.5462742152960396
#define SH_C3_0 0.5900435899266435
#define SH_C3_1 2.890611442640554
#define SH_C3_2 0.4570457994644658
#define SH_C3_3 0.3731763325901154
#define SH_C3_4 1.445305721320277

/* sh.sh_basis_terms at the unit direction (x, y, z): the q terms, each by the reference's expression. */
static void sh_terms(double x, double y, double z, int degree, double *term) {
    term[0] = SH_C0;
    if (degree >= 1) {
        term[1] = SH_C1 * y;
        term[2] = SH_C1 * z;
        term[3] = SH_C1 * x;
    }
    if (degree >= 2) {
        const double xx = x * x, yy = y * y, zz = z * z;
        term[4] = SH_C2_0 * (x * y);
        term[5] = SH_C2_0 * (y * z);
        term[6] = SH_C2_1 * (2.0 * zz - xx - yy);
        term[7] = SH_C2_0 * (x * z);
        term[8] = SH_C2_2 * (xx - yy);
        if (degree >= 3) {
            term[9] = SH_C3_0 * y * (3.0 * xx - yy);
            term[10] = SH_C3_1 * (x * y * z);
            term[11] = SH_C3_2 * y * (4.0 * zz - xx - yy);
            term[12] = SH_C3_3 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
            term[13] = SH_C3_2 * x * (4.0 * zz - xx - yy);
            term[14] = SH_C3_4 * z * (xx - yy);
            term[15] = SH_C3_0 * x * (xx - 3.0 * yy);
        }
    }
}

/* _edge_vertices for the edge (i inside, j outside): paper eq. 1-2, the reference's operations in its order. */
static void edge_vertex(const double *points, const double *s, const double *c, int degree, int q, uint32_t i,
                        uint32_t j, double *v) {
    const double *pi = points + 3 * (size_t)i, *pj = points + 3 * (size_t)j;
    double si = s[i], sj = s[j];
    if (q > 0) {
        double d0 = pj[0] - pi[0], d1 = pj[1] - pi[1], d2 = pj[2] - pi[2];
        const double length = sqrt(d0 * d0 + d1 * d1 + d2 * d2); /* numpy's sum of 3: ((a + b) + c) */
        const double safe = length > 0 ? length : 1.0;
        d0 = d0 / safe;
        d1 = d1 / safe;
        d2 = d2 / safe;
        double term[16];
        sh_terms(d0, d1, d2, degree, term);
        const double *ci = c + (size_t)q * i, *cj = c + (size_t)q * j;
        /* sh_i, sh_j start as d0 * 0 (a signed zero, as the reference's) */
        double sh_i = d0 * 0, sh_j = d0 * 0;
        for (int k = 0; k < q; k++) {
            /* k < 1: degree 0 (even); 1..3: degree 1 (odd); 4..8: even; 9..15: odd */
            const int odd = (k >= 1 && k < 4) || k >= 9;
            sh_i = sh_i + term[k] * ci[k];
            sh_j = odd ? sh_j - term[k] * cj[k] : sh_j + term[k] * cj[k];
        }
        si = (1 + tw_tanh(sh_i)) * si;
        sj = (1 + tw_tanh(sh_j)) * sj;
    }
    const double denom = sj - si;
    double wi = 0.5, wj = 0.5; /* s_hat_i and s_hat_j both 0 (saturated tanh): the midpoint */
    if (denom != 0) {
        wi = sj / denom;
        wj = -si / denom;
    }
    for (int a = 0; a < 3; a++) v[a] = wi * pi[a] + wj * pj[a];
}

/* The edge of sorted (lo, hi) arrays equal to (a, b) (a < b), or -1. */
static int64_t find_edge(const tw_mt_topo *topo, uint32_t a, uint32_t b) {
    size_t lo = 0, hi = topo->nu;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (topo->lo[mid] < a || (topo->lo[mid] == a && topo->hi[mid] < b))
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo < topo->nu && topo->lo[lo] == a && topo->hi[lo] == b ? (int64_t)lo : -1;
}

int tw_marching_tets(const double *points, const double *s, const double *c, int sh_degree, size_t n,
                     const tw_tets *tz, tw_surface *out, tw_error *err) {
    if (!out) return tw_fail(err, TW_ERROR_ARGUMENT, "tw_marching_tets: out is NULL");
    memset(out, 0, sizeof *out);
    if (sh_degree < -1 || sh_degree > 3)
        return tw_fail(err, TW_ERROR_ARGUMENT, "SH degree must be in -1..3, got %d", sh_degree);
    const int q = (sh_degree + 1) * (sh_degree + 1);
    if (!tz || (n && (!points || !s || (q && !c))) || (tz->nt && !tz->tets) || (tz->nh && !tz->hull))
        return tw_fail(err, TW_ERROR_ARGUMENT, "tw_marching_tets: NULL array");
    for (size_t k = 0; k < 3 * tz->nh; k++)
        if (tz->hull[k] < 0 || (size_t)tz->hull[k] >= n)
            return tw_fail(err, TW_ERROR_ARGUMENT, "marching tets: hull face index out of range");
    tw_mt_tables tables;
    default_tables(&tables);
    tw_mt_topo topo;
    uint8_t *inside = malloc(n ? n : 1);
    int32_t *cap_slot = NULL;
    if (!inside) return tw_fail(err, TW_ERROR_MEMORY, "out of memory in marching tets");
    for (size_t i = 0; i < n; i++) inside[i] = s[i] < 0;
    int status = tw_mt_topology(tz->tets, tz->nt, inside, n, &tables, &topo, err);
    if (status) {
        free(inside);
        return status;
    }
    /* caps: the hull faces with inside corners (code > 0), the inside hull points in ascending order */
    size_t cap_points = 0, cap_faces = 0;
    if (tz->nh) {
        cap_slot = malloc(n * sizeof(int32_t));
        if (!cap_slot) {
            status = tw_fail(err, TW_ERROR_MEMORY, "out of memory in marching tets");
            goto fail;
        }
        for (size_t i = 0; i < n; i++) cap_slot[i] = -1;
        for (size_t h = 0; h < tz->nh; h++) {
            const int32_t *hf = tz->hull + 3 * h;
            const int code = inside[hf[0]] | inside[hf[1]] << 1 | inside[hf[2]] << 2;
            for (int k = 0; k < 3; k++)
                if (inside[hf[k]]) cap_slot[hf[k]] = 0; /* marked; numbered below */
            for (int r = 0; r < 2; r++) cap_faces += CAP_TABLE[code][r][0] >= 0;
        }
        for (size_t i = 0; i < n; i++)
            if (cap_slot[i] == 0) cap_slot[i] = (int32_t)(topo.nu + cap_points++);
            else cap_slot[i] = -1;
    }
    out->nv = topo.nu + cap_points;
    out->nf = topo.nf + cap_faces;
    if (out->nv > ((size_t)1 << 31) || out->nf > ((size_t)1 << 31)) {
        status = tw_fail(err, TW_ERROR_LIMIT, "marching tets: more than 2^31 vertices or faces");
        goto fail;
    }
    out->v = malloc((out->nv ? out->nv : 1) * 3 * sizeof(double));
    out->f = malloc((out->nf ? out->nf : 1) * 3 * sizeof(int32_t));
    if (!out->v || !out->f) {
        status = tw_fail(err, TW_ERROR_MEMORY, "out of memory in marching tets");
        goto fail;
    }
    for (size_t e = 0; e < topo.nu; e++) {
        const uint32_t lo = topo.lo[e], hi = topo.hi[e];
        const uint32_t i = inside[lo] ? lo : hi, j = inside[lo] ? hi : lo;
        edge_vertex(points, s, c, sh_degree, q, i, j, out->v + 3 * e);
    }
    memcpy(out->f, topo.faces, topo.nf * 3 * sizeof(int32_t));
    if (cap_points) {
        for (size_t i = 0; i < n; i++)
            if (cap_slot[i] >= 0) memcpy(out->v + 3 * (size_t)cap_slot[i], points + 3 * i, 3 * sizeof(double));
        size_t f = topo.nf;
        for (size_t h = 0; h < tz->nh; h++) {
            const int32_t *hf = tz->hull + 3 * h;
            const int code = inside[hf[0]] | inside[hf[1]] << 1 | inside[hf[2]] << 2;
            if (!code) continue;
            int32_t slots[6];
            for (int k = 0; k < 3; k++) {
                slots[k] = cap_slot[hf[k]];
                const int32_t a = hf[HULL_EDGE_A[k]], b = hf[HULL_EDGE_B[k]];
                slots[3 + k] = -1;
                if (inside[a] != inside[b]) {
                    const int64_t e = find_edge(&topo, (uint32_t)(a < b ? a : b), (uint32_t)(a < b ? b : a));
                    if (e < 0) {
                        status = tw_fail(err, TW_ERROR_INTERNAL,
                                         "hull_faces do not match the tets: a hull edge with a sign change is not a "
                                         "tet edge");
                        goto fail;
                    }
                    slots[3 + k] = (int32_t)e;
                }
            }
            for (int r = 0; r < 2 && CAP_TABLE[code][r][0] >= 0; r++, f++)
                for (int k = 0; k < 3; k++) out->f[3 * f + k] = slots[CAP_TABLE[code][r][k]];
        }
    }
    if (out->nf) {
        int defect;
        if ((status = tw_manifold_defect(out->f, out->nf, out->nv, 1, &defect, err))) goto fail;
        if (defect) {
            status = tw_fail(err, TW_ERROR_INTERNAL, "%s", MANIFOLD_ERRORS[defect - 1]);
            goto fail;
        }
    }
    free(inside);
    free(cap_slot);
    tw_mt_topology_free(&topo);
    return TW_OK;
fail:
    free(inside);
    free(cap_slot);
    tw_mt_topology_free(&topo);
    tw_surface_free(out);
    return status;
}
