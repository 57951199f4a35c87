/* Fitted lenses' table reader: a system's lines (P_o, P_s, a ghost's P_clip: inputs with
 * their domains, outputs with their terms, the probe lines) and their checks (the
 * polynomials evaluated at the probes' inputs against their outputs); P_clip's inputs
 * and pairs against the ghost's half. */
#include "../c_numbers.h"
#include "table.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

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
        return lensrt_table_parse_failf(r, "system %s: input %s: domain lo %s, hi %s is empty (lo must be below hi)", sys,
                                        in->name, r->tok[3], r->tok[4]);
    if (in->transform == LENSRT_TRANSFORM_INVERSE_SQUARE && !(in->lo > 0))
        return lensrt_table_parse_failf(r, "system %s: input %s: inverse_square needs lo > 0, found lo %s", sys, in->name,
                                        r->tok[3]);
    // The domain's ends, normalised: -1 and 1 (in either order: 1/v^2 falls with v)
    a = lensrt_normalise(in, in->lo);
    b = lensrt_normalise(in, in->hi);
    if (!(fabs(fmin(a, b) + 1.0) <= DOMAIN_SLACK && fabs(fmax(a, b) - 1.0) <= DOMAIN_SLACK))
        return lensrt_table_parse_failf(r, "system %s: input %s: transform %s c %s s %s maps the domain [%s, %s] to [%.17g, "
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
        if (!lensrt_table_next_line(r) || strcmp(r->tok[0], "probe") != 0)
            return lensrt_table_parse_failf(r, "expected 'probe <input values> <output values>' (probe line %d of %d of system "
                                  "%s, after its outputs), found '%s'", p + 1, PROBES, sys->name,
                                            r->n_tok ? r->tok[0] : "");
        if (r->n_tok != 1 + sys->n_inputs + sys->n_outputs)
            return lensrt_table_parse_failf(r, "probe of system %s: expected %d input values and %d output values, found %d "
                                  "values", sys->name, sys->n_inputs, sys->n_outputs, r->n_tok - 1);
        pr->line[p] = r->line;
        for (j = 0; j < sys->n_inputs + sys->n_outputs; j++) {
            const char *tok = r->tok[1 + j];
            double *v = &pr->value[p][j];
            if (!lensrt_table_parse_real(tok, v))
                return lensrt_table_parse_failf(r, "probe of system %s: %s %s: '%s' is not a finite number", sys->name,
                                                j < sys->n_inputs ? "input" : "output",
                                                j < sys->n_inputs ? sys->inputs[j].name : sys->outputs[j - sys->n_inputs].name, tok);
            if (j < sys->n_inputs && !(*v >= sys->inputs[j].lo && *v <= sys->inputs[j].hi))
                return lensrt_table_parse_failf(r, "probe of system %s: input %s = %s is outside its domain [%.17g, %.17g]",
                                                sys->name, sys->inputs[j].name, tok, sys->inputs[j].lo, sys->inputs[j].hi);
        }
    }
    return LENSRT_SUCCESS;
}

/* The probes of a system against its polynomials as read (the last check of a table):
 * every output within PROBE_RTOL * sum |c_t| + PROBE_ATOL of the probe line's value. */
lensrt_result lensrt_table_check_probes(lensrt_context ctx, const char *file, const lensrt_system *sys, const probes *pr)
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

