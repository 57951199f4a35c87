/* Fitted lenses: the `lensfit-poly-table` reader (version 5: version 3's lines, each
 * system ending with PROBES probe lines, its own polynomials evaluated at fixed points
 * and checked here, and a last line with the CRC-32 of everything before it;
 * fit/lensfit/codegen/table.py has the format, its ranges and the probe tolerance).
 *
 * Reentrant and independent of the host's locale: lines are split by split_fields (not
 * strtok, whose hidden state a host's own strtok loop or another thread would share),
 * numbers are read by lensrt_strtod_c (the "C" locale on this thread for the call: under
 * de_DE's LC_NUMERIC strtod stops at the '.' of "1.5"), and characters are classified
 * as ASCII, not by the locale's <ctype.h> tables. */
#include "../c_numbers.h"
#include "../internal.h"
#include "../core/crc32.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

/* Probe lines (version 5): PROBES per system, after its outputs. A probe output read
 * back may differ from the polynomials evaluated here by PROBE_RTOL * sum |c_t| +
 * PROBE_ATOL: only rounding separates them (the writer's numpy sums and these sums of
 * the same terms at the same doubles each err by at most (n_terms + 15) 2^-53 sum |c_t|,
 * 1.2e-10 sum |c_t| at LENSRT_MAX_TERMS), while a coefficient edited, or two swapped, by
 * more than ~1e-9 of sum |c_t| (the output's bound over its domain) moves a probe further
 * (table.py, PROBE_XHAT, for the points' choice). */
#define PROBES 6
#define PROBE_RTOL 1e-9
#define PROBE_ATOL 1e-300
#define MAX_IO 16 /* inputs and outputs of one system, at most 8 each */

/* The ranges of the lens and trust values (table.py's module doc, "Ranges"; lensfit's
 * facts.py and table.py hold the same numbers): lengths (radii, |focal length|) in
 * [LENGTH_MIN_MM, LENGTH_MAX_MM], signed distances at most LENGTH_MAX_MM either way. */
#define LENGTH_MIN_MM 1e-3
#define LENGTH_MAX_MM 1e6
#define SQUEEZE_MIN 0.1
#define SQUEEZE_MAX 10.0
#define PSF_VS_EXACT_MIN 1e-12
#define PSF_VS_EXACT_MAX 10.0
#define PSF_TARGET_MIN 1e-6
#define PSF_TARGET_MAX 1.0

/* A system's probe lines as read: inputs then outputs of each, and their line numbers. */
typedef struct probes {
    double value[PROBES][MAX_IO];
    int line[PROBES];
} probes;

/* A cursor over the table text that knows the current line for messages. */
typedef struct reader {
    lensrt_context ctx;
    const char *name; /* file name for messages */
    const char *p, *end;
    int line;
    char buf[4096];   /* the current line */
    char *tok[24];
    int n_tok;
} reader;

static lensrt_result parse_fail(reader *r, const char *fmt, const char *what)
{
    char msg[512];
    snprintf(msg, sizeof msg, fmt, what);
    return lensrt_fail(r->ctx, LENSRT_ERROR_PARSE, "%s:%d: %s", r->name, r->line, msg);
}

/* The same with any printf arguments. */
static lensrt_result parse_failf(reader *r, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 2, 3)))
#endif
    ;
