/* The geometry of a G17 arc (core/arcs.py: arc_sweep, Arc.point, Arc.length_to, Arc.cuts)
 * and the checks before an arc is kept (core/arcpath.py: ArcWriter.monotone,
 * ArcWriter.inside_limits; core/moves.py: the radius check), with the reference's operations
 * in the same order. Lengths mm, angles rad (from +X towards +Y). */
#include "kernel.h"

#define TWO_PI (2.0 * M_PI)
#define MAX_PIECE_RAD M_PI
#define BREAK_EDGE 1e-9

double kk_norm2(double a, double b)
{
    return sqrt(a * a + b * b);
}

static double py_mod(double a, double b)
{
    double m = fmod(a, b);
    if (m != 0.0) {
        if ((b < 0) != (m < 0))
            m += b;
    } else {
        m = copysign(0.0, b);
    }
    return m;
}

void kk_arc_point(const Geo *a, double f, double *p)
{
    double t, r;
    if (f == 0.0) {
        memcpy(p, a->start, sizeof a->start);
        return;
    }
    if (f == 1.0) {
        memcpy(p, a->end, sizeof a->end);
        return;
    }
    t = a->t0 + a->sweep * f;
    r = a->r0 + a->dr * f;
    p[0] = a->ca + r * cos(t);
    p[1] = a->cb + r * sin(t);
    p[2] = a->l0 + a->dl * f;
}

/* Arc.points: the points at fa + (fb - fa) * j / n, j = 0..n, the angle stepped by a
 * rotation (the reference's operations in its order) */
void kk_arc_points(const Geo *a, double fa, double fb, int n, double (*out)[3])
{
    double t = a->t0 + a->sweep * fa, step = a->sweep * (fb - fa) / n;
    double c = cos(t), s = sin(t), cs = cos(step), ss = sin(step), c1;
    int j;
    for (j = 0; j <= n; j++) {
        double f = fa + (fb - fa) * ((double)j / n), r;
        if (f == 0.0) {
            memcpy(out[j], a->start, sizeof a->start);
        } else if (f == 1.0) {
            memcpy(out[j], a->end, sizeof a->end);
        } else {
            r = a->r0 + a->dr * f;
            out[j][0] = a->ca + r * c;
            out[j][1] = a->cb + r * s;
            out[j][2] = a->l0 + a->dl * f;
        }
        c1 = c * cs - s * ss;
        s = s * cs + c * ss;
        c = c1;
    }
}

double kk_length_to(const Geo *a, double f)
{
    double planar = fabs(a->sweep) * f * (a->r0 + 0.5 * a->dr * f);
    double lin = a->dl * f;
    return sqrt(planar * planar + lin * lin);
}

/* Arc.cuts: -1 if there would be too many (Python decides) */
int kk_arc_cuts(const Kernel *K, const Geo *a, double *cuts)
{
    double lo, hi, width = fabs(a->sweep), fr[3 * MAX_BREAKS + 4], fa = 0.0, prev = -1.0;
    int nf = 0, nc = 0, i, j, first = 1;
    if (a->sweep > 0) {
        lo = a->t0;
        hi = a->t0 + a->sweep;
    } else {
        lo = a->t0 + a->sweep;
        hi = a->t0;
    }
    for (i = 0; i < K->nbreaks; i++) {
        double phi = K->breaks[i], k = ceil((lo - phi) / M_PI);
        while (phi + k * M_PI < hi) {
            double f = (phi + k * M_PI - a->t0) / a->sweep;
            if (BREAK_EDGE < f && f < 1.0 - BREAK_EDGE) {
                if (nf >= 3 * MAX_BREAKS + 2)
                    return -1;
                fr[nf++] = f;
            }
            k += 1;
        }
    }
    for (i = 1; i < nf; i++)  /* sort */
        for (j = i; j > 0 && fr[j - 1] > fr[j]; j--) {
            double t = fr[j];
            fr[j] = fr[j - 1];
            fr[j - 1] = t;
        }
    fr[nf++] = 1.0;
    for (i = 0; i < nf; i++) {
        double fb = fr[i], n;
        long m;
        if (!first && fb == prev)
            continue;
        first = 0;
        prev = fb;
        n = ceil(width * (fb - fa) / MAX_PIECE_RAD - 1e-9);
        if (n > MAX_CUTS)
            return -1;
        for (m = 1; m < (long)n; m++) {
            if (nc >= MAX_CUTS)
                return -1;
            cuts[nc++] = fa + (fb - fa) * (double)m / n;
        }
        if (nc >= MAX_CUTS)
            return -1;
        cuts[nc++] = fb;
        fa = fb;
    }
    return nc;
}

/* ArcWriter.inside_limits */
int kk_inside_limits(const Kernel *K, const Geo *a)
{
    double rmax = a->r0 > a->r1 ? a->r0 : a->r1, lo[3], hi[3], margin, p[3], q[3];
    int i, k;
    if (!K->has_limits)
        return 1;
    lo[0] = a->ca - rmax;
    hi[0] = a->ca + rmax;
    lo[1] = a->cb - rmax;
    hi[1] = a->cb + rmax;
    lo[2] = a->start[2] < a->end[2] ? a->start[2] : a->end[2];
    hi[2] = a->start[2] > a->end[2] ? a->start[2] : a->end[2];
    margin = K->tol + K->max_offset;
    for (k = 0; k < 3; k++)
        if (lo[k] < K->lim[2 * k] || hi[k] > K->lim[2 * k + 1])
            return 0;
    for (i = 0; i < 8; i++) {
        for (k = 0; k < 3; k++)
            p[k] = (i >> k & 1) ? hi[k] : lo[k];
        kk_inverse(K, p, q);
        for (k = 0; k < 3; k++)
            if (q[k] - margin < K->lim[2 * k] || q[k] + margin > K->lim[2 * k + 1])
                return 0;
    }
    return 1;
}

