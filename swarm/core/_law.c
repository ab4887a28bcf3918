/* swarm.core.law.robot_command compiled, for the robot process (docs/performance.md, "The compiled parts of a period").
 *
 * swarm/core/law.py stays the law: it is what the paper's equations are written as, what numba compiles for
 * the simulator, and what a robot runs where this file is not built. This is a line-for-line transcription of
 * its robot_command and the functions it calls, in the same order of floating-point operations, with the
 * same libm functions (exp, expm1, sin, cos, sqrt), no contraction into fused multiply-adds (setup.py:
 * -ffp-contract=off) and Python's own semantics where C differs (float %, min, max). The constants and
 * layouts come from law.py at import (configure()). tests/unit/test_law_compiled.py holds the two to the same
 * bits on every branch; a lock-step run stays identical to `swarm sim` (bench/up_parity.py). */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>

#define MAX_BODIES 4096

/* The constants of law.py (configure() sets them from the module; the values below are never used). */
static double PI, TWO_PI, LN2, COLLISION_EPS, GOVERNOR_FRACTION, MAX_SPEED, MAX_TURN;
static long THRESHOLD_OFF, THRESHOLD_FROZEN, KIND_ROBOT;
static Py_ssize_t P_K1, P_K2, P_K3, P_TU, P_VT, P_THRESHOLD, P_GOVERNOR, P_DT, P_SENSE, P_REACH, P_OBSTACLE_R,
    P_V_MAX, P_W_MAX, P_SIZE;
static Py_ssize_t M_FROZEN, M_SNAP_X, M_SNAP_Y, M_SNAP_TH, M_T_SNAP, M_EX, M_EY, M_ETH, M_SCALE, M_SIZE;
static int configured;

static double py_mod(double vx, double wx) { /* Python's float % (Objects/floatobject.c, float_rem) */
    double mod = fmod(vx, wx);
    if (mod) {
        if ((wx < 0) != (mod < 0))
            mod += wx;
    } else {
        mod = copysign(0.0, wx);
    }
    return mod;
}

/* math.cos and the others as Python's math module has them (Modules/mathmodule.c, math_1): a NaN from a
 * number that was not NaN is a domain error (ValueError), an infinity from a finite number a range error
 * (OverflowError for exp and expm1). The first error is kept; robot_command raises it where Python would. */
static int math_error; /* 0, 1: ValueError("math domain error"), 2: OverflowError("math range error") */

static double checked(double r, double x, int can_overflow) {
    if (math_error == 0) {
        if (isnan(r) && !isnan(x))
            math_error = 1;
        else if (isinf(r) && isfinite(x))
            math_error = can_overflow ? 2 : 1;
    }
    return r;
}

static double py_cos(double x) { return checked(cos(x), x, 0); }
static double py_sin(double x) { return checked(sin(x), x, 0); }
static double py_exp(double x) { return checked(exp(x), x, 1); }
static double py_expm1(double x) { return checked(expm1(x), x, 1); }
static double py_sqrt(double x) { return checked(sqrt(x), x, 0); }

static double py_min(double a, double b) { return b < a ? b : a; } /* min(a, b): the first unless b is less */
static double py_max(double a, double b) { return b > a ? b : a; }

static double wrap_angle(double a) {
    if (-PI < a && a <= PI)
        return a;
    double w = py_mod(a, TWO_PI);
    if (w > PI)
        w -= TWO_PI;
    return w;
}

static double potential_slope(double l, double r, double R) {
    if (l >= R)
        return 0.0;
    if (l < r + COLLISION_EPS)
        l = r + COLLISION_EPS;
    double d = l - R;
    double u = (l - r) / d;
    double b, one_minus_b;
    if (u < -LN2) { /* law.exp_pair */
        b = py_exp(u);
        one_minus_b = 1.0 - b;
    } else {
        double e = py_expm1(u);
        b = 1.0 + e;
        one_minus_b = -e;
    }
    if (b == 0.0)
        return 0.0;
    return b * (r - R) / (d * d * one_minus_b * one_minus_b);
}