static lensrt_result parse_failf(reader *r, const char *fmt, ...)
{
    char msg[768];
    va_list args;
    va_start(args, fmt);
    vsnprintf(msg, sizeof msg, fmt, args);
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

static int ascii_alnum(char c)
{
    return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z');
}

/* Read the next line that is not blank or a comment and split it at spaces. */
static int next_line(reader *r)
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
static void decode_field(char *s)
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

static int parse_real(const char *s, double *v)
{
    char *end;
    if (!real_syntax(s)) return 0;
    errno = 0;
    *v = lensrt_strtod_c(s, &end);
    return end != s && *end == '\0' && errno == 0 && isfinite(*v);
}

/* A decimal integer in [lo, hi] (optional sign, ASCII digits only, nothing after). */
static int parse_int(const char *s, int lo, int hi, int *v)
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

/* The declared domain of an input (its line's fields are r->tok[3..7]: lo, hi, transform,
 * c, s), checked against its transform (a reader's check, so
 * that nothing the polynomials are evaluated at can overflow): lo < hi, lo > 0 for
 * inverse_square (w = 1/v^2), and the transform maps the domain onto [-1, 1] exactly as
 * lensfit writes it (within DOMAIN_SLACK for the decimal text), so that every monomial
 * of normalised inputs is at most 1 inside the domain. */
#define DOMAIN_SLACK 1e-9
static lensrt_result check_input(reader *r, const char *sys, const lensrt_input *in)
{
    double a, b;
    if (!(in->lo < in->hi))
        return parse_failf(r, "system %s: input %s: domain lo %s, hi %s is empty (lo must be below hi)", sys,
                           in->name, r->tok[3], r->tok[4]);
    if (in->transform == LENSRT_TRANSFORM_INVERSE_SQUARE && !(in->lo > 0))
        return parse_failf(r, "system %s: input %s: inverse_square needs lo > 0, found lo %s", sys, in->name,
                           r->tok[3]);
    // The domain's ends, normalised: -1 and 1 (in either order: 1/v^2 falls with v)
    a = lensrt_normalise(in, in->lo);
    b = lensrt_normalise(in, in->hi);
    if (!(fabs(fmin(a, b) + 1.0) <= DOMAIN_SLACK && fabs(fmax(a, b) - 1.0) <= DOMAIN_SLACK))
        return parse_failf(r, "system %s: input %s: transform %s c %s s %s maps the domain [%s, %s] to [%.17g, "
                              "%.17g], not [-1, 1]", sys, in->name, r->tok[5], r->tok[6], r->tok[7], r->tok[3],
                           r->tok[4], fmin(a, b), fmax(a, b));
    return LENSRT_SUCCESS;
}

/* Inside the domain every monomial is at most 1 in magnitude, so sum |c_t| bounds the
 * output there: it must stay below LENSRT_MAX_COEFFICIENT_SUM (transmittances tau_o and
 * tau_i, output 2, below LENSRT_MAX_TRANSMITTANCE_SUM). */
static lensrt_result check_output(reader *r, const char *sys, const lensrt_poly *p, int k, int line)
{
    /* P_clip's outputs are all positions (ratios or mm): no transmittance among them */
    const double bound = k == 2 && strcmp(sys, "P_clip") != 0 ? LENSRT_MAX_TRANSMITTANCE_SUM : LENSRT_MAX_COEFFICIENT_SUM;
    double total = 0.0;
    int t;
    for (t = 0; t < p->n_terms; t++) total += fabs(p->coefficients[t]);
    if (!(total <= bound))
        return lensrt_fail(r->ctx, LENSRT_ERROR_PARSE,
                           "%s:%d: system %s: output %s: the sum of |coefficients| is %.6g, above the bound %g "
                           "(the largest value the output may reach inside its domain)", r->name, line, sys, p->name,
                           total, bound);
    return LENSRT_SUCCESS;
}

/* A system's PROBES probe lines (after its outputs): each 'probe', the input values (in
 * their units, inside the declared domain) and the output values; kept in *pr. */
static lensrt_result read_probes(reader *r, const lensrt_system *sys, probes *pr)
{
    int p, j;
    for (p = 0; p < PROBES; p++) {
        if (!next_line(r) || strcmp(r->tok[0], "probe") != 0)
            return parse_failf(r, "expected 'probe <input values> <output values>' (probe line %d of %d of system "
                                  "%s, after its outputs), found '%s'", p + 1, PROBES, sys->name,
                               r->n_tok ? r->tok[0] : "");
        if (r->n_tok != 1 + sys->n_inputs + sys->n_outputs)
            return parse_failf(r, "probe of system %s: expected %d input values and %d output values, found %d "
                                  "values", sys->name, sys->n_inputs, sys->n_outputs, r->n_tok - 1);
        pr->line[p] = r->line;
        for (j = 0; j < sys->n_inputs + sys->n_outputs; j++) {
            const char *tok = r->tok[1 + j];
            double *v = &pr->value[p][j];
            if (!parse_real(tok, v))
                return parse_failf(r, "probe of system %s: %s %s: '%s' is not a finite number", sys->name,
                                   j < sys->n_inputs ? "input" : "output",
                                   j < sys->n_inputs ? sys->inputs[j].name : sys->outputs[j - sys->n_inputs].name, tok);
            if (j < sys->n_inputs && !(*v >= sys->inputs[j].lo && *v <= sys->inputs[j].hi))
                return parse_failf(r, "probe of system %s: input %s = %s is outside its domain [%.17g, %.17g]",
                                   sys->name, sys->inputs[j].name, tok, sys->inputs[j].lo, sys->inputs[j].hi);
        }
    }
    return LENSRT_SUCCESS;
}

/* The probes of a system against its polynomials as read (the last check of a table):
 * every output within PROBE_RTOL * sum |c_t| + PROBE_ATOL of the probe line's value. */
static lensrt_result check_probes(lensrt_context ctx, const char *file, const lensrt_system *sys, const probes *pr)
{
    int p, j, k, t, d;
    for (p = 0; p < PROBES; p++) {
        double pw[8][LENSRT_MAX_DEGREE + 1] = {{0.0}};
        for (j = 0; j < sys->n_inputs; j++) {
            double x = lensrt_normalise(&sys->inputs[j], pr->value[p][j]);
            pw[j][0] = 1.0;
            for (d = 1; d <= LENSRT_MAX_DEGREE; d++) pw[j][d] = pw[j][d - 1] * x;
        }
        for (k = 0; k < sys->n_outputs; k++) {
            const lensrt_poly *poly = &sys->outputs[k];
            double got = 0.0, scale = 0.0, want = pr->value[p][sys->n_inputs + k], tol;
            for (t = 0; t < poly->n_terms; t++) {
                const unsigned char *e = poly->exponents + (size_t)t * (size_t)sys->n_inputs;
                double m = poly->coefficients[t];
                for (j = 0; j < sys->n_inputs; j++) m *= pw[j][e[j]];
                got += m;
                scale += fabs(poly->coefficients[t]);
            }
            tol = PROBE_RTOL * scale + PROBE_ATOL;
            if (!(fabs(got - want) <= tol))
                return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                                   "%s:%d: system %s: output %s: probe %d of %d: the polynomials give %.17g, the probe "
                                   "line says %.17g (difference %.3g, tolerance %.3g): coefficients changed after "
                                   "lensfit wrote the table (edited, or lines swapped, behind a valid checksum); "
                                   "refused", file, pr->line[p], sys->name, poly->name, p + 1, PROBES, got, want,
                                   fabs(got - want), tol);
        }
    }
    return LENSRT_SUCCESS;
}

