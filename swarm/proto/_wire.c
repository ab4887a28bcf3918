/* A robot's loops over its messages, compiled (docs/performance.md, "The compiled parts of a period"): draining
 * zenoh's inboxes (drain), the cell states of a batch (decode_states, through the decoder it is given: msgspec's,
 * swarm.proto.protocol.decoder), a real-time robot's windows and table (take_states), lock-step's passes over the
 * table (lock_bodies, wait_for) and its neighbour states on zenoh's thread (StateSink), and the real-time waker's
 * timer (Deadline). Each is a transcription of the Python it stands in for (agents/), which runs where this was not
 * built: tests hold the two equal. It parses no msgpack. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <structmember.h>
#include <stddef.h>
#include <limits.h>
#include <stdint.h>
#include <string.h>
#include <math.h>
#include <errno.h>
#include <pthread.h>
#include <time.h>

/* What the loops read of Python objects is handed over by setup() (swarm.proto.protocol calls it once), never
 * looked up here by name: a state's fields as a tuple, a sender window's common-case take, a zenoh sample's parts
 * and a payload's bytes. A rename on the Python side changes the call of setup(), where the tests see it. */
static PyObject *state_fields, *window_take_fn, *sample_parts, *to_bytes_fn;
enum { F_ID, F_T, F_SEQ, F_X, F_Y, F_R, F_RR, F_N }; /* the tuple state_fields gives: id, t, seq, x, y, r, R */

static PyObject *wire_setup(PyObject *module, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "setup(state_fields, window_take, sample_parts, to_bytes)");
        return NULL;
    }
    for (int i = 0; i < 4; i++)
        if (!PyCallable_Check(args[i])) {
            PyErr_Format(PyExc_TypeError, "setup: argument %d is not callable", i + 1);
            return NULL;
        }
    Py_XSETREF(state_fields, Py_NewRef(args[0]));
    Py_XSETREF(window_take_fn, Py_NewRef(args[1]));
    Py_XSETREF(sample_parts, Py_NewRef(args[2]));
    Py_XSETREF(to_bytes_fn, Py_NewRef(args[3]));
    Py_RETURN_NONE;
}

static int ready(void) {
    if (state_fields == NULL || window_take_fn == NULL || sample_parts == NULL || to_bytes_fn == NULL) {
        PyErr_SetString(PyExc_RuntimeError, "swarm.proto._wire.setup() was not called");
        return -1;
    }
    return 0;
}

/* A state's fields (state_fields(st): id, t, seq, x, y, r, R) as a tuple: a new reference, NULL with the error. */
static PyObject *fields_of(PyObject *st) {
    PyObject *f = PyObject_CallOneArg(state_fields, st);
    if (f != NULL && (!PyTuple_CheckExact(f) || PyTuple_GET_SIZE(f) != F_N)) {
        Py_DECREF(f);
        PyErr_SetString(PyExc_TypeError, "state_fields() must give a tuple of (id, t, seq, x, y, r, R)");
        return NULL;
    }
    return f;
}

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

static PyTypeObject WindowType;
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

