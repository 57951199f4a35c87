/* Fitted lenses' table reader (internal, lens/table*.c): the cursor over a table's text
 * and what the reader's pieces share.
 *
 *   table.c         the table whole: header, lens, trust and ghost lines, the checksum, the
 *                   lens's information; lensrt_lens_load_text and lensrt_lens_load
 *   table_system.c  a system's lines (inputs, outputs, probes) and their checks; P_clip's
 *   table_text.c    lines, fields and numbers: ASCII and the "C" locale only */
#ifndef LENSRT_TABLE_H
#define LENSRT_TABLE_H

#include "../internal.h"

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

/* ------------------------------------------------------------ table_text.c ----- */

/* A parse error at the reader's line (fmt takes one %s: what), recorded in its context. */
lensrt_result lensrt_table_parse_fail(reader *r, const char *fmt, const char *what);
/* The same with any printf arguments. */
lensrt_result lensrt_table_parse_failf(reader *r, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 2, 3)))
#endif
    ;
/* An ASCII letter or digit (not the locale's <ctype.h>). */
int lensrt_table_ascii_alnum(char c);
/* Read the next line that is not blank or a comment and split it at spaces. */
int lensrt_table_next_line(reader *r);
/* Decode %XX escapes in place (fields with spaces are percent-encoded). */
void lensrt_table_decode_field(char *s);
/* A number of the table's syntax (no hex, inf or nan), finite, read in the "C" locale. */
int lensrt_table_parse_real(const char *s, double *v);
/* A decimal integer in [lo, hi] (optional sign, ASCII digits only, nothing after). */
int lensrt_table_parse_int(const char *s, int lo, int hi, int *v);

/* ---------------------------------------------------------- table_system.c ----- */

/* A system's lines (its header, inputs, outputs with their terms, probe lines into pr). */
lensrt_result lensrt_table_read_system(reader *r, lensrt_system *sys, probes *pr);
/* The system's inputs and outputs are the expected ones, by name and in order. */
lensrt_result lensrt_table_check_system(lensrt_context ctx, const char *file, const lensrt_system *s,
                                        const char *const *ins, const char *const *outs);
/* P_o and P_s share their stop and wavelength inputs exactly. */
lensrt_result lensrt_table_check_shared_inputs(lensrt_context ctx, const char *file, const lensrt_lens lens);
/* The system's polynomials evaluated at its probe lines' inputs match their outputs. */
lensrt_result lensrt_table_check_probes(lensrt_context ctx, const char *file, const lensrt_system *sys,
                                        const probes *pr);
/* A ghost's P_clip: the ghost half's inputs exactly, then its pairs. */
lensrt_result lensrt_table_check_clip(lensrt_context ctx, const char *file, lensrt_lens lens);

#endif /* LENSRT_TABLE_H */
