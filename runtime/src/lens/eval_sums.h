/* The sums of lens/eval.c for W rays at once (W a constant, so that the compiler unrolls
 * and vectorises the loops over rays): included by eval.c once per width, with W,
 * SUM_VALUES and SUM_GRADIENTS defined. Rays o .. o + W - 1 of the block are summed;
 * v[r] and g[i][r] receive ray o + r. */

/* Values of output p: v = sum_t c_t prod_i xhat_i^e_ti, summed run by run as
 * sum_runs F (sum_t c_t x_a^e y_a^f), F the run's field monomial, each product taken in
 * the order written (the values of SUM_GRADIENTS are the same bits). */
static void SUM_VALUES(const block *b, int o, const lensrt_poly *p, double *v)
{
    double acc[W], s[W]; /* local sums: the compiler need not fear aliasing */
    const unsigned char *first = p->exponents;
    int t, r;
    for (r = 0; r < W; r++) acc[r] = s[r] = 0.0;
    for (t = 0; t <= p->n_terms && p->n_terms > 0; t++) {
        const unsigned char *e = p->exponents + (size_t)t * N_IN;
        // At the end of a run: its field monomial times its stop sum
        if (t == p->n_terms || !same_field(e, first)) {
            const double *f0 = b->pw[0][first[0]] + o, *f1 = b->pw[1][first[1]] + o;
            const double *f2 = b->pw[2][first[2]] + o, *f5 = b->pw[5][first[5]] + o;
            for (r = 0; r < W; r++) {
                acc[r] += f0[r] * f1[r] * f2[r] * f5[r] * s[r];
                s[r] = 0.0;
            }
            if (t == p->n_terms) break;
            first = e;
        }
        {
            const double c = p->coefficients[t];
            const double *ax = b->pw[STOP_X][e[STOP_X]] + o, *ay = b->pw[STOP_Y][e[STOP_Y]] + o;
            for (r = 0; r < W; r++) s[r] += c * ax[r] * ay[r];
        }
    }
    memcpy(v, acc, sizeof acc);
}

/* Values and gradients over the normalised inputs, g[i][o + r]. Per run with field
 * monomial F and stop sum S: d/d field input i is (dF/dxhat_i) S, d/d x_a is
 * F sum_t c_t e x_a^(e-1) y_a^f, likewise y_a; d xhat^e / d xhat = e xhat^(e-1) is read
 * from the power table (the index clamped at e = 0, where the factor e is 0). */
static void SUM_GRADIENTS(const block *b, int o, const lensrt_poly *p, double *v, double (*g)[BLOCK])
{
    double acc[W], s[W], sx[W], sy[W], ga[N_IN][W];
    const unsigned char *first = p->exponents;
    int t, r, i;
    for (r = 0; r < W; r++) {
        acc[r] = s[r] = sx[r] = sy[r] = 0.0;
        for (i = 0; i < N_IN; i++) ga[i][r] = 0.0;
    }
    for (t = 0; t <= p->n_terms && p->n_terms > 0; t++) {
        const unsigned char *e = p->exponents + (size_t)t * N_IN;
        if (t == p->n_terms || !same_field(e, first)) {
            const double *f0 = b->pw[0][first[0]] + o, *f1 = b->pw[1][first[1]] + o;
            const double *f2 = b->pw[2][first[2]] + o, *f5 = b->pw[5][first[5]] + o;
            const double e0 = first[0], e1 = first[1], e2 = first[2], e5 = first[5];
            const double *d0 = b->pw[0][first[0] ? first[0] - 1 : 0] + o;
            const double *d1 = b->pw[1][first[1] ? first[1] - 1 : 0] + o;
            const double *d2 = b->pw[2][first[2] ? first[2] - 1 : 0] + o;
            const double *d5 = b->pw[5][first[5] ? first[5] - 1 : 0] + o;
            for (r = 0; r < W; r++) {
                double q = f0[r] * f1[r] * f2[r] * f5[r];
                acc[r] += q * s[r];
                ga[0][r] += e0 * d0[r] * f1[r] * f2[r] * f5[r] * s[r];
                ga[1][r] += f0[r] * e1 * d1[r] * f2[r] * f5[r] * s[r];
                ga[2][r] += f0[r] * f1[r] * e2 * d2[r] * f5[r] * s[r];
                ga[5][r] += f0[r] * f1[r] * f2[r] * e5 * d5[r] * s[r];
                ga[STOP_X][r] += q * sx[r];
                ga[STOP_Y][r] += q * sy[r];
                s[r] = sx[r] = sy[r] = 0.0;
            }
            if (t == p->n_terms) break;
            first = e;
        }
        {
            const int ex = e[STOP_X], ey = e[STOP_Y];
            const double c = p->coefficients[t], cx = c * (double)ex, cy = c * (double)ey;
            const double *ax = b->pw[STOP_X][ex] + o, *ay = b->pw[STOP_Y][ey] + o;
            const double *dx = b->pw[STOP_X][ex ? ex - 1 : 0] + o, *dy = b->pw[STOP_Y][ey ? ey - 1 : 0] + o;
            for (r = 0; r < W; r++) {
                s[r] += c * ax[r] * ay[r];
                sx[r] += cx * dx[r] * ay[r];
                sy[r] += cy * ax[r] * dy[r];
            }
        }
    }
    memcpy(v, acc, sizeof acc);
    for (i = 0; i < N_IN; i++) memcpy(g[i] + o, ga[i], sizeof ga[i]);
}