static PyTypeObject WindowType = {
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
static int window_take(PyObject *w, PyObject *tt, PyObject *seq) {
    if (Py_IS_TYPE(w, &WindowType) && PyFloat_CheckExact(tt) && PyLong_CheckExact(seq)) {
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

/* ------------------------------------------------------------------------------------------- inboxes */

/* The (key, payload) of a zenoh sample, or Py_None for a wake-up (an empty payload with the wake attachment):
 * swarm.net.bus._ZenohInbox._item. sample_parts(s) gives (key_expr, payload, attachment), to_bytes(z) a payload's
 * bytes. A new reference; NULL with an exception. */
static PyObject *sample_item(PyObject *s, PyObject *wake) {
    if (ready() < 0)
        return NULL;
    PyObject *parts = PyObject_CallOneArg(sample_parts, s);
    if (parts == NULL)
        return NULL;
    if (!PyTuple_CheckExact(parts) || PyTuple_GET_SIZE(parts) != 3) {
        Py_DECREF(parts);
        PyErr_SetString(PyExc_TypeError, "sample_parts() must give (key_expr, payload, attachment)");
        return NULL;
    }
    PyObject *b = PyObject_CallOneArg(to_bytes_fn, PyTuple_GET_ITEM(parts, 1)), *result = NULL;
    if (b == NULL)
        goto done;
    if (!PyBytes_Check(b)) {
        PyErr_SetString(PyExc_TypeError, "a sample's payload gave no bytes");
        goto done;
    }
    PyObject *a = PyTuple_GET_ITEM(parts, 2);
    if (PyBytes_GET_SIZE(b) == 0 && a != Py_None) { /* a real message is never empty: only then look for the wake */
        PyObject *ab = PyObject_CallOneArg(to_bytes_fn, a);
        if (ab == NULL)
            goto done;
        int is_wake = PyObject_RichCompareBool(ab, wake, Py_EQ);
        Py_DECREF(ab);
        if (is_wake < 0)
            goto done;
        if (is_wake) {
            result = Py_NewRef(Py_None);
            goto done;
        }
    }
    PyObject *k = PyObject_Str(PyTuple_GET_ITEM(parts, 0));
    if (k == NULL)
        goto done;
    result = PyTuple_Pack(2, k, b);
    Py_DECREF(k);
done:
    Py_XDECREF(b);
    Py_DECREF(parts);
    return result;
}

/* recv()'s sample appended to out as (key, payload), a wake-up left out: 1; recv() gave None: 0; -1 on error. */
static int take_one(PyObject *out, PyObject *recv, PyObject *wake) {
    PyObject *s = PyObject_CallNoArgs(recv);
    if (s == NULL)
        return -1;
    if (s == Py_None) {
        Py_DECREF(s);
        return 0;
    }
    PyObject *item = sample_item(s, wake);
    Py_DECREF(s);
    if (item == NULL)
        return -1;
    int rc = item == Py_None ? 0 : PyList_Append(out, item);
    Py_DECREF(item);
    return rc < 0 ? -1 : 1;
}

static int drain_into(PyObject *out, PyObject *recv, PyObject *wake) {
    int rc;
    while ((rc = take_one(out, recv, wake)) > 0)
        ;
    return rc;
}

/* drain(recv, wake[, first]): the (key, payload) of every sample recv() gives until None, wake-ups left out; recv
 * may be a tuple of such callables (several inboxes drained in one call, in the tuple's order). first: a
 * blocking receive called once before (the inbox's wait(): its sample, unless a wake-up, comes first). */
static PyObject *wire_drain(PyObject *module, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 2 && nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "drain(try_recv, wake[, recv]) takes 2 or 3 arguments");
        return NULL;
    }
    PyObject *recv = args[0], *wake = args[1];
    PyObject *out = PyList_New(0);
    if (out == NULL)
        return NULL;
    if (nargs == 3 && take_one(out, args[2], wake) < 0)
        goto fail;
    if (PyTuple_Check(recv)) {
        for (Py_ssize_t i = 0; i < PyTuple_GET_SIZE(recv); i++)
            if (drain_into(out, PyTuple_GET_ITEM(recv, i), wake) < 0)
                goto fail;
    } else if (drain_into(out, recv, wake) < 0)
        goto fail;
    return out;
fail:
    Py_DECREF(out);
    return NULL;
}

/* decode_states(items, dec, ids, parse, states, bad, error, limit): for each (key, payload) of items, the
 * robot id of its cell key (ids caches parse(key); cleared when it holds limit keys), then dec(payload, id)
 * appended to states as (state, key); a key parse refuses, or an error dec raises, goes to bad as (key, error).
 * agents.realtime.Realtime._take_inboxes's loop over its cells, without a bytecode per message. */
static PyObject *wire_decode_states(PyObject *module, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 8) {
        PyErr_SetString(PyExc_TypeError, "decode_states(items, dec, ids, parse, states, bad, error, limit)");
        return NULL;
    }
    PyObject *items = args[0], *dec = args[1], *ids = args[2], *parse = args[3], *states = args[4], *bad = args[5];
    PyObject *error = args[6];
    Py_ssize_t limit = PyLong_AsSsize_t(args[7]);
    if (limit == -1 && PyErr_Occurred())
        return NULL;
    if (!PyList_Check(items) || !PyDict_Check(ids) || !PyList_Check(states) || !PyList_Check(bad)) {
        PyErr_SetString(PyExc_TypeError, "decode_states: items, states and bad are lists, ids a dict");
        return NULL;
    }
    for (Py_ssize_t i = 0; i < PyList_GET_SIZE(items); i++) {
        PyObject *it = PyList_GET_ITEM(items, i);
        if (!PyTuple_Check(it) || PyTuple_GET_SIZE(it) != 2) {
            PyErr_SetString(PyExc_TypeError, "decode_states: items are (key, payload) pairs");
            return NULL;
        }
        PyObject *key = PyTuple_GET_ITEM(it, 0), *payload = PyTuple_GET_ITEM(it, 1);
        PyObject *j = PyDict_GetItemWithError(ids, key); /* borrowed */
        if (j == NULL) {
            if (PyErr_Occurred())
                return NULL;
            PyObject *pj = PyObject_CallOneArg(parse, key);
            if (pj == NULL)
                return NULL;
            if (pj == Py_None) {
                Py_DECREF(pj);
                PyObject *e = PyObject_CallFunction(error, "N", PyUnicode_FromFormat("not a cell key: %R", key));
                if (e == NULL)
                    return NULL;
                PyObject *t = PyTuple_Pack(2, key, e);
                Py_DECREF(e);
                if (t == NULL || PyList_Append(bad, t) < 0) {
                    Py_XDECREF(t);
                    return NULL;
                }
                Py_DECREF(t);
                continue;
            }
            if (PyDict_GET_SIZE(ids) >= limit) /* keys of robots long gone (or a stranger's): bounded */
                PyDict_Clear(ids);
            int rc = PyDict_SetItem(ids, key, pj);
            Py_DECREF(pj);
            if (rc < 0)
                return NULL;
            j = PyDict_GetItemWithError(ids, key);
            if (j == NULL)
                return NULL;
        }
        PyObject *call[2] = {payload, j};
        PyObject *m = PyObject_Vectorcall(dec, call, 2, NULL);
        PyObject *t;
        if (m == NULL) {
            if (!PyErr_ExceptionMatches(error))
                return NULL;
            PyObject *type, *value, *tb;
            PyErr_Fetch(&type, &value, &tb);
            PyErr_NormalizeException(&type, &value, &tb);
            if (tb != NULL)
                PyException_SetTraceback(value, tb);
            Py_XDECREF(type);
            Py_XDECREF(tb);
            if (value == NULL)
                return NULL;
            t = PyTuple_Pack(2, key, value);
            Py_DECREF(value);
            if (t == NULL || PyList_Append(bad, t) < 0) {
                Py_XDECREF(t);
                return NULL;
            }
        } else {
            t = PyTuple_Pack(2, m, key);
            Py_DECREF(m);
            if (t == NULL || PyList_Append(states, t) < 0) {
                Py_XDECREF(t);
                return NULL;
            }
        }
        Py_DECREF(t);
    }
    Py_RETURN_NONE;
}


