/* The Python type ``Kernel``: one model's kernel, and its two entry points, ``line``
 * (the queuing hook: one line) and ``feed`` (files: a block of lines). */
#include "kernel.h"

/* -- Python interface ------------------------------------------------------------------ */

static int read_table(PyObject *seq, Table *t)
{
    Py_ssize_t i, n;
    PyObject *fast = PySequence_Fast(seq, "a backlash table is a sequence of (mm, um)");
    if (fast == NULL)
        return -1;
    n = PySequence_Fast_GET_SIZE(fast);
    if (n < 1 || n > MAX_PTS) {
        Py_DECREF(fast);
        PyErr_SetString(PyExc_ValueError, "backlash table: 1..64 points");
        return -1;
    }
    t->n = (int)n;
    for (i = 0; i < n; i++) {
        PyObject *pt = PySequence_Fast_GET_ITEM(fast, i);
        if (!PyArg_ParseTuple(pt, "dd", &t->pos[i], &t->um[i])) {
            Py_DECREF(fast);
            return -1;
        }
    }
    Py_DECREF(fast);
    return 0;
}

static int Kernel_init(Kernel *self, PyObject *args, PyObject *kwds)
{
    static char *kwlist[] = {"affine", "tables", "half", "deadband", "limits", "decimals",
                             "arcs", NULL};
    PyObject *affine, *tables, *limits, *arcs = Py_None, *breaks;
    int k;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "OOddOi|O", kwlist, &affine, &tables,
                                     &self->half, &self->deadband, &limits, &self->dec,
                                     &arcs))
        return -1;
    /* arcs: None (left to Python), or (pure_translation, tol, k_dev, (budget mm, budget
     * inch), (sliver mm, sliver inch), (overshoot mm, overshoot inch), max_offset, G17
     * breaks) */
    self->keep_arcs = arcs != Py_None;
    if (self->keep_arcs) {
        Py_ssize_t i;
        if (!PyArg_ParseTuple(arcs, "pdd(dd)(dd)(dd)dO", &self->pure_translation, &self->tol,
                              &self->k_dev, &self->budget[0], &self->budget[1],
                              &self->sliver[0], &self->sliver[1], &self->overshoot[0],
                              &self->overshoot[1], &self->max_offset, &breaks))
            return -1;
        if (!PyTuple_Check(breaks) || PyTuple_GET_SIZE(breaks) > MAX_BREAKS) {
            PyErr_SetString(PyExc_TypeError, "arcs: breaks must be a tuple of at most 3");
            return -1;
        }
        self->nbreaks = (int)PyTuple_GET_SIZE(breaks);
        for (i = 0; i < self->nbreaks; i++) {
            self->breaks[i] = PyFloat_AsDouble(PyTuple_GET_ITEM(breaks, i));
            if (self->breaks[i] == -1.0 && PyErr_Occurred())
                return -1;
        }
    }
    if (!PyArg_ParseTuple(affine, "dddddddddddd", &self->A[0], &self->A[1], &self->A[2],
                          &self->A[3], &self->A[4], &self->A[5], &self->A[6], &self->A[7],
                          &self->A[8], &self->b[0], &self->b[1], &self->b[2]))
        return -1;
    if (!PyTuple_Check(tables) || PyTuple_GET_SIZE(tables) != 3) {
        PyErr_SetString(PyExc_TypeError, "tables: a tuple of 3 (None or a table)");
        return -1;
    }
    for (k = 0; k < 3; k++) {
        PyObject *t = PyTuple_GET_ITEM(tables, k);
        self->active[k] = t != Py_None;
        if (self->active[k] && read_table(t, &self->tab[k]) < 0)
            return -1;
        self->any_active |= self->active[k];
    }
    self->has_limits = limits != Py_None;
    if (self->has_limits &&
        !PyArg_ParseTuple(limits, "dddddd", &self->lim[0], &self->lim[1], &self->lim[2],
                          &self->lim[3], &self->lim[4], &self->lim[5]))
        return -1;
    if (self->dec < 0 || self->dec > 12) {
        PyErr_SetString(PyExc_ValueError, "decimals: 0..12");
        return -1;
    }
    return 0;
}

