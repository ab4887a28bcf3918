/* A robot's loops over its messages, compiled (docs/performance.md, "The compiled parts of a period"): draining
 * zenoh's inboxes (drain), the cell states of a batch (decode_states, through the decoder it is given: msgspec's,
 * swarm.proto.protocol.decoder), a real-time robot's windows and table (take_states), lock-step's passes over the
 * table (lock_bodies, wait_for) and its neighbour states on zenoh's thread (StateSink), and the real-time waker's
 * timer (Deadline). Each is a transcription of the Python it stands in for (agents/), which runs where this was not
 * built: tests hold the two equal. It parses no msgpack. */
#include "_wire.h"

/* What the loops read of Python objects is handed over by setup() (swarm.proto.protocol calls it once), never
 * looked up here by name: a state's fields as a tuple, a sender window's common-case take, a zenoh sample's parts
 * and a payload's bytes. A rename on the Python side changes the call of setup(), where the tests see it. */
PyObject *state_fields, *window_take_fn, *sample_parts, *to_bytes_fn;

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

int wire_ready(void) {
    if (state_fields == NULL || window_take_fn == NULL || sample_parts == NULL || to_bytes_fn == NULL) {
        PyErr_SetString(PyExc_RuntimeError, "swarm.proto._wire.setup() was not called");
        return -1;
    }
    return 0;
}

/* A state's fields (state_fields(st): id, t, seq, x, y, r, R) as a tuple: a new reference, NULL with the error. */
PyObject *fields_of(PyObject *st) {
    PyObject *f = PyObject_CallOneArg(state_fields, st);
    if (f != NULL && (!PyTuple_CheckExact(f) || PyTuple_GET_SIZE(f) != F_N)) {
        Py_DECREF(f);
        PyErr_SetString(PyExc_TypeError, "state_fields() must give a tuple of (id, t, seq, x, y, r, R)");
        return NULL;
    }
    return f;
}

/* ------------------------------------------------------------------------------------------- inboxes */

/* The (key, payload) of a zenoh sample, or Py_None for a wake-up (an empty payload with the wake attachment):
 * swarm.net.bus._ZenohInbox._item. sample_parts(s) gives (key_expr, payload, attachment), to_bytes(z) a payload's
 * bytes. A new reference; NULL with an exception. */
PyObject *sample_item(PyObject *s, PyObject *wake) {
    if (wire_ready() < 0)
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
        Py_INCREF(j); /* borrowed from ids: held while dec runs */
        PyObject *m = PyObject_Vectorcall(dec, call, 2, NULL);
        Py_DECREF(j);
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

/* A thread that Python did not start (zenoh's) gets a fresh Python thread state for every callback and
   loses it after: pyo3 takes the GIL with PyGILState_Ensure, and the matching Release deletes a thread state
   whose count falls to 0, with the 16 KiB frame stack CPython maps for it (an mmap, page faults and a munmap
   a message: docs/performance.md, "Callbacks on zenoh's threads"). One Ensure never released keeps this thread's state for the life of the
   process; every later callback then only takes and drops the GIL. Call it with the GIL held. */
static _Thread_local int thread_pinned = 0;

void pin_this_thread(void) {
    if (!thread_pinned) {
        thread_pinned = 1;
        (void)PyGILState_Ensure();
    }
}

static PyObject *wire_pin_thread(PyObject *module, PyObject *unused) {
    pin_this_thread();
    Py_RETURN_NONE;
}

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
    if (window_module_init() < 0)
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