/* ------------------------------------------------------------------------------------------- states */

/* take_states(states, me, ahead, now, mono, windows, table, rx, away, slow): real time, a batch of decoded
 * neighbour states (agents.realtime.Realtime._on_states). A state of another robot, not ahead of this robot's clock
 * (t <= ahead), that its sender's window takes in the common case is taken here: table[j] = s, rx[j] = (its age
 * now, mono), j not away any more. Any other goes to slow(s, key), in its turn (the windows see the states in
 * order). Returns how many were taken here. */
static PyObject *wire_take_states(PyObject *module, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 10) {
        PyErr_SetString(PyExc_TypeError, "take_states(states, me, ahead, now, mono, windows, table, rx, away, slow)");
        return NULL;
    }
    PyObject *states = args[0], *me = args[1], *now = args[3], *mono = args[4], *windows = args[5];
    PyObject *table = args[6], *rx = args[7], *away = args[8], *slow = args[9];
    double ahead = PyFloat_AsDouble(args[2]);
    if ((ahead == -1.0 && PyErr_Occurred()) || ready() < 0)
        return NULL;
    if (!PyList_Check(states) || !PyDict_Check(windows) || !PyDict_Check(table) || !PyDict_Check(rx) ||
        !PySet_Check(away)) {
        PyErr_SetString(PyExc_TypeError, "take_states: states a list, windows, table, rx dicts, away a set");
        return NULL;
    }
    double nowv = 0.0;
    int has_now = now != Py_None;
    if (has_now && (nowv = PyFloat_AsDouble(now)) == -1.0 && PyErr_Occurred())
        return NULL;
    Py_ssize_t taken = 0;
    for (Py_ssize_t i = 0; i < PyList_GET_SIZE(states); i++) {
        PyObject *it = PyList_GET_ITEM(states, i);
        if (!PyTuple_Check(it) || PyTuple_GET_SIZE(it) != 2) {
            PyErr_SetString(PyExc_TypeError, "take_states: states are (state, key) pairs");
            return NULL;
        }
        PyObject *st = PyTuple_GET_ITEM(it, 0), *key = PyTuple_GET_ITEM(it, 1);
        PyObject *f = fields_of(st);
        if (f == NULL)
            return NULL;
        PyObject *j = PyTuple_GET_ITEM(f, F_ID), *tt = PyTuple_GET_ITEM(f, F_T), *seq = PyTuple_GET_ITEM(f, F_SEQ);
        int fast = 0;
        if (PyFloat_CheckExact(tt) && PyFloat_AS_DOUBLE(tt) <= ahead) {
            int mine = PyObject_RichCompareBool(j, me, Py_EQ);
            if (mine < 0)
                goto fail;
            PyObject *w = mine ? NULL : PyDict_GetItemWithError(windows, j); /* borrowed */
            if (w == NULL && PyErr_Occurred())
                goto fail;
            if (w != NULL) {
                Py_INCREF(w);
                fast = window_take(w, tt, seq);
                Py_DECREF(w);
                if (fast < 0)
                    goto fail;
            }
        }
        if (fast) {
            double t = PyFloat_AS_DOUBLE(tt);
            PyObject *age = PyFloat_FromDouble(!has_now || nowv <= t ? 0.0 : nowv - t);
            PyObject *pair = age == NULL ? NULL : PyTuple_Pack(2, age, mono);
            Py_XDECREF(age);
            if (pair == NULL || PyDict_SetItem(table, j, st) < 0 || PyDict_SetItem(rx, j, pair) < 0 ||
                PySet_Discard(away, j) < 0) {
                Py_XDECREF(pair);
                goto fail;
            }
            Py_DECREF(pair);
            taken++;
        } else {
            PyObject *r = PyObject_CallFunctionObjArgs(slow, st, key, NULL);
            if (r == NULL)
                goto fail;
            Py_DECREF(r);
        }
        Py_DECREF(f);
        continue;
    fail:
        Py_DECREF(f);
        return NULL;
    }
    return PyLong_FromSsize_t(taken);
}


static int append_double(PyObject *list, double v) {
    PyObject *f = PyFloat_FromDouble(v);
    int rc = f == NULL ? -1 : PyList_Append(list, f);
    Py_XDECREF(f);
    return rc;
}

