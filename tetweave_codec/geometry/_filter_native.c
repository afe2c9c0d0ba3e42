/* Python binding of the decoder core's filter kernels (decoder/filter.c, decoder/loop.c), the compiled fast path of
 * geometry/smoothing.py `taubin` and `crease_edges` and geometry/subdivision.py `loop_and_midpoint` on a closed mesh
 * without crease rules: the core's binary64 operations are the numpy reference's in its order, so the results are
 * bit for bit the reference's (tests/test_filter_native.py); the numpy code stays the reference and the fallback
 * (`smoothing.NATIVE`, `subdivision.NATIVE`, environment TETWEAVE_NATIVE=0). This file only checks the arrays,
 * converts int64 indices to the core's int32 and releases the GIL around the core's calls.
 *
 * taubin(vertices (V,3) float64 in/out, edges (E,2) int64, steps, lam, mu) -> 0: `smoothing.taubin`'s numpy steps
 *     (neighbour sums from 0.0 in the order of `edges`, as np.bincount adds its weights): tw_taubin.
 * loop(vertices (V,3), reference (V,3), faces (F,3), edges (3F,2) = smoothing.mesh_edges(faces, V, closed=True),
 *     out_vertices (V+E,3), out_reference (V+E,3), out_faces (4F,3) int64) -> 0: one Loop level of `vertices` and
 *     one midpoint level of `reference` on the same faces (tw_loop_level without creases); 1 when the faces are not
 *     a closed, consistently oriented 2-manifold (the outputs are then unspecified: the caller runs the reference).
 * creases(vertices (V,3), faces (F,3), edges (3F,2) = mesh_edges(faces, V, closed=True), cos, sharp (3F,) uint8 out)
 *     -> 0: sharp = smoothing.crease_edges(vertices, faces, edges) with CREASE_COS = cos (tw_crease_rows); 1 when
 *     the faces are not a closed, consistently oriented 2-manifold whose half-edges are `edges` in order (nothing
 *     decided: the caller runs the reference).
 * Index arrays out of range [0, V): ValueError.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

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

/* x[0..count) (int64 vertex indices, each in [0, nv)) as a new int32 array; NULL with ValueError ("NAME: index out
 * of range") or MemoryError set. */
static int32_t *indices32(const int64_t *x, int64_t count, int64_t nv, const char *name) {
    if (nv > INT32_MAX) {
        PyErr_Format(PyExc_ValueError, "%s: more than 2^31 - 1 vertices", name);
        return NULL;
    }
    int32_t *out = (int32_t *)malloc(sizeof(int32_t) * (size_t)(count > 0 ? count : 1));
    if (!out) {
        PyErr_NoMemory();
        return NULL;
    }
    for (int64_t i = 0; i < count; i++) {
        if (x[i] < 0 || x[i] >= nv) {
            free(out);
            PyErr_Format(PyExc_ValueError, "%s: index out of range", name);
            return NULL;
        }
        out[i] = (int32_t)x[i];
    }
    return out;
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
    int32_t *rows = indices32((const int64_t *)b[1].view.buf, 2 * ne, nv, "edges");
    if (!rows) {
        release(b, 2);
        return NULL;
    }
    int status;
    Py_BEGIN_ALLOW_THREADS;
    status = tw_taubin((double *)b[0].view.buf, (size_t)nv, rows, (size_t)ne, steps, lam, mu);
    Py_END_ALLOW_THREADS;
    free(rows);
    release(b, 2);
    if (status < 0) return PyErr_NoMemory();
    return PyLong_FromLong(0);
}

