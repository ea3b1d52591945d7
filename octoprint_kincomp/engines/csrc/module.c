/* The Python type ``Kernel``: one model's kernel, and its two entry points, ``line``
 * (the queuing hook: one line) and ``feed`` (files: a block of lines). */
#include "kernel.h"

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
    for (i = 0; i + 1 < n; i++)
        t->slope[i] = (t->um[i + 1] - t->um[i]) / (t->pos[i + 1] - t->pos[i]);
    return 0;
}

static int Kernel_init(Kernel *self, PyObject *args, PyObject *kwds)
{
    static char *kwlist[] = {"affine", "tables", "half", "deadband", "limits", "decimals",
                             "arcs", "get", "put", NULL};
    PyObject *affine, *tables, *limits, *arcs = Py_None, *breaks, *get = NULL, *put = NULL;
    int k;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "OOddOi|OOO", kwlist, &affine, &tables,
                                     &self->half, &self->deadband, &limits, &self->dec,
                                     &arcs, &get, &put))
        return -1;
    /* get() and put(tuple): Python's StreamState as the record and back (kernel.py) */
    Py_CLEAR(self->get);
    Py_CLEAR(self->put);
    Py_XINCREF(get);
    Py_XINCREF(put);
    self->get = get;
    self->put = put;
    self->holds = self->dirty = 0;
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

/* The text of a str the kernel may take (ASCII, at most MAX_LINE characters), else NULL
 * (with no error set). ASCII: as many UTF-8 bytes as characters. */
static const char *line_text(PyObject *line, Py_ssize_t *n)
{
    const char *c;
    if (!PyUnicode_Check(line) || PyUnicode_GET_LENGTH(line) > MAX_LINE)
        return NULL;
    if ((c = PyUnicode_AsUTF8AndSize(line, n)) == NULL) {
        PyErr_Clear();  /* (lone surrogates: not a line the kernel takes) */
        return NULL;
    }
    return *n == PyUnicode_GET_LENGTH(line) ? c : NULL;
}

/* A line that is no command (blank, or a ';' comment), as the reference path counts it. */
static void no_command(Kernel *K)
{
    State *s = &K->st;
    s->lineno++, s->lines++, s->lines_out++;
    s->q_last_known = 0;
    s->recheck[0] = s->recheck[1] = s->recheck[2] = 1;
    K->dirty = 1;
}

/* Kernel.line(line) -> None (the reference path takes it: the state is handed back to
 * Python first) | line | [str, ...] */
static PyObject *Kernel_line(Kernel *self, PyObject *line)
{
    PyObject *res;
    const char *c = NULL;
    Py_ssize_t n;
    Lines out;
    int r, i;

    if ((c = line_text(line, &n)) != NULL && self->holds && (n == 0 || c[0] == ';')) {
        no_command(self);  /* (taken while held: no hand-over for a comment) */
        Py_INCREF(line);
        return line;
    }
    if (c == NULL || n < 4 || c[0] != 'G' || (r = kk_take(self)) > 0) {
        if (kk_give(self) < 0)
            return NULL;
        Py_RETURN_NONE;
    }
    if (r < 0)
        return NULL;
    r = do_line(self, &self->st, c, n, &out);
    if (r == LINE_PYTHON) {
        if (kk_give(self) < 0)
            return NULL;
        Py_RETURN_NONE;
    }
    self->dirty = 1;
    if (r == LINE_SAME) {
        Py_INCREF(line);
        return line;
    }
    if ((res = PyList_New(out.n)) == NULL)
        return NULL;
    for (i = 0; i < out.n; i++) {
        PyObject *o = PyUnicode_FromKindAndData(PyUnicode_1BYTE_KIND, out.buf + out.start[i],
                                                out.start[i + 1] - out.start[i]);
        if (o == NULL) {
            Py_DECREF(res);
            return NULL;
        }
        PyList_SET_ITEM(res, i, o);
    }
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

/* Kernel.feed(buf, pos) -> (out, stop): complete lines of buf (bytes) from pos on, as the
 * reference path gives them, up to the first line the kernel does not take (stop: its
 * start, the state then handed back to Python; len(buf) if none). Taken: blank lines and
 * ';' comments (unchanged), and the move lines of ``line``. A line with a lone CR is not
 * taken (universal newlines are Python's). */
static PyObject *Kernel_feed(Kernel *self, PyObject *const *args, Py_ssize_t nargs)
{
    PyObject *res = NULL, *out;
    char *buf;
    Py_ssize_t size, pos;
    Buf o = {NULL, 0, 0};
    Lines *lines = NULL;
    State *s = &self->st;
    int r;

    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "feed(buf, pos)");
        return NULL;
    }
    if (!PyBytes_Check(args[0])) {
        PyErr_SetString(PyExc_TypeError, "feed: buf must be bytes");
        return NULL;
    }
    if (PyBytes_AsStringAndSize(args[0], &buf, &size) < 0)
        return NULL;
    if ((pos = PyLong_AsSsize_t(args[1])) == -1 && PyErr_Occurred())
        return NULL;
    if (pos < 0 || pos > size) {
        PyErr_SetString(PyExc_ValueError, "feed: pos outside buf");
        return NULL;
    }
    if ((r = kk_take(self)) < 0)
        return NULL;
    if (r > 0)
        return Py_BuildValue("(y#n)", "", (Py_ssize_t)0, pos);
    o.cap = (size - pos) + (size - pos) / 4 + 4096;  /* (room for the usual output) */
    if ((o.data = PyMem_Malloc(o.cap)) == NULL || (lines = PyMem_Malloc(sizeof(Lines))) == NULL) {
        PyMem_Free(o.data);
        return PyErr_NoMemory();
    }
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
            no_command(self);
            if (buf_put(&o, ln, raw) < 0)
                goto fail;
            pos += raw;
            continue;
        }
        r = do_line(self, s, ln, n, lines);
        if (r == LINE_PYTHON)
            break;
        self->dirty = 1;
        if (r == LINE_SAME) {
            if (buf_put(&o, ln, raw) < 0)
                goto fail;
        } else {
            const char *end = crlf ? "\r\n" : "\n";
            for (i = 0; i < lines->n; i++)
                if (buf_put(&o, lines->buf + lines->start[i],
                            lines->start[i + 1] - lines->start[i]) < 0 ||
                    buf_put(&o, end, crlf + 1) < 0)
                    goto fail;
        }
        pos += raw;
    }
    if (pos < size && kk_give(self) < 0)
        goto fail;
    if ((out = PyBytes_FromStringAndSize(o.data ? o.data : "", o.len)) != NULL)
        res = Py_BuildValue("(Nn)", out, pos);