/* An int as a long long: 1, 0 when it is not an int that fits (the common case does not hold), -1. */
static int as_ll(PyObject *v, long long *out) {
    if (!PyLong_CheckExact(v))
        return 0;
    int overflow;
    *out = PyLong_AsLongLongAndOverflow(v, &overflow);
    if (*out == -1 && PyErr_Occurred())
        return -1;
    return !overflow;
}

/* The passes over a robot's table (its neighbours' newest states, by id) below share these. */

/* n float arguments into v; -1 with the error set if one is not a number. */
static int float_args(PyObject *const *args, int n, double *v) {
    for (int i = 0; i < n; i++) {
        v[i] = PyFloat_AsDouble(args[i]);
        if (v[i] == -1.0 && PyErr_Occurred())
            return -1;
    }
    return 0;
}

/* Robot j's state in the table (*nb, borrowed), and whether j is dead: 1 dead (appended to dead_near if that is
 * not NULL), 0 live, -1 on an error (who names the pass). */
static int table_entry(PyObject *table, PyObject *dead, PyObject *dead_near, PyObject *j, PyObject **nb,
                       const char *who) {
    *nb = PyDict_GetItemWithError(table, j);
    if (*nb == NULL) {
        if (!PyErr_Occurred())
            PyErr_Format(PyExc_RuntimeError, "%s: the table changed under it", who);
        return -1;
    }
    int c = PySet_Contains(dead, j);
    if (c > 0 && dead_near != NULL && PyList_Append(dead_near, *nb) < 0)
        return -1;
    return c;
}

/* A state's fields (a new reference, fields_of) with its seq and x, y as numbers; NULL with the error set. */
static PyObject *state_xy(PyObject *nb, long long *seq, double *x, double *y, const char *who) {
    PyObject *f = fields_of(nb);
    if (f == NULL)
        return NULL;
    int got = as_ll(PyTuple_GET_ITEM(f, F_SEQ), seq);
    if (got == 0)
        PyErr_Format(PyExc_TypeError, "%s: a state's seq is not an int", who);
    if (got <= 0)
        goto fail;
    *x = PyFloat_AsDouble(PyTuple_GET_ITEM(f, F_X));
    if (*x == -1.0 && PyErr_Occurred())
        goto fail;
    *y = PyFloat_AsDouble(PyTuple_GET_ITEM(f, F_Y));
    if (*y == -1.0 && PyErr_Occurred())
        goto fail;
    return f;
fail:
    Py_DECREF(f);
    return NULL;
}

/* bodies()'s six lists (nx, ny, nr, nR, nk, na), the dead ones near and the table's ids in ascending order
 * (new references); -1 with the error set (whatever was made is released by bodies_free). */
static int bodies_new(PyObject *table, PyObject **ids, PyObject **out, PyObject **dead_near) {
    *ids = PyDict_Keys(table);
    *dead_near = PyList_New(0);
    if (*ids == NULL || *dead_near == NULL || PyList_Sort(*ids) < 0)
        return -1;
    for (int i = 0; i < 6; i++)
        if ((out[i] = PyList_New(0)) == NULL)
            return -1;
    return 0;
}

static void bodies_free(PyObject *ids, PyObject **out, PyObject *dead_near) {
    Py_XDECREF(ids);
    Py_XDECREF(dead_near);
    for (int i = 0; i < 6; i++)
        Py_XDECREF(out[i]);
}

/* A robot's body (its state's fields f) appended to bodies()'s lists, with its kind and age: its x, y, r and R
 * objects themselves, as the Python appends them (no float made for them). */
static int append_body(PyObject **out, PyObject *f, PyObject *kind, double age) {
    const int at[4] = {F_X, F_Y, F_R, F_RR};
    for (int i = 0; i < 4; i++)
        if (PyList_Append(out[i], PyTuple_GET_ITEM(f, at[i])) < 0)
            return -1;
    if (PyList_Append(out[4], kind) < 0 || append_double(out[5], age) < 0)
        return -1;
    return 0;
}

/* lock_bodies(table, dead, waiting, seq, x, y, r2, kind): lock-step, agents.bodies.Bodies.bodies()'s loop over
 * its table, robots in ascending id: a dead one goes to the dead list; a live one counts with its state of tick
 * seq, or, when it was awaited (waiting) and did not come, its last one (stale); closer than r2 (squared) it is a
 * body, of age 0. The same float operations in the same order as the Python (lock-step parity with swarm sim).
 * Returns (nx, ny, nr, nR, nk, na, robots, stale, 0.0, dead). */