static void repulsion_gradient(double xi, double yi, double xj, double yj, double r, double R, double *gx, double *gy) {
    double dx = xi - xj;
    double dy = yi - yj;
    double l = py_sqrt(dx * dx + dy * dy);
    if (l >= R) {
        *gx = 0.0;
        *gy = 0.0;
        return;
    }
    double s = potential_slope(l, r, R);
    if (l < 1e-12) {
        *gx = s;
        *gy = 0.0;
        return;
    }
    *gx = s * dx / l;
    *gy = s * dy / l;
}

static double sgn_gain(double vl) {
    if (vl > 0.0)
        return 1.0;
    if (vl < 0.0)
        return -1.0;
    return 1.0;
}

static void tracking_command(double x, double y, double th, double xd, double yd, double thd, double vl, double wl,
                             double gx, double gy, double k1, double k2, double k3, double *out) {
    double px = xd - x;
    double py = yd - y;
    double eth = wrap_angle(thd - th);
    double cx = px - gx;
    double cy = py - gy;
    double c = py_cos(th);
    double s = py_sin(th);
    double ex = c * cx + s * cy;
    double ey = -s * cx + c * cy;
    double v = vl * py_cos(eth) + k1 * ex;
    double w = wl + k2 * sgn_gain(vl) * ey + k3 * eth;
    out[0] = v, out[1] = w, out[2] = ex, out[3] = ey, out[4] = eth;
}

static double apply_threshold(double v, double vt, long mode, int frozen) {
    if (mode == THRESHOLD_OFF || (mode == THRESHOLD_FROZEN && !frozen))
        return v;
    if (fabs(v) < vt)
        return v >= 0.0 ? vt : -vt;
    return v;
}

static int freeze_update(double *mem, int inside, double t, double xl, double yl, double thl, double tu) {
    if (!inside) {
        mem[M_FROZEN] = 0.0;
        return 0;
    }
    if (mem[M_FROZEN] == 0.0 || t - mem[M_T_SNAP] >= tu * (1.0 - 1e-9)) {
        mem[M_SNAP_X] = xl;
        mem[M_SNAP_Y] = yl;
        mem[M_SNAP_TH] = thl;
        mem[M_T_SNAP] = t;
    }
    mem[M_FROZEN] = 1.0;
    return 1;
}

static double speed_bound_scale(double v, double w, double v_max, double w_max) {
    double vb = v_max > 0.0 ? v_max : MAX_SPEED;
    double wb = w_max > 0.0 ? w_max : MAX_TURN;
    double s = 1.0;
    if (fabs(v) > vb)
        s = vb / fabs(v);
    if (fabs(w) * s > wb)
        s = wb / fabs(w);
    return s;
}

static double clip(double x, double b) {
    if (x > b)
        return b;
    if (x < -b)
        return -b;
    return x;
}

static void governor_speed_limit(double x, double y, double r_self, const double *nx, const double *ny,
                                 const double *nr, const long *nk, const double *na, Py_ssize_t n, double dt,
                                 double reach, double sense, double obstacle_r, double v_max, double hx, double hy,
                                 double *limit_out, double *blocked_out) {
    double per_step = py_min(0.5 * GOVERNOR_FRACTION * (reach - r_self), GOVERNOR_FRACTION * (sense - obstacle_r));
    double limit = per_step / dt;
    double vb = v_max > 0.0 ? v_max : per_step / dt;
    double blocked = 0.0;
    for (Py_ssize_t k = 0; k < n; k++) {
        double dx = x - nx[k];
        double dy = y - ny[k];
        double l = py_sqrt(dx * dx + dy * dy);
        double drift = na[k] * vb;
        if (l - drift >= (nk[k] == KIND_ROBOT ? reach : sense))
            continue;
        double c, share;
        if (nk[k] == KIND_ROBOT) {
            c = l - py_max(r_self, nr[k]);
            share = 0.5 * GOVERNOR_FRACTION;
        } else {
            c = l - nr[k];
            share = GOVERNOR_FRACTION;
        }
        if (c > 0.0) {
            c -= drift;
            if (c > 0.0) {
                double cap = share * c / dt;
                if (cap < limit)
                    limit = cap;
            } else if (-dx * hx - dy * hy > 0.0) {
                blocked = 1.0;
            }
        }
    }
    *limit_out = limit;
    *blocked_out = blocked;
}

