/* G2/G3 lines kept as arcs: core/arcpath.py (the reference) and core/arcs.py (Arc), the
 * same operations in the same order. Taken: absolute mode, G17, IJ form (X Y Z I J E F
 * words, each at most once, single-spaced, no comment), no P; every piece must fit as an
 * arc or be a G1 (the reference's chord fallback is left to Python, as is anything else:
 * limits near the arc, an unknown position or E, a radius too large). */
#include "kernel.h"

#define MAX_DEPTH 3

static const int SAMPLES[6] = {1, 2, 3, 5, 6, 7};  /* the eighths checked (4: the middle) */

/* EDistribution (core/path.py) */
typedef struct {
    int present, relative, dec;
    const char *text;  /* the word as written, "E..." */
    int text_len;
    double value, scale, e0, total;
    long long units, done;
} EDist;

typedef struct {
    Kernel *K;
    State *s;
    const Geo *a;
    int cw;
    const int *given;
    EDist ed;
    const char *code;           /* "G2"/"G3" */
    const char *tail[2];        /* E/F tokens in input order (NULL: none) */
    int tail_len[2];
    int first, arcs, segments;
    double dev;                 /* worst deviation of a written arc (um) */
    Lines *out;
    double m_old[3];
} Job;

/* -- E split ----------------------------------------------------------------------------- */

static int decimals_of(const char *t, int len)
{
    int i = 0, d;
    while (i < len && t[i] != '.')
        i++;
    if (i == len)
        return 0;
    d = 0;
    for (i++; i < len && t[i] >= '0' && t[i] <= '9'; i++)
        d++;
    return d;
}

/* 0, or -1: outside what the kernel holds (Python decides) */
static int edist_init(EDist *e, const char *text, int len, double value, int relative,
                      int e_known, double e_pos, double total)
{
    e->present = text != NULL;
    if (!e->present)
        return 0;
    e->text = text;
    e->text_len = len;
    e->value = value;
    e->relative = relative;
    e->e0 = e_pos;
    e->total = total;
    e->dec = decimals_of(text + 1, len - 1);
    if (e->dec < 5)
        e->dec = 5;
    if (e->dec > 12)  /* (the fast formatter's integer range) */
        return -1;
    e->scale = kk_P10[e->dec];
    if (relative) {
        double x = value * e->scale;
        if (!(fabs(x) < 4503599627370496.0))  /* 2**52: Python's round() is exact there */
            return -1;
        e->units = (long long)nearbyint(x);
        e->done = 0;
    } else if (!e_known) {
        return -1;
    }
    return 0;
}

/* EDistribution.take: appends " E..." to out; -1: Python decides */
static int edist_take(EDist *e, double s_end, int last, char *out, int *len)
{
    double v;
    if (last && (!e->relative || e->done == 0)) {
        out[(*len)++] = ' ';
        memcpy(out + *len, e->text, e->text_len);
        *len += e->text_len;
        return 0;
    }
    if (last) {
        v = (double)(e->units - e->done) / e->scale;
    } else {
        double f = e->total > 0 ? s_end / e->total : 1.0;
        if (e->relative) {
            double x = (double)e->units * f;
            long long upto;
            if (!(fabs(x) < 4503599627370496.0))
                return -1;
            upto = (long long)nearbyint(x);
            v = (double)(upto - e->done) / e->scale;
            e->done = upto;
        } else {
            v = e->e0 + (e->value - e->e0) * f;
        }
    }
    return kk_put_word(out, len, 'E', v, e->dec);
}

/* -- pieces ------------------------------------------------------------------------------ */

/* the command of axis k for geometric command q: q plus its take-up offset, as the reference
 * adds it (``c += offset`` whenever some axis has backlash) */
static double with_offset(const Kernel *K, const State *s, int k, double q)
{
    if (!K->any_active)
        return q;
    return q + ((s->dir[k] && K->active[k])
                    ? (double)s->dir[k] * K->half * kk_um_at(&K->tab[k], q) : 0.0);
}

/* Firmware coordinates (mm) of the compensated point for desired p (_Job.target); q: its
 * command if already known (kept by kk_monotone; p is then NULL), else NULL */