static lensrt_result read_system(reader *r, lensrt_system *sys, probes *pr)
{
    lensrt_result res;
    int i, t, k, line;
    // system NAME n_inputs n_outputs
    if (r->n_tok != 4 || !parse_int(r->tok[2], 1, 8, &sys->n_inputs) ||
        !parse_int(r->tok[3], 1, 8, &sys->n_outputs))
        return parse_fail(r, "expected 'system NAME N_IN N_OUT' (at most 8 each), found '%s'",
                          r->tok[0]);
    snprintf(sys->name, sizeof sys->name, "%s", r->tok[1]);
    // input NAME UNIT LO HI TRANSFORM C S
    for (i = 0; i < sys->n_inputs; i++) {
        lensrt_input *in = &sys->inputs[i];
        if (!next_line(r) || strcmp(r->tok[0], "input") != 0 || r->n_tok != 8)
            return parse_fail(r, "expected 'input NAME UNIT LO HI TRANSFORM C S'%s", "");
        snprintf(in->name, sizeof in->name, "%s", r->tok[1]);
        if (!parse_real(r->tok[3], &in->lo) || !parse_real(r->tok[4], &in->hi) ||
            !parse_real(r->tok[6], &in->c) || !parse_real(r->tok[7], &in->s) || in->s == 0.0 ||
            !(in->lo <= in->hi))
            return parse_fail(r, "input '%s': bounds or normalisation are not finite numbers "
                                 "with lo <= hi and s != 0", in->name);
        if (strcmp(r->tok[5], "affine") == 0) in->transform = LENSRT_TRANSFORM_AFFINE;
        else if (strcmp(r->tok[5], "inverse_square") == 0) in->transform = LENSRT_TRANSFORM_INVERSE_SQUARE;
        else return parse_fail(r, "unknown transform '%s' (affine or inverse_square)", r->tok[5]);
        if ((res = check_input(r, sys->name, in)) != LENSRT_SUCCESS) return res;
    }
    // output NAME UNIT N_TERMS, then one line per term: exponents and coefficient
    for (k = 0; k < sys->n_outputs; k++) {
        lensrt_poly *p = &sys->outputs[k];
        if (!next_line(r) || strcmp(r->tok[0], "output") != 0 || r->n_tok != 4 ||
            !parse_int(r->tok[3], 0, LENSRT_MAX_TERMS, &p->n_terms))
            return parse_fail(r, "expected 'output NAME UNIT N_TERMS'%s", "");
        snprintf(p->name, sizeof p->name, "%s", r->tok[1]);
        if (strcmp(r->tok[2], "-") == 0) r->tok[2][0] = '\0'; /* an empty text field */
        decode_field(r->tok[2]);
        snprintf(p->unit, sizeof p->unit, "%s", r->tok[2]);
        line = r->line;
        p->exponents = lensrt_calloc(r->ctx, (size_t)p->n_terms * (size_t)sys->n_inputs + 1, 1);
        p->coefficients = lensrt_calloc(r->ctx, (size_t)p->n_terms + 1, sizeof(double));
        if (!p->exponents || !p->coefficients)
            return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "%s: out of memory", r->name);
        for (t = 0; t < p->n_terms; t++) {
            if (!next_line(r) || r->n_tok != sys->n_inputs + 1)
                return parse_fail(r, "output '%s': expected a term line with one exponent per "
                                     "input and a coefficient", p->name);
            for (i = 0; i < sys->n_inputs; i++) {
                int e;
                if (!parse_int(r->tok[i], 0, LENSRT_MAX_DEGREE, &e))
                    return parse_fail(r, "exponent '%s' is not an integer in 0..15", r->tok[i]);
                p->exponents[t * sys->n_inputs + i] = (unsigned char)e;
            }
            if (!parse_real(r->tok[sys->n_inputs], &p->coefficients[t]))
                return parse_fail(r, "coefficient '%s' is not a finite number", r->tok[sys->n_inputs]);
        }
        if ((res = check_output(r, sys->name, p, k, line)) != LENSRT_SUCCESS) return res;
    }
    if ((res = read_probes(r, sys, pr)) != LENSRT_SUCCESS) return res;
    if (!next_line(r) || strcmp(r->tok[0], "end") != 0)
        return parse_fail(r, "expected 'end' after the outputs of system %s", sys->name);
    return LENSRT_SUCCESS;
}

/* The input names each system must have, in this order. */
static const char *const P_O_INPUTS[6] = {"x_O", "y_O", "u_O", "x_a", "y_a", "lambda"};
static const char *const P_S_INPUTS[6] = {"x_S", "y_S", "z_S", "x_a", "y_a", "lambda"};
static const char *const P_O_OUTPUTS[4] = {"x_o", "y_o", "tau_o", "phi_o"};
static const char *const P_S_OUTPUTS[4] = {"x_i", "y_i", "tau_i", "phi_i"};

static lensrt_result check_system(lensrt_context ctx, const char *file, const lensrt_system *s,
                                  const char *const *ins, const char *const *outs)
{
    int i;
    if (s->n_inputs != 6 || s->n_outputs != 4)
        return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                           "%s: system %s: expected 6 inputs and 4 outputs, found %d and %d",
                           file, s->name, s->n_inputs, s->n_outputs);
    for (i = 0; i < 6; i++)
        if (strcmp(s->inputs[i].name, ins[i]) != 0)
            return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                               "%s: system %s: input %d: expected '%s', found '%s'", file,
                               s->name, i, ins[i], s->inputs[i].name);
    for (i = 0; i < 4; i++)
        if (strcmp(s->outputs[i].name, outs[i]) != 0)
            return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                               "%s: system %s: output %d: expected '%s', found '%s'", file,
                               s->name, i, outs[i], s->outputs[i].name);
    return LENSRT_SUCCESS;
}

/* The two systems describe one lens: the stop point and wavelength inputs (3, 4, 5) have
 * the same domain in both, and u_O (an inverse distance) is not negative. */
static lensrt_result check_shared_inputs(lensrt_context ctx, const char *file, const lensrt_lens lens)
{
    int i;
    for (i = 3; i < 6; i++) {
        const lensrt_input *a = &lens->p_o.inputs[i], *b = &lens->p_s.inputs[i];
        if (a->lo != b->lo || a->hi != b->hi)
            return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                               "%s: input %s: P_o's domain [%.17g, %.17g] differs from P_s's [%.17g, %.17g] "
                               "(one lens, one stop and one wavelength range)", file, a->name, a->lo, a->hi, b->lo,
                               b->hi);
    }
    if (!(lens->p_o.inputs[2].lo >= 0))
        return lensrt_fail(ctx, LENSRT_ERROR_PARSE, "%s: input u_O (1 / distance): domain lo %.17g is negative", file,
                           lens->p_o.inputs[2].lo);
    return LENSRT_SUCCESS;
}

/* `lens KEY VALUE` lines (since table version 2). */
static lensrt_result read_lens_line(reader *r, lensrt_lens lens, unsigned *seen)
{
    static const char *const keys[] = {"focal_length_mm", "stop_radius_max_mm",
                                       "stop_radius_f1_mm", "housing_first_mm",
                                       "housing_last_mm", "sensor_defocus_mm",
                                       "front_focal_distance_mm", "squeeze"};
    double *slots[8];
    double v;
    int i;
    slots[0] = &lens->focal_length_mm;
    slots[1] = &lens->stop_radius_max_mm;
    slots[2] = &lens->stop_radius_f1_mm;
    slots[3] = &lens->housing_first_mm;
    slots[4] = &lens->housing_last_mm;
    slots[5] = &lens->sensor_defocus_mm;
    slots[6] = &lens->front_focal_distance_mm;
    slots[7] = &lens->squeeze;
    if (r->n_tok != 3) return parse_fail(r, "expected 'lens KEY VALUE'%s", "");
    if (strcmp(r->tok[1], "name") == 0) {
        decode_field(r->tok[2]);
        snprintf(lens->name, sizeof lens->name, "%s", r->tok[2]);
        return LENSRT_SUCCESS;
    }
    for (i = 0; i < 8; i++) {
        if (strcmp(r->tok[1], keys[i]) != 0) continue;
        if (!parse_real(r->tok[2], &v))
            return parse_failf(r, "lens %s '%s' is not a finite number", keys[i], r->tok[2]);
        // The ranges (defines above): lengths 0..4 (the focal length either sign), the
        // signed distances 5 and 6, the squeeze 7
        if (i == 0 && !(fabs(v) >= LENGTH_MIN_MM && fabs(v) <= LENGTH_MAX_MM))
            return parse_failf(r, "lens focal_length_mm %s is out of range: expected %g to %g mm either sign", r->tok[2],
                               LENGTH_MIN_MM, LENGTH_MAX_MM);
        if (i >= 1 && i <= 4 && !(v >= LENGTH_MIN_MM && v <= LENGTH_MAX_MM))
            return parse_failf(r, "lens %s %s is out of range: expected a length in [%g, %g] mm", keys[i], r->tok[2],
                               LENGTH_MIN_MM, LENGTH_MAX_MM);
        if ((i == 5 || i == 6) && !(fabs(v) <= LENGTH_MAX_MM))
            return parse_failf(r, "lens %s %s is out of range: expected a distance in [%g, %g] mm", keys[i], r->tok[2],
                               -LENGTH_MAX_MM, LENGTH_MAX_MM);
        if (i == 7 && !(v >= SQUEEZE_MIN && v <= SQUEEZE_MAX))
            return parse_failf(r, "lens squeeze %s is out of range: expected a squeeze in [%g, %g]", r->tok[2],
                               SQUEEZE_MIN, SQUEEZE_MAX);
        *slots[i] = v;
        *seen |= 1u << i;
        return LENSRT_SUCCESS;
    }
    return LENSRT_SUCCESS; /* unknown keys are for newer readers */
}

