/* Numbers as Python reads and writes them: float(text) and "%.{dec}f" % v (gcode.fmt),
 * fast where that is provably exact, Python's own parser and formatter elsewhere. */
#include "kernel.h"

static int format_slow(double v, int dec, char *out);

const double kk_P10[23] = {1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11,
                           1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21,
                           1e22};
#define P10 kk_P10

/* float(text) for a number text of [0-9.+-] (text[len] need not be 0). Exact where the
 * digits make an integer below 2**53 and there are at most 22 decimals: then the value is
 * that integer divided by a power of ten, both exact, and IEEE division rounds it correctly,
 * as Python's parser does (Clinger's fast path); anything else goes to Python's parser.
 * Returns 0, -1 if the text is no number. */
int kk_parse_num(const char *text, Py_ssize_t len, double *out)
{
    Py_ssize_t i = 0;
    int neg = 0, digits = 0, decimals = 0, dot = 0;
    unsigned long long mant = 0;
    if (len > 0 && (text[0] == '+' || text[0] == '-')) {
        neg = text[0] == '-';
        i = 1;
    }
    for (; i < len; i++) {
        unsigned d = (unsigned)(unsigned char)text[i] - '0';
        if (d <= 9) {
            if (++digits > 15 && mant > (1ULL << 53) / 10) {
                digits = -1000;  /* too many digits for the fast path */
                break;
            }
            mant = mant * 10 + d;
            decimals += dot;
        } else if (text[i] == '.' && !dot) {
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
        if (strspn(buf, "0123456789.+-") < (size_t)len)
            return -1;  /* (the fast loop stopped early: no exponent, no letters) */
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

/* The words of ln[i..n): "<letter><number>", single-spaced, each number as kk_parse_num
 * reads it (w[].start: the letter's index, .end: the word's end). Their count, -1: more than
 * max, an empty or bare-letter word, or no number (Python decides). */
int kk_words(const char *ln, Py_ssize_t i, Py_ssize_t n, Word *w, int max)
{
    int count = 0;
    for (;;) {
        const char *sp = memchr(ln + i, ' ', n - i);
        Py_ssize_t e = sp != NULL ? sp - ln : n;
        if (e - i < 2 || count == max || kk_parse_num(ln + i + 1, e - i - 1, &w[count].value) < 0)
            return -1;
        w[count].letter = ln[i];
        w[count].start = i;
        w[count++].end = e;
        if (sp == NULL)
            return count;
        i = e + 1;
    }
}

/* Drops the trailing zeros of the decimals of text[0..len) and a bare dot; "-0" -> "0"
 * (gcode.fmt). Returns the new length. */
static int trim_zeros(char *text, int len, int dec)
{
    if (dec > 0) {
        while (text[len - 1] == '0')
            len--;
        if (text[len - 1] == '.')
            len--;
    }
    if (len == 2 && text[0] == '-' && text[1] == '0') {
        text[0] = '0';
        len = 1;
    }
    text[len] = 0;
    return len;
}

/* "%.{dec}f" % v, trimmed as gcode.fmt. Returns the length, -1: Python decides.
 * Where |v| * 10**dec is at most 1e9 and not within 1e-6 of a half, rounding the scaled
 * value (off the exact one by less than 2.5e-7) gives the correctly rounded digits that
 * Python's formatter writes; elsewhere Python's formatter does it. With ``value``: float()
 * of the text written, from the fast path's digits, as an integer below 2**53 divided by a
 * power of ten, one correctly rounded IEEE division, as kk_parse_num would compute it from
 * the text; else by parsing the text. */
int kk_format_value(double v, int dec, char *out, double *value)
{
    double r = fabs(v) * P10[dec];
    int len;
    if (r <= 1e9) {
        double fl = (double)(unsigned long long)r, frac = r - fl;  /* (floor: r >= 0) */
        if (fabs(frac - 0.5) >= 1e-6) {
            unsigned long long n = (unsigned long long)fl + (frac > 0.5);
            unsigned long long ip = n / (unsigned long long)P10[dec];
            unsigned long long fp = n % (unsigned long long)P10[dec];
            char tmp[32];
            int t = 0, k;
            len = 0;
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
            if (value != NULL) {
                double x = (double)n / P10[dec];
                *value = v < 0 && n > 0 ? -x : x;
            }
            return trim_zeros(out, len, dec);
        }
    }
    len = format_slow(v, dec, out);
    if (len >= 0 && value != NULL && kk_parse_num(out, len, value) < 0)
        return -1;
    return len;
}

/* " <letter><v as kk_format_value writes it>" appended at out[*len]; 0, -1: Python decides */
int kk_put_word(char *out, int *len, char letter, double v, int dec)
{
    int n = kk_format_value(v, dec, out + *len + 2, NULL);
    if (n < 0)
        return -1;
    out[*len] = ' ';
    out[*len + 1] = letter;
    *len += n + 2;
    return 0;
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
    if (len > MAX_TEXT) {
        PyMem_Free(s);
        return -1;
    }
    memcpy(out, p, len);
    PyMem_Free(s);
    return trim_zeros(out, (int)len, dec);
}