/* ------------------------------------------------------------------------------------------- Python */

/* *items: the items of a list or tuple with at least n (borrowed; NULL when empty); -1: an error naming it. */
static int items_of(PyObject *seq, Py_ssize_t n, const char *what, PyObject ***items) {
    if (!PyList_Check(seq) && !PyTuple_Check(seq)) {
        PyErr_Format(PyExc_TypeError, "%s: a list or tuple of numbers", what);
        return -1;
    }
    if (PySequence_Fast_GET_SIZE(seq) < n) {
        PyErr_Format(PyExc_IndexError, "%s: fewer than %zd items", what, n);
        return -1;
    }
    *items = PySequence_Fast_ITEMS(seq);
    return 0;
}

static int floats_of(PyObject *seq, Py_ssize_t n, double *out, const char *what) {
    PyObject **items;
    if (items_of(seq, n, what, &items) < 0)
        return -1;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *o = items[i];
        out[i] = PyFloat_CheckExact(o) ? PyFloat_AS_DOUBLE(o) : PyFloat_AsDouble(o);
        if (out[i] == -1.0 && PyErr_Occurred())
            return -1;
    }
    return 0;
}

static int longs_of(PyObject *seq, Py_ssize_t n, long *out, const char *what) {
    PyObject **items;
    if (items_of(seq, n, what, &items) < 0)
        return -1;
    for (Py_ssize_t i = 0; i < n; i++) {
        out[i] = PyLong_AsLong(items[i]);
        if (out[i] == -1 && PyErr_Occurred())
            return -1;
    }
    return 0;
}