/* One line: a move (transform.c) or an arc (arc.c); as kk_do_line */
static int do_line(Kernel *K, State *s, const char *ln, Py_ssize_t n, Lines *out)
{
    out->n = out->len = 0;
    if (n >= 4 && n <= MAX_LINE && ln[0] == 'G' && (ln[1] == '2' || ln[1] == '3') &&
        ln[2] == ' ')
        return kk_do_arc(K, s, ln, n, out);
    return kk_do_line(K, s, ln, n, out);
}

/* a str of ASCII text (every output line is: ASCII input, numbers, letters) */
static PyObject *make_str(const char *c, int len)
{
    PyObject *o = PyUnicode_New(len, 127);
    if (o != NULL)
        memcpy(PyUnicode_1BYTE_DATA(o), c, len);
    return o;
}

/* Kernel.line(state, line) -> None (the Python path decides) | line | [str, ...] */
static PyObject *Kernel_line(Kernel *self, PyObject *const *args, Py_ssize_t nargs)
{
    PyObject *state, *line, *res = NULL;
    const char *c;
    Py_ssize_t n;
    State s, before;
    Objs D;
    Lines out;
    int r, i;

    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "line(state, line)");
        return NULL;
    }
    state = args[0];
    line = args[1];
    if (!PyUnicode_Check(line) || !PyUnicode_IS_ASCII(line))
        Py_RETURN_NONE;
    c = (const char *)PyUnicode_DATA(line);
    n = PyUnicode_GET_LENGTH(line);
    if (n > MAX_LINE || n < 4 || c[0] != 'G')
        Py_RETURN_NONE;  /* (do_line would say so too, after the costly load) */
    if (kk_load(state, &s, &D) > 0)
        Py_RETURN_NONE;
    before = s;
    r = do_line(self, &s, c, n, &out);
    if (r == LINE_PYTHON) {
        kk_objs_release(&D);
        Py_RETURN_NONE;
    }
    if (r == LINE_SAME) {
        res = line;
        Py_INCREF(res);
    } else {
        res = PyList_New(out.n);
        if (res == NULL) {
            kk_objs_release(&D);
            return NULL;
        }
        for (i = 0; i < out.n; i++) {
            PyObject *o = make_str(out.buf + out.start[i], out.start[i + 1] - out.start[i]);
            if (o == NULL) {
                Py_DECREF(res);
                kk_objs_release(&D);
                return NULL;
            }
            PyList_SET_ITEM(res, i, o);
        }
    }
    if (kk_store(&D, &s, &before) < 0)
        Py_CLEAR(res);
    kk_objs_release(&D);
    return res;
}

typedef struct {
    char *data;
    Py_ssize_t len, cap;
} Buf;

static int buf_put(Buf *b, const char *c, Py_ssize_t n)
{
    if (b->len + n > b->cap) {
        Py_ssize_t cap = b->cap * 2 + n + 4096;
        char *d = PyMem_Realloc(b->data, cap);
        if (d == NULL) {
            PyErr_NoMemory();
            return -1;
        }
        b->data = d;
        b->cap = cap;
    }
    memcpy(b->data + b->len, c, n);
    b->len += n;
    return 0;
}

/* Kernel.feed(state, buf, pos) -> (out, stop): complete lines of buf from pos on, as
 * the reference path gives them, up to the first line the kernel does not take (stop: its
 * start; len(buf) if none). Taken: blank lines and ';' comments (unchanged), and the fast
 * path's move lines. A line with a lone CR is not taken (universal newlines are Python's). */
