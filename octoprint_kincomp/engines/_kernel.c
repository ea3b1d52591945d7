/* Compiled kernel of the compensator's per-line fast path (optional; see kernel.py).
 *
 * It compensates exactly the lines Compensator._fast_line accepts - plain G0/G1 lines with
 * single-spaced X/Y/Z/E/F words in absolute mode, every axis known - with the same
 * arithmetic in the same order (IEEE doubles, no fused multiply-add: built with
 * -ffp-contract=off), and Python's own number parser and formatter (PyOS_string_to_double,
 * PyOS_double_to_string), so its text is the text of the Python path byte for byte.
 * Whatever it does not decide - a limit touched, a value it cannot hold, any other line -
 * it leaves alone, with the compensator's state untouched, for the Python path.
 *
 * Units: positions mm (inches only in the G-code text), backlash tables um, half: fraction
 * of the backlash applied per side, um -> mm. Backlash direction +1: the carriage last moved
 * towards +, the take-up offset is + (half the backlash at that position).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <float.h>
#include <math.h>
#include <string.h>

/* Doubles must round as Python's do: no excess precision (x87 on 32-bit x86). Where that is
 * not so the extension is not built and the pure-Python paths run (setup.py: optional). */
#if defined(FLT_EVAL_METHOD) && FLT_EVAL_METHOD != 0
#error "the kernel needs FLT_EVAL_METHOD == 0 (on i386: -msse2 -mfpmath=sse)"
#endif

#define MAX_LINE 96      /* compensator._FAST_MAX_LEN */
#define MAX_TEXT 120     /* longest number text kept (longer: Python decides) */
#define MAX_PTS 64       /* backlash table points (more: no kernel) */
#define OUT_LINE 1024

static const double MM_PER_INCH = 25.4;

typedef struct {
    int n;
    double pos[MAX_PTS];
    double um[MAX_PTS];
} Table;

typedef struct {
    PyObject_HEAD
    double A[9];     /* inverse of the affine model, row-major */
    double b[3];     /* its offset: q = A (p - b) */
    int active[3];   /* backlash active on the axis */
    Table tab[3];
    double half;
    double deadband;
    int has_limits;
    double lim[6];   /* lo, hi per axis, mm */
    int dec;         /* decimals written (mm) */
} Kernel;

/* The compensator's state that the fast path reads and writes. */
typedef struct {
    int absolute, inches, e_abs_mode; /* e_abs_mode: -1 None, 0 False, 1 True */
    int m_known;
    double m[3];
    int fw_known[3];
    double fw[3];
    int fwt_len[3];                   /* -1: None */
    char fwt[3][MAX_TEXT + 1];
    int fwt_dirty[3];
    double w[3], g[3];
    int qm_known;
    double qm[3];
    int lim_hit[3];
    long dir[3];
    int anchor_known[3];
    double anchor[3];
    long long lineno, lines, moves, moves_comp, lines_out, takeup;
    double maxc[3];
    int e_set, e_none;
    double e_pos;
    int f_set;
    double feed;
    int moved;                        /* a move committed: m, fw, backlash to write */
} State;

static PyObject *s_m, *s_fw, *s_fw_text, *s_w, *s_g, *s_qm, *s_lim_hit, *s_backlash,
    *s_dir, *s_anchor, *s_report, *s_lines, *s_moves, *s_moves_compensated, *s_lines_out,
    *s_takeup_moves, *s_max_correction_um, *s_lineno, *s_inches, *s_e_absolute_mode,
    *s_e_pos, *s_feed, *s_absolute, *s_axis_key[3];

/* -- reading the compensator ------------------------------------------------------------ */

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

/* The instance dictionaries the state lives in: the compensator's, its backlash tracker's
 * and its report's (plain instance attributes, read and written without attribute lookup). */
typedef struct {
    PyObject *comp, *bl, *rep;
} Dicts;