/* ArcWriter.dense */
static int dense(const Kernel *K, const Geo *a)
{
    double r = a->r0 < a->r1 ? a->r0 : a->r1;
    if (a->dl != 0.0)
        return 1;
    return a->dr * a->dr > a->sweep * a->sweep * r * 0.5 * K->deadband;
}

#define N_DENSE 35
/* arcpath.DENSE: 0, 2^-16 .. 2^-4, 1/8 .. 7/8, 1 - 2^-4 .. 1 - 2^-16, 1 */
static void dense_fractions(double *out)
{
    int i, n = 0, e;
    out[n++] = 0.0;
    for (e = 16; e > 3; e--)
        out[n++] = ldexp(1.0, -e);
    for (i = 1; i < 8; i++)
        out[n++] = i * 0.125;
    for (e = 4; e <= 16; e++)
        out[n++] = 1.0 - ldexp(1.0, -e);
    out[n] = 1.0;
}

/* ArcWriter.monotone: 1, or 0 (a backlash axis rises and falls by more than the deadband
 * within a piece). Where it samples the eighths of the pieces (not dense), their commands
 * are kept in kept[c] for the fit of the whole piece (*is_kept = 1): the same points by the
 * same operations, so the fit's result is the one it would compute itself. */
int kk_monotone(const Kernel *K, const Geo *a, const double *cuts, int nc, Eighths *kept,
                int *is_kept)
{
    double fa = 0.0, p[3], dense_qs[N_DENSE][3], fr[N_DENSE];
    int c, j, k, is_dense, n;
    *is_kept = 0;
    if (!K->any_active)
        return 1;
    is_dense = dense(K, a);
    if (is_dense)
        dense_fractions(fr);
    n = is_dense ? N_DENSE : 9;
    for (c = 0; c < nc; c++) {
        double fb = cuts[c];
        double (*qs)[3] = is_dense ? dense_qs : kept[c];
        if (is_dense) {
            for (j = 0; j < n; j++) {
                kk_arc_point(a, fa + (fb - fa) * fr[j], p);
                kk_inverse(K, p, qs[j]);
            }
        } else {  /* the eighths, by rotation (Arc.points) */
            double ps[9][3];
            kk_arc_points(a, fa, fb, 8, ps);
            for (j = 0; j < 9; j++)
                kk_inverse(K, ps[j], qs[j]);
        }
        for (k = 0; k < 3; k++) {
            double lo, hi, rise = 0.0, fall = 0.0;
            if (!K->active[k])
                continue;
            lo = hi = qs[0][k];
            for (j = 0; j < n; j++) {
                double v = qs[j][k];
                if (v - lo > rise)
                    rise = v - lo;
                if (hi - v > fall)
                    fall = hi - v;
                if (v < lo)
                    lo = v;
                if (v > hi)
                    hi = v;
            }
            if (rise > K->deadband && fall > K->deadband)
                return 0;
        }
        fa = fb;
    }
    *is_kept = !is_dense;
    return 1;
}

/* arcs.arc_sweep and the checks of MoveHandler.arc; 0 or -1 (Python decides) */
int kk_make_geo(const Kernel *K, Geo *a, const double *start, const double *end,
                    double ca, double cb, int cw)
{
    double r0, r1, t0, t1, sweep, step, radius;
    r0 = kk_norm2(start[0] - ca, start[1] - cb);
    r1 = kk_norm2(end[0] - ca, end[1] - cb);
    if (r0 < 1e-9 || r1 < 1e-9)
        return -1;
    t0 = atan2(start[1] - cb, start[0] - ca);
    t1 = atan2(end[1] - cb, end[0] - ca);
    if (kk_norm2(end[0] - start[0], end[1] - start[1]) < 1e-6)
        sweep = TWO_PI;
    else if (cw)
        sweep = py_mod(t0 - t1, TWO_PI);
    else
        sweep = py_mod(t1 - t0, TWO_PI);
    if (sweep <= 0.0)
        sweep = TWO_PI;
    sweep += 0.0;  /* (no P turns here) */
    a->ca = ca;
    a->cb = cb;
    a->t0 = t0;
    a->sweep = cw ? -sweep : sweep;
    a->r0 = r0;
    a->r1 = r1;
    a->dr = r1 - r0;
    a->l0 = start[2];
    a->dl = end[2] - start[2];
    memcpy(a->start, start, sizeof a->start);
    memcpy(a->end, end, sizeof a->end);
    /* arcs.segment_angle: a radius too large for the tolerance is malformed */
    radius = r0 > r1 ? r0 : r1;
    if (radius > K->tol) {
        step = 2.0 * acos(1.0 - K->tol / radius);
        if (!(step > 0.0))
            return -1;
    }
    return 0;
}

