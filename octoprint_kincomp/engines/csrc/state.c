/* Reading and writing the stream state: the declared record of core/state.py
 * (StreamState, its BacklashState and its Report), by attribute name, in the instance
 * dictionaries. What the kernel cannot hold leaves the line to the Python path. */
#include "kernel.h"

static PyObject *s_q_drive, *s_m, *s_fw, *s_fw_text, *s_w, *s_g, *s_q_last, *s_limit_recheck, *s_backlash,
    *s_dir, *s_anchor, *s_report, *s_lines, *s_moves, *s_moves_compensated, *s_lines_out,
    *s_takeup_moves, *s_max_correction_um, *s_lineno, *s_inches, *s_e_absolute_mode,
    *s_e_pos, *s_feed, *s_absolute, *s_axis_key[3], *s_plane, *s_ij_absolute, *s_arcs_kept,
    *s_arcs_split, *s_arcs_linearised, *s_arc_segments, *s_arc_max_deviation_um;


int kk_intern_names(void)
{
#define INTERN(var, text) if (!(var = PyUnicode_InternFromString(text))) return -1
    INTERN(s_q_drive, "q_drive");
    INTERN(s_m, "m");
    INTERN(s_fw, "fw");
    INTERN(s_fw_text, "fw_text");
    INTERN(s_w, "w");
    INTERN(s_g, "g");
    INTERN(s_q_last, "q_last");
    INTERN(s_limit_recheck, "limit_recheck");
    INTERN(s_backlash, "backlash");
    INTERN(s_dir, "dir");
    INTERN(s_anchor, "anchor");
    INTERN(s_report, "report");
    INTERN(s_lines, "lines");
    INTERN(s_moves, "moves");
    INTERN(s_moves_compensated, "moves_compensated");
    INTERN(s_lines_out, "lines_out");
    INTERN(s_takeup_moves, "takeup_moves");
    INTERN(s_max_correction_um, "max_correction_um");
    INTERN(s_lineno, "lineno");
    INTERN(s_inches, "inches");
    INTERN(s_e_absolute_mode, "e_absolute_mode");
    INTERN(s_e_pos, "e_pos");
    INTERN(s_feed, "feed");
    INTERN(s_absolute, "absolute");
    INTERN(s_plane, "plane");
    INTERN(s_ij_absolute, "ij_absolute");
    INTERN(s_arcs_kept, "arcs_kept");
    INTERN(s_arcs_split, "arcs_split");
    INTERN(s_arcs_linearised, "arcs_linearised");
    INTERN(s_arc_segments, "arc_segments");
    INTERN(s_arc_max_deviation_um, "arc_max_deviation_um");
    INTERN(s_axis_key[0], "x");
    INTERN(s_axis_key[1], "y");
    INTERN(s_axis_key[2], "z");
#undef INTERN
    return 0;
}

/* -- reading the state ------------------------------------------------------------------ */

static int get_double(PyObject *o, double *v)
{
    if (PyFloat_CheckExact(o)) {
        *v = PyFloat_AS_DOUBLE(o);
        return 0;
    }
    if (PyLong_CheckExact(o)) {
        *v = PyLong_AsDouble(o);
        if (*v == -1.0 && PyErr_Occurred()) {
            PyErr_Clear();
            return -1;
        }
        return 0;
    }
    return -1;
}

/* Three numbers from a list (or a tuple if ``tuple_ok``; None allowed where known != NULL).
 * -1: not readable. Lists the kernel writes back in place must be lists. */
static int get3(PyObject *seq, double *v, int *known, int tuple_ok)
{
    PyObject *fast = seq;
    Py_ssize_t k;
    if (!PyList_CheckExact(seq) && !(tuple_ok && PyTuple_CheckExact(seq)))
        return -1;
    if (PySequence_Fast_GET_SIZE(fast) != 3)
        return -1;
    for (k = 0; k < 3; k++) {
        PyObject *o = PySequence_Fast_GET_ITEM(fast, k);
        if (o == Py_None && known != NULL) {
            known[k] = 0;
            v[k] = 0.0;
            continue;
        }
        if (get_double(o, &v[k]) < 0)
            return -1;
        if (known != NULL)
            known[k] = 1;
    }
    return 0;
}

