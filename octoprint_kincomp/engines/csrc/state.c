/* The kernel's record of the stream state (kernel.h State) as a tuple of plain values, and
 * its handing over: built and parsed with the public C API only (PyArg_ParseTuple,
 * Py_BuildValue, PyFloat_FromDouble, PyUnicode_FromStringAndSize), never reaching into a
 * Python object. The tuple's order is engines/kernel.py RECORD:
 *
 *   (absolute, inches, e_absolute_mode, plane, ij_absolute, m[3], fw[3], fw_text[3], w[3],
 *    g[3], q_last, limit_recheck[3], dir[3], anchor[3], lineno, e_pos, feed,
 *    (lines, moves, moves_compensated, lines_out, takeup_moves, arcs_kept, arcs_split,
 *     arcs_linearised, arc_segments), arc_max_deviation_um, max_correction_um[3])
 *
 * the [3]s and q_last tuples (q_last None: not known), None where a value is unknown. */
#include "kernel.h"

#define RECORD_FORMAT "ppOip(OOO)(OOO)(OOO)(ddd)(ddd)O(ppp)(lll)(OOO)LOO(LLLLLLLLL)d(ddd)"

/* The names of the record's fields, in its order (module constant RECORD: engines/kernel.py
 * uses the kernel only where its own RECORD says the same; a group in parentheses is a
 * nested tuple, the [3]s are one name each). */
const char kk_record_fields[] =
    "absolute inches e_absolute_mode plane ij_absolute m fw fw_text w g q_last limit_recheck "
    "backlash.dir backlash.anchor lineno e_pos feed (report.lines report.moves "
    "report.moves_compensated report.lines_out report.takeup_moves report.arcs_kept "
    "report.arcs_split report.arcs_linearised report.arc_segments) report.arc_max_deviation_um "
    "report.max_correction_um";

static PyObject *none_ref(void)
{
    Py_INCREF(Py_None);
    return Py_None;
}

/* None, or a number: *known, *v */
static int opt_double(PyObject *o, double *v, int *known)
{
    *known = o != Py_None;
    *v = 0.0;
    if (*known && (*v = PyFloat_AsDouble(o)) == -1.0 && PyErr_Occurred())
        return -1;
    return 0;
}

static PyObject *opt_float(int known, double v)
{
    return known ? PyFloat_FromDouble(v) : none_ref();
}

/* The record from a tuple: 0, 1 if it holds what the kernel does not (a number's text
 * longer than MAX_TEXT, or not ASCII: the reference path then decides), -1 error. */
int kk_state_set(State *s, PyObject *t)
{
    PyObject *eam, *m[3], *fw[3], *ft[3], *ql, *an[3], *ep, *fd;
    State n;
    int k;

    memset(&n, 0, sizeof n);
    if (!PyArg_ParseTuple(t, RECORD_FORMAT ":set_state", &n.absolute, &n.inches, &eam,
                          &n.plane, &n.ij_absolute, &m[0], &m[1], &m[2], &fw[0], &fw[1],
                          &fw[2], &ft[0], &ft[1], &ft[2], &n.w[0], &n.w[1], &n.w[2], &n.g[0],
                          &n.g[1], &n.g[2], &ql, &n.recheck[0], &n.recheck[1], &n.recheck[2],
                          &n.dir[0], &n.dir[1], &n.dir[2], &an[0], &an[1], &an[2], &n.lineno,
                          &ep, &fd, &n.lines, &n.moves, &n.moves_comp, &n.lines_out,
                          &n.takeup, &n.arcs_kept, &n.arcs_split, &n.arcs_lin,
                          &n.arc_segments, &n.arc_dev, &n.maxc[0], &n.maxc[1], &n.maxc[2]))
        return -1;
    n.e_abs_mode = eam == Py_None ? -1 : PyObject_IsTrue(eam);
    if (n.e_abs_mode == -1 && eam != Py_None)
        return -1;
    n.m_known = 1;
    for (k = 0; k < 3; k++) {
        if (opt_double(m[k], &n.m[k], &n.m_has[k]) < 0 ||
            opt_double(fw[k], &n.fw[k], &n.fw_known[k]) < 0 ||
            opt_double(an[k], &n.anchor[k], &n.anchor_known[k]) < 0)
            return -1;
        n.m_known &= n.m_has[k];
        if (n.dir[k] < -1 || n.dir[k] > 1)
            return 1;
        n.fwt_len[k] = -1;
        if (ft[k] != Py_None) {
            Py_ssize_t len, i;
            const char *c = PyUnicode_AsUTF8AndSize(ft[k], &len);
            if (c == NULL)
                return -1;
            if (len > MAX_TEXT)
                return 1;
            for (i = 0; i < len; i++)
                if ((unsigned char)c[i] > 127)
                    return 1;
            memcpy(n.fwt[k], c, len);
            n.fwt[k][len] = 0;
            n.fwt_len[k] = (int)len;
        }
    }
    n.q_last_known = ql != Py_None;
    if (n.q_last_known &&
        !PyArg_Parse(ql, "(ddd)", &n.q_last[0], &n.q_last[1], &n.q_last[2]))
        return -1;
    if (opt_double(ep, &n.e_pos, &n.e_known) < 0 || opt_double(fd, &n.feed, &n.f_known) < 0)
        return -1;
    *s = n;
    return 0;
}