static PyObject *wire_lock_bodies(PyObject *module, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 8) {
        PyErr_SetString(PyExc_TypeError, "lock_bodies(table, dead, waiting, seq, x, y, r2, kind)");
        return NULL;
    }
    PyObject *table = args[0], *dead = args[1], *waiting = args[2], *kind = args[7];
    if (!PyDict_Check(table) || !PyAnySet_Check(dead) || !PyAnySet_Check(waiting) || !PyLong_CheckExact(args[3])) {
        PyErr_SetString(PyExc_TypeError, "lock_bodies: table a dict; dead, waiting sets; seq an int");
        return NULL;
    }
    long long seq = PyLong_AsLongLong(args[3]);
    double v[3];
    if ((seq == -1 && PyErr_Occurred()) || float_args(args + 4, 3, v) < 0 || ready() < 0)
        return NULL;
    double x = v[0], y = v[1], r2 = v[2];
    PyObject *ids = NULL, *out[6] = {NULL}, *dead_near = NULL, *result = NULL;
    if (bodies_new(table, &ids, out, &dead_near) < 0)
        goto done;
    Py_ssize_t robots = 0, stale = 0;
    for (Py_ssize_t i = 0; i < PyList_GET_SIZE(ids); i++) {
        PyObject *j = PyList_GET_ITEM(ids, i), *nb;
        int c = table_entry(table, dead, dead_near, j, &nb, "lock_bodies");
        if (c < 0)
            goto done;
        if (c)
            continue;
        long long nseq;
        double bx, by;
        PyObject *f = state_xy(nb, &nseq, &bx, &by, "lock_bodies");
        if (f == NULL)
            goto done;
        int is_stale = nseq != seq;
        if (is_stale && (c = PySet_Contains(waiting, j)) <= 0) {
            Py_DECREF(f);
            if (c < 0)
                goto done;
            continue;
        }
        double dx = x - bx, dy = y - by;
        int rc = 0;
        if (dx * dx + dy * dy < r2) {
            rc = append_body(out, f, kind, 0.0);
            robots += 1;
            stale += is_stale;
        }
        Py_DECREF(f);
        if (rc < 0)
            goto done;
    }
    result = Py_BuildValue("(OOOOOOnndO)", out[0], out[1], out[2], out[3], out[4], out[5], robots, stale, 0.0,
                           dead_near);
done:
    bodies_free(ids, out, dead_near);
    return result;
}

/* wait_for(table, dead, k, px, py, reach2): lock-step, no faults: agents.lockstep.Lockstep._start_tick's pass over its
 * table as tick k starts. A live robot's state older than k - 1 is never used again: deleted from the table. A
 * live robot whose state of k - 1 put it closer than reach2 (squared) to this robot's previous position is
 * waited for. Returns the set of those. */
static PyObject *wire_wait_for(PyObject *module, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 6) {
        PyErr_SetString(PyExc_TypeError, "wait_for(table, dead, k, px, py, reach2)");
        return NULL;
    }
    PyObject *table = args[0], *dead = args[1];
    if (!PyDict_Check(table) || !PyAnySet_Check(dead) || !PyLong_CheckExact(args[2])) {
        PyErr_SetString(PyExc_TypeError, "wait_for: table a dict, dead a set, k an int");
        return NULL;
    }
    long long k = PyLong_AsLongLong(args[2]);
    double v[3];
    if ((k == -1 && PyErr_Occurred()) || float_args(args + 3, 3, v) < 0 || ready() < 0)
        return NULL;
    double px = v[0], py = v[1], reach2 = v[2];
    PyObject *ids = PyDict_Keys(table), *waiting = PySet_New(NULL), *result = NULL;
    if (ids == NULL || waiting == NULL)
        goto done;
    for (Py_ssize_t i = 0; i < PyList_GET_SIZE(ids); i++) {
        PyObject *j = PyList_GET_ITEM(ids, i), *nb;
        int c = table_entry(table, dead, NULL, j, &nb, "wait_for");
        if (c < 0)
            goto done;
        if (c)
            continue;
        long long nseq;
        double bx, by;
        PyObject *f = state_xy(nb, &nseq, &bx, &by, "wait_for");
        if (f == NULL)
            goto done;
        Py_DECREF(f);
        if (nseq < k - 1) {
            if (PyDict_DelItem(table, j) < 0)
                goto done;
            continue;
        }
        if (nseq != k - 1)
            continue;
        double dx = px - bx, dy = py - by;
        if (dx * dx + dy * dy < reach2 && PySet_Add(waiting, j) < 0)
            goto done;
    }
    result = waiting;
    waiting = NULL;
done:
    Py_XDECREF(ids);
    Py_XDECREF(waiting);
    return result;
}

/* ------------------------------------------------------------------------------------------- lock-step states */

/* StateSink(me, ids, dec, slow, report, acquire, release, kick, due, table, windows, waiting): a lock-step robot's
 * neighbour states, taken on zenoh's receiving thread without a Python frame in the common case
 * (agents.intake.Intake._on_state_msg and _on_state, lock-step, no faults: the agent makes none under faults).
 * Everything it reads is handed to it: the robot's id `me`, its cell keys' ids `ids`, the decoder `dec`, the
 * Python path `slow(key, payload)` and `report(key, error)`, its lock's `acquire` and `release`, `kick()` (the
 * loop woken, or the tick run on this thread: agents.agent), `due()` (is the tick due now), and its `table`,
 * sender `windows` and `waiting` set; the agent keeps the members `ended`, `started` (the tick under way) and
 * `posed` (its newest pose's seq) up to date under its lock, and reads `taken` (the states taken here).
 * A state whose cell key's id is known, that dec decodes, of another robot, not ahead of the robot's next tick,
 * and that its sender's window takes in the common case, is taken under the lock: counted, put in the table, and
 * no longer waited for if it is of the tick under way; kick() is called when that took the last awaited robot off
 * and due() says so (nothing else a state changes is read by due()). Any other message goes, untouched, to slow
 * (the Python, which takes, refuses or counts it); an error of either goes to report. Nothing raises into the bus. */