/* `trust KEY VALUE` lines (table version 3): after the lens lines, before the first
 * system, each key once in this order. *n_trust counts the lines read so far. */
#define TRUST_LINES 3
static const char *const TRUST_KEYS[TRUST_LINES] = {"psf_vs_exact", "psf_vs_exact_cell", "psf_target"};
static const char *const TRUST_FORMS[TRUST_LINES] = {"trust psf_vs_exact <real>",
                                                     "trust psf_vs_exact_cell <text>",
                                                     "trust psf_target <real>"};
#define TRUST_ORDER "keys come in the order psf_vs_exact, psf_vs_exact_cell, psf_target, " \
                    "after the lens lines and before the first system"

static lensrt_result read_trust_line(reader *r, lensrt_lens lens, int n_lens, int n_systems, int *n_trust)
{
    const char *key = r->n_tok > 1 ? r->tok[1] : "";
    const char *value = r->n_tok > 2 ? r->tok[2] : "";
    double v;
    int i;
    if (n_systems)
        return parse_failf(r, "trust %s '%s' after a system: the trust lines come before the first "
                              "system", key, value);
    if (!n_lens)
        return parse_failf(r, "trust %s '%s' before the lens lines: the trust lines follow them",
                           key, value);
    for (i = 0; i < *n_trust; i++)
        if (strcmp(key, TRUST_KEYS[i]) == 0)
            return parse_failf(r, "trust %s '%s' appears twice (each trust key once: " TRUST_ORDER ")",
                               key, value);
    if (*n_trust == TRUST_LINES)
        return parse_failf(r, "unknown trust key '%s' (value '%s') after the %d trust lines (" TRUST_ORDER ")",
                           key, value, TRUST_LINES);
    if (strcmp(key, TRUST_KEYS[*n_trust]) != 0)
        return parse_failf(r, "expected '%s' (trust line %d of %d: " TRUST_ORDER "), found trust %s '%s'",
                           TRUST_FORMS[*n_trust], *n_trust + 1, TRUST_LINES, key, value);
    if (r->n_tok != 3)
        return parse_failf(r, "expected '%s' (3 fields), found %d fields", TRUST_FORMS[*n_trust], r->n_tok);
    if (*n_trust == 1) {
        decode_field(r->tok[2]);
        snprintf(lens->psf_vs_exact_cell, sizeof lens->psf_vs_exact_cell, "%s", r->tok[2]);
    } else {
        const double lo = *n_trust == 0 ? PSF_VS_EXACT_MIN : PSF_TARGET_MIN;
        const double hi = *n_trust == 0 ? PSF_VS_EXACT_MAX : PSF_TARGET_MAX;
        if (!parse_real(value, &v))
            return parse_failf(r, "trust %s '%s' is not a finite number", key, value);
        if (!(v >= lo && v <= hi))
            return parse_failf(r, "trust %s %s is out of range: expected a number in [%g, %g]", key, value, lo, hi);
        if (*n_trust == 0) lens->psf_vs_exact = v;
        else lens->psf_target = v;
    }
    ++*n_trust;
    return LENSRT_SUCCESS;
}

/* `ghost KEY VALUE` lines (ghost tables, issue 13): after the trust lines, before the
 * first system, each key once in this order. *n_ghost counts the lines read so far. */
#define GHOST_LINES 4
static const char *const GHOST_KEYS[GHOST_LINES] = {"first", "second", "label", "side"};
static const char *const GHOST_FORMS[GHOST_LINES] = {"ghost first <i>", "ghost second <j>", "ghost label <text>",
                                                     "ghost side <P_o|P_s>"};
#define GHOST_ORDER "keys come in the order first, second, label, side, after the trust lines and " \
                    "before the first system"

/* A decimal integer without sign or leading zeros, at most 9 digits, ending at *end. */
static int label_number(const char *s, const char **end, int *v)
{
    int n = 0;
    *v = 0;
    if (s[0] == '0' && s[1] >= '0' && s[1] <= '9') return 0;
    for (; *s >= '0' && *s <= '9' && n < 10; s++, n++) *v = 10 * *v + (*s - '0');
    *end = s;
    return n >= 1 && n <= 9;
}

/* Whether a ghost label "a-b" numbers model surfaces (first, second) as the lens file
 * does (lensfit's ghost_label_problem): the loader inserts at most one surface (the
 * stop, which reflects nothing), so a is first or first - 1, b is second or second - 1,
 * and 0 <= first - a <= second - b <= 1. */
static int label_matches(const char *label, int first, int second)
{
    const char *p;
    int a, b;
    if (!label_number(label, &p, &a) || *p != '-' || !label_number(p + 1, &p, &b) || *p != '\0') return 0;
    return 0 <= first - a && first - a <= second - b && second - b <= 1;
}

