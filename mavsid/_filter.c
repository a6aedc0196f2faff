/* The recursion of an IIR filter, compiled: mavsid.numerics.filters.lfilter's loop over the
 * samples (the numerator's sum is numpy's). Optional: where the package is built without a C
 * compiler, mavsid.numerics.filters.lfilter runs the recursion through scipy.signal.lfilter
 * (the same numbers to rounding; tests/test_dsp.py compares both with scipy).
 *
 * recurse(a, y, n) -> None
 *   a  a readable buffer of p + 1 doubles, the denominator with a[0] = 1 (a[0] not read)
 *   y  a writable buffer of doubles: columns of n samples one after the other, each the
 *      right-hand side (the numerator's output) on entry and the filter's output on return:
 *      y[k] -= a[1] y[k-1] + ... + a[p] y[k-p] for k = 1 .. n-1, column by column
 *   n  the samples per column (y's length a multiple of it)
 * The loop runs without the GIL.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

static PyObject *recurse(PyObject *self, PyObject *args)
{
    Py_buffer a, y;
    Py_ssize_t n;
    if (!PyArg_ParseTuple(args, "y*w*n", &a, &y, &n))
        return NULL;
    PyObject *result = NULL;
    const Py_ssize_t p = a.len / (Py_ssize_t)sizeof(double) - 1;
    const Py_ssize_t total = y.len / (Py_ssize_t)sizeof(double);
    if (p < 0 || n < 1 || total % n != 0 || a.len % sizeof(double) || y.len % sizeof(double)) {
        PyErr_SetString(PyExc_ValueError, "recurse: a needs a[0], y whole columns of n doubles");
        goto done;
    }
    const double *c = (const double *)a.buf;
    double *v = (double *)y.buf;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t col = 0; col < total; col += n) {
        double *x = v + col;
        /* (the oldest term first, a[1] last) */
        if (p == 1) {
            const double a1 = c[1];
            for (Py_ssize_t k = 1; k < n; k++)
                x[k] -= a1 * x[k - 1];
        } else if (p == 2) {
            const double a1 = c[1], a2 = c[2];
            if (n > 1)
                x[1] -= a1 * x[0];
            for (Py_ssize_t k = 2; k < n; k++)
                x[k] = (x[k] - a2 * x[k - 2]) - a1 * x[k - 1];
        } else {
            for (Py_ssize_t k = 1; k < n; k++) {
                double s = x[k];
                for (Py_ssize_t j = k < p ? k : p; j >= 1; j--)
                    s -= c[j] * x[k - j];
                x[k] = s;
            }
        }
    }
    Py_END_ALLOW_THREADS
    Py_INCREF(Py_None);
    result = Py_None;
done:
    PyBuffer_Release(&a);
    PyBuffer_Release(&y);
    return result;
}

static PyMethodDef methods[] = {
    {"recurse", recurse, METH_VARARGS,
     "recurse(a, y, n) -> None: an IIR filter's recursion y[k] -= a[1] y[k-1] + ... + "
     "a[p] y[k-p], in place, on each column of n doubles of y."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_filter",
    "An IIR filter's recursion, compiled (mavsid.numerics.filters.lfilter)", -1,
    methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__filter(void)
{
    return PyModule_Create(&module);
}
