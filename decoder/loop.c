/*
 * loop.c -- half-edges of a closed mesh and one Loop subdivision level (geometry/smoothing.py mesh_edges,
 * geometry/subdivision.py loop_level / _apply_level / _child_creases are the reference): Warren's weights, Hoppe's
 * crease rules, the midpoint level of the reference surface. Every binary64 operation is the reference's, in its
 * order (compile with -ffp-contract=off, no -ffast-math), so the vertices are the reference's bits.
 *
 * The reference sums an old vertex's neighbours with np.bincount, which adds its weights from 0.0 in input order:
 * the rows here are in that order (sorted by (a, b)), so each sum runs over ascending neighbours.
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

#define EDGE_NEAR 0.375      /* weight of an edge's two ends in its new vertex */
#define EDGE_FAR 0.125       /* weight of the two opposite corners */
#define BETA_VALENCE_3 0.1875 /* Warren's beta for three neighbours; 3 / (8k) above */
#define BETA_CREASE 0.125    /* a crease vertex's weight of each of its two crease neighbours */

/*
 * tw_half_edges: the 3 nf half-edges (a, b) of faces f (nf * 3 int32 in [0, nv)) sorted by (a, b), the order of
 * smoothing.mesh_edges(f, nv, closed=True), as *rows (2 per row); *face_of: each row's face; *twin: the row of
 * (b, a). Any output pointer may be NULL (not computed). Two stable counting sorts (by b, then by a): O(nf + nv)
 * whatever the valences. Returns 0; 1 when f is not a closed, consistently oriented 2-manifold's faces (an index
 * out of range, a face with a repeated corner, a half-edge twice, one without its twin); -1 out of memory. On
 * failure nothing is allocated.
 */
int tw_half_edges(const int32_t *f, size_t nf, size_t nv, int32_t **rows, int32_t **face_of, int32_t **twin) {
    if (rows) *rows = NULL;
    if (face_of) *face_of = NULL;
    if (twin) *twin = NULL;
    if (nv > (size_t)INT32_MAX || nf > (size_t)INT32_MAX / 3) return 1;
    size_t nh = 3 * nf;
    for (size_t i = 0; i < nh; i++)
        if (f[i] < 0 || (size_t)f[i] >= nv) return 1;
    for (size_t i = 0; i < nf; i++)
        if (f[3 * i] == f[3 * i + 1] || f[3 * i + 1] == f[3 * i + 2] || f[3 * i + 2] == f[3 * i]) return 1;
    size_t cap = nh > 0 ? nh : 1;
    int32_t *start = (int32_t *)calloc(nv + 1, sizeof(int32_t));
    int32_t *by_b = (int32_t *)malloc(sizeof(int32_t) * cap); /* half-edge h = 3 face + slot, sorted by b */
    int32_t *order = (int32_t *)malloc(sizeof(int32_t) * cap); /* then stably by a */
    int32_t *r = (int32_t *)malloc(sizeof(int32_t) * 2 * cap);
    int32_t *tw = (int32_t *)malloc(sizeof(int32_t) * cap);
    int32_t *fo = face_of ? (int32_t *)malloc(sizeof(int32_t) * cap) : NULL;
    int status = 0;
    if (!start || !by_b || !order || !r || !tw || (face_of && !fo)) {
        status = -1;
        goto done;
    }
#define HEAD(h) f[(h)]                               /* a of half-edge h */
#define TAIL(h) f[3 * ((h) / 3) + ((h) % 3 + 1) % 3] /* b of half-edge h */
    for (size_t h = 0; h < nh; h++) start[TAIL(h) + 1]++;
    for (size_t u = 0; u < nv; u++) start[u + 1] += start[u];
    for (size_t h = 0; h < nh; h++) by_b[start[TAIL(h)]++] = (int32_t)h;
    memset(start, 0, sizeof(int32_t) * (nv + 1));
    for (size_t h = 0; h < nh; h++) start[HEAD(h) + 1]++;
    for (size_t u = 0; u < nv; u++) start[u + 1] += start[u];
    for (size_t i = 0; i < nh; i++) order[start[HEAD(by_b[i])]++] = by_b[i];
    /* start[u] is now the end of u's rows: shift back to their beginnings */
    for (size_t u = nv; u > 0; u--) start[u] = start[u - 1];
    start[0] = 0;
    for (size_t i = 0; i < nh; i++) {
        int32_t h = order[i];
        r[2 * i] = HEAD(h);
        r[2 * i + 1] = TAIL(h);
        if (fo) fo[i] = h / 3;
        if (i > 0 && r[2 * i] == r[2 * i - 2] && r[2 * i + 1] == r[2 * i - 1]) {
            status = 1; /* a half-edge twice */
            goto done;
        }
    }
#undef HEAD
#undef TAIL
    /* the twins: for each b, the rows (a, b) with a > b come in ascending a (rows are sorted by a), as do b's own
     * rows (b, a) with a > b (sorted by their ends, after b's rows to smaller ends), so the k-th of the former is
     * the twin of the k-th of the latter: a cursor per vertex instead of a search. Each row (a, b), a > b, either
     * meets its twin there or some row has none (then a binary search fails as well); with as many rows a < b as
     * a > b (a != b: no repeated corner) the pairing covers every row. start[u] holds u's first row. */
    {
        int32_t *cursor = by_b; /* by_b (cap entries) is done with: it holds the cursors unless nv > cap */
        int32_t *own = NULL;
        if (nv > cap) {
            own = (int32_t *)malloc(sizeof(int32_t) * nv);
            if (!own) {
                status = -1;
                goto done;
            }
            cursor = own;
        }
        for (size_t u = 0; u < nv; u++) cursor[u] = start[u];
        size_t above = 0, listed = 0;
        /* branch-free (a > b goes either way unpredictably): the rows a > b listed in order (in `order`, done
         * with), each vertex's cursor past its rows to smaller ends */
        for (size_t i = 0; i < nh; i++) {
            int32_t below = r[2 * i + 1] < r[2 * i];
            cursor[r[2 * i]] += below;
            order[listed] = (int32_t)i;
            listed += (size_t)below;
        }
        for (size_t k = 0; k < listed; k++) {
            int32_t i = order[k], a = r[2 * i], b = r[2 * i + 1];
            int32_t t = cursor[b]++;
            if (t >= start[b + 1] || r[2 * t + 1] != a) {
                status = 1;
                break;
            }
            tw[i] = t;
            tw[t] = (int32_t)i;
            above++;
        }
        free(own);
        if (status == 0 && 2 * above != nh) status = 1;
        if (status != 0) goto done;
    }
done:
    free(start);
    free(by_b);
    free(order);
    if (status == 0 && rows) *rows = r;
    else free(r);
    if (status == 0 && twin) *twin = tw;
    else free(tw);
    if (status == 0 && face_of) *face_of = fo;
    else free(fo);
    return status;
}

