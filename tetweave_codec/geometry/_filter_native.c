/* Compiled fast path of the decoder's filter (geometry/smoothing.py `taubin`, geometry/subdivision.py
 * `loop_and_midpoint` on a closed mesh without crease rules): the same binary64 operations in the same order as
 * the numpy reference (built with -ffp-contract=off, no -ffast-math), so the results are bit for bit the
 * reference's (tests/test_native.py); the numpy code stays the reference and the fallback (`smoothing.NATIVE`,
 * `subdivision.NATIVE`, environment TETWEAVE_NATIVE=0).
 *
 * taubin(vertices (V,3) float64 in/out, edges (E,2) int64, steps, lam, mu) -> 0: `smoothing.taubin`'s numpy steps
 *     (neighbour sums from 0.0 in the order of `edges`, as np.bincount adds its weights).
 * loop(vertices (V,3), reference (V,3), faces (F,3), edges (3F,2) = smoothing.mesh_edges(faces, V, closed=True),
 *     out_vertices (V+E,3), out_reference (V+E,3), out_faces (4F,3)) -> 0: one Loop level of `vertices` and one
 *     midpoint level of `reference` on the same faces (subdivision.py's `_apply_level` and `loop_level` for a
 *     closed mesh: edge e = the e-th half-edge (a, b) with a < b in `edges`' order, its opposite corners the
 *     third corners of the faces of (a, b) and (b, a)); 1 when the faces are not a closed, consistently oriented
 *     2-manifold (a half-edge twice, one without its twin or not in `edges`): nothing written, the caller runs
 *     the reference.
 * creases(...): smoothing.crease_edges of a closed mesh, below.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* with no half-edge twice, nh / 2 rows (a, b) with a < b and a twin for every row (b, a) with b > a, the rows
 * pair up one to one: every half-edge has its twin */
#define EDGE_NEAR 0.375
#define EDGE_FAR 0.125
#define BETA_VALENCE_3 0.1875

typedef struct {
    Py_buffer view;
    int have;
} Buf;

static int take(PyObject *obj, Buf *b, Py_ssize_t itemsize, Py_ssize_t count, int writable, const char *name) {
    int flags = PyBUF_C_CONTIGUOUS | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, &b->view, flags) < 0) return -1;
    b->have = 1;
    if (b->view.itemsize != itemsize || (count >= 0 && b->view.len != itemsize * count) ||
        b->view.len % itemsize) {
        PyErr_Format(PyExc_ValueError, "%s: wrong size or type", name);
        return -1;
    }
    return 0;
}

static void release(Buf *b, int n) {
    for (int i = 0; i < n; i++)
        if (b[i].have) PyBuffer_Release(&b[i].view);
}

/* 0 when every one of x[0..count) is a vertex index (0 <= x < nv), else -1 with "NAME: index out of range" set */
static int indices_in_range(const int64_t *x, int64_t count, int64_t nv, const char *name) {
    for (int64_t i = 0; i < count; i++)
        if (x[i] < 0 || x[i] >= nv) {
            PyErr_Format(PyExc_ValueError, "%s: index out of range", name);
            return -1;
        }
    return 0;
}

/* sum (V,3) of v[dst] over edges in list order per src, from 0.0 (np.bincount's order) */
static void neighbour_sums(const double *v, const int64_t *e, int64_t ne, int64_t nv, double *sum) {
    memset(sum, 0, sizeof(double) * 3 * (size_t)nv);
    for (int64_t i = 0; i < ne; i++) {
        const double *p = v + 3 * e[2 * i + 1];
        double *s = sum + 3 * e[2 * i];
        s[0] += p[0];
        s[1] += p[1];
        s[2] += p[2];
    }
}