void kk_dicts_release(Dicts *d)
{
    Py_CLEAR(d->st);
    Py_CLEAR(d->bl);
    Py_CLEAR(d->rep);
}

/* obj.__dict__ (new reference), NULL without an error if there is none. */
static PyObject *instance_dict(PyObject *obj)
{
    PyObject *d;
    if (obj == NULL || Py_TYPE(obj)->tp_dictoffset == 0)
        return NULL;
    d = PyObject_GenericGetDict(obj, NULL);
    if (d == NULL || !PyDict_CheckExact(d)) {
        PyErr_Clear();
        Py_XDECREF(d);
        return NULL;
    }
    return d;
}

/* d[name], borrowed; NULL (no error set) if missing. */
static PyObject *dget(PyObject *d, PyObject *name)
{
    PyObject *o = PyDict_GetItemWithError(d, name);
    if (o == NULL)
        PyErr_Clear();
    return o;
}

static int get_ll(PyObject *d, PyObject *name, long long *v)
{
    PyObject *o = dget(d, name);
    if (o == NULL || !PyLong_CheckExact(o))
        return -1;
    *v = PyLong_AsLongLong(o);
    if (*v == -1 && PyErr_Occurred()) {
        PyErr_Clear();
        return -1;
    }
    return 0;
}

static int get_flag(PyObject *d, PyObject *name, int *v, int none_ok)
{
    PyObject *o = dget(d, name);
    if (o == NULL)
        return -1;
    if (o == Py_None && none_ok) {
        *v = -1;
        return 0;
    }
    if (o != Py_True && o != Py_False)
        return -1;
    *v = o == Py_True;
    return 0;
}

/* Load the state. Returns 0, or 1 when the state is outside what the kernel holds (the
 * Python path decides; the dictionaries are then released). */