static void dicts_release(Dicts *d)
{
    Py_CLEAR(d->comp);
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
static int load(PyObject *comp, State *s, Dicts *D)
{
    PyObject *o, *bl;
    int k;
    double tmp[3];
    int known[3];

    memset(s, 0, sizeof(State));
    D->comp = D->bl = D->rep = NULL;
    if (!(D->comp = instance_dict(comp)))
        goto python;
    bl = dget(D->comp, s_backlash);
    if (!(D->bl = instance_dict(bl)) || !(D->rep = instance_dict(dget(D->comp, s_report))))
        goto python;
    if (get_flag(D->comp, s_absolute, &s->absolute, 0) < 0 ||
        get_flag(D->comp, s_inches, &s->inches, 0) < 0 ||
        get_flag(D->comp, s_e_absolute_mode, &s->e_abs_mode, 1) < 0)
        goto python;
    if (!(o = dget(D->comp, s_m)) || get3(o, s->m, known, 1) < 0)
        goto python;
    s->m_known = known[0] && known[1] && known[2];
    if (!(o = dget(D->comp, s_fw)) || get3(o, s->fw, s->fw_known, 0) < 0)
        goto python;
    if (!(o = dget(D->comp, s_fw_text)) || !PyList_CheckExact(o) || PyList_GET_SIZE(o) != 3)
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
    if (!(o = dget(D->comp, s_w)) || get3(o, s->w, NULL, 1) < 0)
        goto python;
    if (!(o = dget(D->comp, s_g)) || get3(o, s->g, NULL, 1) < 0)
        goto python;
    if (!(o = dget(D->comp, s_qm)))
        goto python;
    s->qm_known = o != Py_None;
    if (s->qm_known && get3(o, s->qm, NULL, 1) < 0)
        goto python;
    if (!(o = dget(D->comp, s_lim_hit)) || !PyList_CheckExact(o) || PyList_GET_SIZE(o) != 3)
        goto python;
    for (k = 0; k < 3; k++) {
        PyObject *b = PyList_GET_ITEM(o, k);
        if (b != Py_True && b != Py_False)
            goto python;
        s->lim_hit[k] = b == Py_True;
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
    if (get_ll(D->comp, s_lineno, &s->lineno) < 0 || get_ll(D->rep, s_lines, &s->lines) < 0 ||
        get_ll(D->rep, s_moves, &s->moves) < 0 ||
        get_ll(D->rep, s_moves_compensated, &s->moves_comp) < 0 ||
        get_ll(D->rep, s_lines_out, &s->lines_out) < 0 ||
        get_ll(D->rep, s_takeup_moves, &s->takeup) < 0)
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
    dicts_release(D);
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
static int store(const Dicts *D, const State *s, const State *before)
{
    PyObject *o;
    int k;

    if (s->lines == before->lines)
        return 0;  /* nothing committed */
    if (set_ll(D->comp, s_lineno, s->lineno, before->lineno) < 0 ||
        set_ll(D->rep, s_lines, s->lines, before->lines) < 0 ||
        set_ll(D->rep, s_moves, s->moves, before->moves) < 0 ||
        set_ll(D->rep, s_moves_compensated, s->moves_comp, before->moves_comp) < 0 ||
        set_ll(D->rep, s_lines_out, s->lines_out, before->lines_out) < 0 ||
        set_ll(D->rep, s_takeup_moves, s->takeup, before->takeup) < 0)
        return -1;
    if (s->e_set) {
        if (s->e_none ? PyDict_SetItem(D->comp, s_e_pos, Py_None) < 0
                      : set_double(D->comp, s_e_pos, s->e_pos) < 0)
            return -1;
    }
    if (s->f_set && set_double(D->comp, s_feed, s->feed) < 0)
        return -1;
    /* the previous command and the axes to re-evaluate (inert lines reset them) */
    if (s->qm_known) {
        if (set_owned(D->comp, s_qm, seq3(s->qm, 1)) < 0)
            return -1;
    } else if (PyDict_SetItem(D->comp, s_qm, Py_None) < 0) {
        return -1;
    }
    if (memcmp(s->lim_hit, before->lim_hit, sizeof s->lim_hit) != 0) {
        if (!(o = PyList_New(3)))
            return -1;
        for (k = 0; k < 3; k++) {
            PyObject *b = s->lim_hit[k] ? Py_True : Py_False;
            Py_INCREF(b);
            PyList_SET_ITEM(o, k, b);
        }
        if (set_owned(D->comp, s_lim_hit, o) < 0)
            return -1;
    }
    if (!s->moved)
        return 0;
    if (set_owned(D->comp, s_m, seq3(s->m, 0)) < 0)
        return -1;
    for (k = 0; k < 3; k++) {
        if (!s->fwt_dirty[k])
            continue;
        PyObject *t = PyUnicode_FromStringAndSize(s->fwt[k], s->fwt_len[k]);
        if (t == NULL || PyList_SetItem(dget(D->comp, s_fw_text), k, t) < 0)
            return -1;
        if (set_item_double(dget(D->comp, s_fw), k, s->fw[k]) < 0)
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

/* -- the arithmetic ---------------------------------------------------------------------- */

/* BacklashAxis.um_at: um at carriage position q (mm), same operation order. */
static double um_at(const Table *t, double q)
{
    int i;
    if (t->n == 1 || q <= t->pos[0])
        return t->um[0];
    if (q >= t->pos[t->n - 1])
        return t->um[t->n - 1];
    for (i = 0; i + 1 < t->n; i++) {
        double p0 = t->pos[i], v0 = t->um[i], p1 = t->pos[i + 1], v1 = t->um[i + 1];
        if (q < p1)
            return (v1 - v0) / (p1 - p0) * (q - p0) + v0;
        if (q == p1)
            return v1;
    }
    return t->um[t->n - 1];
}

static int format_slow(double v, int dec, char *out);

static const double P10[23] = {1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11,
                               1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21,
                               1e22};

/* float(text) for a number text of [0-9.+-] (text[len] need not be 0). Exact where the
 * digits make an integer below 2**53 and there are at most 22 decimals: then the value is
 * that integer divided by a power of ten, both exact, and IEEE division rounds it correctly,
 * as Python's parser does (Clinger's fast path); anything else goes to Python's parser.
 * Returns 0, -1 if the text is no number. */
static int parse_num(const char *text, Py_ssize_t len, double *out)
{
    Py_ssize_t i = 0;
    int neg = 0, digits = 0, decimals = 0, dot = 0;
    unsigned long long mant = 0;
    if (len > 0 && (text[0] == '+' || text[0] == '-')) {
        neg = text[0] == '-';
        i = 1;
    }
    for (; i < len; i++) {
        char c = text[i];
        if (c >= '0' && c <= '9') {
            digits++;
            if (mant > (1ULL << 53) / 10) {
                digits = -1000;  /* too many digits for the fast path */
                break;
            }
            mant = mant * 10 + (unsigned long long)(c - '0');
            decimals += dot;
        } else if (c == '.' && !dot) {
            dot = 1;
        } else {
            return -1;  /* a second sign or dot: no number */
        }
    }
    if (digits > 0 && mant <= (1ULL << 53) && decimals <= 22) {
        double v = (double)mant / P10[decimals];
        *out = neg ? -v : v;
        return 0;
    }
    if (digits == 0)
        return -1;
    {
        char buf[MAX_LINE + 1], *end;
        double v;
        if (len > MAX_LINE)
            return -1;
        memcpy(buf, text, len);
        buf[len] = 0;
        v = PyOS_string_to_double(buf, &end, NULL);
        if (v == -1.0 && PyErr_Occurred()) {
            PyErr_Clear();
            return -1;
        }
        if (end != buf + len)
            return -1;
        *out = v;
        return 0;
    }
}

/* "%.{dec}f" % v without negative zero (gcode.fmt). Returns the length, -1: Python decides.
 * Where |v| * 10**dec is at most 1e9 and not within 1e-6 of a half, rounding the scaled
 * value (off the exact one by less than 2.5e-7) gives the correctly rounded digits that
 * Python's formatter writes; elsewhere Python's formatter does it. */
static int format_num(double v, int dec, char *out)
{
    double r = fabs(v) * P10[dec];
    if (r <= 1e9) {
        double fl = floor(r), frac = r - fl;
        if (fabs(frac - 0.5) >= 1e-6) {
            unsigned long long n = (unsigned long long)fl + (frac > 0.5);
            unsigned long long ip = n / (unsigned long long)P10[dec];
            unsigned long long fp = n % (unsigned long long)P10[dec];
            char tmp[32];
            int len = 0, t = 0, k;
            if (v < 0 && n > 0)
                out[len++] = '-';
            do {
                tmp[t++] = (char)('0' + ip % 10);
                ip /= 10;
            } while (ip);
            while (t)
                out[len++] = tmp[--t];
            if (dec > 0) {
                out[len++] = '.';
                for (k = dec - 1; k >= 0; k--) {
                    out[len + k] = (char)('0' + fp % 10);
                    fp /= 10;
                }
                len += dec;
            }
            out[len] = 0;
            return len;
        }
    }
    return format_slow(v, dec, out);
}

static int format_slow(double v, int dec, char *out)
{
    char *s = PyOS_double_to_string(v, 'f', dec, 0, NULL);
    size_t len;
    const char *p;
    if (s == NULL) {
        PyErr_Clear();
        return -1;
    }
    len = strlen(s);
    p = s;
    if (s[0] == '-' && strspn(s, "-0.") == len) {
        p++;
        len--;
    }
    if (len > MAX_TEXT) {
        PyMem_Free(s);
        return -1;
    }
    memcpy(out, p, len);
    out[len] = 0;
    PyMem_Free(s);
    return (int)len;
}

/* Compensator._fast_point: append " <axis><text>" for each axis written to out (after the
 * code). Returns the number of axes written, -1: Python decides (nothing to undo: the
 * caller drops the whole tentative state). */
static int point(Kernel *K, State *s, const double *p, const double *q, const int *given,
                 const double *q_prev, const int *redo, const double *m_old, char *out,
                 int *out_len)
{
    static const char LETTER[3] = {'X', 'Y', 'Z'};
    double u = s->inches ? MM_PER_INCH : 1.0;
    int dec = K->dec + (s->inches ? 2 : 0);
    int k, written = 0;
    char text[MAX_TEXT + 1], oldfmt[MAX_TEXT + 1];
    for (k = 0; k < 3; k++) {
        double c = q[k], corr, parsed;
        int len, append;
        if (!given[k] && c == q_prev[k] && !redo[k])
            continue;
        if (s->dir[k] && K->active[k])
            c += (double)s->dir[k] * K->half * um_at(&K->tab[k], c);
        if (K->has_limits) {
            double lo = K->lim[2 * k], hi = K->lim[2 * k + 1];
            if (lo <= p[k] && p[k] <= hi) {
                if (c < lo || c > hi)
                    return -1;  /* a limit hit: counted and reported by the Python path */
            } else if (p[k] != m_old[k]) {
                return -1;      /* a source point outside the limits: likewise */
            }
        }
        s->lim_hit[k] = 0;
        corr = fabs(c - p[k]) * 1000.0;
        if (corr > s->maxc[k])
            s->maxc[k] = corr;
        len = format_num((c + s->g[k]) / u, dec, text);
        if (len < 0)
            return -1;
        if (s->fwt_len[k] == len && memcmp(text, s->fwt[k], len) == 0) {
            append = given[k];
        } else {
            if (given[k] || s->fwt_len[k] >= 0) {
                append = 1;
            } else {
                int ol;
                if (!s->fw_known[k])
                    return -1;
                ol = format_num(s->fw[k] / u, dec, oldfmt);
                if (ol < 0)
                    return -1;
                append = !(ol == len && memcmp(text, oldfmt, len) == 0);
            }
            if (parse_num(text, len, &parsed) < 0)
                return -1;
            s->fw[k] = parsed * u;
            s->fw_known[k] = 1;
            memcpy(s->fwt[k], text, len + 1);
            s->fwt_len[k] = len;
            s->fwt_dirty[k] = 1;
        }
        if (append) {
            if (*out_len + 2 + len >= OUT_LINE)
                return -1;
            out[(*out_len)++] = ' ';
            out[(*out_len)++] = LETTER[k];
            memcpy(out + *out_len, text, len);
            *out_len += len;
            written++;
        }
    }
    return written;
}

static void inverse(const Kernel *K, const double *p, double *q)
{
    double x = p[0] - K->b[0], y = p[1] - K->b[1], z = p[2] - K->b[2];
    q[0] = K->A[0] * x + K->A[1] * y + K->A[2] * z;
    q[1] = K->A[3] * x + K->A[4] * y + K->A[5] * z;
    q[2] = K->A[6] * x + K->A[7] * y + K->A[8] * z;
}

static int is_num_char(char c)
{
    return (c >= '0' && c <= '9') || c == '.' || c == '+' || c == '-';
}

enum { LINE_OUT, LINE_SAME, LINE_PYTHON };

/* One line (without its ending), Compensator._fast_line. LINE_OUT: the take-up line (if
 * take_len >= 0) and the main line; LINE_SAME: the line as it is; LINE_PYTHON: nothing
 * changed, the Python path decides. ``s`` is changed only for LINE_OUT and LINE_SAME. */
static int do_line(Kernel *K, State *s0, const char *ln, Py_ssize_t n, char *take,
                   int *take_len, char *main_out, int *main_len)
{
    /* slots: 0 F (first), 1 X, 2 Y, 3 Z, 4 E, 5 F (after) */
    Py_ssize_t tok_start[6], tok_end[6];
    int present[6] = {0, 0, 0, 0, 0, 0};
    double val[6];
    int last = -1, ntok = 0, k;
    Py_ssize_t i;
    State s;

    if (n > MAX_LINE || n < 4 || ln[0] != 'G' || (ln[1] != '0' && ln[1] != '1') ||
        ln[2] != ' ')
        return LINE_PYTHON;
    if (!s0->absolute || !s0->m_known)
        return LINE_PYTHON;
    i = 3;
    while (i <= n) {
        Py_ssize_t st = i, e;
        int slot;
        char L;
        while (i < n && ln[i] != ' ')
            i++;
        e = i;  /* token [st, e) */
        i++;    /* past the space (or the end) */
        if (e == st)
            return LINE_PYTHON;  /* empty token: two spaces or a trailing one */
        L = ln[st];
        switch (L) {
        case 'X': slot = 1; break;
        case 'Y': slot = 2; break;
        case 'Z': slot = 3; break;
        case 'E': slot = 4; break;
        case 'F': slot = ntok == 0 ? 0 : 5; break;
        default: return LINE_PYTHON;
        }
        if (slot <= last || (slot == 5 && present[0]))
            return LINE_PYTHON;
        for (Py_ssize_t j = st + 1; j < e; j++)
            if (!is_num_char(ln[j]))
                return LINE_PYTHON;
        present[slot] = 1;
        tok_start[slot] = st;
        tok_end[slot] = e;
        last = slot;
        ntok++;
    }
    for (k = 0; k < 6; k++)
        if (present[k] && parse_num(ln + tok_start[k] + 1, tok_end[k] - tok_start[k] - 1,
                                    &val[k]) < 0)
            return LINE_PYTHON;
    s = *s0;
    {
        double u = s.inches ? MM_PER_INCH : 1.0;
        int given[3] = {present[1], present[2], present[3]};
        int none[3] = {0, 0, 0};
        int redo[3], rev = 0;
        double p1[3], q1[3], q0[3];
        Py_ssize_t tail_from = -1;
        int f_first = present[0], fslot = present[0] ? 0 : 5;
        if (present[fslot]) {
            s.feed = val[fslot] * u;
            s.f_set = 1;
        }
        if (present[4]) {
            s.e_set = 1;
            s.e_none = s.e_abs_mode == 0;
            s.e_pos = val[4];
        }
        s.lineno++;
        s.lines++;
        s.moves++;
        if (!given[0] && !given[1] && !given[2]) {
            s.lines_out++;
            *s0 = s;
            return LINE_SAME;
        }
        for (k = 0; k < 3; k++)
            p1[k] = given[k] ? val[k + 1] * u - s.w[k] : s.m[k];
        inverse(K, p1, q1);
        if (s.qm_known)
            memcpy(q0, s.qm, sizeof q0);
        else
            inverse(K, s.m, q0);
        memcpy(redo, s.lim_hit, sizeof redo);
        *take_len = -1;
        for (k = 0; k < 3; k++) {
            /* BacklashTracker.turn: a hysteresis of ``deadband`` around the anchor */
            double q = q1[k], a;
            long d;
            if (!K->active[k])
                continue;
            d = s.dir[k];
            a = s.anchor[k];
            if (d != 0 && !s.anchor_known[k])
                return LINE_PYTHON;  /* (a direction has an anchor) */
            if (d > 0) {
                if (q >= a) { s.anchor[k] = q; continue; }
                if (q >= a - K->deadband) continue;
                d = -1;
            } else if (d < 0) {
                if (q <= a) { s.anchor[k] = q; continue; }
                if (q <= a + K->deadband) continue;
                d = 1;
            } else {
                if (!s.anchor_known[k]) {
                    a = s.anchor[k] = q0[k];
                    s.anchor_known[k] = 1;
                }
                if (q > a + K->deadband) d = 1;
                else if (q < a - K->deadband) d = -1;
                else continue;
            }
            s.dir[k] = d;
            s.anchor[k] = q;
            s.anchor_known[k] = 1;
            rev = redo[k] = 1;
        }
        if (rev) {
            int tl = 2, r;
            take[0] = 'G';
            take[1] = '1';
            r = point(K, &s, s.m, q0, none, q0, redo, s0->m, take, &tl);
            if (r < 0)
                return LINE_PYTHON;
            if (r > 0) {
                *take_len = tl;
                s.takeup++;
            }
        }
        main_out[0] = 'G';
        main_out[1] = ln[1];
        *main_len = 2;
        if (point(K, &s, p1, q1, given, q0, redo, s0->m, main_out, main_len) < 0)
            return LINE_PYTHON;
        /* the E/F words after X/Y/Z as written; a leading F word goes after them */
        if (present[4])
            tail_from = tok_start[4] - 1;
        else if (present[5])
            tail_from = tok_start[5] - 1;
        if (f_first) {
            Py_ssize_t fl = tok_end[0] - tok_start[0];
            main_out[(*main_len)++] = ' ';
            memcpy(main_out + *main_len, ln + tok_start[0], fl);
            *main_len += (int)fl;
        }
        if (tail_from >= 0) {
            memcpy(main_out + *main_len, ln + tail_from, n - tail_from);
            *main_len += (int)(n - tail_from);
        }
        memcpy(s.m, p1, sizeof p1);
        memcpy(s.qm, q1, sizeof q1);
        s.qm_known = 1;
        s.moved = 1;
        s.moves_comp++;
        s.lines_out += *take_len >= 0 ? 2 : 1;
        *s0 = s;
        return LINE_OUT;
    }
}

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
                             NULL};
    PyObject *affine, *tables, *limits;
    int k;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "OOddOi", kwlist, &affine, &tables,
                                     &self->half, &self->deadband, &limits, &self->dec))
        return -1;
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

static PyObject *make_str(const char *c, int len)
{
    return PyUnicode_DecodeASCII(c, len, NULL);
}

/* Kernel.line(comp, line) -> None (the Python path decides) | line | [str, ...] */
static PyObject *Kernel_line(Kernel *self, PyObject *const *args, Py_ssize_t nargs)
{
    PyObject *comp, *line, *res = NULL;
    const char *c;
    Py_ssize_t n;
    State s, before;
    Dicts D;
    char take[OUT_LINE], main_out[OUT_LINE];
    int take_len = -1, main_len = 0, r;

    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "line(comp, line)");
        return NULL;
    }
    comp = args[0];
    line = args[1];
    if (!PyUnicode_Check(line) || !PyUnicode_IS_ASCII(line))
        Py_RETURN_NONE;
    c = (const char *)PyUnicode_DATA(line);
    n = PyUnicode_GET_LENGTH(line);
    if (n > MAX_LINE || n < 4 || c[0] != 'G')
        Py_RETURN_NONE;  /* (do_line would say so too, after the costly load) */
    if (load(comp, &s, &D) > 0)
        Py_RETURN_NONE;
    before = s;
    r = do_line(self, &s, c, n, take, &take_len, main_out, &main_len);
    if (r == LINE_PYTHON) {
        dicts_release(&D);
        Py_RETURN_NONE;
    }
    if (r == LINE_SAME) {
        res = line;
        Py_INCREF(res);
    } else {
        PyObject *a = NULL, *b;
        res = PyList_New(take_len >= 0 ? 2 : 1);
        if (res == NULL) {
            dicts_release(&D);
            return NULL;
        }
        if (take_len >= 0) {
            if (!(a = make_str(take, take_len))) {
                Py_DECREF(res);
                dicts_release(&D);
                return NULL;
            }
            PyList_SET_ITEM(res, 0, a);
        }
        if (!(b = make_str(main_out, main_len))) {
            Py_DECREF(res);
            dicts_release(&D);
            return NULL;
        }
        PyList_SET_ITEM(res, take_len >= 0 ? 1 : 0, b);
    }
    if (store(&D, &s, &before) < 0)
        Py_CLEAR(res);
    dicts_release(&D);
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

/* Kernel.feed(comp, buf, pos) -> (out, stop): complete lines of buf from pos on, as
 * Compensator.process gives them, up to the first line the kernel does not take (stop: its
 * start; len(buf) if none). Taken: blank lines and ';' comments (unchanged), and the fast
 * path's move lines. A line with a lone CR is not taken (universal newlines are Python's). */
static PyObject *Kernel_feed(Kernel *self, PyObject *const *args, Py_ssize_t nargs)
{
    PyObject *comp, *data, *res = NULL, *out = NULL;
    const char *buf;
    Py_ssize_t size, pos;
    State s, before;
    Dicts D;
    Buf o = {NULL, 0, 0};
    char take[OUT_LINE], main_out[OUT_LINE];
    int r;

    if (nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "feed(comp, buf, pos)");
        return NULL;
    }
    comp = args[0];
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
    if (load(comp, &s, &D) > 0)
        return Py_BuildValue("(y#n)", "", (Py_ssize_t)0, pos);
    before = s;
    while (pos < size) {
        const char *ln = buf + pos;
        const char *nl = memchr(ln, '\n', size - pos);
        Py_ssize_t n, raw;
        int crlf, take_len = -1, main_len = 0;
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
            /* Compensator.process on a line that is no command */
            s.lineno++;
            s.lines++;
            s.lines_out++;
            s.qm_known = 0;
            s.lim_hit[0] = s.lim_hit[1] = s.lim_hit[2] = 1;
            if (buf_put(&o, ln, raw) < 0) goto fail;
            pos += raw;
            continue;
        }
        r = do_line(self, &s, ln, n, take, &take_len, main_out, &main_len);
        if (r == LINE_PYTHON)
            break;
        if (r == LINE_SAME) {
            if (buf_put(&o, ln, raw) < 0) goto fail;
        } else {
            const char *end = crlf ? "\r\n" : "\n";
            if (take_len >= 0 && (buf_put(&o, take, take_len) < 0 ||
                                  buf_put(&o, end, crlf + 1) < 0))
                goto fail;
            if (buf_put(&o, main_out, main_len) < 0 || buf_put(&o, end, crlf + 1) < 0)
                goto fail;
        }
        pos += raw;
    }
    if (store(&D, &s, &before) < 0)
        goto fail;
    out = PyBytes_FromStringAndSize(o.data ? o.data : "", o.len);
    if (out == NULL)
        goto fail;
    res = Py_BuildValue("(Nn)", out, pos);
