/* One line through the transform: the reference path's arithmetic (core/path.py
 * PathWriter.emit, core/backlash.py reversal) for a plain absolute G0/G1 line. */
#include "kernel.h"

/* BacklashAxis.um_at: um at carriage position q (mm), same operation order. */
double kk_um_at(const Table *t, double q)
{
    int i;
    if (t->n == 1 || q <= t->pos[0])
        return t->um[0];
    if (q >= t->pos[t->n - 1])
        return t->um[t->n - 1];
    for (i = 0; i + 1 < t->n; i++) {
        double p1 = t->pos[i + 1];
        if (q < p1)  /* (v1 - v0) / (p1 - p0) * (q - p0) + v0, the quotient kept */
            return t->slope[i] * (q - t->pos[i]) + t->um[i];
        if (q == p1)
            return t->um[i + 1];
    }
    return t->um[t->n - 1];
}

/* backlash.reversal for axis k commanded to q (from q_from): 1 a reversal (dir and anchor
 * updated), 0 none (the anchor follows), -1 Python decides (a direction without anchor). */
int kk_reversal(const Kernel *K, State *s, int k, double q, double q_from)
{
    long d = s->dir[k];
    double a = s->anchor[k];
    if (d != 0 && !s->anchor_known[k])
        return -1;
    if (d > 0) {
        if (q >= a) { s->anchor[k] = q; return 0; }
        if (q >= a - K->deadband) return 0;
        d = -1;
    } else if (d < 0) {
        if (q <= a) { s->anchor[k] = q; return 0; }
        if (q <= a + K->deadband) return 0;
        d = 1;
    } else {
        if (!s->anchor_known[k]) {
            a = s->anchor[k] = q_from;
            s->anchor_known[k] = 1;
        }
        if (q > a + K->deadband) d = 1;
        else if (q < a - K->deadband) d = -1;
        else return 0;
    }
    s->dir[k] = d;
    s->anchor[k] = q;
    s->anchor_known[k] = 1;
    return 1;
}

/* PathWriter.emit for one point: append " <axis><text>" for each axis written to out (after the
 * code). Returns the number of axes written, -1: Python decides (nothing to undo: the
 * caller drops the whole tentative state). */
/* kk_format_value of x, or the arc fit's text of the very same x (K->memo) */
static int format_fw(const Kernel *K, int k, double x, int dec, char *text, double *value)
{
    if (K->memo.on && K->memo.len[k] > 0 && memcmp(&x, &K->memo.arg[k], sizeof x) == 0) {
        memcpy(text, K->memo.text[k], K->memo.len[k] + 1);
        *value = K->memo.value[k];
        return K->memo.len[k];
    }
    return kk_format_value(x, dec, text, value);
}

