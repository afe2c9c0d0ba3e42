/* Python binding of the exact Delaunay of the decoder core (decoder/delaunay.c, where the definition, the
 * exactness bounds and the algorithm are documented; formats/README.md "The exact Delaunay" is the specification).
 *
 *   tetrahedralize(cells) -> (tets, hull_faces) as bytearrays of int64 ((T, 4) and (H, 3), C order)
 *       cells: a C-contiguous int64 buffer of N * 3 coordinates. Raises ValueError (coordinates outside
 *       [0, 2^23), N > 2^26, wrong buffer), MemoryError (allocation failure, or more than max(64 N + 4096, 2^22)
 *       tets: a degenerate set whose tetrahedralization grows quadratically, e.g. points on two skew lines),
 *       RuntimeError starting with "flat tet" (a tet with no volume: an internal inconsistency, never expected) or
 *       "walk" (point location did not end).
 *
 * The binding checks the buffer, narrows the cells to int32 (after the range check), runs tw_delaunay without the
 * GIL and widens its int32 arrays to int64.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

static PyObject *py_tetrahedralize(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *obj;
    if (!PyArg_ParseTuple(args, "O", &obj)) return NULL;
    Py_buffer view;
    if (PyObject_GetBuffer(obj, &view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) != 0) return NULL;
    const char *f = view.format ? view.format : "B";
    if (*f == '<' || *f == '=' || *f == '@') f++;
    if (view.itemsize != 8 || (f[0] != 'q' && f[0] != 'l') || f[1] != '\0' || view.len % 24) {
        PyBuffer_Release(&view);
        PyErr_SetString(PyExc_ValueError, "_delaunay_native: cells must be a C-contiguous int64 (N, 3) buffer");
        return NULL;
    }
    const int64_t *cells = (const int64_t *)view.buf;
    int64_t n = view.len / 24;
    if (n > TW_DELAUNAY_MAX_POINTS) {
        PyBuffer_Release(&view);
        PyErr_Format(PyExc_ValueError, "at most %d points can be tetrahedralized, got %lld", TW_DELAUNAY_MAX_POINTS,
                     (long long)n);
        return NULL;
    }
    int32_t *narrow = malloc((size_t)(n ? 3 * n : 1) * sizeof(int32_t));
    if (!narrow) {
        PyBuffer_Release(&view);
        return PyErr_NoMemory();
    }
    for (int64_t i = 0; i < 3 * n; i++) {
        if (cells[i] < 0 || cells[i] >= ((int64_t)1 << TW_DELAUNAY_MAX_BITS)) {
            PyErr_Format(PyExc_ValueError, "cell coordinates must lie in [0, 2^%d), got %lld", TW_DELAUNAY_MAX_BITS,
                         (long long)cells[i]);
            free(narrow);
            PyBuffer_Release(&view);
            return NULL;
        }
        narrow[i] = (int32_t)cells[i];
    }
    PyBuffer_Release(&view);
    tw_tets tz;
    tw_error err = {0, {0}};
    int status;
    Py_BEGIN_ALLOW_THREADS status = tw_delaunay(narrow, (size_t)n, &tz, &err);
    Py_END_ALLOW_THREADS free(narrow);
    if (status != TW_OK) {
        if (status == TW_ERROR_MEMORY) return PyErr_NoMemory();
        PyErr_SetString(status == TW_ERROR_LIMIT      ? PyExc_MemoryError
                        : status == TW_ERROR_ARGUMENT ? PyExc_ValueError
                                                      : PyExc_RuntimeError,
                        err.message);
        return NULL;
    }
    PyObject *tets = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(tz.nt * 32));
    PyObject *hull = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(tz.nh * 24));
    if (tets && hull) {
        int64_t *out = (int64_t *)PyByteArray_AS_STRING(tets);
        for (size_t i = 0; i < 4 * tz.nt; i++) out[i] = tz.tets[i];
        out = (int64_t *)PyByteArray_AS_STRING(hull);
        for (size_t i = 0; i < 3 * tz.nh; i++) out[i] = tz.hull[i];
    }
    tw_tets_free(&tz);
    if (!tets || !hull) {
        Py_XDECREF(tets);
        Py_XDECREF(hull);
        return NULL;
    }
    return Py_BuildValue("(NN)", tets, hull);
}

static PyMethodDef methods[] = {
    {"tetrahedralize", py_tetrahedralize, METH_VARARGS,
     "tetrahedralize(cells int64 (N, 3) buffer) -> (tets, hull_faces) bytearrays of int64 (module docstring)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_delaunay_native",
    "Exact 3-D Delaunay tetrahedralization of integer points under a fixed symbolic perturbation "
    "(geometry/delaunay.py; the core is decoder/delaunay.c).",
    -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__delaunay_native(void) { return PyModule_Create(&module); }