static PyObject *taubin(PyObject *self, PyObject *args) {
    PyObject *ov, *oe;
    int steps;
    double lam, mu;
    if (!PyArg_ParseTuple(args, "OOidd", &ov, &oe, &steps, &lam, &mu)) return NULL;
    Buf b[2];
    memset(b, 0, sizeof b);
    if (take(ov, &b[0], 8, -1, 1, "vertices") < 0 || take(oe, &b[1], 8, -1, 0, "edges") < 0) {
        release(b, 2);
        return NULL;
    }
    if (b[0].view.len % 24 || b[1].view.len % 16) {
        release(b, 2);
        PyErr_SetString(PyExc_ValueError, "vertices (V,3) float64, edges (E,2) int64");
        return NULL;
    }
    int64_t nv = b[0].view.len / 24, ne = b[1].view.len / 16;
    double *v = (double *)b[0].view.buf;
    const int64_t *e = (const int64_t *)b[1].view.buf;
    if (indices_in_range(e, 2 * ne, nv, "edges") < 0) {
        release(b, 2);
        return NULL;
    }
    int status = 0;
    Py_BEGIN_ALLOW_THREADS;
    double *sum = (double *)malloc(sizeof(double) * 3 * (size_t)(nv > 0 ? nv : 1));
    double *deg = (double *)calloc((size_t)(nv > 0 ? nv : 1), sizeof(double));
    if (!sum || !deg)
        status = -1;
    else {
        for (int64_t i = 0; i < ne; i++) deg[e[2 * i]] += 1.0;
        for (int s = 0; s < steps; s++)
            for (int half = 0; half < 2; half++) {
                double fac = half ? mu : lam;
                neighbour_sums(v, e, ne, nv, sum);
                for (int64_t i = 0; i < nv; i++) {
                    if (!(deg[i] > 0)) continue;
                    for (int k = 0; k < 3; k++) v[3 * i + k] = v[3 * i + k] + fac * (sum[3 * i + k] / deg[i] - v[3 * i + k]);
                }
            }
    }
    free(sum);
    free(deg);
    Py_END_ALLOW_THREADS;
    release(b, 2);
    if (status < 0) return PyErr_NoMemory();
    return PyLong_FromLong(0);
}

/* index of half-edge (u, w) in the sorted list (rows of u start at start[u]); -1 if absent */
static inline int64_t find_half(const int64_t *e, const int64_t *start, int64_t u, int64_t w) {
    for (int64_t j = start[u]; j < start[u + 1]; j++)
        if (e[2 * j + 1] == w) return j;
    return -1;
}

