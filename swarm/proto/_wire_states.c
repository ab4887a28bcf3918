/* swarm.proto._wire: a robot's passes over its neighbour states (take_states, lock_bodies, wait_for) and the
 * lock-step state sink. The shared parts: _wire.h. */
#include "_wire.h"

/* ------------------------------------------------------------------------------------------- states */

/* take_states(states, me, ahead, now, mono, windows, table, rx, away, slow): real time, a batch of decoded
 * neighbour states (agents.realtime.Realtime._on_states). A state of another robot, not ahead of this robot's clock
 * (t <= ahead), that its sender's window takes in the common case is taken here: table[j] = s, rx[j] = (its age
 * now, mono), j not away any more. Any other goes to slow(s, key), in its turn (the windows see the states in
 * order). Returns how many were taken here. */
PyObject *wire_take_states(PyObject *module, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 10) {
        PyErr_SetString(PyExc_TypeError, "take_states(states, me, ahead, now, mono, windows, table, rx, away, slow)");
        return NULL;
    }
    PyObject *states = args[0], *me = args[1], *now = args[3], *mono = args[4], *windows = args[5];
    PyObject *table = args[6], *rx = args[7], *away = args[8], *slow = args[9];
    double ahead = PyFloat_AsDouble(args[2]);
    if ((ahead == -1.0 && PyErr_Occurred()) || wire_ready() < 0)
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
PyObject *wire_lock_bodies(PyObject *module, PyObject *const *args, Py_ssize_t nargs) {
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
    if ((seq == -1 && PyErr_Occurred()) || float_args(args + 4, 3, v) < 0 || wire_ready() < 0)
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
        Py_INCREF(nb); /* borrowed from the table: held while the getter runs */
        PyObject *f = state_xy(nb, &nseq, &bx, &by, "lock_bodies");
        Py_DECREF(nb);
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
PyObject *wire_wait_for(PyObject *module, PyObject *const *args, Py_ssize_t nargs) {
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
    if ((k == -1 && PyErr_Occurred()) || float_args(args + 3, 3, v) < 0 || wire_ready() < 0)
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
        Py_INCREF(nb); /* borrowed from the table: held while the getter runs */
        PyObject *f = state_xy(nb, &nseq, &bx, &by, "wait_for");
        Py_DECREF(nb);
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
 * `posed` (its newest pose's seq) and `done` (the newest tick done) up to date under its lock, and reads `taken` (the
 * states taken here). A state of a tick past the next one the robot computes (the larger of done + 1 and started) goes
 * to the Python, which keeps it aside until that tick is done.
 * A state whose cell key's id is known, that dec decodes, of another robot, not ahead of the robot's next tick,
 * and that its sender's window takes in the common case, is taken under the lock: counted, put in the table, and
 * no longer waited for if it is of the tick under way; kick() is called when that took the last awaited robot off
 * and due() says so (nothing else a state changes is read by due()). Any other message goes, untouched, to slow
 * (the Python, which takes, refuses or counts it); an error of either goes to report. Nothing raises into the bus. */
typedef struct {
    PyObject_HEAD
    vectorcallfunc vectorcall;
    PyObject *ids, *dec, *slow, *report, *acquire, *release, *kick, *due, *table, *windows, *waiting;
    long long me, started, posed, done, taken;
    char ended;
} StateSink;

static PyObject *StateSink_vectorcall(PyObject *callable, PyObject *const *args, size_t nargsf, PyObject *kwnames);

static PyObject *StateSink_new(PyTypeObject *tp, PyObject *args, PyObject *kw) {
    long long me;
    PyObject *o[11];
    if (wire_ready() < 0)
        return NULL;
    if (!PyArg_ParseTuple(args, "LO!OOOOOOOO!O!O!", &me, &PyDict_Type, &o[0], &o[1], &o[2], &o[3], &o[4], &o[5],
                          &o[6], &o[7], &PyDict_Type, &o[8], &PyDict_Type, &o[9], &PySet_Type, &o[10]))
        return NULL;
    StateSink *k = (StateSink *)tp->tp_alloc(tp, 0);
    if (k == NULL)
        return NULL;
    k->vectorcall = StateSink_vectorcall;
    k->me = me;
    k->started = k->posed = k->done = -1;
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
    long long law = k->done + 1 > k->started ? k->done + 1 : k->started; /* Agent._law_tick */
    if (q > law) /* of the tick after the next one it computes: kept aside by the Python (Intake._on_state) */
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
    rc = -1;
    if (PyObject_SetItem(k->table, j, st) < 0)
        goto done;
    k->taken += 1;
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
    {"done", T_LONGLONG, offsetof(StateSink, done), 0, "the newest tick done, its early states taken (-1: none)"},
    {"taken", T_LONGLONG, offsetof(StateSink, taken), 0, "the states taken here"},
    {"me", T_LONGLONG, offsetof(StateSink, me), READONLY, "the robot's id"},
    {NULL, 0, 0, 0, NULL},
};

static PyMethodDef StateSink_methods[] = {
    {"take", (PyCFunction)(void (*)(void))StateSink_take, METH_FASTCALL, "take(key, payload): one message"},
    {NULL, NULL, 0, NULL},
};

PyTypeObject StateSinkType = {
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