static lensrt_result read_ghost_line(reader *r, lensrt_lens lens, int n_trust, int n_systems, int *n_ghost)
{
    const char *key = r->n_tok > 1 ? r->tok[1] : "";
    const char *value = r->n_tok > 2 ? r->tok[2] : "";
    int i;
    if (n_systems)
        return parse_failf(r, "ghost %s '%s' after a system: the ghost lines come before the first system", key,
                           value);
    if (n_trust < TRUST_LINES)
        return parse_failf(r, "ghost %s '%s' before the trust lines end: the ghost lines follow them", key, value);
    for (i = 0; i < *n_ghost; i++)
        if (strcmp(key, GHOST_KEYS[i]) == 0)
            return parse_failf(r, "ghost %s '%s' appears twice (each ghost key once: " GHOST_ORDER ")", key, value);
    if (*n_ghost == GHOST_LINES)
        return parse_failf(r, "unknown ghost key '%s' (value '%s') after the %d ghost lines (" GHOST_ORDER ")", key,
                           value, GHOST_LINES);
    if (strcmp(key, GHOST_KEYS[*n_ghost]) != 0)
        return parse_failf(r, "expected '%s' (ghost line %d of %d: " GHOST_ORDER "), found ghost %s '%s'",
                           GHOST_FORMS[*n_ghost], *n_ghost + 1, GHOST_LINES, key, value);
    if (r->n_tok != 3)
        return parse_failf(r, "expected '%s' (3 fields), found %d fields", GHOST_FORMS[*n_ghost], r->n_tok);
    switch (*n_ghost) {
    case 0: /* a model surface index */
        if (!parse_int(value, 0, 1000000, &lens->ghost_first))
            return parse_failf(r, "ghost first '%s' is not a surface index (an integer >= 0)", value);
        break;
    case 1: /* the second reflection lies behind the first */
        if (!parse_int(value, 0, 1000000, &lens->ghost_second))
            return parse_failf(r, "ghost second '%s' is not a surface index (an integer >= 0)", value);
        if (lens->ghost_second <= lens->ghost_first)
            return parse_failf(r, "ghost second '%s' is not after ghost first %d (a ghost (i, j) needs i < j)", value,
                               lens->ghost_first);
        break;
    case 2:
        if (strcmp(r->tok[2], "-") == 0) r->tok[2][0] = '\0';
        decode_field(r->tok[2]);
        if (!label_matches(r->tok[2], lens->ghost_first, lens->ghost_second))
            return parse_failf(r, "ghost label '%s' does not number ghost first %d and ghost second %d: expected '%d-%d' "
                                  "(or one less for a surface behind the stop surface the loader inserts: '%d-%d', "
                                  "'%d-%d')", r->tok[2], lens->ghost_first, lens->ghost_second, lens->ghost_first,
                               lens->ghost_second, lens->ghost_first, lens->ghost_second - 1,
                               lens->ghost_first > 0 ? lens->ghost_first - 1 : 0, lens->ghost_second - 1);
        snprintf(lens->ghost_label, sizeof lens->ghost_label, "%s", r->tok[2]);
        break;
    default:
        if (strcmp(value, "P_o") == 0) lens->ghost_side = LENSRT_SYSTEM_OBJECT;
        else if (strcmp(value, "P_s") == 0) lens->ghost_side = LENSRT_SYSTEM_SENSOR;
        else return parse_failf(r, "ghost side '%s' is neither P_o nor P_s (the system that is the ghost half)", value);
        lens->ghost = 1;
        break;
    }
    ++*n_ghost;
    return LENSRT_SUCCESS;
}

/* P_clip (ghost tables): the ghost side's inputs exactly (names, domains, transforms),
 * then pairs x_h<k> y_h<k> (unit 1: a housing crossing over its radius) or x_s<c> y_s<c>
 * (unit mm: a crossing of the stop plane). A unit may carry a description after a space
 * ("1 (over the radius)"), as the inputs' units do. */
static int unit_is(const char *unit, const char *want)
{
    size_t n = strlen(want);
    return strncmp(unit, want, n) == 0 && (unit[n] == '\0' || unit[n] == ' ');
}

static int pair_name(const char *name, char axis, char kind, char *index, size_t size)
{
    const char *d = name + 3;
    if (name[0] != axis || name[1] != '_' || name[2] != kind || *d == '\0') return 0;
    for (; *d; d++)
        if (*d < '0' || *d > '9') return 0;
    snprintf(index, size, "%s", name + 3);
    return 1;
}

static lensrt_result check_clip(lensrt_context ctx, const char *file, lensrt_lens lens)
{
    const lensrt_system *c = &lens->p_clip;
    const lensrt_system *g = lens->ghost_side == LENSRT_SYSTEM_OBJECT ? &lens->p_o : &lens->p_s;
    const char *gname = lens->ghost_side == LENSRT_SYSTEM_OBJECT ? "P_o" : "P_s";
    int i, q;
    if (c->n_inputs != g->n_inputs)
        return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                           "%s: system P_clip: %d inputs, the ghost side %s has %d (P_clip takes exactly its inputs)",
                           file, c->n_inputs, gname, g->n_inputs);
    for (i = 0; i < c->n_inputs; i++) {
        const lensrt_input *a = &c->inputs[i], *b = &g->inputs[i];
        if (strcmp(a->name, b->name) != 0 || a->lo != b->lo || a->hi != b->hi || a->transform != b->transform ||
            a->c != b->c || a->s != b->s)
            return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                               "%s: system P_clip: input %d '%s' [%.17g, %.17g] (transform %d, c %.17g, s %.17g) "
                               "differs from the ghost side %s's '%s' [%.17g, %.17g] (transform %d, c %.17g, s %.17g)",
                               file, i, a->name, a->lo, a->hi, a->transform, a->c, a->s, gname, b->name, b->lo,
                               b->hi, b->transform, b->c, b->s);
    }
    if (c->n_outputs % 2 != 0)
        return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                           "%s: system P_clip: %d outputs, an odd count (outputs come in pairs x, y)", file,
                           c->n_outputs);
    for (q = 0; q < c->n_outputs / 2; q++) {
        const lensrt_poly *x = &c->outputs[2 * q], *y = &c->outputs[2 * q + 1];
        char ix[32], iy[32];
        int stop;
        if (pair_name(x->name, 'x', 'h', ix, sizeof ix)) stop = 0;
        else if (pair_name(x->name, 'x', 's', ix, sizeof ix)) stop = 1;
        else
            return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                               "%s: system P_clip: output %d '%s' (unit '%s'): expected x_h<k> (a housing, unit 1) or "
                               "x_s<c> (a stop crossing, unit mm)", file, 2 * q, x->name, x->unit);
        if (!pair_name(y->name, 'y', stop ? 's' : 'h', iy, sizeof iy) || strcmp(ix, iy) != 0)
            return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                               "%s: system P_clip: output %d '%s' follows '%s': expected its pair y_%c%s", file,
                               2 * q + 1, y->name, x->name, stop ? 's' : 'h', ix);
        if (!unit_is(x->unit, stop ? "mm" : "1") || !unit_is(y->unit, stop ? "mm" : "1"))
            return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                               "%s: system P_clip: pair %s, %s has units '%s', '%s': expected '%s' (%s)", file,
                               x->name, y->name, x->unit, y->unit, stop ? "mm" : "1",
                               stop ? "a stop crossing in mm" : "a housing crossing over its radius");
        lens->clip_stop[q] = stop;
        lens->n_stop_pairs += stop;
    }
    lens->n_clip_pairs = c->n_outputs / 2;
    return LENSRT_SUCCESS;
}