static void target(const Job *j, const double *p, const double *q, double *out)
{
    const Kernel *K = j->K;
    const State *s = j->s;
    double qp[3];
    int k;
    if (q == NULL) {
        kk_inverse(K, p, qp);
        q = qp;
    }
    for (k = 0; k < 3; k++)
        out[k] = with_offset(K, s, k, q[k]) + s->g[k];
}

/* the rounded firmware coordinate (mm) axis k gets for command c (PathWriter.fw_after);
 * its text is kept for kk_point (K->memo: the piece's end is written next) */
static int fw_after(Kernel *K, const State *s, int dec, double u, int k, double c, double *fw)
{
    double x = (c + s->g[k]) / u, v;
    int len = kk_format_value(x, dec, K->memo.text[k], &v);
    K->memo.len[k] = len > 0 ? len : 0;
    if (len < 0)
        return -1;
    K->memo.arg[k] = x;
    K->memo.value[k] = v;
    *fw = v * u;
    return 0;
}

/* _half_turn (core/arcpath.py): the half turn an angle from the start direction lies in, from
 * its cross (positive in the turning sense) and dot products: 0 (0, pi], 1 (pi, 2 pi), -1 0 */
static int half_turn(double cross, double dot)
{
    if (cross > 0.0)
        return 0;
    if (cross < 0.0)
        return 1;
    return dot < 0.0 ? 0 : -1;
}

/* strictly_between (core/arcpath.py): the direction (va, vb) strictly between the start
 * (sa, sb) and the end (ea, eb) directions, turning as the arc turns */
static int strictly_between(double va, double vb, double sa, double sb, double ea, double eb,
                            int cw)
{
    double turn = cw ? -1.0 : 1.0;
    int hv = half_turn(turn * (sa * vb - sb * va), sa * va + sb * vb);
    int he = half_turn(turn * (sa * eb - sb * ea), sa * ea + sb * eb);
    if (hv < 0 || he < 0)
        return 0;
    if (hv != he)
        return hv < he;
    return turn * (va * eb - vb * ea) > 0.0;
}

/* _Job.overshoots: the written circle turns a backlash axis (X, Y) round inside the piece
 * by more than the output resolution */
static int overshoots(const Job *j, const double *S, const double *E, double ka, double kb,
                      double radius, double sa, double sb)
{
    static const double VA[4] = {1.0, -1.0, 0.0, 0.0}, VB[4] = {0.0, 0.0, 1.0, -1.0};
    double allowed = j->K->overshoot[j->s->inches];
    double ea = E[0] - ka, eb = E[1] - kb;
    int i;
    for (i = 0; i < 4; i++) {
        int k = i < 2 ? 0 : 1;
        double va = VA[i] * radius, vb = VB[i] * radius, extreme, lo, hi, over;
        if (!j->K->active[k])
            continue;
        if (VA[i] == 0.0)
            va = 0.0;
        if (VB[i] == 0.0)
            vb = 0.0;
        if (!strictly_between(va, vb, sa, sb, ea, eb, j->cw))
            continue;
        extreme = k == 0 ? ka + va : kb + vb;
        lo = S[k] < E[k] ? S[k] : E[k];
        hi = S[k] > E[k] ? S[k] : E[k];
        over = extreme > hi ? extreme - hi : lo - extreme;
        if (over > allowed)
            return 1;
    }
    return 0;
}

/* _Job.fit: 1 fits (words in ij, deviation mm in dev), 0 no fit, 2 the rounded end is the
 * start, -1 Python decides */