static PyObject *text_or_none(const State *s, int k)
{
    return s->fwt_len[k] < 0 ? none_ref() : PyUnicode_FromStringAndSize(s->fwt[k], s->fwt_len[k]);
}

/* The tuple of the record (a new reference; NULL: error). */
PyObject *kk_state_get(const State *s)
{
    PyObject *q_last = s->q_last_known
                           ? Py_BuildValue("(ddd)", s->q_last[0], s->q_last[1], s->q_last[2])
                           : none_ref();
    PyObject *e_mode = s->e_abs_mode < 0 ? none_ref() : PyBool_FromLong(s->e_abs_mode);
    if (q_last == NULL)
        return NULL;
    return Py_BuildValue(
        "(NNNiN(NNN)(NNN)(NNN)(ddd)(ddd)N(NNN)(lll)(NNN)LNN(LLLLLLLLL)d(ddd))",
        PyBool_FromLong(s->absolute), PyBool_FromLong(s->inches), e_mode, s->plane,
        PyBool_FromLong(s->ij_absolute), opt_float(s->m_has[0], s->m[0]),
        opt_float(s->m_has[1], s->m[1]), opt_float(s->m_has[2], s->m[2]),
        opt_float(s->fw_known[0], s->fw[0]), opt_float(s->fw_known[1], s->fw[1]),
        opt_float(s->fw_known[2], s->fw[2]), text_or_none(s, 0), text_or_none(s, 1),
        text_or_none(s, 2), s->w[0], s->w[1], s->w[2], s->g[0], s->g[1], s->g[2], q_last,
        PyBool_FromLong(s->recheck[0]), PyBool_FromLong(s->recheck[1]),
        PyBool_FromLong(s->recheck[2]), s->dir[0], s->dir[1], s->dir[2],
        opt_float(s->anchor_known[0], s->anchor[0]), opt_float(s->anchor_known[1], s->anchor[1]),
        opt_float(s->anchor_known[2], s->anchor[2]), s->lineno, opt_float(s->e_known, s->e_pos),
        opt_float(s->f_known, s->feed), s->lines, s->moves, s->moves_comp, s->lines_out,
        s->takeup, s->arcs_kept, s->arcs_split, s->arcs_lin, s->arc_segments, s->arc_dev,
        s->maxc[0], s->maxc[1], s->maxc[2]);
}

/* Take the state from Python (``get()``) unless the kernel holds it: 0 held, 1 not one the
 * kernel holds (no ``get``, or Python's state outside the record), -1 error (of ``get``). */
int kk_take(Kernel *K)
{
    PyObject *t;
    int r;
    if (K->holds)
        return 0;
    if (K->get == NULL)
        return 1;
    if (!(t = PyObject_CallObject(K->get, NULL)))
        return -1;
    r = t == Py_None ? 1 : kk_state_set(&K->st, t);
    Py_DECREF(t);
    if (r < 0)  /* a value of a type the record does not take: the reference path decides */
        PyErr_Clear(), r = 1;
    if (r == 0)
        K->holds = 1, K->dirty = 0;
    return r;
}

/* Hand the state back to Python (``put(tuple)``) where the kernel holds it and took lines
 * since it took it (else Python's copy is the same): 0, or -1 (an error: Python's copy is
 * then stale; the caller raises and the queue forgets the positions). */
int kk_give(Kernel *K)
{
    PyObject *t, *r;
    int dirty = K->dirty;
    if (!K->holds)
        return 0;
    K->holds = K->dirty = 0;
    if (!dirty || K->put == NULL)
        return 0;
    if (!(t = kk_state_get(&K->st)))
        return -1;
    r = PyObject_CallFunctionObjArgs(K->put, t, NULL);
    Py_DECREF(t);
    if (r == NULL)
        return -1;
    Py_DECREF(r);
    return 0;
}