fail:
    dicts_release(&D);
    PyMem_Free(o.data);
    return res;
}

static PyMethodDef Kernel_methods[] = {
    {"line", (PyCFunction)(void (*)(void))Kernel_line, METH_FASTCALL,
     "line(comp, line): Compensator._fast_line compiled (None: the Python path decides)"},
    {"feed", (PyCFunction)(void (*)(void))Kernel_feed, METH_FASTCALL,
     "feed(comp, buf, pos) -> (out, stop): the lines of buf from pos the kernel takes"},
    {NULL}
};

static PyTypeObject KernelType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "octoprint_kincomp.engines._kernel.Kernel",
    .tp_basicsize = sizeof(Kernel),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "The compensator's fast path for one model (see kernel.py).",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Kernel_init,
    .tp_methods = Kernel_methods,
};

static struct PyModuleDef kernel_module = {
    PyModuleDef_HEAD_INIT, "_kernel", "Compiled fast path of the compensator.", -1, NULL,
};

PyMODINIT_FUNC PyInit__kernel(void)
{
    PyObject *mod;
#define INTERN(var, text) if (!(var = PyUnicode_InternFromString(text))) return NULL
    INTERN(s_m, "m");
    INTERN(s_fw, "fw");
    INTERN(s_fw_text, "fw_text");
    INTERN(s_w, "w");
    INTERN(s_g, "g");
    INTERN(s_qm, "_qm");
    INTERN(s_lim_hit, "_lim_hit");
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
    INTERN(s_axis_key[0], "x");
    INTERN(s_axis_key[1], "y");
    INTERN(s_axis_key[2], "z");
#undef INTERN
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
