/* Python binding of marching tets' integer topology in the decoder core (decoder/marching.c: tw_mt_tables_init,
 * tw_mt_topology, tw_manifold_defect); geometry/marching_tets.py `marching_tets_numpy` and `check_manifold` are the
 * reference and the fallback. Integer work only, so the output equals the reference's exactly.
 *
 *   topology(tets, inside, n, active_table, triangle_table) -> (keys, faces, face_tets) as bytearrays of int64,
 *       or None when the work would not fit the core's 32-bit numbering (the caller falls back)
 *       keys: the sorted unique keys lo * n + hi (lo < hi) of the active edges; faces (F, 3): per mixed tet in
 *       order, its triangles of triangle_table in order, as indices into keys; face_tets (F,): the tet of each.
 *   manifold(faces, num_vertices, closed) -> 0 ok, 1 degenerate triangle, 2 directed edge used twice, 3 edge
 *       without its twin (closed only), -1 not decided here (an index out of range, or keys beyond 63 bits).
 *
 * The binding checks the buffers and every index, narrows the int64 indices to the core's int32 and widens the
 * results back.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

static int get_buffer(PyObject *obj, Py_buffer *view, int itemsize, Py_ssize_t count, const char *name) {
    if (PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) != 0) return -1;
    const char *f = view->format ? view->format : "B";
    if (*f == '<' || *f == '=' || *f == '@') f++;
    int ok = view->itemsize == itemsize && f[1] == '\0' &&
             (itemsize == 8 ? (f[0] == 'q' || f[0] == 'l') : (f[0] == '?' || f[0] == 'B'));
    if (!ok || (count >= 0 && view->len != count * itemsize)) {
        PyBuffer_Release(view);
        PyErr_Format(PyExc_ValueError, "_mt_native: %s has the wrong type or size", name);
        return -1;
    }
    return 0;
}

/* int64 indices (each checked in [0, n)) narrowed to int32; NULL with a Python error set on failure */
static int32_t *narrow_indices(const int64_t *src, int64_t count, int64_t n, const char *what) {
    int32_t *dst = malloc((size_t)(count > 0 ? count : 1) * sizeof(int32_t));
    if (!dst) {
        PyErr_NoMemory();
        return NULL;
    }
    for (int64_t i = 0; i < count; i++) {
        if (src[i] < 0 || src[i] >= n) {
            free(dst);
            PyErr_Format(PyExc_ValueError, "_mt_native: %s index out of range", what);
            return NULL;
        }
        dst[i] = (int32_t)src[i];
    }
    return dst;
}

