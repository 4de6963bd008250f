/* liemef's online step in one call from Python (liemef.codegen._fast): a CPython extension, built once per
 * Python and compiler by the C engine, that calls a kernel's kernel_step (by its address) with the samples
 * read through the buffer protocol. A ctypes call of kernel_step converts seven arguments and the samples
 * must first be copied into a buffer by NumPy: 8-10 us of a 12 us step on a slow core, against a kernel of
 * 2-3 us. This one reads its arguments in a few nanoseconds each.
 *
 * step(ctl, x, xo, t, u, y, dt, gap) -> int
 *   ctl: (the address of a pointer to kernel_step, theta's address, S, m, p) as a tuple of ints (the pointer is
 *   the kernel's to change: its -O2 build replaces the first one), x and xo the addresses of the
 *   packed state in and of a buffer of S + 2 (m + p) doubles out (the samples are copied to xo + S, as
 *   kernel_step reads them: u, u, y, y, the samples held). Returns kernel_step's code (-2: an infinite sample,
 *   xo's state untouched), or FALLBACK (nothing done) if a sample is not a C-contiguous float64 vector of its
 *   length (None for a length of 0), or t is not a finite number, or dt not a finite number > 0: the caller
 *   then takes its checked path, which names what is wrong. No Python exception leaves this function.
 *
 * leaves(x, spec) -> list
 *   The leaves of the FilterState packed in x (a C-contiguous float64 array), by spec: one (kind, offset, shape,
 *   typenum) per leaf, kind 0 a float64 view of x, 1 a float64 scalar, 2 a scalar of typenum, 3 an array of
 *   typenum (a copy): the objects NumPy's indexing and astype give (views keep x's memory alive), at a tenth of
 *   their cost. Integer and boolean leaves are stored as doubles holding their exact values.
 *
 * state(x, spec, tree) -> object
 *   The FilterState itself: leaves(x, spec) put into tree, where a node is a leaf's index (an int), a tuple
 *   (None, None, kids) for a tuple of kids, or (cls, names, kids) for object.__new__(cls) with each
 *   names[k] set to kids[k] by object.__setattr__: what a generated Python reader does with them.
 *
 * step_state(ctl, x, xo, t, u, y, dt, gap, xrow, spec, tree) -> object
 *   step(...), then, if it stepped (a code >= 0), state(xrow, spec, tree) of the new state (xrow: the array
 *   whose memory is xo's state); else step's negative code. One call for flt.step. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>
#include <math.h>
#include <string.h>

#define FALLBACK -1000

typedef int (*kernel_step_fn)(const double *, const double *, double *, double, double, double, const double *);

/* the n doubles of sample v into z (twice: at z and at z + n): 1, or 0 if v is not such a vector */
static int take(PyObject *v, double *z, Py_ssize_t n)
{
    if (n == 0 && v == Py_None) return 1;
    Py_buffer b;
    if (PyObject_GetBuffer(v, &b, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) != 0) {
        PyErr_Clear();
        return 0;
    }
    int ok = b.ndim == 1 && b.shape != NULL && b.shape[0] == n && b.itemsize == 8 && b.format != NULL
             && strcmp(b.format, "d") == 0;
    if (ok && n > 0) {
        memcpy(z, b.buf, (size_t)n * sizeof(double));
        memcpy(z + n, b.buf, (size_t)n * sizeof(double));
    }
    PyBuffer_Release(&b);
    return ok;
}

static int number(PyObject *v, double *out)
{
    if (PyFloat_CheckExact(v)) {
        *out = PyFloat_AS_DOUBLE(v);
        return 1;
    }
    if (!(PyFloat_Check(v) || PyLong_Check(v))) return 0; /* np.float64 is a float; a bool is an int */
    *out = PyFloat_AsDouble(v);
    if (*out == -1.0 && PyErr_Occurred()) {
        PyErr_Clear();
        return 0;
    }
    return 1;
}

static PyObject *fallback(void) { return PyLong_FromLong(FALLBACK); }

static PyObject *step(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 8 || !PyTuple_CheckExact(args[0]) || PyTuple_GET_SIZE(args[0]) != 5) return fallback();
    PyObject *ctl = args[0];
    void *const *cell = (void *const *)PyLong_AsVoidPtr(PyTuple_GET_ITEM(ctl, 0));
    const double *theta = (const double *)PyLong_AsVoidPtr(PyTuple_GET_ITEM(ctl, 1));
    Py_ssize_t S = PyLong_AsSsize_t(PyTuple_GET_ITEM(ctl, 2));
    Py_ssize_t m = PyLong_AsSsize_t(PyTuple_GET_ITEM(ctl, 3));
    Py_ssize_t p = PyLong_AsSsize_t(PyTuple_GET_ITEM(ctl, 4));
    const double *x = (const double *)PyLong_AsVoidPtr(args[1]);
    double *xo = (double *)PyLong_AsVoidPtr(args[2]);
    if (PyErr_Occurred() || cell == NULL || *cell == NULL || x == NULL || xo == NULL) {
        PyErr_Clear();
        return fallback();
    }
    void *fn = *cell;
    double t, dt, gap;
    if (!number(args[3], &t) || !number(args[6], &dt) || !number(args[7], &gap) || !isfinite(t)
        || !isfinite(dt) || !(dt > 0))
        return fallback();
    double *z = xo + S;
    if (!take(args[4], z, m) || !take(args[5], z + 2 * m, p)) return fallback();
    int code = ((kernel_step_fn)fn)(theta, x, xo, t, dt, gap, z);
    return PyLong_FromLong(code);
}