lensrt_result lensrt_table_read_system(reader *r, lensrt_system *sys, probes *pr)
{
    lensrt_result res;
    int i, t, k, line;
    // system NAME n_inputs n_outputs
    if (r->n_tok != 4 || !lensrt_table_parse_int(r->tok[2], 1, 8, &sys->n_inputs) ||
        !lensrt_table_parse_int(r->tok[3], 1, 8, &sys->n_outputs))
        return lensrt_table_parse_fail(r, "expected 'system NAME N_IN N_OUT' (at most 8 each), found '%s'",
                                       r->tok[0]);
    snprintf(sys->name, sizeof sys->name, "%s", r->tok[1]);
    // input NAME UNIT LO HI TRANSFORM C S
    for (i = 0; i < sys->n_inputs; i++) {
        lensrt_input *in = &sys->inputs[i];
        if (!lensrt_table_next_line(r) || strcmp(r->tok[0], "input") != 0 || r->n_tok != 8)
            return lensrt_table_parse_fail(r, "expected 'input NAME UNIT LO HI TRANSFORM C S'%s", "");
        snprintf(in->name, sizeof in->name, "%s", r->tok[1]);
        if (!lensrt_table_parse_real(r->tok[3], &in->lo) || !lensrt_table_parse_real(r->tok[4], &in->hi) ||
            !lensrt_table_parse_real(r->tok[6], &in->c) || !lensrt_table_parse_real(r->tok[7], &in->s) || in->s == 0.0 ||
            !(in->lo <= in->hi))
            return lensrt_table_parse_fail(r, "input '%s': bounds or normalisation are not finite numbers "
                                 "with lo <= hi and s != 0", in->name);
        if (strcmp(r->tok[5], "affine") == 0) in->transform = LENSRT_TRANSFORM_AFFINE;
        else if (strcmp(r->tok[5], "inverse_square") == 0) in->transform = LENSRT_TRANSFORM_INVERSE_SQUARE;
        else return lensrt_table_parse_fail(r, "unknown transform '%s' (affine or inverse_square)", r->tok[5]);
        if ((res = check_input(r, sys->name, in)) != LENSRT_SUCCESS) return res;
    }
    // output NAME UNIT N_TERMS, then one line per term: exponents and coefficient
    for (k = 0; k < sys->n_outputs; k++) {
        lensrt_poly *p = &sys->outputs[k];
        if (!lensrt_table_next_line(r) || strcmp(r->tok[0], "output") != 0 || r->n_tok != 4 ||
            !lensrt_table_parse_int(r->tok[3], 0, LENSRT_MAX_TERMS, &p->n_terms))
            return lensrt_table_parse_fail(r, "expected 'output NAME UNIT N_TERMS'%s", "");
        snprintf(p->name, sizeof p->name, "%s", r->tok[1]);
        if (strcmp(r->tok[2], "-") == 0) r->tok[2][0] = '\0'; /* an empty text field */
        lensrt_table_decode_field(r->tok[2]);
        snprintf(p->unit, sizeof p->unit, "%s", r->tok[2]);
        line = r->line;
        p->exponents = lensrt_calloc(r->ctx, (size_t)p->n_terms * (size_t)sys->n_inputs + 1, 1);
        p->coefficients = lensrt_calloc(r->ctx, (size_t)p->n_terms + 1, sizeof(double));
        if (!p->exponents || !p->coefficients)
            return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "%s: out of memory", r->name);
        for (t = 0; t < p->n_terms; t++) {
            if (!lensrt_table_next_line(r) || r->n_tok != sys->n_inputs + 1)
                return lensrt_table_parse_fail(r, "output '%s': expected a term line with one exponent per "
                                     "input and a coefficient", p->name);
            for (i = 0; i < sys->n_inputs; i++) {
                int e;
                if (!lensrt_table_parse_int(r->tok[i], 0, LENSRT_MAX_DEGREE, &e))
                    return lensrt_table_parse_fail(r, "exponent '%s' is not an integer in 0..15", r->tok[i]);
                p->exponents[t * sys->n_inputs + i] = (unsigned char)e;
            }
            if (!lensrt_table_parse_real(r->tok[sys->n_inputs], &p->coefficients[t]))
                return lensrt_table_parse_fail(r, "coefficient '%s' is not a finite number", r->tok[sys->n_inputs]);
        }
        if ((res = check_output(r, sys->name, p, k, line)) != LENSRT_SUCCESS) return res;
    }
    if ((res = read_probes(r, sys, pr)) != LENSRT_SUCCESS) return res;
    if (!lensrt_table_next_line(r) || strcmp(r->tok[0], "end") != 0)
        return lensrt_table_parse_fail(r, "expected 'end' after the outputs of system %s", sys->name);
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_table_check_system(lensrt_context ctx, const char *file, const lensrt_system *s,
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
lensrt_result lensrt_table_check_shared_inputs(lensrt_context ctx, const char *file, const lensrt_lens lens)
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

lensrt_result lensrt_table_check_clip(lensrt_context ctx, const char *file, lensrt_lens lens)
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
