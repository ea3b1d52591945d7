/* The compiled kernel of the transform (optional; see engines/kernel.py): shared types.
 *
 * It compensates plain G0/G1 lines with single-spaced X/Y/Z/E/F words in absolute mode,
 * every axis known, with the arithmetic of the reference path (core/path.py) in the same
 * order (IEEE doubles, no fused multiply-add: built with -ffp-contract=off) and Python's
 * own number parser and formatter where the fast ones cannot be exact, so its text is the
 * reference path's byte for byte. Whatever it does not decide (a limit touched, a value it
 * cannot hold, any other line) it leaves alone, with the stream state untouched.
 *
 * It owns its stream state while it takes lines: the record ``State`` below, in the Kernel
 * object, which crosses to Python only as a tuple of plain values (state.c; the order of
 * engines/kernel.py RECORD). No line here touches a Python object's internals.
 *
 * Files: state.c the record's tuple and its handing over, numbers.c numbers and the words
 * of a line, transform.c one line, arc.c/arcgeo.c arcs, module.c the Python type. Units:
 * positions mm (inches only in the G-code text), backlash tables um, ``half``: the fraction
 * of the backlash applied per side, um -> mm. Backlash direction +1: the carriage command
 * last moved towards +, the take-up offset is + (half the backlash there). */
#ifndef KINCOMP_KERNEL_H
#define KINCOMP_KERNEL_H

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

#define MAX_LINE 96      /* longest line taken (longer: Python; no number reaches gcode's limit) */
#define MAX_TEXT 40      /* longest number text kept (longer: Python decides) */
#define MAX_PTS 64       /* backlash table points (more: no kernel) */
#define OUT_LINE 1024
#define OUT_BUF 16384    /* the output of one input line (more: Python decides) */
#define MAX_OUT 128      /* lines written for one input line (more: Python decides) */
#define MAX_BREAKS 3
#define MM_PER_INCH 25.4

typedef struct {
    int n;
    double pos[MAX_PTS];
    double um[MAX_PTS];
    double slope[MAX_PTS];  /* (um[i+1] - um[i]) / (pos[i+1] - pos[i]): the same double */
} Table;

/* The stream state (core/state.py StreamState, its backlash directions and the report's
 * counters that the kernel keeps): mm, um for max correction, flags 0/1. */
typedef struct {
    int absolute, inches, e_abs_mode; /* e_abs_mode: -1 None, 0 False, 1 True */
    int plane, ij_absolute;
    int m_known;                      /* all three of m known */
    int m_has[3];
    double m[3];
    int fw_known[3];
    double fw[3];
    int fwt_len[3];                   /* -1: None */
    char fwt[3][MAX_TEXT + 1];
    double w[3], g[3];
    int q_last_known;
    double q_last[3];
    int recheck[3];
    long dir[3];
    int anchor_known[3];
    double anchor[3];
    long long lineno, lines, moves, moves_comp, lines_out, takeup;
    long long arcs_kept, arcs_split, arcs_lin, arc_segments;
    double arc_dev;
    double maxc[3];
    int e_known;                      /* e_pos is a number (else None) */
    double e_pos;
    int f_known;                      /* feed is a number (else None) */
    double feed;
} State;

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
    int any_active;  /* backlash active on some axis */
    /* arcs (core/arcpath.py): kept as arcs, or left to Python (linearised there) */
    int keep_arcs, pure_translation;
    double tol;                   /* chord_tol_mm */
    double k_dev;                 /* gain * sample margin */
    double budget[2], sliver[2];  /* mm, [mm output, inch output] */
    double overshoot[2];          /* mm: a written circle may turn a backlash axis back */
    double max_offset;            /* largest take-up offset, mm */
    int nbreaks;
    double breaks[MAX_BREAKS];    /* G17: angles (rad) where a backlash axis reverses */
    /* while an arc is written (arc.c): the firmware coordinates its fit formatted, by axis,
     * which kk_point takes instead of formatting the very same number again */
    struct {
        int on;
        int len[3];                /* 0: none */
        double arg[3], value[3];   /* kk_format_value's argument and value */
        char text[3][MAX_TEXT + 1];
    } memo;
    /* the stream state: held (the record is the truth, Python's copy is stale once a line
     * was taken: ``dirty``) or not (Python's StreamState is the truth) */
    State st;
    int holds, dirty;
    PyObject *get, *put;  /* get() -> the record's tuple (None: not one the kernel holds),
                           * put(tuple): Python's StreamState from the record */
} Kernel;

/* The lines written for one input line, without endings. */
typedef struct {
    int n, len;
    int start[MAX_OUT + 1];
    char buf[OUT_BUF];
} Lines;

/* MoveHandler.track_e: an E word ``v`` (program units) seen on a move; absolute E sets the
   position, relative E (``relative``) adds to it, from an unknown position it stays unknown */
static inline void kk_track_e(State *s, int relative, double v)
{
    if (relative) {
        if (s->e_known)
            s->e_pos = s->e_pos + v;
    } else {
        s->e_known = 1;
        s->e_pos = v;
    }
}

enum { LINE_OUT, LINE_SAME, LINE_PYTHON };

/* state.c */
int kk_take(Kernel *K);
int kk_give(Kernel *K);
extern const char kk_record_fields[]; /* the record's field names (state.c) */
int kk_state_set(State *s, PyObject *t);
PyObject *kk_state_get(const State *s);
/* numbers.c */
typedef struct {
    char letter;
    Py_ssize_t start, end;  /* the letter's index, the word's end */
    double value;
} Word;
int kk_parse_num(const char *text, Py_ssize_t len, double *out);
int kk_words(const char *ln, Py_ssize_t i, Py_ssize_t n, Word *w, int max);
extern const double kk_P10[23];  /* 1e0 .. 1e22 */
int kk_put_word(char *out, int *len, char letter, double v, int dec);
int kk_format_value(double v, int dec, char *out, double *value);
/* transform.c */
int kk_do_line(Kernel *K, State *s0, const char *ln, Py_ssize_t n, Lines *out);
double kk_um_at(const Table *t, double q);
int kk_reversal(const Kernel *K, State *s, int k, double q, double q_from);
void kk_inverse(const Kernel *K, const double *p, double *q);
int kk_point(Kernel *K, State *s, const double *p, const double *q, const int *given,
             const double *q_prev, const int *redo, const double *m_old, char *out,
             int *out_len);
/* arcgeo.c: one arc in G17 (core/arcs.py Arc), mm and rad */
#define MAX_CUTS 64
typedef struct {
    double ca, cb, t0, sweep, r0, r1, dr, l0, dl;
    double start[3], end[3];
} Geo;
double kk_norm2(double a, double b);
void kk_arc_point(const Geo *a, double f, double *p);
void kk_arc_points(const Geo *a, double fa, double fb, int n, double (*out)[3]);
double kk_length_to(const Geo *a, double f);
int kk_arc_cuts(const Kernel *K, const Geo *a, double *cuts);
int kk_inside_limits(const Kernel *K, const Geo *a);
/* commands (mm) at the eighths 0, 1/8 .. 1 of each piece, kept by kk_monotone for the fit */
typedef double Eighths[9][3];
int kk_monotone(const Kernel *K, const Geo *a, const double *cuts, int nc, Eighths *kept,
                int *is_kept);
int kk_make_geo(const Kernel *K, Geo *a, const double *start, const double *end, double ca,
                double cb, int cw);
/* arc.c */
int kk_do_arc(Kernel *K, State *s, const char *ln, Py_ssize_t n, Lines *out);
/* lines */
char *kk_line_begin(Lines *o);
int kk_line_end(Lines *o, int len);

#endif