static PyObject *law_robot_command(PyObject *module, PyObject *const *args, Py_ssize_t nargs) {
    if (!configured) {
        PyErr_SetString(PyExc_RuntimeError, "swarm.core._law: configure(law) first");
        return NULL;
    }
    if (nargs != 21) {
        PyErr_SetString(PyExc_TypeError, "robot_command takes the 21 arguments of swarm.core.law.robot_command");
        return NULL;
    }
    double s[12];
    for (int i = 0; i < 12; i++) {
        s[i] = PyFloat_AsDouble(args[i]);
        if (s[i] == -1.0 && PyErr_Occurred())
            return NULL;
    }
    double x = s[0], y = s[1], th = s[2], ox = s[3], oy = s[4], r_self = s[5], t = s[6], xl = s[7], yl = s[8],
           thl = s[9], vl = s[10], wl = s[11];
    Py_ssize_t n = PyLong_AsSsize_t(args[18]);
    if (n == -1 && PyErr_Occurred())
        return NULL;
    if (n < 0 || n > MAX_BODIES) {
        PyErr_Format(PyExc_ValueError, "robot_command: %zd bodies (at most %d)", n, MAX_BODIES);
        return NULL;
    }
    PyObject *memo = args[19];
    if (!PyList_Check(memo) || PyList_GET_SIZE(memo) < M_SIZE) {
        PyErr_SetString(PyExc_TypeError, "robot_command: mem is a list of M_SIZE floats (updated in place)");
        return NULL;
    }
    double *buf = PyMem_Malloc(sizeof(double) * (size_t)(5 * n + 1) + sizeof(long) * (size_t)(n + 1));
    if (buf == NULL)
        return PyErr_NoMemory();
    double *X = buf, *Y = buf + n, *NR = buf + 2 * n, *NRR = buf + 3 * n, *NA = buf + 4 * n;
    long *NK = (long *)(buf + 5 * n + 1);
    double mem[64], p[64];
    PyObject *result = NULL;
    if (M_SIZE > 64 || P_SIZE > 64 || floats_of(args[12], n, X, "nx") < 0 || floats_of(args[13], n, Y, "ny") < 0 ||
        floats_of(args[14], n, NR, "nr") < 0 || floats_of(args[15], n, NRR, "nR") < 0 ||
        longs_of(args[16], n, NK, "nk") < 0 || floats_of(args[17], n, NA, "na") < 0 ||
        floats_of(memo, M_SIZE, mem, "mem") < 0 || floats_of(args[20], P_SIZE, p, "p") < 0)
        goto done;
    math_error = 0;
    double v = 0.0, w = 0.0, ex = 0.0, ey = 0.0, eth = 0.0;
    double gx = 0.0, gy = 0.0;
    int inside = 0;
    for (Py_ssize_t k = 0; k < n; k++) {
        double dx = x - X[k];
        double dy = y - Y[k];
        if (NK[k] == KIND_ROBOT && dx * dx + dy * dy < NRR[k] * NRR[k])
            inside = 1;
        double ax, ay;
        repulsion_gradient(x, y, X[k], Y[k], NR[k], NRR[k], &ax, &ay);
        gx += ax;
        gy += ay;
    }
    int frozen = freeze_update(mem, inside, t, xl, yl, thl, p[P_TU]);
    double c[5];
    if (frozen)
        tracking_command(x, y, th, mem[M_SNAP_X] + ox, mem[M_SNAP_Y] + oy, mem[M_SNAP_TH], 0.0, 0.0, gx, gy,
                         p[P_K1], p[P_K2], p[P_K3], c);
    else
        tracking_command(x, y, th, xl + ox, yl + oy, thl, vl, wl, gx, gy, p[P_K1], p[P_K2], p[P_K3], c);
    if (math_error)
        goto write_mem; /* Python raises in tracking_command: mem holds what freeze_update wrote */
    v = c[0], w = c[1], ex = c[2], ey = c[3], eth = c[4];
    double pt = p[P_THRESHOLD];
    if (!isfinite(pt)) {
        PyErr_SetString(PyExc_ValueError, "robot_command: p[P_THRESHOLD] is not a finite number");
        goto done;
    }
    v = apply_threshold(v, p[P_VT], (long)pt, frozen);
    double bound = speed_bound_scale(v, w, p[P_V_MAX], p[P_W_MAX]);
    if (bound < 1.0) {
        v *= bound;
        w *= bound;
        double vb = p[P_V_MAX] > 0.0 ? p[P_V_MAX] : MAX_SPEED;
        double wb = p[P_W_MAX] > 0.0 ? p[P_W_MAX] : MAX_TURN;
        v = clip(v, vb);
        w = clip(w, wb);
    }
    double scale = 1.0;
    if (p[P_GOVERNOR] != 0.0) {
        double sv = v >= 0.0 ? 1.0 : -1.0;
        double limit, blocked;
        governor_speed_limit(x, y, r_self, X, Y, NR, NK, NA, n, p[P_DT], p[P_REACH], p[P_SENSE], p[P_OBSTACLE_R],
                             p[P_V_MAX], sv * py_cos(th), sv * py_sin(th), &limit, &blocked);
        if (math_error)
            goto write_mem;
        if (fabs(v) > limit) {
            scale = limit / fabs(v);
            v *= scale;
            w *= scale;
        }
        if (blocked != 0.0)
            v = 0.0;
    }
    mem[M_EX] = ex;
    mem[M_EY] = ey;
    mem[M_ETH] = eth;
    mem[M_SCALE] = scale;
write_mem:
    for (Py_ssize_t i = 0; i < M_SIZE; i++) {
        PyObject *f = PyFloat_FromDouble(mem[i]);
        if (f == NULL || PyList_SetItem(memo, i, f) < 0) /* steals f */
            goto done;
    }
    if (math_error)
        PyErr_SetString(math_error == 1 ? PyExc_ValueError : PyExc_OverflowError,
                        math_error == 1 ? "math domain error" : "math range error");
    else
        result = Py_BuildValue("(dd)", v, w);
done:
    PyMem_Free(buf);
    return result;
}

/* A constant of the dict configure() is handed (swarm.core.fastlaw.CONSTANTS), as a double or an index. */
static int get_double(PyObject *d, const char *name, double *out) {
    PyObject *o = PyDict_GetItemString(d, name); /* borrowed */
    if (o == NULL) {
        PyErr_Format(PyExc_KeyError, "configure: the law's constants lack %s", name);
        return -1;
    }
    *out = PyFloat_AsDouble(o);
    return *out == -1.0 && PyErr_Occurred() ? -1 : 0;
}

static int get_index(PyObject *d, const char *name, Py_ssize_t *out) {
    PyObject *o = PyDict_GetItemString(d, name); /* borrowed */
    if (o == NULL) {
        PyErr_Format(PyExc_KeyError, "configure: the law's constants lack %s", name);
        return -1;
    }
    *out = PyLong_AsSsize_t(o);
    return *out == -1 && PyErr_Occurred() ? -1 : 0;
}

