/* Compiled fast path of meshio's text writers (OBJ, OFF): the rows `_rows_text` formats with one %-call, the same
 * bytes (tests/test_meshio_text.py), ~10x faster. meshio.py stays the reference and the fallback (`meshio.NATIVE`,
 * environment TETWEAVE_NATIVE=0).
 *
 * float_rows(values (R,C) float64, prefix bytes, digits int) -> bytes: per row, prefix, then each value as
 *     Python's "%.{digits}f" writes it, separated by one space, then "\n".
 * int_rows(values (R,C) int64, prefix bytes, offset int) -> bytes: per row, prefix, then each value + offset as
 *     "%d" writes it, separated by one space, then "\n".
 *
 * "%.Nf" in Python is the correctly rounded decimal (round half to even on exact ties) of the binary64 value, with
 * a "-" for every negative value, -0.0 and those that round to zero included. Here: x = m 2^e exactly (m < 2^53,
 * an integer), the value times 10^N is m 10^N 2^e, an integer shifted right by -e bits and rounded half to even on
 * the bits shifted out, all in 128-bit integers; where that does not fit (N > 17, |x| >= 2^64, no 128-bit integer
 * type, NaN or infinity) the row goes through PyOS_double_to_string, Python's own routine.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#define MAX_FAST_DIGITS 17

typedef struct {
    char *buf;
    size_t len, cap;
} Out;

static int reserve(Out *o, size_t more) {
    if (o->len + more <= o->cap) return 0;
    size_t cap = o->cap ? o->cap : 1024;
    while (cap < o->len + more) cap *= 2;
    char *b = (char *)PyMem_Realloc(o->buf, cap);
    if (!b) return -1;
    o->buf = b;
    o->cap = cap;
    return 0;
}

/* the decimal digits of v (no sign) at p; returns their count */
static int put_u64(char *p, uint64_t v) {
    char tmp[20];
    int n = 0;
    do {
        tmp[n++] = (char)('0' + v % 10);
        v /= 10;
    } while (v);
    for (int i = 0; i < n; i++) p[i] = tmp[n - 1 - i];
    return n;
}

/* 10^digits (digits <= MAX_FAST_DIGITS) */
static uint64_t power_of_ten(int digits) {
    uint64_t p = 1;
    for (int i = 0; i < digits; i++) p *= 10;
    return p;
}

/* x as "%.{digits}f" at the end of o (room for 64 + digits bytes reserved by the caller), scale = 10^digits; 0, or 1
 * when not handled here */
static int put_fixed(Out *o, double x, int digits, uint64_t scale) {
#ifdef __SIZEOF_INT128__
    if (!isfinite(x) || digits > MAX_FAST_DIGITS || fabs(x) >= 18446744073709551616.0) return 1;
    int e;
    double frac = frexp(fabs(x), &e); /* |x| = frac 2^e, 0.5 <= frac < 1 */
    uint64_t m = (uint64_t)ldexp(frac, 53);
    e -= 53; /* |x| = m 2^e, exactly */
    unsigned __int128 p = (unsigned __int128)m * scale, n; /* < 2^53 10^17 < 2^110 */
    if (e >= 0) {
        if (e > 10) return 1; /* cannot happen below 2^64 with m >= 2^52; kept for the shift's sake */
        n = p << e;
    } else if (-e >= 120) { /* p < 2^110 < half of 2^-e: rounds to 0 */
        n = 0;
    } else {
        int s = -e;
        unsigned __int128 rem = p & ((((unsigned __int128)1) << s) - 1), half = ((unsigned __int128)1) << (s - 1);
        n = p >> s;
        if (rem > half || (rem == half && (n & 1))) n += 1;
    }
    uint64_t whole, part; /* part < 10^17: 64 bits; the 128-bit division only where n needs it */
    if (!(n >> 64)) {
        uint64_t n64 = (uint64_t)n;
        whole = n64 / scale;
        part = n64 % scale;
    } else {
        if ((n / scale) >> 64) return 1;
        whole = (uint64_t)(n / scale);
        part = (uint64_t)(n % scale);
    }
    char *q = o->buf + o->len;
    int k = 0;
    if (signbit(x)) q[k++] = '-';
    k += put_u64(q + k, whole);
    if (digits > 0) {
        q[k++] = '.';
        for (int i = digits - 1; i >= 0; i--) {
            q[k + i] = (char)('0' + (int)(part % 10));
            part /= 10;
        }
        k += digits;
    }
    o->len += (size_t)k;
    return 0;
#else
    (void)o;
    (void)x;
    (void)digits;
    (void)scale;
    return 1;
#endif
}

static int put_python_fixed(Out *o, double x, int digits) {
    char *s = PyOS_double_to_string(x, 'f', digits, 0, NULL);
    if (!s) return -1;
    size_t n = strlen(s);
    int r = reserve(o, n + 2);
    if (r == 0) {
        memcpy(o->buf + o->len, s, n);
        o->len += n;
    }
    PyMem_Free(s);
    return r;
}