int kk_load(PyObject *state, State *s, Dicts *D)
{
    PyObject *o, *bl;
    int k;
    double tmp[3];
    int known[3];

    memset(s, 0, sizeof(State));
    D->st = D->bl = D->rep = NULL;
    if (!(D->st = instance_dict(state)))
        goto python;
    bl = dget(D->st, s_backlash);
    if (!(D->bl = instance_dict(bl)) || !(D->rep = instance_dict(dget(D->st, s_report))))
        goto python;
    /* drives away from the command of the desired position (after a partial G28 under
     * skew): the reference path starts the next move from there */
    if ((o = dget(D->st, s_q_drive)) == NULL || o != Py_None)
        goto python;
    if (get_flag(D->st, s_absolute, &s->absolute, 0) < 0 ||
        get_flag(D->st, s_inches, &s->inches, 0) < 0 ||
        get_flag(D->st, s_e_absolute_mode, &s->e_abs_mode, 1) < 0 ||
        get_flag(D->st, s_ij_absolute, &s->ij_absolute, 0) < 0)
        goto python;
    {
        long long plane;
        if (get_ll(D->st, s_plane, &plane) < 0)
            goto python;
        s->plane = (int)plane;
    }
    if (!(o = dget(D->st, s_e_pos)))
        goto python;
    s->e_known = o != Py_None;
    if (s->e_known && get_double(o, &s->e_pos) < 0)
        goto python;
    if (!(o = dget(D->st, s_m)) || get3(o, s->m, known, 1) < 0)
        goto python;
    s->m_known = known[0] && known[1] && known[2];
    if (!(o = dget(D->st, s_fw)) || get3(o, s->fw, s->fw_known, 0) < 0)
        goto python;
    if (!(o = dget(D->st, s_fw_text)) || !PyList_CheckExact(o) || PyList_GET_SIZE(o) != 3)
        goto python;
    for (k = 0; k < 3; k++) {
        PyObject *t = PyList_GET_ITEM(o, k);
        Py_ssize_t len;
        if (t == Py_None) {
            s->fwt_len[k] = -1;
            continue;
        }
        if (!PyUnicode_Check(t) || !PyUnicode_IS_ASCII(t))
            goto python;
        len = PyUnicode_GET_LENGTH(t);
        if (len > MAX_TEXT)
            goto python;
        memcpy(s->fwt[k], PyUnicode_DATA(t), len);
        s->fwt[k][len] = 0;
        s->fwt_len[k] = (int)len;
    }
    if (!(o = dget(D->st, s_w)) || get3(o, s->w, NULL, 1) < 0)
        goto python;
    if (!(o = dget(D->st, s_g)) || get3(o, s->g, NULL, 1) < 0)
        goto python;
    if (!(o = dget(D->st, s_q_last)))
        goto python;
    s->q_last_known = o != Py_None;
    if (s->q_last_known && get3(o, s->q_last, NULL, 1) < 0)
        goto python;
    if (!(o = dget(D->st, s_limit_recheck)) || !PyList_CheckExact(o) || PyList_GET_SIZE(o) != 3)
        goto python;
    for (k = 0; k < 3; k++) {
        PyObject *b = PyList_GET_ITEM(o, k);
        if (b != Py_True && b != Py_False)
            goto python;
        s->recheck[k] = b == Py_True;
    }
    if (!(o = dget(D->bl, s_dir)) || get3(o, tmp, NULL, 0) < 0)
        goto python;
    for (k = 0; k < 3; k++) {
        if (tmp[k] != 0.0 && tmp[k] != 1.0 && tmp[k] != -1.0)
            goto python;
        s->dir[k] = (long)tmp[k];
    }
    if (!(o = dget(D->bl, s_anchor)) || get3(o, s->anchor, s->anchor_known, 0) < 0)
        goto python;
    if (get_ll(D->st, s_lineno, &s->lineno) < 0 || get_ll(D->rep, s_lines, &s->lines) < 0 ||
        get_ll(D->rep, s_moves, &s->moves) < 0 ||
        get_ll(D->rep, s_moves_compensated, &s->moves_comp) < 0 ||
        get_ll(D->rep, s_lines_out, &s->lines_out) < 0 ||
        get_ll(D->rep, s_takeup_moves, &s->takeup) < 0 ||
        get_ll(D->rep, s_arcs_kept, &s->arcs_kept) < 0 ||
        get_ll(D->rep, s_arcs_split, &s->arcs_split) < 0 ||
        get_ll(D->rep, s_arcs_linearised, &s->arcs_lin) < 0 ||
        get_ll(D->rep, s_arc_segments, &s->arc_segments) < 0)
        goto python;
    if (!(o = dget(D->rep, s_arc_max_deviation_um)) || get_double(o, &s->arc_dev) < 0)
        goto python;
    if (!(o = dget(D->rep, s_max_correction_um)) || !PyDict_CheckExact(o))
        goto python;
    for (k = 0; k < 3; k++) {
        PyObject *v = dget(o, s_axis_key[k]);
        if (v == NULL || get_double(v, &s->maxc[k]) < 0)
            goto python;
    }
    return 0;
python:
    kk_dicts_release(D);
    return 1;
}

/* d[name] = o, o a new reference (consumed; NULL: the error is passed on). */
/* A fresh list (or tuple) of three floats. */
static PyObject *seq3(const double *v, int tuple)
{
    PyObject *t = tuple ? PyTuple_New(3) : PyList_New(3);
    int k;
    if (t == NULL)
        return NULL;
    for (k = 0; k < 3; k++) {
        PyObject *o = PyFloat_FromDouble(v[k]);
        if (o == NULL) {
            Py_DECREF(t);
            return NULL;
        }
        if (tuple)
            PyTuple_SET_ITEM(t, k, o);
        else
            PyList_SET_ITEM(t, k, o);
    }
    return t;
}

static int set_owned(PyObject *d, PyObject *name, PyObject *o)
{
    int r;
    if (o == NULL)
        return -1;
    r = PyDict_SetItem(d, name, o);
    Py_DECREF(o);
    return r;
}

static int set_ll(PyObject *d, PyObject *name, long long v, long long old)
{
    return v == old ? 0 : set_owned(d, name, PyLong_FromLongLong(v));
}

static int set_double(PyObject *d, PyObject *name, double v)
{
    return set_owned(d, name, PyFloat_FromDouble(v));
}

static int set_item_double(PyObject *list, int k, double v)
{
    PyObject *o = PyFloat_FromDouble(v);
    if (o == NULL)
        return -1;
    return PyList_SetItem(list, k, o);  /* steals o */
}

