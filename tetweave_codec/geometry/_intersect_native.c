/* Python binding of the decoder core's crossing checks (decoder/intersect.c), the compiled fast path of
 * geometry/intersections.py `self_intersecting_faces`: the same candidate grid decision (cell size, "coarser" /
 * "finer" retries, failure) and the same pair predicate, with every floating-point operation in the reference's
 * order, so both flag the same faces (tests/test_intersections.py). This file only checks the arrays, converts the
 * int64 faces to the core's int32 and releases the GIL around the core's calls.
 *
 * faces(vertices (V,3) float64, faces (F,3) int64 (indices checked by the caller), flags (F,) uint8 out,
 * only (F,) uint8: test only pairs with a face marked here[, threads int = 1]) -> int: 0 done, 1 the grid found no
 * feasible cell size (the reference raises RuntimeError there): tw_crossings_grid.
 * marked(vertices, faces, flags, only[, threads]) -> 0 decided (exactly `faces`' flags), 2 undecided (flags all 0:
 * the caller runs `faces`): tw_crossings_marked, for checks that mark few faces.
 * stars(vertices, faces, flags, only, children (1 or 4)[, threads]) -> 0 decided, 2 undecided: tw_crossings_stars,
 * for the first check of a Loop level's faces.
 * The flags are the same on any thread count (decoder/intersect.c says why). A face index outside [0, V): ValueError.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

static int get_buffer(PyObject *obj, Py_buffer *view, Py_ssize_t itemsize, Py_ssize_t count, const char *name) {
    if (PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS | PyBUF_WRITABLE) < 0 &&
        (PyErr_Clear(), PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS) < 0))
        return -1;
    if (view->itemsize != itemsize || view->len != itemsize * count) {
        PyBuffer_Release(view);
        PyErr_Format(PyExc_ValueError, "%s: wrong size or type", name);
        return -1;
    }
    return 0;
}

/* The arguments of every entry point: vertices (V,3) float64, faces (F,3) int64, flags (F,) uint8 (the output), only
 * (F,) uint8; *nv = V, *nf = F, *f32 the faces as int32 (malloc'd). 0 with the four buffers held, or -1 with an
 * exception set and none held. */
static int get_face_buffers(PyObject *ov, PyObject *of, PyObject *oo, PyObject *om, Py_buffer *bv, Py_buffer *bf,
                            Py_buffer *bo, Py_buffer *bm, int64_t *nv, int64_t *nf, int32_t **f32) {
    if (PyObject_GetBuffer(ov, bv, PyBUF_C_CONTIGUOUS) < 0) return -1;
    if (bv->itemsize != 8 || bv->len % 24) {
        PyBuffer_Release(bv);
        PyErr_SetString(PyExc_ValueError, "vertices: (V,3) float64");
        return -1;
    }
    if (PyObject_GetBuffer(of, bf, PyBUF_C_CONTIGUOUS) < 0) {
        PyBuffer_Release(bv);
        return -1;
    }
    if (bf->itemsize != 8 || bf->len % 24) {
        PyBuffer_Release(bv);
        PyBuffer_Release(bf);
        PyErr_SetString(PyExc_ValueError, "faces: (F,3) int64");
        return -1;
    }
    *nv = bv->len / 24;
    *nf = bf->len / 24;
    if (get_buffer(oo, bo, 1, *nf, "flags") < 0) {
        PyBuffer_Release(bv);
        PyBuffer_Release(bf);
        return -1;
    }
    if (get_buffer(om, bm, 1, *nf, "only") < 0) {
        PyBuffer_Release(bv);
        PyBuffer_Release(bf);
        PyBuffer_Release(bo);
        return -1;
    }
    const int64_t *f = (const int64_t *)bf->buf;
    int32_t *out = (int32_t *)malloc(sizeof(int32_t) * (size_t)(3 * *nf > 0 ? 3 * *nf : 1));
    const char *problem = out ? NULL : "memory";
    if (out && *nv > INT32_MAX) problem = "faces: more than 2^31 - 1 vertices";
    for (int64_t i = 0; out && !problem && i < 3 * *nf; i++) {
        if (f[i] < 0 || f[i] >= *nv) problem = "faces: index out of range";
        out[i] = (int32_t)f[i];
    }
    if (problem) {
        free(out);
        PyBuffer_Release(bv);
        PyBuffer_Release(bf);
        PyBuffer_Release(bo);
        PyBuffer_Release(bm);
        if (out) PyErr_SetString(PyExc_ValueError, problem);
        else PyErr_NoMemory();
        return -1;
    }
    *f32 = out;
    return 0;
}

