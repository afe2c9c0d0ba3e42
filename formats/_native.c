/* Compiled fast path of the s prediction's decoder loops (formats/predict.py is the reference and the fallback).
 *
 * A thin binding: the kernels are the decoder core's (decoder/predict.c, the same code the C decoder runs); this
 * file only checks the numpy buffers and maps the kernels' status codes to Python exceptions. Three functions,
 * each giving bit for bit what the reference gives:
 *
 *   neighbors(cells, morton, idx, d2, over, k, bound_rank, first_level, cap) -> number of rows in `over`
 *       The causal neighbour rule of formats/README.md ("s section, predicted", step 1): per point i the k points
 *       j < i with the smallest (D_ij, j) among those with D_ij < B_i (the bound_rank-th smallest D_ij over all
 *       points, i itself included; no bound when N <= bound_rank). Exact int64 arithmetic. Points whose search
 *       would scan more than `cap` points at one level are not answered: their rows go to `over` (ascending), for
 *       the reference's k-d tree (the same work bound as the reference).
 *   weights(cells, idx, d2, beta, ridge)
 *       The predictor weights (step 2) of every row; ValueError on a neighbour index or distance out of range.
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

#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "internal.h"

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

static PyObject *neighbors(PyObject *self, PyObject *args) {
    PyObject *o_cells, *o_morton, *o_idx, *o_d2, *o_over;
    Py_ssize_t k, bound_rank, first_level, cap;
    if (!PyArg_ParseTuple(args, "OOOOOnnnn", &o_cells, &o_morton, &o_idx, &o_d2, &o_over, &k, &bound_rank,
                          &first_level, &cap))
        return NULL;
    if (k < 1 || k > TW_PREDICT_MAX_K || bound_rank < 1 || first_level < 0 || first_level > TW_PREDICT_COORD_BITS ||
        cap < 1) {
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

    int64_t *idx = (int64_t *)vi.buf, *d2 = (int64_t *)vd.buf, *over = (int64_t *)vo.buf;
    int64_t n_over = 0;
    tw_neighbor_search *search = NULL;
    int status = tw_neighbors_begin(&search, (const int64_t *)vc.buf, (const int64_t *)vm.buf, n, k, bound_rank,
                                    (int)first_level, cap);
    if (status == TW_ERROR_ARGUMENT) {
        PyErr_SetString(PyExc_ValueError, "_native.neighbors: cells out of range or not in canonical order");
        goto done;
    }
    if (status) {
        PyErr_NoMemory();
        goto done;
    }
    int no_memory = 0;
    Py_BEGIN_ALLOW_THREADS;
    for (int64_t i = 0; i < n; i++) {
        int rc = tw_neighbors_row(search, i, idx + i * k, d2 + i * k);
        if (rc < 0) {
            no_memory = 1;
            break;
        }
        if (rc == 1) over[n_over++] = i; /* the work bound: the reference's k-d tree answers this point */
    }
    Py_END_ALLOW_THREADS;
    tw_neighbors_end(search);
    if (no_memory) PyErr_NoMemory();
done:
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
    if (k > TW_PREDICT_MAX_K || vi.len != 8 * k * n) {
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
    int rc = 0;
    Py_BEGIN_ALLOW_THREADS;
    for (int64_t i = 0; i < n && !rc; i++) {
        int64_t sym;
        rc = tw_predict_symbol(i, idx + i * k, beta + i * k, k, u, lo, hi, res[i], bound, &sym, pred ? pred + i : NULL);
        if (rc) break;
        out[i] = sym;
        u[i] = (double)sym + 0.5; /* |sym| < 2**51: exact */
    }
    Py_END_ALLOW_THREADS;
    free(u);
    if (rc)
        PyErr_SetString(PyExc_ValueError, rc == 1 ? "cannot convert float NaN to integer"
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
    if (k > TW_PREDICT_MAX_K || vi.len != 8 * k * n) {
        PyErr_SetString(PyExc_ValueError, "_native.weights: idx must be (N, K)");
        goto fail_i;
    }
    if (get_buffer(o_d2, &vd, 'q', k * n, 0, "d2")) goto fail_i;
    if (get_buffer(o_beta, &vb, 'd', k * n, 1, "beta")) goto fail_d;
    const int64_t *cells = (const int64_t *)vc.buf, *idx = (const int64_t *)vi.buf, *dd = (const int64_t *)vd.buf;
    double *beta = (double *)vb.buf;
    int bad = 0;
    Py_BEGIN_ALLOW_THREADS;
    for (int64_t i = 0; i < n && !bad; i++)
        bad = tw_predict_weights_row(cells, n, i, idx + i * k, dd + i * k, k, ridge_factor, beta + i * k) != 0;
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