static PyObject *loop(PyObject *self, PyObject *args) {
    PyObject *ov, *or, *of, *oe, *oov, *oor, *oof;
    if (!PyArg_ParseTuple(args, "OOOOOOO", &ov, &or, &of, &oe, &oov, &oor, &oof)) return NULL;
    Buf b[7];
    memset(b, 0, sizeof b);
    if (take(ov, &b[0], 8, -1, 0, "vertices") < 0 || b[0].view.len % 24) goto bad;
    int64_t nv = b[0].view.len / 24;
    if (take(or, &b[1], 8, 3 * nv, 0, "reference") < 0) goto bad;
    if (take(of, &b[2], 8, -1, 0, "faces") < 0 || b[2].view.len % 24) goto bad;
    int64_t nf = b[2].view.len / 24, nh = 3 * nf, ne = nh / 2;
    if (take(oe, &b[3], 8, 2 * nh, 0, "edges") < 0) goto bad;
    if (take(oov, &b[4], 8, 3 * (nv + ne), 1, "out_vertices") < 0) goto bad;
    if (take(oor, &b[5], 8, 3 * (nv + ne), 1, "out_reference") < 0) goto bad;
    if (take(oof, &b[6], 8, 12 * nf, 1, "out_faces") < 0) goto bad;
    const double *v = (const double *)b[0].view.buf, *r = (const double *)b[1].view.buf;
    const int64_t *f = (const int64_t *)b[2].view.buf, *e = (const int64_t *)b[3].view.buf;
    double *out_v = (double *)b[4].view.buf, *out_r = (double *)b[5].view.buf;
    int64_t *out_f = (int64_t *)b[6].view.buf;
    if (indices_in_range(e, 2 * nh, nv, "edges") < 0 || indices_in_range(f, 3 * nf, nv, "faces") < 0) goto bad;
    int status = 0;
    Py_BEGIN_ALLOW_THREADS;
    int64_t *start = (int64_t *)calloc((size_t)nv + 1, sizeof(int64_t));
    int64_t *edge_id = (int64_t *)malloc(sizeof(int64_t) * (size_t)(nh > 0 ? nh : 1)); /* per half-edge row */
    int64_t *opp = (int64_t *)malloc(sizeof(int64_t) * (size_t)(nh > 0 ? nh : 1));     /* third corner per row */
    double *sum = (double *)malloc(sizeof(double) * 3 * (size_t)(nv > 0 ? nv : 1));
    double *deg = (double *)calloc((size_t)(nv > 0 ? nv : 1), sizeof(double));
    if (!start || !edge_id || !opp || !sum || !deg) {
        status = -1;
        goto done;
    }
    for (int64_t i = 0; i < nh; i++) {
        opp[i] = -1; /* every row gets its face's third corner below, or the faces and rows do not match */
        start[e[2 * i] + 1]++;
        /* sorted rows: a repeated half-edge sits next to its copy; out of order means not `mesh_edges` */
        if (i > 0 && (e[2 * i] < e[2 * i - 2] || (e[2 * i] == e[2 * i - 2] && e[2 * i + 1] <= e[2 * i - 1]))) {
            status = 1;
            goto done;
        }
    }
    for (int64_t u = 0; u < nv; u++) start[u + 1] += start[u];
    /* edge ids: the rows (a, b) with a < b, in order; a row (b, a) gets its twin's id */
    int64_t count = 0;
    for (int64_t i = 0; i < nh; i++)
        if (e[2 * i] < e[2 * i + 1]) edge_id[i] = count++;
    if (count != ne) {
        status = 1;
        goto done;
    }
    for (int64_t i = 0; i < nh; i++)
        if (e[2 * i] > e[2 * i + 1]) {
            int64_t twin = find_half(e, start, e[2 * i + 1], e[2 * i]);
            if (twin < 0) {
                status = 1;
                goto done;
            }
            edge_id[i] = edge_id[twin];
        }
    /* each face's half-edges: their rows give the new vertices; the face's third corner is the row's opposite */
    for (int64_t i = 0; i < nf; i++) {
        const int64_t *fc = f + 3 * i;
        int64_t m[3];
        for (int k = 0; k < 3; k++) {
            int64_t row = find_half(e, start, fc[k], fc[(k + 1) % 3]);
            if (row < 0) {
                status = 1;
                goto done;
            }
            opp[row] = fc[(k + 2) % 3];
            m[k] = nv + edge_id[row];
        }
        int64_t a = fc[0], bb = fc[1], c = fc[2], mab = m[0], mbc = m[1], mca = m[2];
        int64_t *o = out_f + 12 * i;
        int64_t faces4[12] = {a, mab, mca, mab, bb, mbc, mca, mbc, c, mab, mbc, mca};
        memcpy(o, faces4, sizeof faces4);
    }
    /* old vertices: keep * v + beta * (sum of neighbours from 0.0 in row order) */
    neighbour_sums(v, e, nh, nv, sum);
    for (int64_t i = 0; i < nh; i++) deg[e[2 * i]] += 1.0;
    for (int64_t i = 0; i < nv; i++) {
        double k = deg[i];
        double beta = k > 3 ? 3.0 / (8.0 * (k > 1.0 ? k : 1.0)) : BETA_VALENCE_3;
        if (k < 3) beta = 0.0;
        double keep = 1.0 - k * beta;
        for (int d = 0; d < 3; d++) {
            out_v[3 * i + d] = keep * v[3 * i + d] + beta * sum[3 * i + d];
            out_r[3 * i + d] = r[3 * i + d];
        }
    }
    /* edge vertices */
    for (int64_t i = 0; i < nh; i++) {
        int64_t a = e[2 * i], bb = e[2 * i + 1];
        if (a > bb) continue;
        int64_t twin = find_half(e, start, bb, a);
        if (twin < 0 || opp[i] < 0 || opp[twin] < 0) { /* checked above for twins; rows no face listed */
            status = 1;
            goto done;
        }
        int64_t c = opp[i], d = opp[twin], id = nv + edge_id[i];
        for (int k = 0; k < 3; k++) {
            double ends = v[3 * a + k] + v[3 * bb + k];
            out_v[3 * id + k] = EDGE_NEAR * ends + EDGE_FAR * (v[3 * c + k] + v[3 * d + k]);
            out_r[3 * id + k] = 0.5 * (r[3 * a + k] + r[3 * bb + k]);
        }
    }
done:
    free(start);
    free(edge_id);
    free(opp);
    free(sum);
    free(deg);
    Py_END_ALLOW_THREADS;
    release(b, 7);
    if (status < 0) return PyErr_NoMemory();
    return PyLong_FromLong(status);
bad:
    if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "loop: wrong array shapes");
    release(b, 7);
    return NULL;
}


static inline double dot3(const double *u, const double *w) { return (u[0] * w[0] + u[1] * w[1]) + u[2] * w[2]; }

/* creases(vertices (V,3), faces (F,3), edges (3F,2) = smoothing.mesh_edges(faces, V, closed=True), cos, sharp (3F,)
 * uint8 out) -> 0: sharp = smoothing.crease_edges(vertices, faces, edges) > 0 with CREASE_COS = cos (the face of
 * each row and of its twin, their normals (v1 - v0) x (v2 - v0) and the test in the reference's operation order);
 * 1 when the faces are not a closed, consistently oriented 2-manifold listing every row once (nothing decided:
 * the caller runs the reference, whose rule for such meshes this does not repeat). */