/* The end of float_rows and int_rows: the bytes written (ok), or NULL with the error set (out of memory unless
 * another error is); the buffer and the rows freed either way. */
static PyObject *finish(Out *o, Py_buffer *view, int ok) {
    PyObject *out = NULL;
    if (ok) out = PyBytes_FromStringAndSize(o->buf ? o->buf : "", (Py_ssize_t)o->len);
    else if (!PyErr_Occurred()) PyErr_NoMemory();
    PyBuffer_Release(view);
    PyMem_Free(o->buf);
    return out;
}

static PyObject *float_rows(PyObject *self, PyObject *args) {
    PyObject *ov;
    const char *prefix;
    Py_ssize_t plen;
    int digits;
    if (!PyArg_ParseTuple(args, "Oy#i", &ov, &prefix, &plen, &digits)) return NULL;
    if (digits < 0 || digits > 300) {
        PyErr_SetString(PyExc_ValueError, "digits: 0 to 300");
        return NULL;
    }
    Py_buffer view;
    if (PyObject_GetBuffer(ov, &view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | PyBUF_ND) < 0) return NULL;
    if (view.itemsize != 8 || view.ndim != 2 || strcmp(view.format, "d") != 0) {
        PyBuffer_Release(&view);
        PyErr_SetString(PyExc_ValueError, "values: (R,C) float64");
        return NULL;
    }
    Py_ssize_t rows = view.shape[0], cols = view.shape[1];
    const double *v = (const double *)view.buf;
    uint64_t scale = power_of_ten(digits <= MAX_FAST_DIGITS ? digits : 0);
    Out o = {NULL, 0, 0};
    for (Py_ssize_t i = 0; i < rows; i++) {
        if (reserve(&o, (size_t)plen + (size_t)cols * (72 + (size_t)digits) + 1) < 0) goto nomem;
        memcpy(o.buf + o.len, prefix, (size_t)plen);
        o.len += (size_t)plen;
        for (Py_ssize_t j = 0; j < cols; j++) {
            if (j) o.buf[o.len++] = ' ';
            double x = v[i * cols + j];
            if (put_fixed(&o, x, digits, scale) && put_python_fixed(&o, x, digits) < 0) goto nomem;
            if (reserve(&o, 73 + (size_t)digits) < 0) goto nomem;
        }
        o.buf[o.len++] = '\n';
    }
    return finish(&o, &view, 1);
nomem:
    return finish(&o, &view, 0);
}

static PyObject *int_rows(PyObject *self, PyObject *args) {
    PyObject *ov;
    const char *prefix;
    Py_ssize_t plen;
    long long offset;
    if (!PyArg_ParseTuple(args, "Oy#L", &ov, &prefix, &plen, &offset)) return NULL;
    Py_buffer view;
    if (PyObject_GetBuffer(ov, &view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | PyBUF_ND) < 0) return NULL;
    if (view.itemsize != 8 || view.ndim != 2 || (strcmp(view.format, "q") != 0 && strcmp(view.format, "l") != 0)) {
        PyBuffer_Release(&view);
        PyErr_SetString(PyExc_ValueError, "values: (R,C) int64");
        return NULL;
    }
    Py_ssize_t rows = view.shape[0], cols = view.shape[1];
    const int64_t *v = (const int64_t *)view.buf;
    Out o = {NULL, 0, 0};
    for (Py_ssize_t i = 0; i < rows; i++) {
        if (reserve(&o, (size_t)plen + (size_t)cols * 22 + 1) < 0) goto nomem;
        memcpy(o.buf + o.len, prefix, (size_t)plen);
        o.len += (size_t)plen;
        for (Py_ssize_t j = 0; j < cols; j++) {
            if (j) o.buf[o.len++] = ' ';
            int64_t x = v[i * cols + j];
            if ((offset > 0 && x > INT64_MAX - offset) || (offset < 0 && x < INT64_MIN - offset)) {
                PyErr_SetString(PyExc_OverflowError, "int_rows: value + offset out of int64");
                return finish(&o, &view, 0);
            }
            x += offset;
            uint64_t u = (uint64_t)x;
            if (x < 0) {
                o.buf[o.len++] = '-';
                u = 0 - u;
            }
            o.len += (size_t)put_u64(o.buf + o.len, u);
        }
        o.buf[o.len++] = '\n';
    }
    return finish(&o, &view, 1);
nomem:
    return finish(&o, &view, 0);
}

static PyMethodDef methods[] = {
    {"float_rows", float_rows, METH_VARARGS, "Rows of '%.Nf' values (meshio._rows_text)."},
    {"int_rows", int_rows, METH_VARARGS, "Rows of '%d' values plus an offset (meshio._rows_text)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_text_native", NULL, -1, methods};

PyMODINIT_FUNC PyInit__text_native(void) { return PyModule_Create(&module); }
