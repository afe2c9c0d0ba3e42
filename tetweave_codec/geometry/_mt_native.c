/* Compiled topology of marching tets (geometry/marching_tets.py `marching_tets_numpy` and `check_manifold` are the
 * reference and the fallback): integer work only, so the output equals the reference's exactly.
 *
 *   topology(tets, inside, n, active_table, triangle_table) -> (keys, faces, face_tets) as bytearrays of int64,
 *       or None when the packed sort keys would not fit 63 bits (the caller falls back)
 *       keys: the sorted unique keys lo * n + hi (lo < hi) of the active edges; faces (F, 3): per mixed tet in
 *       order, its triangles of triangle_table in order, as indices into keys; face_tets (F,): the tet of each.
 *   manifold(faces, num_vertices, closed) -> 0 ok, 1 degenerate triangle, 2 directed edge used twice, 3 edge
 *       without its twin (closed only), -1 not decided here (an index out of range, or keys beyond 63 bits).
 *
 * Both sort packed 64-bit keys with an LSD radix sort (the reference sorts the same packed keys with numpy).
 * Every index read from an input array is bounds-checked.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "_native_sort.h"

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
    const int64_t *tets = (const int64_t *)vt.buf, *active = (const int64_t *)va.buf, *tri = (const int64_t *)vr.buf;
    const uint8_t *inside = (const uint8_t *)vi.buf;
    const int64_t t_count = vt.len / 32;
    for (int i = 0; i < 16 * 2 * 3; i++)
        if (tri[i] < -1 || tri[i] > 5) {
            PyErr_SetString(PyExc_ValueError, "_mt_native: triangle table entry out of range");
            goto done;
        }
    /* per case code: its active local edges in order, the position of each local edge among them, its faces */
    int n_act[16], act[16][6], pos[16][6], n_tri[16], tri_row[16][2];
    for (int code = 0; code < 16; code++) {
        n_act[code] = n_tri[code] = 0;
        for (int e = 0; e < 6; e++) {
            pos[code][e] = active[6 * code + e] ? n_act[code] : -1;
            if (active[6 * code + e]) act[code][n_act[code]++] = e;
        }
        for (int h = 0; h < 2; h++)
            if (code != 0 && code != 15 && tri[6 * code + 3 * h] >= 0) tri_row[code][n_tri[code]++] = h;
        for (int q = 0; q < n_tri[code]; q++)
            for (int c = 0; c < 3; c++)
                if (tri[6 * code + 3 * tri_row[code][q] + c] < 0 || pos[code][tri[6 * code + 3 * tri_row[code][q] + c]] < 0) {
                    PyErr_SetString(PyExc_ValueError, "_mt_native: a table triangle on an inactive edge");
                    goto done;
                }
    }
    if (n > (1LL << 31)) { /* vertex indices in 32 bits, keys lo * n + hi in 62: the reference decides */
        result = Py_None;
        Py_INCREF(result);
        goto done;
    }
    uint8_t *codes = (uint8_t *)malloc((size_t)(t_count > 0 ? t_count : 1));
    if (!codes) {
        PyErr_NoMemory();
        goto done;
    }
    /* pass 1: check the indices, the case code of every tet, count the active edges and faces */
    int64_t m = 0, f_count = 0;
    for (int64_t t = 0; t < t_count; t++) {
        int code = 0;
        for (int k = 0; k < 4; k++) {
            int64_t v = tets[4 * t + k];
            if (v < 0 || v >= n) {
                free(codes);
                PyErr_SetString(PyExc_ValueError, "_mt_native: tet vertex index out of range");
                goto done;
            }
            code |= (inside[v] != 0) << k;
        }
        codes[t] = (uint8_t)code;
        m += n_act[code];
        f_count += n_tri[code];
    }
    if (m >= ((int64_t)1 << 32)) { /* occurrences are numbered in 32 bits here: the reference decides */
        free(codes);
        result = Py_None;
        Py_INCREF(result);
        goto done;
    }
    const size_t mm = (size_t)(m > 0 ? m : 1);
    uint32_t *lo_of = (uint32_t *)malloc(mm * sizeof(uint32_t)), *hi_of = (uint32_t *)malloc(mm * sizeof(uint32_t));
    /* little memory: every page first touched costs a fault, as much as the work on it */
    uint32_t *by_hi = (uint32_t *)malloc(mm * sizeof(uint32_t)), *by_key = (uint32_t *)malloc(mm * sizeof(uint32_t));
    int64_t *count = (int64_t *)malloc(((size_t)n + 1) * sizeof(int64_t));
    PyObject *o_keys = NULL, *o_faces = NULL, *o_ft = NULL;
    if (!lo_of || !hi_of || !by_hi || !by_key || !count) {
        PyErr_NoMemory();
        goto free_all;
    }
    /* pass 2: the end points lo < hi of every active edge, in tet-then-edge order */
    static const int edge_a[6] = {0, 0, 0, 1, 1, 2}, edge_b[6] = {1, 2, 3, 2, 3, 3};
    int64_t occ = 0;
    for (int64_t t = 0; t < t_count; t++) {
        const int64_t *v = tets + 4 * t;
        const int code = codes[t];
        for (int q = 0; q < n_act[code]; q++) {
            const int e = act[code][q];
            const int64_t a = v[edge_a[e]], b = v[edge_b[e]];
            lo_of[occ] = (uint32_t)(a < b ? a : b);
            hi_of[occ] = (uint32_t)(a < b ? b : a);
            occ++;
        }
    }
    /* the occurrences sorted by key lo * n + hi: two stable counting sorts, by hi then by lo */
    memset(count, 0, ((size_t)n + 1) * sizeof(int64_t));
    for (int64_t o = 0; o < m; o++) count[hi_of[o] + 1]++;
    for (int64_t v = 1; v <= n; v++) count[v] += count[v - 1];
    for (int64_t o = 0; o < m; o++) by_hi[count[hi_of[o]]++] = (uint32_t)o;
    memset(count, 0, ((size_t)n + 1) * sizeof(int64_t));
    for (int64_t o = 0; o < m; o++) count[lo_of[o] + 1]++;
    for (int64_t v = 1; v <= n; v++) count[v] += count[v - 1];
    for (int64_t r = 0; r < m; r++) by_key[count[lo_of[by_hi[r]]]++] = by_hi[r];
    /* unique keys in order (into a buffer of m keys, shrunk to u after: its untouched pages cost nothing);
     * inverse[occurrence] = rank of its key, in the memory of by_hi (no longer needed) */
    o_keys = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(8 * mm));
    if (!o_keys) goto free_all;
    int64_t *unique = (int64_t *)PyByteArray_AS_STRING(o_keys);
    uint32_t *inverse = by_hi;
    int64_t u = 0, previous = -1;
    for (int64_t r = 0; r < m; r++) {
        const uint32_t o = by_key[r];
        const int64_t key = (int64_t)lo_of[o] * n + hi_of[o];
        if (key != previous) unique[u++] = previous = key;
        inverse[o] = (uint32_t)(u - 1);
    }
    o_faces = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(24 * f_count));
    o_ft = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(8 * f_count));
    if (!o_faces || !o_ft || PyByteArray_Resize(o_keys, (Py_ssize_t)(8 * u))) {
        Py_CLEAR(o_keys);
        Py_XDECREF(o_faces);
        Py_XDECREF(o_ft);
        goto free_all;
    }
    int64_t *faces = (int64_t *)PyByteArray_AS_STRING(o_faces), *face_tets = (int64_t *)PyByteArray_AS_STRING(o_ft);
    /* pass 3: faces, per mixed tet its table triangles; local edge e is the tet's pos[code][e]-th occurrence */
    int64_t base = 0, f = 0;
    for (int64_t t = 0; t < t_count; t++) {
        const int code = codes[t];
        for (int q = 0; q < n_tri[code]; q++) {
            const int64_t *row = tri + 6 * code + 3 * tri_row[code][q];
            for (int c = 0; c < 3; c++) faces[3 * f + c] = (int64_t)inverse[base + pos[code][row[c]]];
            face_tets[f++] = t;
        }
        base += n_act[code];
    }
    result = Py_BuildValue("(NNN)", o_keys, o_faces, o_ft);