static int fit(Job *j, double fa, double fb, const double *qb, const double (*eighths)[3],
               char *ij, int *ij_len, double *dev_out)
{
    const Kernel *K = j->K;
    const State *s = j->s;
    const Geo *a = j->a;
    double u = s->inches ? MM_PER_INCH : 1.0;
    int dec = K->dec + (s->inches ? 2 : 0), k, i;
    const double *S = s->fw;
    double E[3], M[3], T[3], ps[9][3];
    double bx, by, cx, cy, d, b2, c2, ux, uy, radius, ka, kb, sa, sb, lin0, dlin;
    double sweep = 0.0, dev = 0.0, budget = K->budget[s->inches];
    for (k = 0; k < 3; k++)
        if (fw_after(j->K, s, dec, u, k, with_offset(K, s, k, qb[k]), &E[k]) < 0)
            return -1;
    if (E[0] == S[0] && E[1] == S[1])
        return 2;
    if (budget <= 0.0)
        return 0;
    if (eighths == NULL)  /* (else their commands are kept: the points are not needed) */
        kk_arc_points(a, fa, fb, 8, ps);
    target(j, eighths == NULL ? ps[4] : NULL, eighths == NULL ? NULL : eighths[4], M);
    bx = M[0] - S[0];
    by = M[1] - S[1];
    cx = E[0] - S[0];
    cy = E[1] - S[1];
    d = 2.0 * (bx * cy - by * cx);
    if (d == 0.0 || (d > 0.0) == j->cw)
        return 0;
    b2 = bx * bx + by * by;
    c2 = cx * cx + cy * cy;
    ux = (cy * b2 - by * c2) / d;
    uy = (bx * c2 - cx * b2) / d;
    radius = kk_norm2(ux, uy);
    ka = S[0] + ux;
    kb = S[1] + uy;
    sa = -ux;
    sb = -uy;
    lin0 = S[2];
    dlin = E[2] - lin0;
    if (dlin != 0.0) {
        double ea = E[0] - ka, eb = E[1] - kb;
        sweep = atan2(sa * eb - sb * ea, sa * ea + sb * eb);
        if (j->cw)
            sweep = -sweep;
        if (sweep <= 0.0)  /* a half circle's end at +-pi (arcpath.py) */
            sweep += 2.0 * M_PI;
    }
    for (i = 0; i < 6; i++) {
        double va, vb, dr, lin, dl, e;
        target(j, eighths == NULL ? ps[SAMPLES[i]] : NULL,
               eighths == NULL ? NULL : eighths[SAMPLES[i]], T);
        va = T[0] - ka;
        vb = T[1] - kb;
        dr = kk_norm2(va, vb) - radius;
        lin = lin0;
        if (dlin != 0.0) {
            double ang = atan2(sa * vb - sb * va, sa * va + sb * vb);
            if (j->cw)
                ang = -ang;
            lin = lin0 + dlin * (ang / sweep);
        }
        dl = T[2] - lin;
        e = kk_norm2(dr, dl);
        if (e > dev)
            dev = e;
    }
    dev *= K->k_dev;
    if (dev > budget)
        return 0;
    if (K->any_active && overshoots(j, S, E, ka, kb, radius, sa, sb))
        return 0;
    *ij_len = 0;
    if (kk_put_word(ij, ij_len, 'I', ux / u, dec) < 0 ||
        kk_put_word(ij, ij_len, 'J', uy / u, dec) < 0)
        return -1;
    *dev_out = dev;
    return 1;
}

/* _Job.line: one output line ending at fraction f, desired point p, command q */
static int write_line(Job *j, const char *code, const double *p, const double *q, double f,
                      const char *extra, int extra_len)
{
    static const int NONE[3] = {0, 0, 0}, ALL[3] = {1, 1, 1};
    char *o = kk_line_begin(j->out);
    int len = 2, last = f == 1.0, t;
    State *s = j->s;
    double fw_before[3];
    if (o == NULL)
        return -1;
    o[0] = code[0];
    o[1] = code[1];
    memcpy(fw_before, s->fw, sizeof fw_before);
    if (kk_point(j->K, s, p, q, last ? j->given : NONE, q, ALL, j->m_old, o, &len) < 0)
        return -1;
    /* a piece that does not move but carries words (E, the first piece's F): the reference
     * passes them on or folds them back (core/path.py Pieces); Python decides */
    if (fw_before[0] == s->fw[0] && fw_before[1] == s->fw[1] && fw_before[2] == s->fw[2] &&
        (j->ed.present || (j->first && (j->tail[0] != NULL || j->tail[1] != NULL))))
        return -1;
    memcpy(s->m, p, 3 * sizeof(double));
    memcpy(o + len, extra, extra_len);
    len += extra_len;
    if (j->first) {
        j->first = 0;
        for (t = 0; t < 2; t++) {
            if (j->tail[t] == NULL)
                continue;
            if (j->tail[t][0] == 'E') {
                if (edist_take(&j->ed, kk_length_to(j->a, f), last, o, &len) < 0)
                    return -1;
            } else {
                o[len++] = ' ';
                memcpy(o + len, j->tail[t], j->tail_len[t]);
                len += j->tail_len[t];
            }
        }
    } else if (j->ed.present && edist_take(&j->ed, kk_length_to(j->a, f), last, o, &len) < 0) {
        return -1;
    }
    kk_line_end(j->out, len);
    j->segments++;
    return 0;
}