static PyObject *Kernel_feed(Kernel *self, PyObject *const *args, Py_ssize_t nargs)
{
    PyObject *state, *data, *res = NULL, *out = NULL;
    const char *buf;
    Py_ssize_t size, pos;
    State s, before;
    Objs D;
    Buf o = {NULL, 0, 0};
    Lines *lines = NULL;
    int r;

    if (nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "feed(state, buf, pos)");
        return NULL;
    }
    state = args[0];
    data = args[1];
    if (!PyBytes_Check(data)) {
        PyErr_SetString(PyExc_TypeError, "feed: buf must be bytes");
        return NULL;
    }
    pos = PyLong_AsSsize_t(args[2]);
    if (pos == -1 && PyErr_Occurred())
        return NULL;
    buf = PyBytes_AS_STRING(data);
    size = PyBytes_GET_SIZE(data);
    if (pos < 0 || pos > size) {
        PyErr_SetString(PyExc_ValueError, "feed: pos outside buf");
        return NULL;
    }
    lines = PyMem_Malloc(sizeof(Lines));
    if (lines == NULL)
        return PyErr_NoMemory();
    if (kk_load(state, &s, &D) > 0) {
        PyMem_Free(lines);
        return Py_BuildValue("(y#n)", "", (Py_ssize_t)0, pos);
    }
    before = s;
    while (pos < size) {
        const char *ln = buf + pos;
        const char *nl = memchr(ln, '\n', size - pos);
        Py_ssize_t n, raw;
        int crlf, i;
        if (nl == NULL)
            break;
        raw = nl - ln + 1;
        n = raw - 1;
        crlf = n > 0 && ln[n - 1] == '\r';
        if (crlf)
            n--;
        if (memchr(ln, '\r', n) != NULL)
            break;
        if (n == 0 || ln[0] == ';') {
            /* the reference path on a line that is no command */
            s.lineno++;
            s.lines++;
            s.lines_out++;
            s.q_last_known = 0;
            s.recheck[0] = s.recheck[1] = s.recheck[2] = 1;
            if (buf_put(&o, ln, raw) < 0) goto fail;
            pos += raw;
            continue;
        }
        r = do_line(self, &s, ln, n, lines);
        if (r == LINE_PYTHON)
            break;
        if (r == LINE_SAME) {
            if (buf_put(&o, ln, raw) < 0) goto fail;
        } else {
            const char *end = crlf ? "\r\n" : "\n";
            for (i = 0; i < lines->n; i++)
                if (buf_put(&o, lines->buf + lines->start[i],
                            lines->start[i + 1] - lines->start[i]) < 0
                    || buf_put(&o, end, crlf + 1) < 0)
                    goto fail;
        }
        pos += raw;
    }
    if (kk_store(&D, &s, &before) < 0)
        goto fail;
    out = PyBytes_FromStringAndSize(o.data ? o.data : "", o.len);
    if (out == NULL)
        goto fail;
    res = Py_BuildValue("(Nn)", out, pos);
fail:
    kk_objs_release(&D);
    PyMem_Free(o.data);
    PyMem_Free(lines);
    return res;
}

static PyMethodDef Kernel_methods[] = {
    {"line", (PyCFunction)(void (*)(void))Kernel_line, METH_FASTCALL,
     "line(state, line): one line compensated as the reference path does (None: it decides)"},
    {"feed", (PyCFunction)(void (*)(void))Kernel_feed, METH_FASTCALL,
     "feed(state, buf, pos) -> (out, stop): the lines of buf from pos the kernel takes"},
    {NULL}
};

static PyTypeObject KernelType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "octoprint_kincomp.engines._kernel.Kernel",
    .tp_basicsize = sizeof(Kernel),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "The kernel of one model: the transform of plain moves (see engines/kernel.py).",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Kernel_init,
    .tp_methods = Kernel_methods,
};

static PyMethodDef module_methods[] = {
    {"layout", (PyCFunction)(void (*)(void))kk_layout, METH_FASTCALL,
     "layout(StreamState, BacklashState, Report): the slotted classes of the state"},
    {NULL}
};

static struct PyModuleDef kernel_module = {
    PyModuleDef_HEAD_INIT, "_kernel", "Compiled kernel of the transform (see engines/kernel.py).", -1,
    module_methods,
};

PyMODINIT_FUNC PyInit__kernel(void)
{
    PyObject *mod;
    if (PyType_Ready(&KernelType) < 0)
        return NULL;
    mod = PyModule_Create(&kernel_module);
    if (mod == NULL)
        return NULL;
    Py_INCREF(&KernelType);
    if (PyModule_AddIntConstant(mod, "MAX_POINTS", MAX_PTS) < 0) {
        Py_DECREF(mod);
        return NULL;
    }
    if (PyModule_AddObject(mod, "Kernel", (PyObject *)&KernelType) < 0) {
        Py_DECREF(&KernelType);
        Py_DECREF(mod);
        return NULL;
    }
    return mod;
}