typedef struct {
    PyObject_HEAD
    vectorcallfunc vectorcall;
    PyObject *ids, *dec, *slow, *report, *acquire, *release, *kick, *due, *table, *windows, *waiting;
    long long me, started, posed, taken;
    char ended;
} StateSink;

static PyObject *StateSink_vectorcall(PyObject *callable, PyObject *const *args, size_t nargsf, PyObject *kwnames);

static PyObject *StateSink_new(PyTypeObject *tp, PyObject *args, PyObject *kw) {
    long long me;
    PyObject *o[11];
    if (!PyArg_ParseTuple(args, "LO!OOOOOOOO!O!O!", &me, &PyDict_Type, &o[0], &o[1], &o[2], &o[3], &o[4], &o[5],
                          &o[6], &o[7], &PyDict_Type, &o[8], &PyDict_Type, &o[9], &PySet_Type, &o[10]))
        return NULL;
    StateSink *k = (StateSink *)tp->tp_alloc(tp, 0);
    if (k == NULL)
        return NULL;
    k->vectorcall = StateSink_vectorcall;
    k->me = me;
    k->started = k->posed = -1;
    PyObject **slots[11] = {&k->ids, &k->dec, &k->slow, &k->report, &k->acquire, &k->release, &k->kick, &k->due,
                            &k->table, &k->windows, &k->waiting};
    for (int i = 0; i < 11; i++)
        *slots[i] = Py_NewRef(o[i]);
    return (PyObject *)k;
}

static int StateSink_traverse(StateSink *k, visitproc visit, void *arg) {
    Py_VISIT(k->ids);
    Py_VISIT(k->dec);
    Py_VISIT(k->slow);
    Py_VISIT(k->report);
    Py_VISIT(k->acquire);
    Py_VISIT(k->release);
    Py_VISIT(k->kick);
    Py_VISIT(k->due);
    Py_VISIT(k->table);
    Py_VISIT(k->windows);
    Py_VISIT(k->waiting);
    return 0;
}

static int StateSink_clear(StateSink *k) {
    Py_CLEAR(k->ids);
    Py_CLEAR(k->dec);
    Py_CLEAR(k->slow);
    Py_CLEAR(k->report);
    Py_CLEAR(k->acquire);
    Py_CLEAR(k->release);
    Py_CLEAR(k->kick);
    Py_CLEAR(k->due);
    Py_CLEAR(k->table);
    Py_CLEAR(k->windows);
    Py_CLEAR(k->waiting);
    return 0;
}

static void StateSink_dealloc(StateSink *k) {
    PyObject_GC_UnTrack(k);
    StateSink_clear(k);
    Py_TYPE(k)->tp_free((PyObject *)k);
}

/* Under the agent's lock: 1 if state st was taken in the common case, 0 if it is not that case (nothing changed),
 * -1 on an error. *due: the loop has work. */
static int sink_take(StateSink *k, PyObject *st, int *due) {
    *due = 0;
    if (k->table == NULL || k->windows == NULL || k->waiting == NULL || !PySet_Check(k->waiting)) {
        PyErr_SetString(PyExc_TypeError, "the sink's table and windows are dicts, its waiting a set");
        return -1;
    }
    PyObject *f = fields_of(st);
    if (f == NULL)
        return -1;
    PyObject *j = PyTuple_GET_ITEM(f, F_ID), *tt = PyTuple_GET_ITEM(f, F_T), *seq = PyTuple_GET_ITEM(f, F_SEQ);
    long long id, q;
    int rc = as_ll(j, &id);
    if (rc < 0)
        goto done;
    if (rc == 0 || id == k->me || !PyFloat_CheckExact(tt)) {
        rc = 0; /* its own id from elsewhere, or an odd one: the Python refuses it */
        goto done;
    }
    if ((rc = as_ll(seq, &q)) <= 0)
        goto done;
    rc = 0;
    long long now = k->started > k->posed ? k->started : k->posed; /* Agent._next_tick, no faults: now + 1 */
    if (q > now + 1) /* ahead of this robot: refused, and counted, the long way */
        goto done;
    PyObject *w = PyDict_GetItemWithError(k->windows, j); /* borrowed */
    if (w == NULL) {
        rc = PyErr_Occurred() ? -1 : 0; /* its first state: the Python makes its window */
        goto done;
    }
    Py_INCREF(w);
    rc = window_take(w, tt, seq);
    Py_DECREF(w);
    if (rc != 1)
        goto done;
    /* taken: from here on every step must happen (an error is reported, not undone) */
    k->taken += 1;
    rc = -1;
    if (PyObject_SetItem(k->table, j, st) < 0)
        goto done;
    int removed = q == k->started ? PySet_Discard(k->waiting, j) : 0;
    if (removed < 0)
        goto done;
    rc = 1;
    /* Only the state that took the last robot off `waiting` can make the tick due: while someone is waited for,
     * due() is only true for a new pose, which woke the loop itself; and a state that took nobody off changed
     * nothing due() reads (a pose, the reference, the clock, the robots lost woke the loop when they came). */
    if (removed == 1 && PySet_GET_SIZE(k->waiting) == 0) {
        PyObject *d = PyObject_CallNoArgs(k->due);
        if (d == NULL || (*due = PyObject_IsTrue(d)) < 0)
            rc = -1;
        Py_XDECREF(d);
    }
done:
    Py_DECREF(f);
    return rc;
}