/* _Job.piece: 0, or -1 (Python decides: the chord fallback, or anything odd); eighths:
 * the commands at the piece's eighths if kk_monotone kept them (a whole cut piece), or NULL */
static int piece(Job *j, double fa, double fb, const double *pb, const double *qb,
                 const double (*eighths)[3], int depth)
{
    const Geo *a = j->a;
    double half = fabs(a->sweep) * (fb - fa) * 0.5, rmax = a->r0 > a->r1 ? a->r0 : a->r1;
    double dev = 0.0;
    char ij[2 * MAX_TEXT + 8];
    int ij_len = 0, r;
    if (rmax * half * half * 0.5 <= j->K->sliver[j->s->inches])
        return write_line(j, "G1", pb, qb, fb, "", 0);
    r = fit(j, fa, fb, qb, eighths, ij, &ij_len, &dev);
    if (r < 0)
        return -1;
    if (r == 2)
        return write_line(j, "G1", pb, qb, fb, "", 0);
    if (r == 1) {
        if (write_line(j, j->code, pb, qb, fb, ij, ij_len) < 0)
            return -1;
        j->arcs++;
        dev *= 1000.0;
        if (dev > j->dev)
            j->dev = dev;
        return 0;
    }
    if (depth < MAX_DEPTH) {
        double fm = fa + (fb - fa) * 0.5, pm[3], qm[3];
        kk_arc_point(a, fm, pm);
        kk_inverse(j->K, pm, qm);
        if (piece(j, fa, fm, pm, qm, NULL, depth + 1) < 0)
            return -1;
        return piece(j, fm, fb, pb, qb, NULL, depth + 1);
    }
    return -1;  /* no arc fits: chords, written by the reference path */
}

/* One G2/G3 line (ln[0..2] = "G2 " or "G3 "); as kk_do_line */
static int do_arc(Kernel *K, State *s, const char *ln, Py_ssize_t n, Lines *out);

int kk_do_arc(Kernel *K, State *s0, const char *ln, Py_ssize_t n, Lines *out)
{
    State saved = *s0;  /* (put back where Python decides after all) */
    int r;
    memset(K->memo.len, 0, sizeof K->memo.len);
    K->memo.on = 1;
    r = do_arc(K, s0, ln, n, out);
    K->memo.on = 0;
    if (r == LINE_PYTHON)
        *s0 = saved;
    return r;
}