static PyObject *law_configure(PyObject *module, PyObject *law) {
    /* The constants and layouts of swarm.core.law (one place holds them), handed over as a dict by name. */
    if (!PyDict_Check(law)) {
        PyErr_SetString(PyExc_TypeError, "configure(constants): a dict of swarm.core.law's constants");
        return NULL;
    }
    Py_ssize_t off, frozen, robot;
    if (get_double(law, "PI", &PI) < 0 || get_double(law, "TWO_PI", &TWO_PI) < 0 || get_double(law, "LN2", &LN2) < 0 ||
        get_double(law, "COLLISION_EPS", &COLLISION_EPS) < 0 ||
        get_double(law, "GOVERNOR_FRACTION", &GOVERNOR_FRACTION) < 0 || get_double(law, "MAX_SPEED", &MAX_SPEED) < 0 ||
        get_double(law, "MAX_TURN", &MAX_TURN) < 0 || get_index(law, "THRESHOLD_OFF", &off) < 0 ||
        get_index(law, "THRESHOLD_FROZEN", &frozen) < 0 || get_index(law, "KIND_ROBOT", &robot) < 0 ||
        get_index(law, "P_K1", &P_K1) < 0 || get_index(law, "P_K2", &P_K2) < 0 || get_index(law, "P_K3", &P_K3) < 0 ||
        get_index(law, "P_TU", &P_TU) < 0 || get_index(law, "P_VT", &P_VT) < 0 ||
        get_index(law, "P_THRESHOLD", &P_THRESHOLD) < 0 || get_index(law, "P_GOVERNOR", &P_GOVERNOR) < 0 ||
        get_index(law, "P_DT", &P_DT) < 0 || get_index(law, "P_SENSE", &P_SENSE) < 0 ||
        get_index(law, "P_REACH", &P_REACH) < 0 || get_index(law, "P_OBSTACLE_R", &P_OBSTACLE_R) < 0 ||
        get_index(law, "P_V_MAX", &P_V_MAX) < 0 || get_index(law, "P_W_MAX", &P_W_MAX) < 0 ||
        get_index(law, "P_SIZE", &P_SIZE) < 0 || get_index(law, "M_FROZEN", &M_FROZEN) < 0 ||
        get_index(law, "M_SNAP_X", &M_SNAP_X) < 0 || get_index(law, "M_SNAP_Y", &M_SNAP_Y) < 0 ||
        get_index(law, "M_SNAP_TH", &M_SNAP_TH) < 0 || get_index(law, "M_T_SNAP", &M_T_SNAP) < 0 ||
        get_index(law, "M_EX", &M_EX) < 0 || get_index(law, "M_EY", &M_EY) < 0 || get_index(law, "M_ETH", &M_ETH) < 0 ||
        get_index(law, "M_SCALE", &M_SCALE) < 0 || get_index(law, "M_SIZE", &M_SIZE) < 0)
        return NULL;
    THRESHOLD_OFF = (long)off, THRESHOLD_FROZEN = (long)frozen, KIND_ROBOT = (long)robot;
    if (P_SIZE > 64 || M_SIZE > 64) {
        PyErr_SetString(PyExc_ValueError, "swarm.core._law: a layout larger than 64 slots");
        return NULL;
    }
    configured = 1;
    Py_RETURN_NONE;
}

static PyMethodDef law_methods[] = {
    {"robot_command", (PyCFunction)(void (*)(void))law_robot_command, METH_FASTCALL,
     "swarm.core.law.robot_command, compiled (the same arguments; mem a list, updated in place)"},
    {"configure", (PyCFunction)law_configure, METH_O, "configure(constants): take swarm.core.law's constants and layouts (a dict: swarm.core.fastlaw.CONSTANTS)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef law_module = {
    PyModuleDef_HEAD_INIT, "swarm.core._law", "swarm.core.law.robot_command, compiled for the robot process.", -1,
    law_methods,
};

PyMODINIT_FUNC PyInit__law(void) { return PyModule_Create(&law_module); }