/* the value v (an exact integer or boolean held as a double) as typenum at out; 0 for an unsupported type */
static int put(int typenum, double v, void *out)
{
    switch (typenum) {
    case NPY_BOOL: *(npy_bool *)out = v != 0; return 1;
    case NPY_INT32: *(npy_int32 *)out = (npy_int32)v; return 1;
    case NPY_INT64: *(npy_int64 *)out = (npy_int64)v; return 1;
    default: return 0;
    }
}

static PyObject *leaf(PyArrayObject *x, const double *data, Py_ssize_t size, PyObject *item)
{
    long kind, typenum;
    Py_ssize_t off;
    PyObject *shape;
    if (!PyTuple_Check(item) || PyTuple_GET_SIZE(item) != 4 || !PyTuple_Check(PyTuple_GET_ITEM(item, 2)))
        return PyErr_Format(PyExc_ValueError, "leaves: a spec item is (kind, offset, shape, typenum)");
    kind = PyLong_AsLong(PyTuple_GET_ITEM(item, 0));
    off = PyLong_AsSsize_t(PyTuple_GET_ITEM(item, 1));
    shape = PyTuple_GET_ITEM(item, 2);
    typenum = PyLong_AsLong(PyTuple_GET_ITEM(item, 3));
    if (PyErr_Occurred()) return NULL;
    int nd = (int)PyTuple_GET_SIZE(shape);
    npy_intp dims[NPY_MAXDIMS];
    Py_ssize_t n = 1;
    if (nd > NPY_MAXDIMS) return PyErr_Format(PyExc_ValueError, "leaves: a leaf of %d dimensions", nd);
    for (int i = 0; i < nd; i++) {
        dims[i] = PyLong_AsSsize_t(PyTuple_GET_ITEM(shape, i));
        if (dims[i] < 0) return PyErr_Occurred() ? NULL : PyErr_Format(PyExc_ValueError, "leaves: bad shape");
        n *= dims[i];
    }
    if (off < 0 || off + n > size) return PyErr_Format(PyExc_ValueError, "leaves: a leaf past the state");
    const double *at = data + off;
    if (kind == 0) {
        PyObject *v = PyArray_NewFromDescr(&PyArray_Type, PyArray_DescrFromType(NPY_DOUBLE), nd, dims, NULL,
                                           (void *)at, NPY_ARRAY_CARRAY, NULL);
        if (v == NULL) return NULL;
        Py_INCREF(x);
        if (PyArray_SetBaseObject((PyArrayObject *)v, (PyObject *)x) != 0) {
            Py_DECREF(v);
            return NULL;
        }
        return v;
    }
    if (kind == 1) {
        PyArray_Descr *d = PyArray_DescrFromType(NPY_DOUBLE);
        PyObject *v = PyArray_Scalar((void *)at, d, NULL);
        Py_DECREF(d);
        return v;
    }
    char buf[16];
    if (kind == 2) {
        if (!put((int)typenum, *at, buf)) return PyErr_Format(PyExc_ValueError, "leaves: type %ld", typenum);
        PyArray_Descr *d = PyArray_DescrFromType((int)typenum);
        PyObject *v = PyArray_Scalar(buf, d, NULL);
        Py_DECREF(d);
        return v;
    }
    if (kind == 3) {
        PyObject *v = PyArray_SimpleNew(nd, dims, (int)typenum);
        if (v == NULL) return NULL;
        char *out = PyArray_BYTES((PyArrayObject *)v);
        npy_intp step = PyArray_ITEMSIZE((PyArrayObject *)v);
        for (Py_ssize_t i = 0; i < n; i++)
            if (!put((int)typenum, at[i], out + i * step)) {
                Py_DECREF(v);
                return PyErr_Format(PyExc_ValueError, "leaves: type %ld", typenum);
            }
        return v;
    }
    return PyErr_Format(PyExc_ValueError, "leaves: kind %ld", kind);
}