/* Hand the pending exception to report(key, error); if even that fails, the error is written as unraisable. */
static void sink_report(StateSink *k, PyObject *key) {
    PyObject *type, *value, *tb;
    PyErr_Fetch(&type, &value, &tb);
    PyErr_NormalizeException(&type, &value, &tb);
    if (value == NULL) {
        Py_XDECREF(type);
        Py_XDECREF(tb);
        return;
    }
    if (tb != NULL)
        PyException_SetTraceback(value, tb);
    PyObject *r = PyObject_CallFunctionObjArgs(k->report, key != NULL ? key : Py_None, value, NULL);
    Py_XDECREF(type);
    Py_XDECREF(value);
    Py_XDECREF(tb);
    if (r == NULL)
        PyErr_WriteUnraisable(k->report);
    Py_XDECREF(r);
}

/* The message (key, payload); never raises. */
static void sink_message(StateSink *k, PyObject *key, PyObject *payload) {
    if (k->ended)
        return;
    int rc = 0, due = 0;
    PyObject *j = PyUnicode_CheckExact(key) ? PyDict_GetItemWithError(k->ids, key) : NULL; /* borrowed */
    if (j == NULL && PyErr_Occurred()) {
        sink_report(k, key);
        return;
    }
    if (j != NULL) {
        PyObject *call[2] = {payload, j};
        Py_INCREF(j);
        PyObject *st = PyObject_Vectorcall(k->dec, call, 2, NULL);
        Py_DECREF(j);
        if (st == NULL) {
            PyErr_Clear(); /* the Python decodes it again and names what is wrong */
        } else {
            PyObject *got = PyObject_CallNoArgs(k->acquire);
            if (got == NULL) {
                Py_DECREF(st);
                sink_report(k, key);
                return;
            }
            Py_DECREF(got);
            rc = sink_take(k, st, &due);
            Py_DECREF(st);
            PyObject *exc_type, *exc_value, *exc_tb;
            PyErr_Fetch(&exc_type, &exc_value, &exc_tb); /* release even after an error */
            PyObject *r = PyObject_CallNoArgs(k->release);
            Py_XDECREF(r);
            if (r == NULL)
                PyErr_WriteUnraisable(k->release);
            PyErr_Restore(exc_type, exc_value, exc_tb);
            if (rc < 0) {
                sink_report(k, key);
                return;
            }
        }
    }
    if (rc == 0) { /* not the common case: the Python's, from the start */
        PyObject *r = PyObject_CallFunctionObjArgs(k->slow, key, payload, NULL);
        if (r == NULL)
            sink_report(k, key);
        Py_XDECREF(r);
        return;
    }
    if (due) {
        PyObject *r = PyObject_CallNoArgs(k->kick);
        if (r == NULL)
            sink_report(k, key);
        Py_XDECREF(r);
    }
}

/* A thread that Python did not start (zenoh's) gets a fresh Python thread state for every callback and
   loses it after: pyo3 takes the GIL with PyGILState_Ensure, and the matching Release deletes a thread state
   whose count falls to 0, with the 16 KiB frame stack CPython maps for it (an mmap, page faults and a munmap
   a message: docs/performance.md, "Callbacks on zenoh's threads"). One Ensure never released keeps this thread's state for the life of the
   process; every later callback then only takes and drops the GIL. Call it with the GIL held. */
static _Thread_local int thread_pinned = 0;

static void pin_this_thread(void) {
    if (!thread_pinned) {
        thread_pinned = 1;
        (void)PyGILState_Ensure();
    }
}

static PyObject *wire_pin_thread(PyObject *module, PyObject *unused) {
    pin_this_thread();
    Py_RETURN_NONE;
}

/* sink(sample): a zenoh sample (on zenoh's thread) */
static PyObject *StateSink_vectorcall(PyObject *callable, PyObject *const *args, size_t nargsf, PyObject *kwnames) {
    StateSink *k = (StateSink *)callable;
    pin_this_thread();
    if (PyVectorcall_NARGS(nargsf) != 1 || kwnames != NULL) {
        PyErr_SetString(PyExc_TypeError, "a StateSink takes one zenoh sample");
        return NULL;
    }
    PyObject *item = sample_item(args[0], Py_None);
    if (item == NULL) {
        sink_report(k, NULL);
        Py_RETURN_NONE;
    }
    if (item != Py_None)
        sink_message(k, PyTuple_GET_ITEM(item, 0), PyTuple_GET_ITEM(item, 1));
    Py_DECREF(item);
    Py_RETURN_NONE;
}