/* What to pass to `lensfit fit` for a table file: the ID of lens<ID>.table, else LENS. */
/* The generated/<lens> folder a table lives in, for `lensfit regenerate <folder>`: the
 * table's folder, or the one above ghosts/, or two above scenes/<name>/ and
 * scene-fits/<name>/ ("LENS" when the path does not say). */
static void lens_folder_of(const char *file, char *folder, size_t size)
{
    const char *part[4] = {NULL, NULL, NULL, NULL}; /* the last folders, innermost first */
    size_t len[4] = {0, 0, 0, 0};
    const char *end = strrchr(file, '/'), *p;
    int n = 0, k;
    while (end && n < 4) {
        for (p = end; p > file && p[-1] != '/'; p--) continue;
        part[n] = p;
        len[n++] = (size_t)(end - p);
        end = p > file ? p - 1 : NULL;
    }
    k = n > 1 && len[0] == 6 && strncmp(part[0], "ghosts", 6) == 0 ? 1
        : n > 2 && ((len[1] == 6 && strncmp(part[1], "scenes", 6) == 0) ||
                    (len[1] == 10 && strncmp(part[1], "scene-fits", 10) == 0)) ? 2 : 0;
    if (n > k && len[k] > 0 && len[k] < size) snprintf(folder, size, "%.*s", (int)len[k], part[k]);
    else snprintf(folder, size, "LENS");
}

static void lens_id_of(const char *file, char *id, size_t size)
{
    const char *base = strrchr(file, '/');
    size_t n;
    base = base ? base + 1 : file;
    n = strlen(base);
    snprintf(id, size, "LENS");
    if (n > 10 && strncmp(base, "lens", 4) == 0 && strcmp(base + n - 6, ".table") == 0 && n - 10 < size) {
        size_t i;
        for (i = 4; i < n - 6; i++)
            if (!ascii_alnum(base[i]) && base[i] != '-' && base[i] != '_') return;
        memcpy(id, base + 4, n - 10);
        id[n - 10] = '\0';
    }
}

/* The trust figures on load: INFO always, WARNING when the worst cell misses the target. */
static void log_trust(lensrt_context ctx, const lensrt_lens lens)
{
    char cell[300] = "";
    if (lens->psf_vs_exact_cell[0]) snprintf(cell, sizeof cell, " (%s)", lens->psf_vs_exact_cell);
    lensrt_log(ctx, LENSRT_LOG_INFO, "%s: PSF against exactly traced rays: worst %.3g%% relative L2%s, target %.3g%%",
               lens->file, 100.0 * lens->psf_vs_exact, cell, 100.0 * lens->psf_target);
    if (lens->psf_vs_exact > lens->psf_target)
        lensrt_log(ctx, LENSRT_LOG_WARNING,
                   "%s: PSF against exactly traced rays: worst %.3g%% relative L2%s, target %.3g%%; "
                   "this exceeds the fit's target: regenerate with a tighter `lensfit fit --psf-target` "
                   "or a narrower domain",
                   lens->file, 100.0 * lens->psf_vs_exact, cell, 100.0 * lens->psf_target);
}

static void fill_info(lensrt_lens lens)
{
    lensrt_lens_info *info = &lens->info;
    const lensrt_input *xa = &lens->p_o.inputs[3];
    double stop = fmin(xa->hi, lens->stop_radius_max_mm);
    memset(info, 0, sizeof *info);
    info->struct_size = sizeof *info;
    info->name = lens->name;
    info->focal_length_mm = lens->focal_length_mm;
    info->stop_radius_max_mm = stop;
    info->f_number_min = lens->stop_radius_f1_mm / stop;
    info->wavelength_min_nm = lens->p_s.inputs[5].lo;
    info->wavelength_max_nm = lens->p_s.inputs[5].hi;
    info->focus_offset_min_mm = lens->p_s.inputs[2].lo;
    info->focus_offset_max_mm = lens->p_s.inputs[2].hi;
    info->field_x = lens->p_o.inputs[0].hi;
    info->field_y = lens->p_o.inputs[1].hi;
    info->distance_min_mm = lens->p_o.inputs[2].hi > 0 ? 1.0 / lens->p_o.inputs[2].hi : 0.0;
    info->sensor_radius_mm = fmax(lens->p_s.inputs[0].hi, lens->p_s.inputs[1].hi);
    info->psf_vs_exact = lens->psf_vs_exact;
    info->psf_target = lens->psf_target;
    info->psf_vs_exact_cell = lens->psf_vs_exact_cell;
    info->ghost = lens->ghost;
    info->ghost_first = lens->ghost_first;
    info->ghost_second = lens->ghost_second;
    info->ghost_label = lens->ghost_label;
    info->ghost_clip_pairs = lens->n_clip_pairs;
}

/* Version 4's last line, `checksum crc32 <8 lowercase hex digits>\n` exactly, against the
 * CRC-32 of every byte before it (core/crc32.h). On success *body_end is where that line
 * starts (the parser stops there). */
static lensrt_result check_checksum(lensrt_context ctx, const char *name, const char *text, size_t size,
                                    const char **body_end)
{
    size_t start, line;
    uint32_t want = 0, got = 0;
    if (!lensrt_crc32_checksum_line(text, size, &start, &line, &want, &got))
        return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                           "%s:%zu: expected the last line 'checksum crc32 <8 lowercase hex digits>' (a table cut "
                           "short, or edited): refused", name, line);
    if (got != want)
        return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                           "%s:%zu: checksum %08x does not match the content (%08x): the table was changed after "
                           "lensfit wrote it; refused", name, line, (unsigned)want, (unsigned)got);
    *body_end = text + start;
    return LENSRT_SUCCESS;
}