free_all:
    free(codes);
    free(lo_of);
    free(hi_of);
    free(by_hi);
    free(by_key);
    free(count);
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
    long status = 0;
    if (m % 3 || nv < 0 || nv > (1LL << 31) || bit_length(nv > 0 ? (uint64_t)nv * nv : 0) + 1 > 63) {
        status = -1;
        goto done;
    }
    for (int64_t i = 0; i < m; i++)
        if (faces[i] < 0 || faces[i] >= nv) {
            status = -1;
            goto done;
        }
    for (int64_t i = 0; i < m; i++) /* tail == head: the reference's first check */
        if (faces[i] == faces[i % 3 == 2 ? i - 2 : i + 1]) {
            status = 1;
            goto done;
        }
    if (m == 0) goto done;
    uint64_t *packed = (uint64_t *)malloc((size_t)m * sizeof(uint64_t));
    uint64_t *tmp = (uint64_t *)malloc((size_t)m * sizeof(uint64_t));
    if (!packed || !tmp) {
        free(packed);
        free(tmp);
        PyBuffer_Release(&vf);
        return PyErr_NoMemory();
    }
    for (int64_t i = 0; i < m; i++) {
        uint64_t tail = (uint64_t)faces[i], head = (uint64_t)faces[i % 3 == 2 ? i - 2 : i + 1];
        uint64_t forward = tail * (uint64_t)nv + head, backward = head * (uint64_t)nv + tail;
        packed[i] = ((forward < backward ? forward : backward) << 1) | (forward > backward);
    }
    radix_sort(packed, tmp, m, bit_length((uint64_t)nv * nv) + 1);
    for (int64_t i = 1; i < m && !status; i++)
        if (packed[i] == packed[i - 1]) status = 2;
    if (!status && closed) {
        if (m % 2) status = 3;
        for (int64_t i = 0; i + 1 < m && !status; i += 2)
            if ((packed[i] & 1) || (packed[i] | 1) != packed[i + 1]) status = 3;
    }
    free(packed);
    free(tmp);
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
    PyModuleDef_HEAD_INIT, "_mt_native", "Compiled topology of marching tets.", -1, methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__mt_native(void) { return PyModule_Create(&module); }
