/* Fitted lenses' table reader: the text layer (lines, fields, numbers).
 *
 * Reentrant and independent of the host's locale: lines are split by split_fields (not
 * strtok, whose hidden state a host's own strtok loop or another thread would share),
 * numbers are read by lensrt_strtod_c (the "C" locale on this thread for the call: under
 * de_DE's LC_NUMERIC strtod stops at the '.' of "1.5"), and characters are classified
 * as ASCII, not by the locale's <ctype.h> tables. */
#include "../c_numbers.h"
#include "table.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

lensrt_result lensrt_table_parse_fail(reader *r, const char *fmt, const char *what)
{
    char msg[512];
    snprintf(msg, sizeof msg, fmt, what);
    return lensrt_fail(r->ctx, LENSRT_ERROR_PARSE, "%s:%d: %s", r->name, r->line, msg);
}

/* The same with any printf arguments. */
lensrt_result lensrt_table_parse_failf(reader *r, const char *fmt, ...)
{
    char msg[768];
    va_list args;
    va_start(args, fmt);
    lensrt_vsnprintf_c(msg, sizeof msg, fmt, args); /* numbers with a point, any locale */
    va_end(args);
    return lensrt_fail(r->ctx, LENSRT_ERROR_PARSE, "%s:%d: %s", r->name, r->line, msg);
}

/* Split s in place at runs of spaces and tabs into at most max fields; the count. */
static int split_fields(char *s, char **fields, int max)
{
    int n = 0;
    while (n < max) {
        // Skip the separators, then mark the field's start and end it at the next one
        while (*s == ' ' || *s == '\t') s++;
        if (*s == '\0') break;
        fields[n++] = s;
        while (*s != '\0' && *s != ' ' && *s != '\t') s++;
        if (*s == '\0') break;
        *s++ = '\0';
    }
    return n;
}

/* ASCII classes (the locale's <ctype.h> may count other bytes as letters or digits). */
static int hex_digit(char c)
{
    return c >= '0' && c <= '9' ? c - '0' : c >= 'a' && c <= 'f' ? c - 'a' + 10 : c >= 'A' && c <= 'F' ? c - 'A' + 10 : -1;
}

int lensrt_table_ascii_alnum(char c)
{
    return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z');
}

/* Read the next line that is not blank or a comment and split it at spaces. */
int lensrt_table_next_line(reader *r)
{
    while (r->p < r->end) {
        const char *eol = memchr(r->p, '\n', (size_t)(r->end - r->p));
        size_t len = eol ? (size_t)(eol - r->p) : (size_t)(r->end - r->p);
        r->line++;
        if (len >= sizeof r->buf) len = sizeof r->buf - 1;
        memcpy(r->buf, r->p, len);
        r->buf[len] = '\0';
        r->p = eol ? eol + 1 : r->end;
        if (len && r->buf[len - 1] == '\r') r->buf[len - 1] = '\0';
        if (r->buf[0] == '#' || r->buf[0] == '\0') continue;
        r->n_tok = split_fields(r->buf, r->tok, 24);
        if (r->n_tok && r->tok[0][0] != '#') return 1; /* '#' after blanks: a comment too */
    }
    return 0;
}

/* Decode %XX escapes in place (fields with spaces are percent-encoded). */
void lensrt_table_decode_field(char *s)
{
    char *o = s;
    for (; *s; s++) {
        if (s[0] == '%' && hex_digit(s[1]) >= 0 && hex_digit(s[2]) >= 0) {
            *o++ = (char)(16 * hex_digit(s[1]) + hex_digit(s[2]));
            s += 2;
        } else {
            *o++ = *s;
        }
    }
    *o = '\0';
}

/* The table's number syntax, nothing else: [-+] digits [. digits] or [-+] . digits, then
 * an optional exponent [eE][-+]digits. strtod alone would also take hex floats (0x1p3),
 * "inf", "nan" and "infinity"; the writer never emits them and Python's reader refuses
 * them (issue 39). */
static int real_syntax(const char *s)
{
    int digits = 0;
    if (*s == '-' || *s == '+') s++;
    for (; *s >= '0' && *s <= '9'; s++) digits++;
    if (*s == '.')
        for (s++; *s >= '0' && *s <= '9'; s++) digits++;
    if (!digits) return 0;
    if (*s == 'e' || *s == 'E') {
        s++;
        if (*s == '-' || *s == '+') s++;
        if (!(*s >= '0' && *s <= '9')) return 0;
        while (*s >= '0' && *s <= '9') s++;
    }
    return *s == '\0';
}

int lensrt_table_parse_real(const char *s, double *v)
{
    char *end;
    if (!real_syntax(s)) return 0;
    errno = 0;
    *v = lensrt_strtod_c(s, &end);
    return end != s && *end == '\0' && errno == 0 && isfinite(*v);
}

/* A decimal integer in [lo, hi] (optional sign, ASCII digits only, nothing after). */
int lensrt_table_parse_int(const char *s, int lo, int hi, int *v)
{
    long x = 0;
    int negative = *s == '-';
    if (*s == '-' || *s == '+') s++;
    if (*s == '\0') return 0;
    for (; *s; s++) {
        if (*s < '0' || *s > '9') return 0;
        x = 10 * x + (*s - '0');
        if (x > 2147483647L) return 0; /* beyond any int bound: stop before overflow */
    }
    if (negative) x = -x;
    if (x < lo || x > hi) return 0;
    *v = (int)x;
    return 1;
}