/* The row of half-edge (u, w) among the sorted rows (u's rows are start[u] .. start[u + 1]), or -1. The lower
 * bound of w among u's ends: for the few rows of a vertex of ordinary valence counted without branches (a binary
 * search's branches go either way unpredictably), for many a binary search; both find the same row. */
#define FIND_LINEAR 16
static int64_t find_row(const int32_t *rows, const int64_t *start, int32_t u, int32_t w) {
    int64_t lo = start[u], hi = start[u + 1];
    if (hi - lo <= FIND_LINEAR) {
        int64_t below = 0;
        for (int64_t i = lo; i < hi; i++) below += rows[2 * i + 1] < w;
        lo += below;
    } else {
        while (lo < hi) {
            int64_t mid = lo + (hi - lo) / 2;
            if (rows[2 * mid + 1] < w)
                lo = mid + 1;
            else
                hi = mid;
        }
        hi = start[u + 1];
    }
    return lo < hi && rows[2 * lo + 1] == w ? lo : -1;
}

/*
 * tw_loop_level: one Loop level of v (nv * 3) and one midpoint level of r (nv * 3, or NULL) on faces f (nf * 3,
 * a closed, consistently oriented 2-manifold) whose sorted half-edges are `rows` (tw_half_edges; their order and
 * pairing are checked again, so any rows are safe). Edge e (the e-th row (a, b) with a < b) becomes vertex nv + e;
 * face i = (a, b, c) becomes faces 4i .. 4i + 3: (a, m_ab, m_ca), (m_ab, b, m_bc), (m_ca, m_bc, c),
 * (m_ab, m_bc, m_ca).
 *
 * crease (NULL, or one byte per edge e): the crease rules (subdivision.loop_level's `creases`): a crease edge's
 * vertex is its midpoint; an old vertex averages over its crease neighbours when it is on two crease edges, over
 * none when on one or three and more (smoothing.neighbours_along_creases), over all its neighbours when on none,
 * and with exactly two neighbours it takes beta 1/8.
 *
 * Outputs: out_v, out_r ((nv + ne) * 3, ne = 3 nf / 2; out_r ignored when r is NULL), out_f (4 nf * 3),
 * out_ends (NULL, or 2 ne: edge e's ends a < b, what tw_child_creases needs of this level). Returns 0; 1 when the
 * rows are not those of a closed manifold (the outputs are then unspecified); -1 out of memory.
 */
