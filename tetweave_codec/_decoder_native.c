/*
 * _decoder_native.c -- the Python binding of the decoder core (decoder/tetweave_decoder.h, decoder/decode.c).
 *
 * One call per decode: decode(data: bytes, level: int, threads: int) -> (status, message, result). status is the
 * core's tw_status (0: ok); on failure result is None and message the core's one line. On success result is a
 * dict of bytes objects (native-endian arrays, wrapped by tetweave_codec/decoder.py without copying) and ints:
 *   "vertices" (V*3 float64), "faces" (F*3 int32): the decoded mesh in the input's frame;
 *   "closed_vertices", "closed_faces": the surface before the holes were opened (absent without a holes section:
 *   the mesh is that surface); "extracted_faces" (F0*3 int32): the control surface's faces;
 *   "points", "tets", "restored", "gave_up", "level", "smoothing", "subdivision": tw_decode_stats;
 *   header fields "flags", "sh_degree", "position_bits", "creases", "file_smoothing", "file_subdivision",
 *   "holes" (K), "scale" (float), "offset" (3 floats).
 * The GIL is released while the core runs. No kernel code lives here.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include "../decoder/internal.h"

static PyObject *bytes_of(const void *data, size_t size) {
    return PyBytes_FromStringAndSize(size ? (const char *)data : "", (Py_ssize_t)size);
}

static int put(PyObject *dict, const char *key, PyObject *value) {
    if (!value) return -1;
    int rc = PyDict_SetItemString(dict, key, value);
    Py_DECREF(value);
    return rc;
}

static int put_surface(PyObject *dict, const char *vkey, const char *fkey, const tw_surface *s) {
    if (vkey && put(dict, vkey, bytes_of(s->v, s->nv * 3 * sizeof(double)))) return -1;
    return put(dict, fkey, bytes_of(s->f, s->nf * 3 * sizeof(int32_t)));
}

static PyObject *py_decode(PyObject *self, PyObject *args) {
    Py_buffer data;
    int level, threads;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*ii", &data, &level, &threads)) return NULL;
    tw_decode_options options = tw_default_options();
    options.level = level;
    options.threads = threads;
    tw_decode_detail detail;
    tw_error err;
    memset(&err, 0, sizeof err);
    int status;
    if (level < TW_LEVEL_CONTROL || level > TW_LEVEL_FULL || threads < 1) {
        status = tw_fail(&err, TW_ERROR_ARGUMENT, "bad level %d or threads %d", level, threads);
    } else {
        Py_BEGIN_ALLOW_THREADS
        status = tw_decode_detailed((const unsigned char *)data.buf, (size_t)data.len, &options, &detail, &err);
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&data);
    if (status) return Py_BuildValue("(isO)", status, err.message, Py_None);
    PyObject *out = PyDict_New();
    const tw_file *f = &detail.file;
    const tw_decode_stats *st = &detail.stats;
    int bad = !out;
    if (!bad) bad = put_surface(out, "vertices", "faces", tw_decoded_mesh(&detail));
    if (!bad && f->hole_count) bad = put_surface(out, "closed_vertices", "closed_faces", &detail.closed);
    if (!bad) bad = put_surface(out, NULL, "extracted_faces", &detail.control);
    if (!bad) bad = put(out, "points", PyLong_FromUnsignedLong(st->points));
    if (!bad) bad = put(out, "tets", PyLong_FromUnsignedLongLong(st->tets));
    if (!bad) bad = put(out, "restored", PyLong_FromUnsignedLongLong(st->restored));
    if (!bad) bad = put(out, "gave_up", PyLong_FromLong(st->gave_up));
    if (!bad) bad = put(out, "level", PyLong_FromLong(st->level));
    if (!bad) bad = put(out, "smoothing", PyLong_FromLong(st->smoothing));
    if (!bad) bad = put(out, "subdivision", PyLong_FromLong(st->subdivision));
    if (!bad) bad = put(out, "flags", PyLong_FromLong(f->flags));
    if (!bad) bad = put(out, "sh_degree", PyLong_FromLong(f->sh_degree));
    if (!bad) bad = put(out, "position_bits", PyLong_FromLong(f->position_bits));
    if (!bad) bad = put(out, "creases", PyLong_FromLong(f->creases));
    if (!bad) bad = put(out, "file_smoothing", PyLong_FromLong(f->smoothing));
    if (!bad) bad = put(out, "file_subdivision", PyLong_FromLong(f->subdivision));
    if (!bad) bad = put(out, "holes", PyLong_FromSize_t(f->hole_count));
    if (!bad) bad = put(out, "scale", PyFloat_FromDouble(f->scale));
    if (!bad) bad = put(out, "offset", Py_BuildValue("(ddd)", f->offset[0], f->offset[1], f->offset[2]));
    tw_decode_detail_free(&detail);
    if (bad) {
        Py_XDECREF(out);
        return NULL;
    }
    return Py_BuildValue("(isN)", 0, "", out);
}

static PyMethodDef methods[] = {
    {"decode", py_decode, METH_VARARGS, "decode(data, level, threads) -> (status, message, result or None)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_decoder_native",
                                    "Binding of the C decoder core (decoder/).", -1, methods};

PyMODINIT_FUNC PyInit__decoder_native(void) { return PyModule_Create(&module); }
