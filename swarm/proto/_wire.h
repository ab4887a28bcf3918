/* The compiled loops of swarm.proto._wire (one extension module of three files: _wire.c, _wire_states.c,
 * _wire_window.c): what they share. */
#ifndef SWARM_WIRE_H
#define SWARM_WIRE_H
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

/* handed over by setup() (_wire.c): what the loops read of Python objects */
extern PyObject *state_fields, *window_take_fn, *sample_parts, *to_bytes_fn;
enum { F_ID, F_T, F_SEQ, F_X, F_Y, F_R, F_RR, F_N }; /* the tuple state_fields gives: id, t, seq, x, y, r, R */

int wire_ready(void);                                          /* -1 with an error if setup() was not called */
PyObject *fields_of(PyObject *st);                             /* a state's fields as that tuple */
PyObject *sample_item(PyObject *s, PyObject *wake);            /* a zenoh sample as (key, payload), None: a wake */
void pin_this_thread(void);                                    /* keep a foreign thread's Python state */
int window_take(PyObject *w, PyObject *tt, PyObject *seq);     /* a window's common case (_wire_window.c) */
int window_module_init(void);                                  /* the window's verdict strings */

extern PyTypeObject WindowType, DeadlineType, StateSinkType;

/* the functions of the module (_wire_states.c) */
PyObject *wire_take_states(PyObject *module, PyObject *const *args, Py_ssize_t nargs);
PyObject *wire_lock_bodies(PyObject *module, PyObject *const *args, Py_ssize_t nargs);
PyObject *wire_wait_for(PyObject *module, PyObject *const *args, Py_ssize_t nargs);
#endif