static PyObject *creases(PyObject *self, PyObject *args) {
    PyObject *ov, *of, *oe, *os;
    double cosine;
    if (!PyArg_ParseTuple(args, "OOOdO", &ov, &of, &oe, &cosine, &os)) return NULL;
    Buf b[4];
    memset(b, 0, sizeof b);
    if (take(ov, &b[0], 8, -1, 0, "vertices") < 0 || b[0].view.len % 24) goto bad;
    int64_t nv = b[0].view.len / 24;
    if (take(of, &b[1], 8, -1, 0, "faces") < 0 || b[1].view.len % 24) goto bad;
    int64_t nf = b[1].view.len / 24, nh = 3 * nf;
    if (take(oe, &b[2], 8, 2 * nh, 0, "edges") < 0) goto bad;
    if (take(os, &b[3], 1, nh, 1, "sharp") < 0) goto bad;
    const double *v = (const double *)b[0].view.buf;
    const int64_t *f = (const int64_t *)b[1].view.buf, *e = (const int64_t *)b[2].view.buf;
    uint8_t *sharp = (uint8_t *)b[3].view.buf;
    if (indices_in_range(e, 2 * nh, nv, "edges") < 0 || indices_in_range(f, 3 * nf, nv, "faces") < 0) goto bad;
    int status = 0;
    Py_BEGIN_ALLOW_THREADS;
    int64_t *start = (int64_t *)calloc((size_t)nv + 1, sizeof(int64_t));
    int64_t *side = (int64_t *)malloc(sizeof(int64_t) * (size_t)(nh > 0 ? nh : 1)); /* the face of each row */
    double *normal = (double *)malloc(sizeof(double) * 3 * (size_t)(nf > 0 ? nf : 1));
    if (!start || !side || !normal) {
        status = -1;
        goto done;
    }
    for (int64_t i = 0; i < nh; i++) {
        side[i] = -1;
        start[e[2 * i] + 1]++;
        if (i > 0 && (e[2 * i] < e[2 * i - 2] || (e[2 * i] == e[2 * i - 2] && e[2 * i + 1] <= e[2 * i - 1]))) {
            status = 1; /* not sorted, or a row twice */
            goto done;
        }
    }
    for (int64_t u = 0; u < nv; u++) start[u + 1] += start[u];
    for (int64_t i = 0; i < nf; i++) {
        const int64_t *fc = f + 3 * i;
        for (int k = 0; k < 3; k++) {
            int64_t row = find_half(e, start, fc[k], fc[(k + 1) % 3]);
            if (row < 0 || side[row] >= 0) {
                status = 1;
                goto done;
            }
            side[row] = i;
        }
        const double *p0 = v + 3 * fc[0], *p1 = v + 3 * fc[1], *p2 = v + 3 * fc[2];
        double u[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]}, w[3] = {p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]};
        double *n = normal + 3 * i;
        n[0] = u[1] * w[2] - u[2] * w[1];
        n[1] = u[2] * w[0] - u[0] * w[2];
        n[2] = u[0] * w[1] - u[1] * w[0];
    }
    for (int64_t i = 0; i < nh; i++) {
        int64_t twin = find_half(e, start, e[2 * i + 1], e[2 * i]);
        if (twin < 0) {
            status = 1;
            goto done;
        }
        const double *n1 = normal + 3 * side[i], *n2 = normal + 3 * side[twin];
        double bound = cosine * sqrt(dot3(n1, n1)) * sqrt(dot3(n2, n2));
        sharp[i] = dot3(n1, n2) < bound;
    }
done:
    free(start);
    free(side);
    free(normal);
    Py_END_ALLOW_THREADS;
    release(b, 4);
    if (status < 0) return PyErr_NoMemory();
    return PyLong_FromLong(status);
bad:
    if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "creases: wrong array shapes");
    release(b, 4);
    return NULL;
}

static PyMethodDef methods[] = {
    {"creases", creases, METH_VARARGS, "Crease edges of a closed mesh (smoothing.crease_edges)."},
    {"taubin", taubin, METH_VARARGS, "Taubin steps in place (smoothing.taubin's numpy arithmetic)."},
    {"loop", loop, METH_VARARGS, "One Loop level and one midpoint level of a closed mesh (subdivision.py)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_filter_native", NULL, -1, methods};

PyMODINIT_FUNC PyInit__filter_native(void) { return PyModule_Create(&module); }