static int do_arc(Kernel *K, State *s, const char *ln, Py_ssize_t n, Lines *out)
{
    /* slots: 0 X, 1 Y, 2 Z, 3 I, 4 J, 5 E, 6 F */
    static const char LETTERS[] = "XYZIJEF";
    Py_ssize_t ts[7], te[7];
    int present[7] = {0, 0, 0, 0, 0, 0, 0}, k, ntail = 0, nc, c, is_kept, nw, t;
    Eighths kept[MAX_CUTS];
    double val[7], start[3], end[3], ca, cb, oa, ob, cuts[MAX_CUTS], fa, pa[3], qa[3];
    Word w[7];
    Geo a;
    Job j;

    if (!K->keep_arcs || K->pure_translation || !s->absolute || !s->m_known ||
        s->plane != 17 || s->ij_absolute || (nw = kk_words(ln, 3, n, w, 7)) < 0)
        return LINE_PYTHON;
    for (k = 0; k < 3; k++)
        if (!s->fw_known[k])
            return LINE_PYTHON;
    memset(&j, 0, sizeof j);
    for (t = 0; t < nw; t++) {
        const char *L = w[t].letter ? strchr(LETTERS, w[t].letter) : NULL;
        int slot = L != NULL ? (int)(L - LETTERS) : 0;
        if (L == NULL || present[slot])
            return LINE_PYTHON;
        present[slot] = 1;
        val[slot] = w[t].value;
        ts[slot] = w[t].start;
        te[slot] = w[t].end;
        if (slot >= 5) {
            j.tail[ntail] = ln + ts[slot];
            j.tail_len[ntail++] = (int)(te[slot] - ts[slot]);
        }
    }
    if (!present[3] && !present[4])
        return LINE_PYTHON;
    {
        double u = s->inches ? MM_PER_INCH : 1.0;
        int given[3] = {present[0], present[1], present[2]};
        int e_rel = s->e_abs_mode == 0;
        if (present[6]) {
            s->feed = val[6] * u;
            s->f_known = 1;
        }
        s->lineno++;
        s->lines++;
        s->moves++;
        for (k = 0; k < 3; k++) {
            start[k] = s->m[k];
            end[k] = given[k] ? val[k] * u - s->w[k] : s->m[k];
        }
        oa = present[3] ? val[3] * u : 0.0;
        ob = present[4] ? val[4] * u : 0.0;
        if (oa == 0.0)
            oa = 0.0;  /* (Python's ``oa or 0.0``: -0.0 becomes 0.0) */
        if (ob == 0.0)
            ob = 0.0;
        ca = start[0] + oa;
        cb = start[1] + ob;
        if (kk_make_geo(K, &a, start, end, ca, cb, ln[1] == '2') < 0)
            return LINE_PYTHON;
        if (!kk_inside_limits(K, &a))
            return LINE_PYTHON;
        nc = kk_arc_cuts(K, &a, cuts);
        if (nc < 0 || !kk_monotone(K, &a, cuts, nc, kept, &is_kept))
            return LINE_PYTHON;
        j.K = K;
        j.s = s;
        j.a = &a;
        j.cw = ln[1] == '2';
        j.given = given;
        j.code = ln;
        j.first = 1;
        j.out = out;
        memcpy(j.m_old, s->m, sizeof j.m_old);
        if (edist_init(&j.ed, present[5] ? ln + ts[5] : NULL, present[5] ? (int)(te[5] - ts[5]) : 0,
                       present[5] ? val[5] : 0.0, e_rel, s->e_known, s->e_pos,
                       kk_length_to(&a, 1.0)) < 0)
            return LINE_PYTHON;
        fa = 0.0;
        memcpy(pa, start, sizeof pa);
        kk_inverse(K, pa, qa);
        for (c = 0; c < nc; c++) {
            double fb = cuts[c], pb[3], qb[3];
            int rev = 0;
            kk_arc_point(&a, fb, pb);
            kk_inverse(K, pb, qb);
            for (k = 0; k < 3 && K->any_active; k++) {
                /* BacklashTracker.detect_reversals from qa to qb */
                int r;
                if (!K->active[k])
                    continue;
                r = kk_reversal(K, s, k, qb[k], qa[k]);
                if (r < 0)
                    return LINE_PYTHON;
                if (r == 0)
                    continue;
                rev = 1;
            }
            if (rev) {
                static const int NONE[3] = {0, 0, 0}, ALL[3] = {1, 1, 1};
                char *o = kk_line_begin(out);
                int tl = 2, r;
                if (o == NULL)
                    return LINE_PYTHON;
                o[0] = 'G';
                o[1] = '1';
                r = kk_point(K, s, pa, qa, NONE, qa, ALL, j.m_old, o, &tl);
                if (r < 0)
                    return LINE_PYTHON;
                memcpy(s->m, pa, sizeof pa);
                if (r > 0) {
                    kk_line_end(out, tl);
                    s->takeup++;
                }
            }
            if (piece(&j, fa, fb, pb, qb, is_kept ? (const double (*)[3])kept[c] : NULL, 0) < 0)
                return LINE_PYTHON;
            fa = fb;
            memcpy(pa, pb, sizeof pa);
            memcpy(qa, qb, sizeof qa);
        }
        if (j.arcs == 0)
            s->arcs_lin++;
        else if (j.segments == 1)
            s->arcs_kept++;
        else
            s->arcs_split++;
        s->arc_segments += j.segments;
        if (j.dev > s->arc_dev)
            s->arc_dev = j.dev;
        if (present[5])
            kk_track_e(s, e_rel, val[5]);
        memcpy(s->q_last, qa, sizeof qa);
        s->q_last_known = 1;
        s->moves_comp++;
        s->lines_out += out->n;
        return LINE_OUT;
    }
}