static PyObject *leaves(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 2 || !PyArray_Check(args[0]) || !PyTuple_Check(args[1]))
        return PyErr_Format(PyExc_TypeError, "leaves(x, spec): x an array, spec a tuple");
    PyArrayObject *x = (PyArrayObject *)args[0];
    if (PyArray_TYPE(x) != NPY_DOUBLE || !PyArray_IS_C_CONTIGUOUS(x) || PyArray_NDIM(x) != 1)
        return PyErr_Format(PyExc_ValueError, "leaves: x must be a C-contiguous float64 vector");
    PyObject *spec = args[1];
    Py_ssize_t k = PyTuple_GET_SIZE(spec);
    PyObject *out = PyList_New(k);
    if (out == NULL) return NULL;
    const double *data = (const double *)PyArray_DATA(x);
    Py_ssize_t size = PyArray_SIZE(x);
    for (Py_ssize_t i = 0; i < k; i++) {
        PyObject *v = leaf(x, data, size, PyTuple_GET_ITEM(spec, i));
        if (v == NULL) {
            Py_DECREF(out);
            return NULL;
        }
        PyList_SET_ITEM(out, i, v);
    }
    return out;
}

static PyObject *build(PyObject *tree, PyObject *leaves, PyObject *empty)
{
    if (PyLong_CheckExact(tree)) {
        Py_ssize_t i = PyLong_AsSsize_t(tree);
        if (i < 0 || i >= PyList_GET_SIZE(leaves))
            return PyErr_Occurred() ? NULL : PyErr_Format(PyExc_ValueError, "state: a leaf index out of range");
        PyObject *v = PyList_GET_ITEM(leaves, i);
        Py_INCREF(v);
        return v;
    }
    if (!PyTuple_Check(tree) || PyTuple_GET_SIZE(tree) != 3 || !PyTuple_Check(PyTuple_GET_ITEM(tree, 2)))
        return PyErr_Format(PyExc_ValueError, "state: a node is an index or (cls, names, kids)");
    PyObject *cls = PyTuple_GET_ITEM(tree, 0), *names = PyTuple_GET_ITEM(tree, 1), *kids = PyTuple_GET_ITEM(tree, 2);
    Py_ssize_t n = PyTuple_GET_SIZE(kids);
    if (cls == Py_None) {
        PyObject *out = PyTuple_New(n);
        for (Py_ssize_t k = 0; out != NULL && k < n; k++) {
            PyObject *v = build(PyTuple_GET_ITEM(kids, k), leaves, empty);
            if (v == NULL) Py_CLEAR(out);
            else PyTuple_SET_ITEM(out, k, v);
        }
        return out;
    }
    if (!PyType_Check(cls) || !PyTuple_Check(names) || PyTuple_GET_SIZE(names) != n)
        return PyErr_Format(PyExc_ValueError, "state: a node (cls, names, kids) with a type and a name per kid");
    /* object.__new__(cls), then each field as object.__setattr__ sets it (the class's own __setattr__, frozen,
     * is not called): in field order, the attributes go to the instance's shared-key values as __init__ leaves
     * them, without a dict of their own */
    PyObject *obj = PyBaseObject_Type.tp_new((PyTypeObject *)cls, empty, NULL);
    for (Py_ssize_t k = 0; obj != NULL && k < n; k++) {
        PyObject *v = build(PyTuple_GET_ITEM(kids, k), leaves, empty);
        if (v == NULL || PyObject_GenericSetAttr(obj, PyTuple_GET_ITEM(names, k), v) != 0) Py_CLEAR(obj);
        Py_XDECREF(v);
    }
    return obj;
}

static PyObject *state(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 3) return PyErr_Format(PyExc_TypeError, "state(x, spec, tree)");
    PyObject *got = leaves(self, args, 2);
    if (got == NULL) return NULL;
    PyObject *empty = PyTuple_New(0);
    PyObject *out = empty != NULL ? build(args[2], got, empty) : NULL;
    Py_XDECREF(empty);
    Py_DECREF(got);
    return out;
}

/* step(...) and then, if it stepped (a status code >= 0), state(xrow, spec, tree) of the new state: one call */
static PyObject *step_state(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 11) return fallback();
    PyObject *code = step(self, args, 8);
    if (code == NULL) return NULL;
    long c = PyLong_AsLong(code);
    if (c < 0) return code; /* FALLBACK or -2: the caller's checked path */
    Py_DECREF(code);
    return state(self, args + 8, 3);
}

static PyMethodDef methods[] = {
    {"state", (PyCFunction)(void (*)(void))state, METH_FASTCALL, "A packed FilterState, made."},
    {"step", (PyCFunction)(void (*)(void))step, METH_FASTCALL, "One online step by a kernel's kernel_step."},
    {"leaves", (PyCFunction)(void (*)(void))leaves, METH_FASTCALL, "The leaves of a packed FilterState."},
    {"step_state", (PyCFunction)(void (*)(void))step_state, METH_FASTCALL, "step, then state of the new row."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_liemef_fast_step", NULL, -1, methods,
                                    NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__liemef_fast_step(void)
{
    import_array();
    PyObject *mod = PyModule_Create(&module);
    if (mod != NULL && PyModule_AddIntConstant(mod, "FALLBACK", FALLBACK) != 0) {
        Py_DECREF(mod);
        return NULL;
    }
    return mod;
}