/* Write back what the lines committed since ``before`` changed (lists that the Python
 * path changes in place are changed in place). Only an allocation failure can stop it
 * half-way: the caller then raises, and the queue forgets the positions (queue.py). */
int kk_store(const Dicts *D, const State *s, const State *before)
{
    PyObject *o;
    int k;

    if (s->lines == before->lines)
        return 0;  /* nothing committed */
    if (set_ll(D->st, s_lineno, s->lineno, before->lineno) < 0 ||
        set_ll(D->rep, s_lines, s->lines, before->lines) < 0 ||
        set_ll(D->rep, s_moves, s->moves, before->moves) < 0 ||
        set_ll(D->rep, s_moves_compensated, s->moves_comp, before->moves_comp) < 0 ||
        set_ll(D->rep, s_lines_out, s->lines_out, before->lines_out) < 0 ||
        set_ll(D->rep, s_takeup_moves, s->takeup, before->takeup) < 0 ||
        set_ll(D->rep, s_arcs_kept, s->arcs_kept, before->arcs_kept) < 0 ||
        set_ll(D->rep, s_arcs_split, s->arcs_split, before->arcs_split) < 0 ||
        set_ll(D->rep, s_arcs_linearised, s->arcs_lin, before->arcs_lin) < 0 ||
        set_ll(D->rep, s_arc_segments, s->arc_segments, before->arc_segments) < 0)
        return -1;
    if (s->arc_dev != before->arc_dev && set_double(D->rep, s_arc_max_deviation_um, s->arc_dev) < 0)
        return -1;
    if (s->e_set) {
        if (s->e_none ? PyDict_SetItem(D->st, s_e_pos, Py_None) < 0
                      : set_double(D->st, s_e_pos, s->e_pos) < 0)
            return -1;
    }
    if (s->f_set && set_double(D->st, s_feed, s->feed) < 0)
        return -1;
    /* the previous command and the axes to re-evaluate (inert lines reset them) */
    if (s->q_last_known) {
        if (set_owned(D->st, s_q_last, seq3(s->q_last, 1)) < 0)
            return -1;
    } else if (PyDict_SetItem(D->st, s_q_last, Py_None) < 0) {
        return -1;
    }
    if (memcmp(s->recheck, before->recheck, sizeof s->recheck) != 0) {
        if (!(o = PyList_New(3)))
            return -1;
        for (k = 0; k < 3; k++) {
            PyObject *b = s->recheck[k] ? Py_True : Py_False;
            Py_INCREF(b);
            PyList_SET_ITEM(o, k, b);
        }
        if (set_owned(D->st, s_limit_recheck, o) < 0)
            return -1;
    }
    if (!s->moved)
        return 0;
    if (set_owned(D->st, s_m, seq3(s->m, 0)) < 0)
        return -1;
    for (k = 0; k < 3; k++) {
        if (!s->fwt_dirty[k])
            continue;
        PyObject *t = PyUnicode_FromStringAndSize(s->fwt[k], s->fwt_len[k]);
        if (t == NULL || PyList_SetItem(dget(D->st, s_fw_text), k, t) < 0)
            return -1;
        if (set_item_double(dget(D->st, s_fw), k, s->fw[k]) < 0)
            return -1;
    }
    for (k = 0; k < 3; k++) {
        if (s->dir[k] != before->dir[k]) {
            PyObject *v = PyLong_FromLong(s->dir[k]);
            if (v == NULL || PyList_SetItem(dget(D->bl, s_dir), k, v) < 0)
                return -1;
        }
        if (s->anchor_known[k] && (!before->anchor_known[k] ||
                                   memcmp(&s->anchor[k], &before->anchor[k],
                                          sizeof(double)) != 0) &&  /* (-0.0 vs 0.0) */
            set_item_double(dget(D->bl, s_anchor), k, s->anchor[k]) < 0)
            return -1;
        if (s->maxc[k] != before->maxc[k] &&
            set_double(dget(D->rep, s_max_correction_um), s_axis_key[k], s->maxc[k]) < 0)
            return -1;
    }
    return 0;
}