int kk_point(Kernel *K, State *s, const double *p, const double *q, const int *given,
             const double *q_prev, const int *redo, const double *m_old, char *out,
             int *out_len)
{
    static const char LETTER[3] = {'X', 'Y', 'Z'};
    double u = s->inches ? MM_PER_INCH : 1.0;
    int dec = K->dec + (s->inches ? 2 : 0);
    int k, written = 0;
    char text[MAX_TEXT + 1], oldfmt[MAX_TEXT + 1];
    (void)m_old;  /* (a source point outside the limits always goes to Python now) */
    for (k = 0; k < 3; k++) {
        double c = q[k], corr, parsed;
        int len, append;
        if (!given[k] && c == q_prev[k] && !redo[k])
            continue;
        if (s->dir[k] && K->active[k])
            c += (double)s->dir[k] * K->half * kk_um_at(&K->tab[k], c);
        /* a limit hit, a source point outside the limits (the travel ends there) or a
         * text outside them: counted, kept inside and reported by the Python path */
        if (K->has_limits && !(K->lim[2 * k] <= p[k] && p[k] <= K->lim[2 * k + 1] &&
                               K->lim[2 * k] <= c && c <= K->lim[2 * k + 1]))
            return -1;
        corr = fabs(c - p[k]) * 1000.0;
        len = format_fw(K, k, (c + s->g[k]) / u, dec, text, &parsed);
        if (len < 0)
            return -1;
        if (K->has_limits) {  /* (core/path.py PathWriter.inward: the number written) */
            double v = parsed * u - s->g[k];
            if (v < K->lim[2 * k] || v > K->lim[2 * k + 1])
                return -1;
        }
        s->recheck[k] = 0;
        if (corr > s->maxc[k])
            s->maxc[k] = corr;
        if (s->fwt_len[k] == len && memcmp(text, s->fwt[k], len) == 0) {
            append = given[k];
        } else {
            if (given[k] || s->fwt_len[k] >= 0) {
                append = 1;
            } else {
                int ol;
                if (!s->fw_known[k])
                    return -1;
                ol = kk_format_value(s->fw[k] / u, dec, oldfmt, NULL);
                if (ol < 0)
                    return -1;
                append = !(ol == len && memcmp(text, oldfmt, len) == 0);
            }
            s->fw[k] = parsed * u;
            s->fw_known[k] = 1;
            memcpy(s->fwt[k], text, len + 1);
            s->fwt_len[k] = len;
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

void kk_inverse(const Kernel *K, const double *p, double *q)
{
    double x = p[0] - K->b[0], y = p[1] - K->b[1], z = p[2] - K->b[2];
    q[0] = K->A[0] * x + K->A[1] * y + K->A[2] * z;
    q[1] = K->A[3] * x + K->A[4] * y + K->A[5] * z;
    q[2] = K->A[6] * x + K->A[7] * y + K->A[8] * z;
}

/* The output lines of one input line: kk_line_begin gives where the next line goes (room
 * for OUT_LINE bytes; NULL: no room, Python decides), kk_line_end records its length. */
char *kk_line_begin(Lines *o)
{
    if (o->n >= MAX_OUT || o->len + OUT_LINE > OUT_BUF)
        return NULL;
    o->start[o->n] = o->len;
    return o->buf + o->len;
}

int kk_line_end(Lines *o, int len)
{
    o->len += len;
    o->n++;
    o->start[o->n] = o->len;
    return 0;
}

/* One line (without its ending). LINE_OUT: the lines in ``out`` (a take-up line, then the
 * move); LINE_SAME: the line as it is; LINE_PYTHON: nothing changed, the Python path
 * decides (``s`` as it was). */
int kk_do_line(Kernel *K, State *s, const char *ln, Py_ssize_t n, Lines *out)
{
    char *take, *main_out;
    int take_len = -1, main_len = 0;
    /* slots: 0 F (first), 1 X, 2 Y, 3 Z, 4 E, 5 F (after) */
    Py_ssize_t tok_start[6], tok_end[6];
    int present[6] = {0, 0, 0, 0, 0, 0};
    double val[6];
    int last = -1, nw, t, k;
    Word w[6];
    State saved;

    out->n = out->len = 0;
    if (n > MAX_LINE || n < 4 || ln[0] != 'G' || (ln[1] != '0' && ln[1] != '1') ||
        ln[2] != ' ')
        return LINE_PYTHON;
    if (!s->absolute || !s->m_known || (nw = kk_words(ln, 3, n, w, 6)) < 0)
        return LINE_PYTHON;
    for (t = 0; t < nw; t++) {
        int slot;
        switch (w[t].letter) {
        case 'X': slot = 1; break;
        case 'Y': slot = 2; break;
        case 'Z': slot = 3; break;
        case 'E': slot = 4; break;
        case 'F': slot = t == 0 ? 0 : 5; break;
        default: return LINE_PYTHON;
        }
        if (slot <= last || (slot == 5 && present[0]))
            return LINE_PYTHON;
        present[slot] = 1;
        tok_start[slot] = w[t].start;
        tok_end[slot] = w[t].end;
        val[slot] = w[t].value;
        last = slot;
    }
    saved = *s;  /* (put back where Python decides after all) */
    {
        double u = s->inches ? MM_PER_INCH : 1.0;
        int given[3] = {present[1], present[2], present[3]};
        int none[3] = {0, 0, 0};
        int redo[3], rev = 0;
        double p1[3], q1[3], q0[3];
        Py_ssize_t tail_from = -1;
        int f_first = present[0], fslot = present[0] ? 0 : 5;
        if (present[fslot]) {
            s->feed = val[fslot] * u;
            s->f_known = 1;
        }
        if (present[4])
            kk_track_e(s, s->e_abs_mode == 0, val[4]);
        s->lineno++;
        s->lines++;
        s->moves++;
        if (!given[0] && !given[1] && !given[2]) {
            s->lines_out++;
            return LINE_SAME;
        }
        for (k = 0; k < 3; k++)
            p1[k] = given[k] ? val[k + 1] * u - s->w[k] : s->m[k];
        kk_inverse(K, p1, q1);
        if (s->q_last_known)
            memcpy(q0, s->q_last, sizeof q0);
        else
            kk_inverse(K, s->m, q0);
        memcpy(redo, s->recheck, sizeof redo);
        for (k = 0; k < 3; k++) {
            /* backlash.reversal: a hysteresis of ``deadband`` around the anchor */
            int r;
            if (!K->active[k])
                continue;
            r = kk_reversal(K, s, k, q1[k], q0[k]);
            if (r < 0)
                goto python;
            if (r == 0)
                continue;
            rev = redo[k] = 1;
        }
        if (rev) {
            int tl = 2, r;
            take = kk_line_begin(out);
            take[0] = 'G';
            take[1] = '1';
            r = kk_point(K, s, s->m, q0, none, q0, redo, saved.m, take, &tl);
            if (r < 0)
                goto python;
            if (r > 0) {
                take_len = tl;
                kk_line_end(out, tl);
                s->takeup++;
            }
        }
        main_out = kk_line_begin(out);
        main_out[0] = 'G';
        main_out[1] = ln[1];
        main_len = 2;
        if (kk_point(K, s, p1, q1, given, q0, redo, saved.m, main_out, &main_len) < 0)
            goto python;
        /* a source move without X/Y that gets X/Y: the move is split (core/moves.py
         * xy_apart) */
        if (!given[0] && !given[1] && main_len > 3 && (main_out[3] == 'X' || main_out[3] == 'Y'))
            goto python;
        /* the E/F words after X/Y/Z as written; a leading F word goes after them */
        if (present[4])
            tail_from = tok_start[4] - 1;
        else if (present[5])
            tail_from = tok_start[5] - 1;
        if (f_first) {
            Py_ssize_t fl = tok_end[0] - tok_start[0];
            main_out[main_len++] = ' ';
            memcpy(main_out + main_len, ln + tok_start[0], fl);
            main_len += (int)fl;
        }
        if (tail_from >= 0) {
            memcpy(main_out + main_len, ln + tail_from, n - tail_from);
            main_len += (int)(n - tail_from);
        }
        kk_line_end(out, main_len);
        memcpy(s->m, p1, sizeof p1);
        memcpy(s->q_last, q1, sizeof q1);
        s->q_last_known = 1;
        s->moves_comp++;
        s->lines_out += take_len >= 0 ? 2 : 1;
        return LINE_OUT;
    }
python:
    *s = saved;
    return LINE_PYTHON;
}

