/* Reading and writing the stream state: the declared record of core/state.py
 * (StreamState, its BacklashState and its Report), slotted classes whose attributes the
 * kernel reads and writes in their slots, at the offsets ``layout`` found (no attribute
 * lookup, no dictionary). What the kernel cannot hold leaves the line to the Python path.
 *
 * Writing back, a number or string that only its slot (or its list) holds - reference
 * count 1 - is changed in place instead of replaced, as CPython itself grows a sole-owned
 * string in place: nobody else holds it, so nobody can see it change (nor a hash cached in
 * it: a string whose hash was taken is replaced), and the queuing hook saves a dozen
 * allocations a line. Anything shared is replaced as before. */
#include "kernel.h"

#include <structmember.h>

/* The fields, by owner: names as in core/state.py, offsets found by kk_layout. */
enum { ST_Q_DRIVE, ST_M, ST_FW, ST_FW_TEXT, ST_W, ST_G, ST_Q_LAST, ST_LIMIT_RECHECK,
       ST_BACKLASH, ST_REPORT, ST_LINENO, ST_INCHES, ST_E_ABS_MODE, ST_E_POS, ST_FEED,
       ST_ABSOLUTE, ST_PLANE, ST_IJ_ABSOLUTE, ST_N };
static const char *const st_names[ST_N] = {
    "q_drive", "m", "fw", "fw_text", "w", "g", "q_last", "limit_recheck", "backlash",
    "report", "lineno", "inches", "e_absolute_mode", "e_pos", "feed", "absolute", "plane",
    "ij_absolute"};
enum { BL_DIR, BL_ANCHOR, BL_N };
static const char *const bl_names[BL_N] = {"dir", "anchor"};
enum { RP_LINES, RP_MOVES, RP_MOVES_COMP, RP_LINES_OUT, RP_TAKEUP, RP_ARCS_KEPT,
       RP_ARCS_SPLIT, RP_ARCS_LIN, RP_ARC_SEGMENTS, RP_ARC_DEV, RP_MAXC, RP_N };
static const char *const rp_names[RP_N] = {
    "lines", "moves", "moves_compensated", "lines_out", "takeup_moves", "arcs_kept",
    "arcs_split", "arcs_linearised", "arc_segments", "arc_max_deviation_um",
    "max_correction_um"};

static PyTypeObject *st_type, *bl_type, *rp_type;  /* NULL until kk_layout */
static PyObject *small_int[3];  /* -1, 0, 1 (CPython's shared ones, where it shares them) */
static Py_ssize_t st_off[ST_N], bl_off[BL_N], rp_off[RP_N];

/* The slot offsets of ``names`` in ``type`` (each a member descriptor of an object slot of
 * that very class); -1 with TypeError if one is not. */
static int find_slots(PyObject *type, const char *const *names, int n, Py_ssize_t *off)
{
    int i;
    for (i = 0; i < n; i++) {
        PyObject *d = PyObject_GetAttrString(type, names[i]);
        int ok;
        if (d == NULL)
            PyErr_Clear();
        ok = d != NULL && Py_IS_TYPE(d, &PyMemberDescr_Type) &&
             ((PyMemberDescrObject *)d)->d_member->type == T_OBJECT_EX &&
             ((PyMemberDescrObject *)d)->d_common.d_type == (PyTypeObject *)type;
        if (ok)
            off[i] = ((PyMemberDescrObject *)d)->d_member->offset;
        Py_XDECREF(d);
        if (!ok) {
            PyErr_Format(PyExc_TypeError, "layout: %R.%s is not a slot", type, names[i]);
            return -1;
        }
    }
    return 0;
}

/* layout(StreamState, BacklashState, Report): where the kernel finds the fields (all or
 * nothing: a refused layout leaves the one before in place). */
PyObject *kk_layout(PyObject *mod, PyObject *const *args, Py_ssize_t nargs)
{
    Py_ssize_t st[ST_N], bl[BL_N], rp[RP_N];
    int k;
    (void)mod;
    if (nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "layout(StreamState, BacklashState, Report)");
        return NULL;
    }
    for (k = 0; k < 3; k++)
        if (!PyType_Check(args[k])) {
            PyErr_SetString(PyExc_TypeError, "layout: three classes");
            return NULL;
        }
    if (find_slots(args[0], st_names, ST_N, st) < 0 ||
        find_slots(args[1], bl_names, BL_N, bl) < 0 ||
        find_slots(args[2], rp_names, RP_N, rp) < 0)
        return NULL;
    for (k = 0; k < 3; k++)
        if (small_int[k] == NULL && !(small_int[k] = PyLong_FromLong(k - 1)))
            return NULL;
    memcpy(st_off, st, sizeof st);
    memcpy(bl_off, bl, sizeof bl);
    memcpy(rp_off, rp, sizeof rp);
    Py_XSETREF(st_type, (PyTypeObject *)Py_NewRef(args[0]));
    Py_XSETREF(bl_type, (PyTypeObject *)Py_NewRef(args[1]));
    Py_XSETREF(rp_type, (PyTypeObject *)Py_NewRef(args[2]));
    Py_RETURN_NONE;
}

