/* swarm.proto._wire: a sender's window (Window, swarm.proto.window's twin) and the real-time waker's timer
 * (Deadline). The shared parts: _wire.h. */
#include "_wire.h"

/* ------------------------------------------------------------------------------------------- windows */

/* Window(t_span, seq_span, dt=0.0): swarm.proto.window.Window compiled, the same rules (its docstring) for the
 * numbers a window sees (t a finite or infinite float, seq an int that fits in 64 bits: every decoded message's):
 * tests/protocol/test_window.py holds the two equal on random sequences. The loops above take a state's window in
 * its common case straight from this struct. */
typedef struct {
    PyObject_HEAD
    double t_span, dt, t, cand_t;
    long long seq_span, seq, cand_seq, run;
    char anchored, has_cand;
} Window;

static PyObject *v_ok, *v_duplicate, *v_stale, *v_jump, *v_forged;
#define TICK_EPS 1e-6 /* swarm.proto.window.TICK_EPS */
#define CONFIRM 3     /* swarm.proto.window.CONFIRM */

static int Window_init(Window *w, PyObject *args, PyObject *kw) {
    static char *names[] = {"t_span", "seq_span", "dt", NULL};
    double dt = 0.0;
    if (!PyArg_ParseTupleAndKeywords(args, kw, "dL|d", names, &w->t_span, &w->seq_span, &dt))
        return -1;
    w->dt = dt;
    w->anchored = w->has_cand = 0;
    w->seq = -1;
    w->run = 0;
    return 0;
}

static PyObject *verdict(Window *w, double t, long long seq, double t0, long long seq0) {
    if (seq == seq0 && t == t0)
        return v_duplicate;
    if (seq <= seq0 || t < t0)
        return v_stale;
    if (seq > seq0 + w->seq_span || t > t0 + w->t_span)
        return v_jump;
    return v_ok;
}

static int take(Window *w, double t, long long seq) {
    if (w->anchored && w->seq < seq && seq <= w->seq + w->seq_span && w->t <= t && t <= w->t + w->t_span &&
        (!w->dt || fabs(t - (double)seq * w->dt) <= TICK_EPS)) {
        w->t = t, w->seq = seq, w->has_cand = 0, w->run = 0;
        return 1;
    }
    return 0;
}

static PyObject *peek(Window *w, double t, long long seq) {
    if (w->dt && !(fabs(t - (double)seq * w->dt) <= TICK_EPS))
        return v_forged;
    return w->anchored ? verdict(w, t, seq, w->t, w->seq) : v_ok;
}

static int window_args(PyObject *const *args, Py_ssize_t nargs, double *t, long long *seq) {
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "(t, seq)");
        return -1;
    }
    *t = PyFloat_AsDouble(args[0]);
    if (*t == -1.0 && PyErr_Occurred())
        return -1;
    *seq = PyLong_AsLongLong(args[1]);
    return *seq == -1 && PyErr_Occurred() ? -1 : 0;
}

static PyObject *Window_take(Window *w, PyObject *const *args, Py_ssize_t nargs) {
    double t;
    long long seq;
    if (window_args(args, nargs, &t, &seq) < 0)
        return NULL;
    return PyBool_FromLong(take(w, t, seq));
}

static PyObject *Window_peek(Window *w, PyObject *const *args, Py_ssize_t nargs) {
    double t;
    long long seq;
    if (window_args(args, nargs, &t, &seq) < 0)
        return NULL;
    return Py_NewRef(peek(w, t, seq));
}

static PyObject *Window_check(Window *w, PyObject *const *args, Py_ssize_t nargs) {
    double t;
    long long seq;
    if (window_args(args, nargs, &t, &seq) < 0)
        return NULL;
    if (take(w, t, seq))
        return Py_NewRef(v_ok);
    PyObject *v = peek(w, t, seq);
    if (v == v_jump || v == v_stale) {
        w->run = w->has_cand && verdict(w, t, seq, w->cand_t, w->cand_seq) == v_ok ? w->run + 1 : 1;
        w->cand_t = t, w->cand_seq = seq, w->has_cand = 1;
        if (w->run < CONFIRM)
            return Py_NewRef(v);
        v = v_ok; /* the sender did jump (or the window was anchored by a crafted message): follow it */
    }
    if (v == v_ok)
        w->t = t, w->seq = seq, w->anchored = 1, w->has_cand = 0, w->run = 0;
    return Py_NewRef(v);
}

static PyObject *Window_reset(Window *w, PyObject *unused) {
    w->anchored = w->has_cand = 0;
    w->seq = -1;
    w->run = 0;
    Py_RETURN_NONE;
}

static PyObject *Window_get_t(Window *w, void *c) {
    return w->anchored ? PyFloat_FromDouble(w->t) : Py_NewRef(Py_None);
}