/* Every byte of the body is text: no control byte but tab (and a CR right before a
 * newline), no DEL; and no line longer than the reader's line buffer unless a comment.
 * A NUL would otherwise end the line early here (a line of NULs read as a blank line,
 * skipped), where lensfit's reader sees other fields (issue 39). */
static lensrt_result check_text(lensrt_context ctx, const char *name, const char *text, const char *end)
{
    const char *p = text, *start = text;
    int line = 1;
    for (; p < end; p++) {
        unsigned char c = (unsigned char)*p;
        if (c == '\n') {
            const char *q = start;
            while (q < p && (*q == ' ' || *q == '\t')) q++;
            if ((size_t)(p - start) >= sizeof ((reader *)0)->buf && (q == p || *q != '#'))
                return lensrt_fail(ctx, LENSRT_ERROR_PARSE, "%s:%d: a line of %zu bytes, longer than %zu: refused",
                                   name, line, (size_t)(p - start), sizeof ((reader *)0)->buf - 1);
            line++;
            start = p + 1;
        } else if ((c < 0x20 && c != '\t' && !(c == '\r' && p + 1 < end && p[1] == '\n')) || c == 0x7f) {
            return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                               "%s:%d: control byte 0x%02x at column %d: a table is text (a tab is the only control "
                               "character it may hold, a CR only before the newline); refused",
                               name, line, (unsigned)c, (int)(p - start) + 1);
        }
    }
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_lens_load_text(lensrt_context ctx, const char *text, size_t size,
                                    const char *name, lensrt_lens *out)
{
    reader r;
    lensrt_lens lens;
    lensrt_result res;
    unsigned seen = 0;
    int version, n_lens = 0, n_trust = 0, n_ghost = 0, n_systems = 0;
    char id[64], folder[256];
    probes *pr; /* P_o's, P_s's and P_clip's probe lines */
    if (!ctx || !text || !out) return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_lens_load_text: NULL argument");
    *out = NULL;
    memset(&r, 0, sizeof r);
    r.ctx = ctx;
    r.name = name ? name : "<memory>";
    r.p = text;
    r.end = text + size;
    // Header: the format name and version
    if (!next_line(&r) || r.n_tok != 2 || strcmp(r.tok[0], "lensfit-poly-table") != 0 ||
        !parse_int(r.tok[1], 1, 1000, &version))
        return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                           "%s:%d: not a lens table: expected 'lensfit-poly-table 5'", r.name, r.line);
    lens_id_of(r.name, id, sizeof id);
    lens_folder_of(r.name, folder, sizeof folder);
    if (version < 3)
        return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                           "%s: table version %d predates the trust figures (the PSF against exactly "
                           "traced rays) that version 3 carries; regenerate it with `lensfit fit %s`",
                           r.name, version, id);
    if (version == 3)
        return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                           "%s: table version 3 carries no checksum (a table changed or cut short could not be "
                           "told); regenerate it with `lensfit regenerate %s` (rewrites generated/<lens>/ with "
                           "checksums, no refit)", r.name, folder);
    if (version == 4)
        return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                           "%s: table version 4 carries no probe lines (swapped or edited coefficients behind a valid "
                           "checksum could not be told); upgrade it with `lensfit regenerate %s` (adds them from the "
                           "table's own polynomials, no refit) or `lensfit upgrade-table %s`", r.name, folder, r.name);
    if (version > 5)
        return lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                           "%s: table version %d is newer than this lensrt reads (5)", r.name, version);
    // The last line is the checksum of every byte before it: verify, then parse the rest
    if ((res = check_checksum(ctx, r.name, text, size, &r.end)) != LENSRT_SUCCESS) return res;
    if ((res = check_text(ctx, r.name, text, r.end)) != LENSRT_SUCCESS) return res;
    pr = lensrt_calloc(ctx, 3, sizeof *pr);
    lens = pr ? lensrt_calloc(ctx, 1, sizeof *lens) : NULL;
    if (!lens) {
        lensrt_free(ctx, pr);
        return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "%s: out of memory", r.name);
    }
    lens->ctx = ctx;
    lens->squeeze = 1.0;
    snprintf(lens->file, sizeof lens->file, "%s", r.name);
    snprintf(lens->name, sizeof lens->name, "%s", r.name);
    // Lens facts, trust figures, then the two systems
    res = LENSRT_SUCCESS;
    while (res == LENSRT_SUCCESS && next_line(&r)) {
        if (strcmp(r.tok[0], "lens") == 0) {
            if (n_trust || n_systems) {
                res = parse_failf(&r, "lens %s '%s' after the %s: the lens lines come first",
                                  r.n_tok > 1 ? r.tok[1] : "", r.n_tok > 2 ? r.tok[2] : "",
                                  n_systems ? "systems" : "trust lines");
                break;
            }
            n_lens++;
            res = read_lens_line(&r, lens, &seen);
        } else if (strcmp(r.tok[0], "trust") == 0) {
            if (n_ghost) {
                res = parse_failf(&r, "trust %s '%s' after the ghost lines: the trust lines come first",
                                  r.n_tok > 1 ? r.tok[1] : "", r.n_tok > 2 ? r.tok[2] : "");
                break;
            }
            res = read_trust_line(&r, lens, n_lens, n_systems, &n_trust);
        } else if (strcmp(r.tok[0], "ghost") == 0) {
            res = read_ghost_line(&r, lens, n_trust, n_systems, &n_ghost);
        } else if (strcmp(r.tok[0], "system") == 0) {
            lensrt_system *sys;
            if (n_trust < TRUST_LINES) {
                res = parse_failf(&r, "missing trust line: expected '%s' (trust line %d of %d: " TRUST_ORDER
                                      "), found '%s %s'", TRUST_FORMS[n_trust], n_trust + 1, TRUST_LINES,
                                  r.tok[0], r.n_tok > 1 ? r.tok[1] : "");
                break;
            }
            if (n_ghost && n_ghost < GHOST_LINES) {
                res = parse_failf(&r, "missing ghost line: expected '%s' (ghost line %d of %d: " GHOST_ORDER
                                      "), found '%s %s'", GHOST_FORMS[n_ghost], n_ghost + 1, GHOST_LINES,
                                  r.tok[0], r.n_tok > 1 ? r.tok[1] : "");
                break;
            }
            n_systems++;
            if (r.n_tok > 1 && strcmp(r.tok[1], "P_o") == 0) sys = &lens->p_o;
            else if (r.n_tok > 1 && strcmp(r.tok[1], "P_s") == 0) sys = &lens->p_s;
            else if (r.n_tok > 1 && strcmp(r.tok[1], "P_clip") == 0) sys = &lens->p_clip;
            else { res = parse_fail(&r, "unknown system '%s' (P_o, P_s, or P_clip in a ghost table)", r.n_tok > 1 ? r.tok[1] : ""); break; }
            if (sys->n_inputs) { res = parse_fail(&r, "system %s appears twice", sys->name); break; }
            if (sys == &lens->p_clip) {
                // Only a ghost table clips, after its two systems, with 1..4 pairs
                int n_out = 0;
                if (!lens->ghost) {
                    res = parse_failf(&r, "system P_clip '%s' in a table without ghost lines (P_clip belongs to a "
                                          "ghost table: ghost first, second, label and side before the systems)",
                                      r.n_tok > 3 ? r.tok[3] : "");
                    break;
                }
                if (!lens->p_o.n_inputs || !lens->p_s.n_inputs) {
                    res = parse_failf(&r, "system P_clip before system %s: P_clip comes third, after P_o and P_s",
                                      !lens->p_o.n_inputs ? "P_o" : "P_s");
                    break;
                }
                if (r.n_tok == 4 && parse_int(r.tok[3], 0, 1000000, &n_out) && (n_out > 2 * LENSRT_MAX_CLIP_PAIRS || n_out % 2)) {
                    res = parse_failf(&r, "system P_clip: %d outputs: expected an even count of 2..%d (pairs x, y; "
                                          "at most %d clip tests)", n_out, 2 * LENSRT_MAX_CLIP_PAIRS, LENSRT_MAX_CLIP_PAIRS);
                    break;
                }
            }
            res = read_system(&r, sys, &pr[sys == &lens->p_o ? 0 : sys == &lens->p_s ? 1 : 2]);
        } else {
            res = parse_fail(&r, "unexpected line starting with '%s'", r.tok[0]);
        }
    }
    if (res == LENSRT_SUCCESS && (!lens->p_o.n_inputs || !lens->p_s.n_inputs))
        res = lensrt_fail(ctx, LENSRT_ERROR_PARSE, "%s:%d: the table ends without system %s (it needs P_o and P_s)",
                          r.name, r.line, !lens->p_o.n_inputs ? "P_o" : "P_s");
    if (res == LENSRT_SUCCESS) res = check_system(ctx, r.name, &lens->p_o, P_O_INPUTS, P_O_OUTPUTS);
    if (res == LENSRT_SUCCESS) res = check_system(ctx, r.name, &lens->p_s, P_S_INPUTS, P_S_OUTPUTS);
    if (res == LENSRT_SUCCESS) res = check_shared_inputs(ctx, r.name, lens);
    if (res == LENSRT_SUCCESS && n_ghost && n_ghost < GHOST_LINES)
        res = lensrt_fail(ctx, LENSRT_ERROR_PARSE, "%s: missing ghost line '%s' (ghost line %d of %d: " GHOST_ORDER ")",
                          r.name, GHOST_FORMS[n_ghost], n_ghost + 1, GHOST_LINES);
    if (res == LENSRT_SUCCESS && lens->p_clip.n_inputs) res = check_clip(ctx, r.name, lens);
    if (res == LENSRT_SUCCESS && (seen & 0x1f) != 0x1f)
        res = lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                          "%s: missing lens line(s): focal_length_mm, stop_radius_max_mm, "
                          "stop_radius_f1_mm, housing_first_mm and housing_last_mm are required", r.name);
    if (res == LENSRT_SUCCESS && !(lens->stop_radius_f1_mm > 0 && lens->housing_first_mm > 0 &&
                                   lens->housing_last_mm > 0 && lens->stop_radius_max_mm > 0))
        res = lensrt_fail(ctx, LENSRT_ERROR_PARSE,
                          "%s: lens radii must be positive (stop_radius_f1_mm %g, housing_first_mm %g, housing_last_mm %g)",
                          r.name, lens->stop_radius_f1_mm, lens->housing_first_mm, lens->housing_last_mm);
    // Last, the probes: the polynomials as read must give what lensfit computed
    if (res == LENSRT_SUCCESS) res = check_probes(ctx, r.name, &lens->p_o, &pr[0]);
    if (res == LENSRT_SUCCESS) res = check_probes(ctx, r.name, &lens->p_s, &pr[1]);
    if (res == LENSRT_SUCCESS && lens->p_clip.n_inputs) res = check_probes(ctx, r.name, &lens->p_clip, &pr[2]);
    lensrt_free(ctx, pr);
    if (res != LENSRT_SUCCESS) {
        lensrt_lens_destroy(ctx, lens);
        return res;
    }
    fill_info(lens);
    log_trust(ctx, lens);
    *out = lens;
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_lens_load(lensrt_context ctx, const char *table_path, lensrt_lens *out)
{
    FILE *f;
    char *text;
    long size;
    size_t got;
    struct stat st;
    lensrt_result res;
    if (!ctx || !table_path || !out) return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_lens_load: NULL argument");
    *out = NULL;
    // A regular file only, checked before opening: a FIFO would block the open, a
    // folder or a device has no size to read
    if (stat(table_path, &st) != 0)
        return lensrt_fail(ctx, LENSRT_ERROR_IO, "%s: cannot open lens table: %s", table_path, strerror(errno));
    if (!S_ISREG(st.st_mode))
        return lensrt_fail(ctx, LENSRT_ERROR_IO, "%s: not a regular file (a lens table is a file)", table_path);
    // Read the whole file, then parse it from memory
    f = fopen(table_path, "rb");
    if (!f) return lensrt_fail(ctx, LENSRT_ERROR_IO, "%s: cannot open lens table: %s", table_path, strerror(errno));
    if (fseek(f, 0, SEEK_END) != 0 || (size = ftell(f)) < 0 || fseek(f, 0, SEEK_SET) != 0) {
        fclose(f);
        return lensrt_fail(ctx, LENSRT_ERROR_IO, "%s: cannot read lens table", table_path);
    }
    text = lensrt_alloc(ctx, (size_t)size + 1);
    if (!text) {
        fclose(f);
        return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "%s: out of memory", table_path);
    }
    got = fread(text, 1, (size_t)size, f);
    fclose(f);
    if (got != (size_t)size) {
        lensrt_free(ctx, text);
        return lensrt_fail(ctx, LENSRT_ERROR_IO, "%s: short read", table_path);
    }
    text[size] = '\0';
    res = lensrt_lens_load_text(ctx, text, (size_t)size, table_path, out);
    lensrt_free(ctx, text);
    return res;
}