/* The end of every entry point: the buffers released, status returned (-1: out of memory). */
static PyObject *face_check_result(Py_buffer *bv, Py_buffer *bf, Py_buffer *bo, Py_buffer *bm, int32_t *f32,
                                   int status) {
    free(f32);
    PyBuffer_Release(bv);
    PyBuffer_Release(bf);
    PyBuffer_Release(bo);
    PyBuffer_Release(bm);
    if (status < 0) return PyErr_NoMemory();
    return PyLong_FromLong(status);
}

static PyObject *faces_flags(PyObject *self, PyObject *args) {
    Py_buffer bv, bf, bo, bm;
    int64_t nv, nf;
    int32_t *f32;
    PyObject *ov, *of, *oo, *om;
    int threads = 1, status;
    if (!PyArg_ParseTuple(args, "OOOO|i", &ov, &of, &oo, &om, &threads)) return NULL;
    if (get_face_buffers(ov, of, oo, om, &bv, &bf, &bo, &bm, &nv, &nf, &f32) < 0) return NULL;
    Py_BEGIN_ALLOW_THREADS;
    status = tw_crossings_grid((const double *)bv.buf, (size_t)nv, f32, (size_t)nf, (const uint8_t *)bm.buf, threads,
                               (uint8_t *)bo.buf);
    Py_END_ALLOW_THREADS;
    return face_check_result(&bv, &bf, &bo, &bm, f32, status);
}

static PyObject *marked_flags(PyObject *self, PyObject *args) {
    Py_buffer bv, bf, bo, bm;
    int64_t nv, nf;
    int32_t *f32;
    PyObject *ov, *of, *oo, *om;
    int threads = 1, status;
    if (!PyArg_ParseTuple(args, "OOOO|i", &ov, &of, &oo, &om, &threads)) return NULL;
    if (get_face_buffers(ov, of, oo, om, &bv, &bf, &bo, &bm, &nv, &nf, &f32) < 0) return NULL;
    Py_BEGIN_ALLOW_THREADS;
    status = tw_crossings_marked((const double *)bv.buf, (size_t)nv, f32, (size_t)nf, (const uint8_t *)bm.buf,
                                 threads, (uint8_t *)bo.buf);
    Py_END_ALLOW_THREADS;
    return face_check_result(&bv, &bf, &bo, &bm, f32, status);
}

static PyObject *stars_flags(PyObject *self, PyObject *args) {
    PyObject *ov, *of, *oo, *om;
    int group, threads = 1, status;
    if (!PyArg_ParseTuple(args, "OOOOi|i", &ov, &of, &oo, &om, &group, &threads)) return NULL;
    if (group != 1 && group != 4) {
        PyErr_SetString(PyExc_ValueError, "children: 1 or 4");
        return NULL;
    }
    Py_buffer bv, bf, bo, bm;
    int64_t nv, nf;
    int32_t *f32;
    if (get_face_buffers(ov, of, oo, om, &bv, &bf, &bo, &bm, &nv, &nf, &f32) < 0) return NULL;
    Py_BEGIN_ALLOW_THREADS;
    status = tw_crossings_stars((const double *)bv.buf, (size_t)nv, f32, (size_t)nf, (const uint8_t *)bm.buf, group,
                                threads, (uint8_t *)bo.buf);
    Py_END_ALLOW_THREADS;
    return face_check_result(&bv, &bf, &bo, &bm, f32, status);
}

static PyMethodDef methods[] = {
    {"stars", stars_flags, METH_VARARGS, "Flags of a first check through vertex patches (decoder/intersect.c)."},
    {"faces", faces_flags, METH_VARARGS, "Flags of self-intersecting faces (geometry.intersections)."},
    {"marked", marked_flags, METH_VARARGS, "Flags of a later check whose changed faces are marked (see above)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_intersect_native", NULL, -1, methods};

PyMODINIT_FUNC PyInit__intersect_native(void) { return PyModule_Create(&module); }
