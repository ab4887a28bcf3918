/* The referee's look at every pair of a sample (world.referee.Referee.sample), compiled.

   pair_scan(q, r, R, live, obstacles, freezes) -> (min_rr, min_ro, inside, frozen)

   q: the poses, n x 3 float64 (x, y, theta), C-contiguous; r, R: n float64; live: n bool; obstacles: m x 4
   float64 (x, y, radius, ...); freezes: whether a robot inside R_j of another live robot j is frozen (the
   paper's law; a user's law never freezes). Returns the smallest centre distance of two robots (inf below two
   robots), the smallest centre distance of a robot to an obstacle's centre (inf without one), the pairs
   (i, j) of robots closer than max(r_i, r_j) with i < j and the pairs (i, n + m) of a robot inside obstacle m,
   in that order, and which robots are frozen (n bytes, 0 or 1). A distance that is not a number (a pose that is
   not) is passed over by the minimums and makes no pair, as in the numpy.

   The same floats as the numpy of Referee.sample, in the same operations (setup.py compiles it without fused
   multiply-add): tests/unit/test_referee_compiled.py holds the two to the same answers. The world runs it
   every lock-step tick, on the same 2 cores as 37 robots (docs/performance.md, "The world's part of a
   lock-step tick"). */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>

static int take(PyObject *o, Py_buffer *b, char fmt, Py_ssize_t itemsize, const char *what) {
    if (PyObject_GetBuffer(o, b, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
        return -1;
    if (b->itemsize != itemsize || b->format == NULL || b->format[0] != fmt || b->format[1] != '\0') {
        PyErr_Format(PyExc_TypeError, "pair_scan: %s must be a contiguous array of '%c', got format %s", what,
                     fmt, b->format ? b->format : "(none)");
        PyBuffer_Release(b);
        return -1;
    }
    return 0;
}

static PyObject *add_pair(PyObject *list, Py_ssize_t i, Py_ssize_t j) {
    PyObject *p = Py_BuildValue("(nn)", i, j);
    if (p == NULL || PyList_Append(list, p) < 0) {
        Py_XDECREF(p);
        return NULL;
    }
    Py_DECREF(p);
    return list;
}

static PyObject *pair_scan(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 6) {
        PyErr_SetString(PyExc_TypeError, "pair_scan(q, r, R, live, obstacles, freezes): 6 arguments");
        return NULL;
    }
    int freezes = PyObject_IsTrue(args[5]);
    if (freezes < 0)
        return NULL;
    Py_buffer bq, br, bR, bl, bo;
    if (take(args[0], &bq, 'd', 8, "q") < 0)
        return NULL;
    if (take(args[1], &br, 'd', 8, "r") < 0) {
        PyBuffer_Release(&bq);
        return NULL;
    }
    if (take(args[2], &bR, 'd', 8, "R") < 0) {
        PyBuffer_Release(&bq), PyBuffer_Release(&br);
        return NULL;
    }
    if (take(args[3], &bl, '?', 1, "live") < 0) {
        PyBuffer_Release(&bq), PyBuffer_Release(&br), PyBuffer_Release(&bR);
        return NULL;
    }
    if (take(args[4], &bo, 'd', 8, "obstacles") < 0) {
        PyBuffer_Release(&bq), PyBuffer_Release(&br), PyBuffer_Release(&bR), PyBuffer_Release(&bl);
        return NULL;
    }
    PyObject *out = NULL, *inside = NULL, *frozen = NULL;
    Py_ssize_t n = br.len / 8, m = bo.len / 32;
    if (bq.ndim != 2 || bq.shape[1] != 3 || bq.shape[0] != n || br.ndim != 1 || bR.ndim != 1 || bR.len != 8 * n ||
        bl.ndim != 1 || bl.len != n || bo.ndim != 2 || bo.shape[1] != 4 || bo.shape[0] != m) {
        PyErr_SetString(PyExc_ValueError, "pair_scan: q must be n x 3, r, R and live n long, obstacles m x 4");
        goto done;
    }
    const double *q = bq.buf, *r = br.buf, *R = bR.buf, *o = bo.buf;
    const unsigned char *live = bl.buf;
    inside = PyList_New(0);
    frozen = PyBytes_FromStringAndSize(NULL, n);
    if (inside == NULL || frozen == NULL)
        goto done;
    char *fz = PyBytes_AS_STRING(frozen);
    double min_rr = INFINITY, min_ro = INFINITY;
    for (Py_ssize_t i = 0; i < n; i++) {
        double xi = q[3 * i], yi = q[3 * i + 1];
        int fr = 0;
        for (Py_ssize_t j = 0; j < n; j++) {
            if (j == i)
                continue;
            double dx = xi - q[3 * j], dy = yi - q[3 * j + 1];
            double d2 = dx * dx + dy * dy;
            if (j > i) {
                double d = sqrt(d2);
                if (d < min_rr)
                    min_rr = d;
                if (d < (r[i] > r[j] ? r[i] : r[j]) && add_pair(inside, i, j) == NULL)
                    goto done;
            }
            if (live[j] && d2 < R[j] * R[j])
                fr = 1;
        }
        fz[i] = (char)(fr && live[i] && freezes);
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        double xi = q[3 * i], yi = q[3 * i + 1];
        for (Py_ssize_t k = 0; k < m; k++) {
            double dx = xi - o[4 * k], dy = yi - o[4 * k + 1];
            double d = sqrt(dx * dx + dy * dy);
            if (d < min_ro)
                min_ro = d;
            if (d < o[4 * k + 2] && add_pair(inside, i, n + k) == NULL)
                goto done;
        }
    }
    out = Py_BuildValue("(ddOO)", min_rr, min_ro, inside, frozen);
done:
    Py_XDECREF(inside);
    Py_XDECREF(frozen);
    PyBuffer_Release(&bq), PyBuffer_Release(&br), PyBuffer_Release(&bR), PyBuffer_Release(&bl),
        PyBuffer_Release(&bo);
    return out;
}

static PyMethodDef referee_methods[] = {
    {"pair_scan", (PyCFunction)(void (*)(void))pair_scan, METH_FASTCALL,
     "pair_scan(q, r, R, live, obstacles, freezes) -> (min_rr, min_ro, inside, frozen): world.referee's pairs"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef referee_module = {
    PyModuleDef_HEAD_INIT, "world._referee", "The referee's look at every pair of a sample, compiled.", -1,
    referee_methods,
};

PyMODINIT_FUNC PyInit__referee(void) { return PyModule_Create(&referee_module); }