fail:
    PyMem_Free(o.data);
    PyMem_Free(lines);
    return res;
}

/* Kernel.get_state() -> the record's tuple while the kernel holds the state, else None */
static PyObject *Kernel_get_state(Kernel *self, PyObject *unused)
{
    (void)unused;
    if (!self->holds)
        Py_RETURN_NONE;
    return kk_state_get(&self->st);
}

/* Kernel.set_state(tuple) -> True (the kernel holds it), False (a state the kernel does not
 * hold: Python's stays the truth) */
static PyObject *Kernel_set_state(Kernel *self, PyObject *t)
{
    State s;
    int r = kk_state_set(&s, t);
    if (r < 0)
        return NULL;
    if (r == 0) {
        self->st = s;
        self->holds = 1;
        self->dirty = 0;
    }
    return PyBool_FromLong(r == 0);
}

/* Kernel.release(): the state back to Python (put) if the kernel holds it */
static PyObject *Kernel_release(Kernel *self, PyObject *unused)
{
    (void)unused;
    if (kk_give(self) < 0)
        return NULL;
    Py_RETURN_NONE;
}

static void Kernel_dealloc(Kernel *self)
{
    Py_CLEAR(self->get);
    Py_CLEAR(self->put);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static PyMethodDef Kernel_methods[] = {
    {"line", (PyCFunction)Kernel_line, METH_O,
     "line(line): one line compensated as the reference path does (None: it decides)"},
    {"feed", (PyCFunction)(void (*)(void))Kernel_feed, METH_FASTCALL,
     "feed(buf, pos) -> (out, stop): the lines of buf from pos the kernel takes"},
    {"get_state", (PyCFunction)Kernel_get_state, METH_NOARGS,
     "get_state(): the state record as a tuple while the kernel holds it, else None"},
    {"set_state", (PyCFunction)Kernel_set_state, METH_O,
     "set_state(tuple) -> bool: the kernel holds this state (False: not one it holds)"},
    {"release", (PyCFunction)Kernel_release, METH_NOARGS,
     "release(): the state back to Python (put) if the kernel holds it"},
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
    .tp_dealloc = (destructor)Kernel_dealloc,
    .tp_methods = Kernel_methods,
};

static struct PyModuleDef kernel_module = {
    PyModuleDef_HEAD_INIT, "_kernel", "Compiled kernel of the transform (see engines/kernel.py).", -1,
    NULL,
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
    if (PyModule_AddIntConstant(mod, "MAX_POINTS", MAX_PTS) < 0 ||
        PyModule_AddStringConstant(mod, "RECORD", kk_record_fields) < 0 ||
        PyModule_AddObject(mod, "Kernel", (PyObject *)&KernelType) < 0) {
        Py_DECREF(&KernelType);
        Py_DECREF(mod);
        return NULL;
    }
    return mod;
}