/* The object in a slot (borrowed; NULL: never set), and a new value for it (stolen). */
#define SLOT(obj, off) (*(PyObject **)((char *)(obj) + (off)))

static void put(PyObject *obj, Py_ssize_t off, PyObject *v)
{
    PyObject *old = SLOT(obj, off);
    SLOT(obj, off) = v;
    Py_XDECREF(old);
}

/* -- reading the state ------------------------------------------------------------------ */

static int get_double(PyObject *o, double *v)
{
    if (o == NULL)
        return -1;
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

/* The items of a list of three (or a tuple, if ``tuple_ok``); NULL: not one. */
static PyObject **items_of3(PyObject *seq, int tuple_ok)
{
    if (seq == NULL)
        return NULL;
    if (PyList_CheckExact(seq))
        return PyList_GET_SIZE(seq) == 3 ? ((PyListObject *)seq)->ob_item : NULL;
    if (tuple_ok && PyTuple_CheckExact(seq))
        return PyTuple_GET_SIZE(seq) == 3 ? ((PyTupleObject *)seq)->ob_item : NULL;
    return NULL;
}

/* Three numbers from a list (or a tuple if ``tuple_ok``; None allowed where known != NULL).
 * -1: not readable. Lists the kernel writes back in place must be lists. */
static int get3(PyObject *seq, double *v, int *known, int tuple_ok)
{
    PyObject **it = items_of3(seq, tuple_ok);
    int k;
    if (it == NULL)
        return -1;
    for (k = 0; k < 3; k++) {
        PyObject *o = it[k];
        if (PyFloat_CheckExact(o))  /* (the common case first) */
            v[k] = PyFloat_AS_DOUBLE(o);
        else if (o == Py_None && known != NULL)
            v[k] = 0.0;
        else if (get_double(o, &v[k]) < 0)
            return -1;
        if (known != NULL)
            known[k] = o != Py_None;
    }
    return 0;
}

/* The backlash directions: a list of three of -1, 0, +1 (ints, or floats). -1: not. */
static int get_dirs(PyObject *seq, long *dir)
{
    PyObject **it = items_of3(seq, 0);
    int k;
    if (it == NULL)
        return -1;
    for (k = 0; k < 3; k++) {
        PyObject *o = it[k];
        double d;
        if (o == small_int[0] || o == small_int[1] || o == small_int[2]) {
            dir[k] = (o == small_int[2]) - (o == small_int[0]);
            continue;
        }
        if (get_double(o, &d) < 0 || (d != 0.0 && d != 1.0 && d != -1.0))
            return -1;
        dir[k] = (long)d;
    }
    return 0;
}

void kk_objs_release(Objs *d)
{
    Py_CLEAR(d->st);
    Py_CLEAR(d->bl);
    Py_CLEAR(d->rep);
}

static int get_ll(PyObject *o, long long *v)
{
    if (o == NULL || !PyLong_CheckExact(o))
        return -1;
#if PY_VERSION_HEX < 0x030C0000
    if (Py_SIZE(o) == 0 || Py_SIZE(o) == 1) {  /* (a counter: one digit at most) */
        *v = Py_SIZE(o) ? (long long)((PyLongObject *)o)->ob_digit[0] : 0;
        return 0;
    }
#endif
    *v = PyLong_AsLongLong(o);
    if (*v == -1 && PyErr_Occurred()) {
        PyErr_Clear();
        return -1;
    }
    return 0;
}

static int get_flag(PyObject *o, int *v, int none_ok)
{
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
 * Python path decides; the objects are then released). */
int kk_load(PyObject *state, State *s, Objs *D)
{
    PyObject *o, *st, *bl, *rp;
    int k;
    int known[3];

    memset(s, 0, sizeof(State));
    D->st = D->bl = D->rep = NULL;
    if (st_type == NULL || !Py_IS_TYPE(state, st_type))
        return 1;
    bl = SLOT(state, st_off[ST_BACKLASH]);
    rp = SLOT(state, st_off[ST_REPORT]);
    if (bl == NULL || !Py_IS_TYPE(bl, bl_type) || rp == NULL || !Py_IS_TYPE(rp, rp_type))
        return 1;
    D->st = st = Py_NewRef(state);
    D->bl = Py_NewRef(bl);
    D->rep = Py_NewRef(rp);
#define F(i) SLOT(st, st_off[i])
    /* drives away from the command of the desired position (after a partial G28 under
     * skew): the reference path starts the next move from there */
    if (F(ST_Q_DRIVE) != Py_None)
        goto python;
    if (get_flag(F(ST_ABSOLUTE), &s->absolute, 0) < 0 ||
        get_flag(F(ST_INCHES), &s->inches, 0) < 0 ||
        get_flag(F(ST_E_ABS_MODE), &s->e_abs_mode, 1) < 0 ||
        get_flag(F(ST_IJ_ABSOLUTE), &s->ij_absolute, 0) < 0)
        goto python;
    {
        long long plane;
        if (get_ll(F(ST_PLANE), &plane) < 0)
            goto python;
        s->plane = (int)plane;
    }
    if (!(o = F(ST_E_POS)))
        goto python;
    s->e_known = o != Py_None;
    if (s->e_known && get_double(o, &s->e_pos) < 0)
        goto python;
    if (get3(F(ST_M), s->m, known, 1) < 0)
        goto python;
    s->m_known = known[0] && known[1] && known[2];
    if (get3(F(ST_FW), s->fw, s->fw_known, 0) < 0)
        goto python;
    if (!(o = F(ST_FW_TEXT)) || !PyList_CheckExact(o) || PyList_GET_SIZE(o) != 3)
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
    if (get3(F(ST_W), s->w, NULL, 1) < 0 || get3(F(ST_G), s->g, NULL, 1) < 0)
        goto python;
    if (!(o = F(ST_Q_LAST)))
        goto python;
    s->q_last_known = o != Py_None;
    if (s->q_last_known && get3(o, s->q_last, NULL, 1) < 0)
        goto python;
    if (!(o = F(ST_LIMIT_RECHECK)) || !PyList_CheckExact(o) || PyList_GET_SIZE(o) != 3)
        goto python;
    for (k = 0; k < 3; k++) {
        PyObject *b = PyList_GET_ITEM(o, k);
        if (b != Py_True && b != Py_False)
            goto python;
        s->recheck[k] = b == Py_True;
    }
    if (get_ll(F(ST_LINENO), &s->lineno) < 0)
        goto python;
#undef F
    if (get_dirs(SLOT(bl, bl_off[BL_DIR]), s->dir) < 0)
        goto python;
    if (get3(SLOT(bl, bl_off[BL_ANCHOR]), s->anchor, s->anchor_known, 0) < 0)
        goto python;
#define R(i) SLOT(rp, rp_off[i])
    if (get_ll(R(RP_LINES), &s->lines) < 0 || get_ll(R(RP_MOVES), &s->moves) < 0 ||
        get_ll(R(RP_MOVES_COMP), &s->moves_comp) < 0 ||
        get_ll(R(RP_LINES_OUT), &s->lines_out) < 0 ||
        get_ll(R(RP_TAKEUP), &s->takeup) < 0 ||
        get_ll(R(RP_ARCS_KEPT), &s->arcs_kept) < 0 ||
        get_ll(R(RP_ARCS_SPLIT), &s->arcs_split) < 0 ||
        get_ll(R(RP_ARCS_LIN), &s->arcs_lin) < 0 ||
        get_ll(R(RP_ARC_SEGMENTS), &s->arc_segments) < 0 ||
        get_double(R(RP_ARC_DEV), &s->arc_dev) < 0)
        goto python;
    if (get3(R(RP_MAXC), s->maxc, NULL, 0) < 0)
        goto python;
#undef R
    return 0;
python:
    kk_objs_release(D);
    return 1;
}

/* -- writing it back --------------------------------------------------------------------- */

/* The float *at (a slot or a list or tuple item) becomes v: written in place where that
 * float is this reference's alone (reference count 1: nobody else can see it change, as
 * CPython itself reuses a sole-owned tuple or string), else a new float replaces it. */
static int put_float(PyObject **at, double v)
{
    PyObject *o = *at, *f;
    if (o != NULL && PyFloat_CheckExact(o) && Py_REFCNT(o) == 1) {
        ((PyFloatObject *)o)->ob_fval = v;
        return 0;
    }
    if (!(f = PyFloat_FromDouble(v)))
        return -1;
    *at = f;
    Py_XDECREF(o);
    return 0;
}

/* The items of a sole-owned list or tuple of three (NULL: not one, or shared; a tuple
 * from CPython 3.14 on, which keeps its hash once computed). */
static PyObject **own3(PyObject *seq)
{
    if (seq == NULL || Py_REFCNT(seq) != 1)
        return NULL;
    if (PyList_CheckExact(seq) && PyList_GET_SIZE(seq) == 3)
        return ((PyListObject *)seq)->ob_item;
#if PY_VERSION_HEX < 0x030E0000
    if (PyTuple_CheckExact(seq) && PyTuple_GET_SIZE(seq) == 3)
        return ((PyTupleObject *)seq)->ob_item;
#endif
    return NULL;
}

/* &item k of a list of three, checked again where it is written (Python code run by a
 * garbage collection between the load and the store could have replaced it): NULL with
 * RuntimeError if it is not one any more */
static PyObject **item_of3(PyObject *list, int k)
{
    if (list == NULL || !PyList_CheckExact(list) || PyList_GET_SIZE(list) != 3) {
        PyErr_SetString(PyExc_RuntimeError, "the stream state changed during a kernel call");
        return NULL;
    }
    return &((PyListObject *)list)->ob_item[k];
}

/* obj's slot at ``off`` = three floats v, a list (or a tuple): the one there now, changed
 * in place, where it is the slot's alone and of that kind; else a new one (the Python path
 * replaces these, so a holder of the old one must not see it change). */
static int set_seq3(PyObject *obj, Py_ssize_t off, const double *v, int tuple)
{
    PyObject *seq = SLOT(obj, off), **items = own3(seq);
    int k;
    if (items != NULL && (tuple ? PyTuple_CheckExact(seq) : PyList_CheckExact(seq))) {
        for (k = 0; k < 3; k++)
            if (put_float(&items[k], v[k]) < 0)
                return -1;
        return 0;
    }
    if (!(seq = tuple ? PyTuple_New(3) : PyList_New(3)))
        return -1;
    items = tuple ? ((PyTupleObject *)seq)->ob_item : ((PyListObject *)seq)->ob_item;
    for (k = 0; k < 3; k++)  /* (fresh: NULL items) */
        if (put_float(&items[k], v[k]) < 0) {
            Py_DECREF(seq);
            return -1;
        }
    put(obj, off, seq);
    return 0;
}

/* obj's slot at ``off`` = o, a new reference (NULL: the error is passed on). */
static int set_owned(PyObject *obj, Py_ssize_t off, PyObject *o)
{
    if (o == NULL)
        return -1;
    put(obj, off, o);
    return 0;
}

/* obj's slot at ``off`` = the int v (``old``: the value there). In place where that int is
 * the slot's alone and v, like it, is one digit above CPython's shared small ints (the
 * counters, from the 257th line on; the layout of CPython 3.8 to 3.11), else a new int. */
static int set_ll(PyObject *obj, Py_ssize_t off, long long v, long long old)
{
    if (v == old)
        return 0;
#if PY_VERSION_HEX < 0x030C0000
    {
        PyObject *o = SLOT(obj, off);
        if (v > 256 && v < ((long long)1 << PyLong_SHIFT) && o != NULL &&
            PyLong_CheckExact(o) && Py_REFCNT(o) == 1 && Py_SIZE(o) == 1) {
            ((PyLongObject *)o)->ob_digit[0] = (digit)v;
            return 0;
        }
    }
#endif
    return set_owned(obj, off, PyLong_FromLongLong(v));
}

/* Item k of ``list`` = the ASCII text t (len characters). In place where the string there
 * is the list's alone, of that length, never hashed nor interned (CPython's own rule for
 * growing a string in place), else a new string. */
static int set_item_text(PyObject *list, int k, const char *t, int len)
{
    PyObject **at = item_of3(list, k), *o, *n;
    if (at == NULL)
        return -1;
    o = *at;
    if (o != NULL && PyUnicode_CheckExact(o) && Py_REFCNT(o) == 1 &&
        PyUnicode_IS_COMPACT_ASCII(o) && PyUnicode_GET_LENGTH(o) == len &&
        ((PyASCIIObject *)o)->hash == -1 && !PyUnicode_CHECK_INTERNED(o)
#if PY_VERSION_HEX < 0x030C0000
        && ((PyASCIIObject *)o)->wstr == NULL
#endif
    ) {
        memcpy(PyUnicode_1BYTE_DATA(o), t, len);
        return 0;
    }
    if (!(n = PyUnicode_New(len, 127)))  /* (ASCII: a number's text) */
        return -1;
    memcpy(PyUnicode_1BYTE_DATA(n), t, len);
    *at = n;
    Py_XDECREF(o);
    return 0;
}

/* item k of a list the Python path changes in place = v */
static int set_item_double(PyObject *list, int k, double v)
{
    PyObject **at = item_of3(list, k);
    return at == NULL ? -1 : put_float(at, v);
}

/* Write back what the lines committed since ``before`` changed (lists that the Python
 * path changes in place are changed in place). Only an allocation failure can stop it
 * half-way: the caller then raises, and the queue forgets the positions (queue.py). */
int kk_store(const Objs *D, const State *s, const State *before)
{
    PyObject *o, *st = D->st, *bl = D->bl, *rp = D->rep;
    int k;

    if (s->lines == before->lines)
        return 0;  /* nothing committed */
#define R(i) rp_off[i]
    if (set_ll(st, st_off[ST_LINENO], s->lineno, before->lineno) < 0 ||
        set_ll(rp, R(RP_LINES), s->lines, before->lines) < 0 ||
        set_ll(rp, R(RP_MOVES), s->moves, before->moves) < 0 ||
        set_ll(rp, R(RP_MOVES_COMP), s->moves_comp, before->moves_comp) < 0 ||
        set_ll(rp, R(RP_LINES_OUT), s->lines_out, before->lines_out) < 0 ||
        set_ll(rp, R(RP_TAKEUP), s->takeup, before->takeup) < 0 ||
        set_ll(rp, R(RP_ARCS_KEPT), s->arcs_kept, before->arcs_kept) < 0 ||
        set_ll(rp, R(RP_ARCS_SPLIT), s->arcs_split, before->arcs_split) < 0 ||
        set_ll(rp, R(RP_ARCS_LIN), s->arcs_lin, before->arcs_lin) < 0 ||
        set_ll(rp, R(RP_ARC_SEGMENTS), s->arc_segments, before->arc_segments) < 0)
        return -1;
    if (s->arc_dev != before->arc_dev && put_float(&SLOT(rp, R(RP_ARC_DEV)), s->arc_dev) < 0)
        return -1;
#undef R
    if (s->e_set && (s->e_none ? (put(st, st_off[ST_E_POS], Py_NewRef(Py_None)), 0)
                               : put_float(&SLOT(st, st_off[ST_E_POS]), s->e_pos)) < 0)
        return -1;
    if (s->f_set && put_float(&SLOT(st, st_off[ST_FEED]), s->feed) < 0)
        return -1;
    /* the previous command and the axes to re-evaluate (inert lines reset them) */
    if (s->q_last_known ? set_seq3(st, st_off[ST_Q_LAST], s->q_last, 1) < 0
                        : (put(st, st_off[ST_Q_LAST], Py_NewRef(Py_None)), 0))
        return -1;
    if (memcmp(s->recheck, before->recheck, sizeof s->recheck) != 0) {
        if (!(o = PyList_New(3)))
            return -1;
        for (k = 0; k < 3; k++)
            PyList_SET_ITEM(o, k, Py_NewRef(s->recheck[k] ? Py_True : Py_False));
        put(st, st_off[ST_LIMIT_RECHECK], o);
    }
    if (!s->moved)
        return 0;
    if (set_seq3(st, st_off[ST_M], s->m, 0) < 0)
        return -1;
    for (k = 0; k < 3; k++) {
        if (!s->fwt_dirty[k])
            continue;
        if (set_item_text(SLOT(st, st_off[ST_FW_TEXT]), k, s->fwt[k], s->fwt_len[k]) < 0)
            return -1;
        if (set_item_double(SLOT(st, st_off[ST_FW]), k, s->fw[k]) < 0)
            return -1;
    }
    for (k = 0; k < 3; k++) {
        if (s->dir[k] != before->dir[k]) {
            PyObject *v = PyLong_FromLong(s->dir[k]);
            if (v == NULL || PyList_SetItem(SLOT(bl, bl_off[BL_DIR]), k, v) < 0)
                return -1;
        }
        if (s->anchor_known[k] && (!before->anchor_known[k] ||
                                   memcmp(&s->anchor[k], &before->anchor[k],
                                          sizeof(double)) != 0) &&  /* (-0.0 vs 0.0) */
            set_item_double(SLOT(bl, bl_off[BL_ANCHOR]), k, s->anchor[k]) < 0)
            return -1;
        if (s->maxc[k] != before->maxc[k] &&
            set_item_double(SLOT(rp, rp_off[RP_MAXC]), k, s->maxc[k]) < 0)
            return -1;
    }
    return 0;
}