int tw_loop_level(const double *v, const double *r, size_t nv, const int32_t *f, size_t nf, const int32_t *rows,
                  const uint8_t *crease, double *out_v, double *out_r, int32_t *out_f, int32_t *out_ends) {
    size_t nh = 3 * nf, ne = nh / 2;
    if (nv > (size_t)INT32_MAX || nf > (size_t)INT32_MAX / 4 || nv + ne > (size_t)INT32_MAX) return 1;
    for (size_t i = 0; i < 2 * nh; i++)
        if (rows[i] < 0 || (size_t)rows[i] >= nv) return 1;
    for (size_t i = 0; i < nh; i++)
        if (f[i] < 0 || (size_t)f[i] >= nv) return 1;
    size_t cap = nh > 0 ? nh : 1, vcap = nv > 0 ? nv : 1;
    int64_t *start = (int64_t *)calloc(nv + 1, sizeof(int64_t));
    int32_t *edge_id = (int32_t *)malloc(sizeof(int32_t) * cap); /* per row: its undirected edge */
    int32_t *opp = (int32_t *)malloc(sizeof(int32_t) * cap);     /* per row: its face's third corner */
    uint8_t *use = (uint8_t *)malloc(cap);                       /* per row: an old vertex averages over it */
    double *sum = (double *)malloc(sizeof(double) * 3 * vcap);
    double *deg = (double *)calloc(vcap, sizeof(double));
    int64_t *sharp_count = crease ? (int64_t *)calloc(vcap, sizeof(int64_t)) : NULL;
    int64_t *cursor = (int64_t *)malloc(sizeof(int64_t) * vcap); /* per vertex: its next row to pair */
    int32_t *twin_row = (int32_t *)malloc(sizeof(int32_t) * cap); /* per row: the row of (b, a) */
    int32_t *edge_row = (int32_t *)malloc(sizeof(int32_t) * (ne + 1)); /* per edge: its row (a, b), a < b */
    int status = 0;
    if (!start || !edge_id || !opp || !use || !sum || !deg || (crease && !sharp_count) || !cursor || !twin_row ||
        !edge_row) {
        status = -1;
        goto done;
    }
    for (size_t i = 0; i < nh; i++) {
        opp[i] = -1;
        start[rows[2 * i] + 1]++;
        /* sorted rows: a repeated half-edge sits next to its copy; out of order means not mesh_edges' rows */
        if (i > 0 && (rows[2 * i] < rows[2 * i - 2] ||
                      (rows[2 * i] == rows[2 * i - 2] && rows[2 * i + 1] <= rows[2 * i - 1]))) {
            status = 1;
            goto done;
        }
    }
    for (size_t u = 0; u < nv; u++) start[u + 1] += start[u];
    /* edge ids: the rows (a, b) with a < b, in order (edge_row: edge e's row); a row (b, a) takes its twin's id.
     * Branch-free (a < b goes either way unpredictably): every row writes at the next edge's slot, which only a
     * row a < b keeps (edge_row has room for ne + 1; out_ends' writes stay below ne) */
    size_t count = 0;
    for (size_t i = 0; i < nh; i++) {
        int32_t a = rows[2 * i], b = rows[2 * i + 1];
        if (count <= ne) edge_row[count] = (int32_t)i;
        if (out_ends && count < ne) {
            out_ends[2 * count] = a;
            out_ends[2 * count + 1] = b;
        }
        edge_id[i] = (int32_t)count; /* a row a >= b gets its twin's below, or is refused */
        count += a < b;
    }
    if (count != ne || 2 * ne != nh) {
        status = 1;
        goto done;
    }
    /* the twins by a cursor per vertex, as in tw_half_edges from the other side: the k-th row (a, b) with a < b, in
     * row order, is the twin of b's k-th row (b, a) to an end below b (b's first rows). A row a < b that does not
     * meet its twin there means some row has none, and then a search would fail too; the ne rows a < b paired
     * with distinct rows of the other ne (no row a == b can be paired, so none is left over): every row has its
     * twin, the one a search finds. */
    for (size_t u = 0; u < nv; u++) cursor[u] = start[u];
    for (size_t e = 0; e < ne; e++) {
        int32_t t = edge_row[e], a = rows[2 * t], b = rows[2 * t + 1];
        int64_t i = cursor[b]++;
        if (i >= start[b + 1] || rows[2 * i + 1] != a) {
            status = 1;
            goto done;
        }
        edge_id[i] = (int32_t)e;
        twin_row[i] = t;
        twin_row[t] = (int32_t)i;
    }
    /* each face's half-edges: their rows give the new vertices; the face's third corner is the row's opposite */
    for (size_t i = 0; i < nf; i++) {
        const int32_t *fc = f + 3 * i;
        int32_t m[3];
        for (int k = 0; k < 3; k++) {
            int64_t row = find_row(rows, start, fc[k], fc[(k + 1) % 3]);
            if (row < 0 || opp[row] >= 0) {
                status = 1;
                goto done;
            }
            opp[row] = fc[(k + 2) % 3];
            m[k] = (int32_t)(nv + (size_t)edge_id[row]);
        }
        int32_t a = fc[0], b = fc[1], c = fc[2], mab = m[0], mbc = m[1], mca = m[2];
        int32_t faces4[12] = {a, mab, mca, mab, b, mbc, mca, mbc, c, mab, mbc, mca};
        memcpy(out_f + 12 * i, faces4, sizeof faces4);
    }
    /* the rows an old vertex averages over (neighbours_along_creases with each row's crease = its edge's) */
    if (crease) {
        for (size_t i = 0; i < nh; i++)
            if (crease[edge_id[i]]) sharp_count[rows[2 * i]]++;
        for (size_t i = 0; i < nh; i++) {
            int sharp = crease[edge_id[i]] != 0;
            int64_t c = sharp_count[rows[2 * i]];
            use[i] = (uint8_t)(c == 0 ? !sharp : (c == 2 && sharp));
        }
    } else {
        memset(use, 1, nh);
    }
    /* old vertices: keep * v + beta * (sum of neighbours from 0.0 in row order) */
    memset(sum, 0, sizeof(double) * 3 * vcap);
    for (size_t i = 0; i < nh; i++) {
        if (!use[i]) continue;
        const double *p = v + 3 * (size_t)rows[2 * i + 1];
        double *s = sum + 3 * (size_t)rows[2 * i];
        s[0] += p[0];
        s[1] += p[1];
        s[2] += p[2];
        deg[rows[2 * i]] += 1.0;
    }
    for (size_t i = 0; i < nv; i++) {
        double k = deg[i];
        double beta = k > 3 ? 3.0 / (8.0 * (k > 1.0 ? k : 1.0)) : BETA_VALENCE_3;
        if (k < 3) beta = 0.0;
        if (crease && k == 2) beta = BETA_CREASE;
        double keep = 1.0 - k * beta;
        for (int d = 0; d < 3; d++) {
            out_v[3 * i + d] = keep * v[3 * i + d] + beta * sum[3 * i + d];
            if (r) out_r[3 * i + d] = r[3 * i + d];
        }
    }
    /* edge vertices, edge by edge (the rows a < b in order) */
    for (size_t e = 0; e < ne; e++) {
        int32_t i = edge_row[e], a = rows[2 * i], b = rows[2 * i + 1];
        int64_t twin = twin_row[i];
        if (opp[i] < 0 || opp[twin] < 0) { /* a row no face listed */
            status = 1;
            goto done;
        }
        size_t id = nv + (size_t)edge_id[i];
        const double *pa = v + 3 * (size_t)a, *pb = v + 3 * (size_t)b;
        const double *pc = v + 3 * (size_t)opp[i], *pd = v + 3 * (size_t)opp[twin];
        int mid = crease && crease[edge_id[i]];
        for (int k = 0; k < 3; k++) {
            double ends = pa[k] + pb[k];
            out_v[3 * id + k] = mid ? 0.5 * ends : EDGE_NEAR * ends + EDGE_FAR * (pc[k] + pd[k]);
            if (r) out_r[3 * id + k] = 0.5 * (r[3 * (size_t)a + k] + r[3 * (size_t)b + k]);
        }
    }
done:
    free(start);
    free(edge_id);
    free(opp);
    free(use);
    free(sum);
    free(deg);
    free(sharp_count);
    free(cursor);
    free(twin_row);
    free(edge_row);
    return status;
}

/*
 * tw_child_creases: subdivision._child_creases. The creases (one byte per edge, ascending) of the level made from
 * a level's faces: the edges {a, m} with a an old vertex (< parent_nv) and m = parent_nv + e the new vertex of a
 * crease edge e (parent_crease[e], its ends parent_ends[2e], parent_ends[2e + 1]) that has a as an end. rows: the
 * child level's sorted half-edges (tw_half_edges), nh of them; parent_ne: the parent's edges. out: nh / 2 bytes.
 */
void tw_child_creases(const int32_t *rows, size_t nh, size_t parent_nv, const int32_t *parent_ends, size_t parent_ne,
                      const uint8_t *parent_crease, uint8_t *out) {
    size_t e = 0;
    for (size_t i = 0; i < nh; i++) {
        int32_t a = rows[2 * i], b = rows[2 * i + 1];
        if (a >= b) continue;
        uint8_t flag = 0;
        if ((size_t)a < parent_nv && (size_t)b >= parent_nv && (size_t)b - parent_nv < parent_ne) {
            size_t p = (size_t)b - parent_nv;
            flag = parent_crease[p] && (parent_ends[2 * p] == a || parent_ends[2 * p + 1] == a);
        }
        out[e++] = flag;
    }
}