/* sink.take(key, payload): the same for a bus that has no zenoh samples (swarm.net.bus.MemoryBus) */
static PyObject *StateSink_take(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "take(key, payload)");
        return NULL;
    }
    sink_message((StateSink *)self, args[0], args[1]);
    Py_RETURN_NONE;
}

static PyMemberDef StateSink_members[] = {
    {"table", T_OBJECT_EX, offsetof(StateSink, table), 0, "the robot's table of states, by id"},
    {"windows", T_OBJECT_EX, offsetof(StateSink, windows), 0, "its senders' windows, by id"},
    {"waiting", T_OBJECT_EX, offsetof(StateSink, waiting), 0, "the robots the tick under way waits for"},
    {"ended", T_BOOL, offsetof(StateSink, ended), 0, "the run is over: nothing is taken"},
    {"started", T_LONGLONG, offsetof(StateSink, started), 0, "the tick under way (-1: none)"},
    {"posed", T_LONGLONG, offsetof(StateSink, posed), 0, "the seq of the robot's newest pose (-1: none)"},
    {"taken", T_LONGLONG, offsetof(StateSink, taken), 0, "the states taken here"},
    {"me", T_LONGLONG, offsetof(StateSink, me), READONLY, "the robot's id"},
    {NULL, 0, 0, 0, NULL},
};

static PyMethodDef StateSink_methods[] = {
    {"take", (PyCFunction)(void (*)(void))StateSink_take, METH_FASTCALL, "take(key, payload): one message"},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject StateSinkType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "swarm.proto._wire.StateSink",
    .tp_basicsize = sizeof(StateSink),
    .tp_dealloc = (destructor)StateSink_dealloc,
    .tp_traverse = (traverseproc)StateSink_traverse,
    .tp_clear = (inquiry)StateSink_clear,
    .tp_vectorcall_offset = offsetof(StateSink, vectorcall),
    .tp_call = PyVectorcall_Call,
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_VECTORCALL | Py_TPFLAGS_HAVE_GC,
    .tp_doc = "StateSink(me, ids, dec, slow, report, acquire, release, kick, due, table, windows, waiting): a "
              "lock-step robot's neighbour states, taken in C",
    .tp_methods = StateSink_methods,
    .tp_members = StateSink_members,
    .tp_new = StateSink_new,
};

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

static PyTypeObject DeadlineType = {
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

static PyMethodDef wire_methods[] = {
    {"setup", (PyCFunction)(void (*)(void))wire_setup, METH_FASTCALL,
     "setup(state_fields, window_take, sample_parts, to_bytes): what the loops read of Python objects"},
    {"pin_thread", wire_pin_thread, METH_NOARGS,
     "pin_thread(): keep this thread's Python thread state (a callback on zenoh's thread: see swarm.net.bus)"},
    {"drain", (PyCFunction)(void (*)(void))wire_drain, METH_FASTCALL,
     "drain(try_recv, wake): the (key, payload) of every sample try_recv() gives until None, wake-ups left out "
     "(try_recv: a callable, or a tuple of them drained in turn)"},
    {"decode_states", (PyCFunction)(void (*)(void))wire_decode_states, METH_FASTCALL,
     "decode_states(items, dec, ids, parse, states, bad, error, limit): decode a batch of cell states"},
    {"take_states", (PyCFunction)(void (*)(void))wire_take_states, METH_FASTCALL,
     "take_states(states, me, ahead, now, mono, windows, table, rx, away, slow): take a batch of states"},
    {"lock_bodies", (PyCFunction)(void (*)(void))wire_lock_bodies, METH_FASTCALL,
     "lock_bodies(table, dead, waiting, seq, x, y, r2, kind): lock-step bodies() over the table"},
    {"wait_for", (PyCFunction)(void (*)(void))wire_wait_for, METH_FASTCALL,
     "wait_for(table, dead, k, px, py, reach2): lock-step, the robots tick k waits for (older states deleted)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef wire_module = {
    PyModuleDef_HEAD_INIT, "swarm.proto._wire", "A robot's loops over its messages, compiled (agents/, swarm.net.bus).", -1, wire_methods,
};

PyMODINIT_FUNC PyInit__wire(void) {
    if (PyType_Ready(&StateSinkType) < 0 || PyType_Ready(&DeadlineType) < 0 || PyType_Ready(&WindowType) < 0)
        return NULL;
    if ((v_ok = PyUnicode_InternFromString("ok")) == NULL ||
        (v_duplicate = PyUnicode_InternFromString("duplicate")) == NULL ||
        (v_stale = PyUnicode_InternFromString("stale")) == NULL ||
        (v_jump = PyUnicode_InternFromString("jump")) == NULL ||
        (v_forged = PyUnicode_InternFromString("forged")) == NULL)
        return NULL;
    PyObject *m = PyModule_Create(&wire_module);
    if (m == NULL)
        return NULL;
    Py_INCREF(&StateSinkType);
    Py_INCREF(&DeadlineType);
    Py_INCREF(&WindowType);
    if (PyModule_AddObject(m, "Deadline", (PyObject *)&DeadlineType) < 0 ||
        PyModule_AddObject(m, "Window", (PyObject *)&WindowType) < 0 ||
        PyModule_AddObject(m, "StateSink", (PyObject *)&StateSinkType) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