static PyObject *Window_get_cand(Window *w, void *c) {
    return w->has_cand ? Py_BuildValue("(dL)", w->cand_t, w->cand_seq) : Py_NewRef(Py_None);
}

static PyGetSetDef Window_getset[] = {
    {"t", (getter)Window_get_t, NULL, "the time of the last message adopted (None: not anchored)", NULL},
    {"_cand", (getter)Window_get_cand, NULL, "the last refused jump, (t, seq), or None", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyMemberDef Window_members[] = {
    {"t_span", T_DOUBLE, offsetof(Window, t_span), READONLY, "how far t may move forward [s]"},
    {"seq_span", T_LONGLONG, offsetof(Window, seq_span), READONLY, "how far seq may move forward"},
    {"dt", T_DOUBLE, offsetof(Window, dt), READONLY, "lock-step: the tick (0: t and seq are not tied)"},
    {"seq", T_LONGLONG, offsetof(Window, seq), READONLY, "the seq of the last message adopted (-1: none)"},
    {"_run", T_LONGLONG, offsetof(Window, run), READONLY, "jumps in a row that agree with each other"},
    {NULL, 0, 0, 0, NULL},
};

static PyMethodDef Window_methods[] = {
    {"check", (PyCFunction)(void (*)(void))Window_check, METH_FASTCALL,
     "check(t, seq): adopt (t, seq) if it is in the window (\"ok\"), else say why not"},
    {"peek", (PyCFunction)(void (*)(void))Window_peek, METH_FASTCALL, "peek(t, seq): what check() would say"},
    {"take", (PyCFunction)(void (*)(void))Window_take, METH_FASTCALL, "take(t, seq): check()'s common case alone"},
    {"reset", (PyCFunction)Window_reset, METH_NOARGS, "reset(): the next message anchors the window"},
    {NULL, NULL, 0, NULL},
};

PyTypeObject WindowType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "swarm.proto._wire.Window",
    .tp_basicsize = sizeof(Window),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "Window(t_span, seq_span, dt=0.0): one sender's forward window (swarm.proto.window.Window, compiled)",
    .tp_methods = Window_methods,
    .tp_members = Window_members,
    .tp_getset = Window_getset,
    .tp_init = (initproc)Window_init,
    .tp_new = PyType_GenericNew,
};

/* 1: the sender's window w took (t, seq) in its common case (window_take(w, t, seq) is true); 0: it is not that
 * case, and nothing changed (the full check decides); -1: an error. */
int window_take(PyObject *w, PyObject *tt, PyObject *seq) {
    if (Py_IS_TYPE(w, &WindowType)) {
        if (!PyFloat_CheckExact(tt) || !PyLong_CheckExact(seq))
            return 0; /* not the common case: the full check decides */
        int overflow;
        long long q = PyLong_AsLongLongAndOverflow(seq, &overflow);
        if (!overflow && !(q == -1 && PyErr_Occurred()))
            return take((Window *)w, PyFloat_AS_DOUBLE(tt), q);
        PyErr_Clear();
        return 0;
    }
    PyObject *call[3] = {w, tt, seq};
    PyObject *r = PyObject_Vectorcall(window_take_fn, call, 3, NULL);
    if (r == NULL)
        return -1;
    int ok = PyObject_IsTrue(r);
    Py_DECREF(r);
    return ok;
}

int window_module_init(void) {
    if ((v_ok = PyUnicode_InternFromString("ok")) == NULL ||
        (v_duplicate = PyUnicode_InternFromString("duplicate")) == NULL ||
        (v_stale = PyUnicode_InternFromString("stale")) == NULL ||
        (v_jump = PyUnicode_InternFromString("jump")) == NULL ||
        (v_forged = PyUnicode_InternFromString("forged")) == NULL)
        return -1;
    return 0;
}

/* ------------------------------------------------------------------------------------- a real-time waker's timer */

/* Deadline(): when a real-time robot's step without a pose is due (agents.robot._watch). Each pose moves that
 * instant a period on, so the waker wakes about once a period only to find it moved. Waiting here, the wake-up
 * that finds the deadline moved costs no GIL and no Python: wait() returns to Python only once the deadline
 * passed (True), or after cap seconds or stop() (False). arm(t) sets the deadline (CLOCK_MONOTONIC seconds, as
 * time.monotonic()); an earlier one wakes the waiter, a later one is seen when the old one comes. */
typedef struct {
    PyObject_HEAD
    pthread_mutex_t mu;
    pthread_cond_t cv;
    double due;
    int stopped;
} Deadline;

static double mono_now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static PyObject *Deadline_new(PyTypeObject *type, PyObject *args, PyObject *kwds) {
    if (PyTuple_GET_SIZE(args) != 0 || (kwds != NULL && PyDict_GET_SIZE(kwds) != 0)) {
        PyErr_SetString(PyExc_TypeError, "Deadline() takes no arguments");
        return NULL;
    }
    Deadline *d = (Deadline *)type->tp_alloc(type, 0);
    if (d == NULL)
        return NULL;
    pthread_condattr_t attr;
    if (pthread_condattr_init(&attr) != 0 || pthread_condattr_setclock(&attr, CLOCK_MONOTONIC) != 0 ||
        pthread_cond_init(&d->cv, &attr) != 0 || pthread_mutex_init(&d->mu, NULL) != 0) {
        Py_TYPE(d)->tp_free((PyObject *)d);
        PyErr_SetString(PyExc_OSError, "Deadline: cannot make its lock");
        return NULL;
    }
    pthread_condattr_destroy(&attr);
    d->due = INFINITY;
    d->stopped = 0;
    return (PyObject *)d;
}

static void Deadline_dealloc(Deadline *d) {
    pthread_cond_destroy(&d->cv);
    pthread_mutex_destroy(&d->mu);
    Py_TYPE(d)->tp_free((PyObject *)d);
}

static PyObject *Deadline_arm(Deadline *d, PyObject *arg) {
    double t = PyFloat_AsDouble(arg);
    if (t == -1.0 && PyErr_Occurred())
        return NULL;
    if (isnan(t)) {
        PyErr_SetString(PyExc_ValueError, "Deadline.arm: NaN");
        return NULL;
    }
    pthread_mutex_lock(&d->mu);
    int earlier = t < d->due;
    d->due = t;
    if (earlier)
        pthread_cond_signal(&d->cv);
    pthread_mutex_unlock(&d->mu);
    Py_RETURN_NONE;
}

static PyObject *Deadline_stop(Deadline *d, PyObject *Py_UNUSED(ignored)) {
    pthread_mutex_lock(&d->mu);
    d->stopped = 1;
    pthread_cond_broadcast(&d->cv);
    pthread_mutex_unlock(&d->mu);
    Py_RETURN_NONE;
}

static PyObject *Deadline_wait(Deadline *d, PyObject *arg) {
    double cap = PyFloat_AsDouble(arg);
    if (cap == -1.0 && PyErr_Occurred())
        return NULL;
    if (!(cap >= 0.0))
        cap = 0.0;
    int late = 0;
    Py_BEGIN_ALLOW_THREADS
    pthread_mutex_lock(&d->mu);
    double end = mono_now() + cap;
    for (;;) {
        if (d->stopped)
            break;
        double now = mono_now();
        if (d->due <= now) {
            late = 1;
            break;
        }
        if (now >= end)
            break;
        double until = d->due < end ? d->due : end;
        struct timespec ts;
        ts.tv_sec = (time_t)until;
        ts.tv_nsec = (long)((until - (double)ts.tv_sec) * 1e9);
        if (ts.tv_nsec >= 1000000000L) {
            ts.tv_sec += 1;
            ts.tv_nsec -= 1000000000L;
        }
        pthread_cond_timedwait(&d->cv, &d->mu, &ts); /* a timeout or a signal: look again */
    }
    pthread_mutex_unlock(&d->mu);
    Py_END_ALLOW_THREADS
    return PyBool_FromLong(late);
}

static PyObject *Deadline_get_due(Deadline *d, void *Py_UNUSED(closure)) {
    pthread_mutex_lock(&d->mu);
    double t = d->due;
    pthread_mutex_unlock(&d->mu);
    return PyFloat_FromDouble(t);
}

static PyMethodDef Deadline_methods[] = {
    {"arm", (PyCFunction)Deadline_arm, METH_O, "arm(t): the deadline is t (monotonic seconds)"},
    {"wait", (PyCFunction)Deadline_wait, METH_O,
     "wait(cap): True once the deadline passed; False after cap seconds or stop() (the GIL released meanwhile)"},
    {"stop", (PyCFunction)Deadline_stop, METH_NOARGS, "stop(): every wait() returns False from now on"},
    {NULL, NULL, 0, NULL},
};

static PyGetSetDef Deadline_getset[] = {
    {"due", (getter)Deadline_get_due, NULL, "the deadline (monotonic seconds; inf: none)", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

PyTypeObject DeadlineType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "swarm.proto._wire.Deadline",
    .tp_basicsize = sizeof(Deadline),
    .tp_dealloc = (destructor)Deadline_dealloc,
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "Deadline(): a real-time waker's timer, waited on without the GIL (arm, wait, stop)",
    .tp_methods = Deadline_methods,
    .tp_getset = Deadline_getset,
    .tp_new = Deadline_new,
};