static PyObject *topology(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *o_tets, *o_inside, *o_active, *o_tri, *result = NULL;
    Py_ssize_t n;
    if (!PyArg_ParseTuple(args, "OOnOO", &o_tets, &o_inside, &n, &o_active, &o_tri)) return NULL;
    Py_buffer vt, vi, va, vr;
    if (get_buffer(o_inside, &vi, 1, n, "inside")) return NULL;
    if (get_buffer(o_tets, &vt, 8, -1, "tets")) goto fail_i;
    if (vt.len % 32) {
        PyErr_SetString(PyExc_ValueError, "_mt_native: tets must be (T, 4)");
        goto fail_t;
    }
    if (get_buffer(o_active, &va, 8, 16 * 6, "active_table")) goto fail_t;
    if (get_buffer(o_tri, &vr, 8, 16 * 2 * 3, "triangle_table")) goto fail_a;
    tw_error err = {0, {0}};
    tw_mt_tables tables;
    if (tw_mt_tables_init(&tables, (const int64_t *)va.buf, (const int64_t *)vr.buf, &err)) {
        PyErr_Format(PyExc_ValueError, "_mt_native: %s", err.message);
        goto done;
    }
    if (n > (1LL << 31)) { /* vertex indices in 32 bits: the reference decides */
        result = Py_None;
        Py_INCREF(result);
        goto done;
    }
    const int64_t t_count = vt.len / 32;
    int32_t *tets = narrow_indices((const int64_t *)vt.buf, 4 * t_count, n, "tet vertex");
    if (!tets) goto done;
    tw_mt_topo topo;
    int status = tw_mt_topology(tets, (size_t)t_count, (const uint8_t *)vi.buf, (size_t)n, &tables, &topo, &err);
    free(tets);
    if (status == TW_ERROR_LIMIT) { /* the reference decides */
        result = Py_None;
        Py_INCREF(result);
        goto done;
    }
    if (status) {
        if (status == TW_ERROR_MEMORY)
            PyErr_NoMemory();
        else
            PyErr_Format(PyExc_ValueError, "_mt_native: %s", err.message);
        goto done;
    }
    PyObject *o_keys = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(8 * topo.nu));
    PyObject *o_faces = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(24 * topo.nf));
    PyObject *o_ft = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(8 * topo.nf));
    if (o_keys && o_faces && o_ft) {
        int64_t *keys = (int64_t *)PyByteArray_AS_STRING(o_keys);
        int64_t *faces = (int64_t *)PyByteArray_AS_STRING(o_faces), *ft = (int64_t *)PyByteArray_AS_STRING(o_ft);
        for (size_t k = 0; k < topo.nu; k++) keys[k] = (int64_t)topo.lo[k] * n + topo.hi[k];
        for (size_t k = 0; k < 3 * topo.nf; k++) faces[k] = topo.faces[k];
        for (size_t k = 0; k < topo.nf; k++) ft[k] = topo.face_tets[k];
        result = Py_BuildValue("(NNN)", o_keys, o_faces, o_ft);
    } else {
        Py_XDECREF(o_keys);
        Py_XDECREF(o_faces);
        Py_XDECREF(o_ft);
    }
    tw_mt_topology_free(&topo);
done:
    PyBuffer_Release(&vr);
fail_a:
    PyBuffer_Release(&va);
fail_t:
    PyBuffer_Release(&vt);
fail_i:
    PyBuffer_Release(&vi);
    return result;
}

static PyObject *manifold(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *o_faces;
    Py_ssize_t nv;
    int closed;
    if (!PyArg_ParseTuple(args, "Onp", &o_faces, &nv, &closed)) return NULL;
    Py_buffer vf;
    if (get_buffer(o_faces, &vf, 8, -1, "faces")) return NULL;
    const int64_t *faces = (const int64_t *)vf.buf;
    const int64_t m = vf.len / 8;
    long status = -1;
    /* not decided here: a shape that is not (F, 3), keys beyond 63 bits, an index out of range */
    if (m % 3 || nv < 0 || nv >= (1LL << 31)) goto done;
    for (int64_t i = 0; i < m; i++)
        if (faces[i] < 0 || faces[i] >= nv) goto done;
    int32_t *narrow = narrow_indices(faces, m, nv, "face");
    if (!narrow) {
        PyBuffer_Release(&vf);
        return NULL;
    }
    tw_error err = {0, {0}};
    int defect = 0;
    int rc = tw_manifold_defect(narrow, (size_t)(m / 3), (size_t)nv, closed, &defect, &err);
    free(narrow);
    if (rc) {
        PyBuffer_Release(&vf);
        return rc == TW_ERROR_MEMORY ? PyErr_NoMemory() : PyErr_Format(PyExc_ValueError, "%s", err.message);
    }
    status = defect;
done:
    PyBuffer_Release(&vf);
    return PyLong_FromLong(status);
}

static PyMethodDef methods[] = {
    {"topology", topology, METH_VARARGS, "Active edges and faces of marching tets (marching_tets_numpy)."},
    {"manifold", manifold, METH_VARARGS, "The checks of marching_tets.check_manifold: 0 ok, 1-3 the defect."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_mt_native", "Compiled topology of marching tets (the core: decoder/marching.c).", -1,
    methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__mt_native(void) { return PyModule_Create(&module); }