static PyObject *loop(PyObject *self, PyObject *args) {
    PyObject *ov, *or, *of, *oe, *oov, *oor, *oof;
    if (!PyArg_ParseTuple(args, "OOOOOOO", &ov, &or, &of, &oe, &oov, &oor, &oof)) return NULL;
    Buf b[7];
    memset(b, 0, sizeof b);
    int32_t *f32 = NULL, *e32 = NULL, *out32 = NULL;
    if (take(ov, &b[0], 8, -1, 0, "vertices") < 0 || b[0].view.len % 24) goto bad;
    int64_t nv = b[0].view.len / 24;
    if (take(or, &b[1], 8, 3 * nv, 0, "reference") < 0) goto bad;
    if (take(of, &b[2], 8, -1, 0, "faces") < 0 || b[2].view.len % 24) goto bad;
    int64_t nf = b[2].view.len / 24, nh = 3 * nf, ne = nh / 2;
    if (take(oe, &b[3], 8, 2 * nh, 0, "edges") < 0) goto bad;
    if (take(oov, &b[4], 8, 3 * (nv + ne), 1, "out_vertices") < 0) goto bad;
    if (take(oor, &b[5], 8, 3 * (nv + ne), 1, "out_reference") < 0) goto bad;
    if (take(oof, &b[6], 8, 12 * nf, 1, "out_faces") < 0) goto bad;
    if (!(e32 = indices32((const int64_t *)b[3].view.buf, 2 * nh, nv, "edges"))) goto bad;
    if (!(f32 = indices32((const int64_t *)b[2].view.buf, 3 * nf, nv, "faces"))) goto bad;
    if (!(out32 = (int32_t *)malloc(sizeof(int32_t) * (size_t)(12 * nf > 0 ? 12 * nf : 1)))) {
        PyErr_NoMemory();
        goto bad;
    }
    int status;
    Py_BEGIN_ALLOW_THREADS;
    status = tw_loop_level((const double *)b[0].view.buf, (const double *)b[1].view.buf, (size_t)nv, f32,
                           (size_t)nf, e32, NULL, (double *)b[4].view.buf, (double *)b[5].view.buf, out32, NULL);
    if (status == 0) {
        int64_t *out_f = (int64_t *)b[6].view.buf;
        for (int64_t i = 0; i < 12 * nf; i++) out_f[i] = out32[i];
    }
    Py_END_ALLOW_THREADS;
    free(f32);
    free(e32);
    free(out32);
    release(b, 7);
    if (status < 0) return PyErr_NoMemory();
    return PyLong_FromLong(status);
bad:
    if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "loop: wrong array shapes");
    free(f32);
    free(e32);
    free(out32);
    release(b, 7);
    return NULL;
}

static PyObject *creases(PyObject *self, PyObject *args) {
    PyObject *ov, *of, *oe, *os;
    double cosine;
    if (!PyArg_ParseTuple(args, "OOOdO", &ov, &of, &oe, &cosine, &os)) return NULL;
    Buf b[4];
    memset(b, 0, sizeof b);
    int32_t *f32 = NULL, *e32 = NULL;
    if (take(ov, &b[0], 8, -1, 0, "vertices") < 0 || b[0].view.len % 24) goto bad;
    int64_t nv = b[0].view.len / 24;
    if (take(of, &b[1], 8, -1, 0, "faces") < 0 || b[1].view.len % 24) goto bad;
    int64_t nf = b[1].view.len / 24, nh = 3 * nf;
    if (take(oe, &b[2], 8, 2 * nh, 0, "edges") < 0) goto bad;
    if (take(os, &b[3], 1, nh, 1, "sharp") < 0) goto bad;
    if (!(e32 = indices32((const int64_t *)b[2].view.buf, 2 * nh, nv, "edges"))) goto bad;
    if (!(f32 = indices32((const int64_t *)b[1].view.buf, 3 * nf, nv, "faces"))) goto bad;
    int status;
    Py_BEGIN_ALLOW_THREADS;
    int32_t *rows = NULL, *face_of = NULL, *twin = NULL;
    status = tw_half_edges(f32, (size_t)nf, (size_t)nv, &rows, &face_of, &twin);
    /* the caller's rows must be the faces' half-edges in order: the rows the answer is given for */
    if (status == 0 && memcmp(rows, e32, sizeof(int32_t) * 2 * (size_t)nh) != 0) status = 1;
    if (status == 0 && tw_crease_rows((const double *)b[0].view.buf, f32, (size_t)nf, face_of, twin, cosine,
                                      (uint8_t *)b[3].view.buf) != 0)
        status = -1;
    free(rows);
    free(face_of);
    free(twin);
    Py_END_ALLOW_THREADS;
    free(f32);
    free(e32);
    release(b, 4);
    if (status < 0) return PyErr_NoMemory();
    return PyLong_FromLong(status);
bad:
    if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "creases: wrong array shapes");
    free(f32);
    free(e32);
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
