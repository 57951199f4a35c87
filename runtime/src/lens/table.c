/* Fitted lenses: the `lensfit-poly-table` reader (version 5: version 3's lines, each
 * system ending with PROBES probe lines, its own polynomials evaluated at fixed points
 * and checked here, and a last line with the CRC-32 of everything before it;
 * fit/lensfit/codegen/table.py has the format, its ranges and the probe tolerance).
 *
 * This file reads the table whole: its header, lens, trust and ghost lines, the checksum
 * and the lens's information; a system's lines are lens/table_system.c's, and the text
 * layer (reentrant, independent of the host's locale) lens/table_text.c's. */
#include "../c_numbers.h"
#include "table.h"
#include "../core/crc32.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

/* The ranges of the lens and trust values (table.py's module doc, "Ranges"; lensfit's
 * lensfit.paraxial.facts and lensfit.codegen.table hold the same numbers): lengths (radii, |focal length|) in
 * [LENGTH_MIN_MM, LENGTH_MAX_MM], signed distances at most LENGTH_MAX_MM either way. */
#define LENGTH_MIN_MM 1e-3
#define LENGTH_MAX_MM 1e6
#define SQUEEZE_MIN 0.1
#define SQUEEZE_MAX 10.0
#define PSF_VS_EXACT_MIN 1e-12
#define PSF_VS_EXACT_MAX 10.0
#define PSF_TARGET_MIN 1e-6
#define PSF_TARGET_MAX 1.0

/* The input names each system must have, in this order. */
static const char *const P_O_INPUTS[6] = {"x_O", "y_O", "u_O", "x_a", "y_a", "lambda"};
static const char *const P_S_INPUTS[6] = {"x_S", "y_S", "z_S", "x_a", "y_a", "lambda"};
static const char *const P_O_OUTPUTS[4] = {"x_o", "y_o", "tau_o", "phi_o"};
static const char *const P_S_OUTPUTS[4] = {"x_i", "y_i", "tau_i", "phi_i"};

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
    if (r->n_tok != 3) return lensrt_table_parse_fail(r, "expected 'lens KEY VALUE'%s", "");
    if (strcmp(r->tok[1], "name") == 0) {
        lensrt_table_decode_field(r->tok[2]);
        snprintf(lens->name, sizeof lens->name, "%s", r->tok[2]);
        return LENSRT_SUCCESS;
    }
    for (i = 0; i < 8; i++) {
        if (strcmp(r->tok[1], keys[i]) != 0) continue;
        if (!lensrt_table_parse_real(r->tok[2], &v))
            return lensrt_table_parse_failf(r, "lens %s '%s' is not a finite number", keys[i], r->tok[2]);
        // The ranges (defines above): lengths 0..4 (the focal length either sign), the
        // signed distances 5 and 6, the squeeze 7
        if (i == 0 && !(fabs(v) >= LENGTH_MIN_MM && fabs(v) <= LENGTH_MAX_MM))
            return lensrt_table_parse_failf(r, "lens focal_length_mm %s is out of range: expected %g to %g mm either sign", r->tok[2],
                                            LENGTH_MIN_MM, LENGTH_MAX_MM);
        if (i >= 1 && i <= 4 && !(v >= LENGTH_MIN_MM && v <= LENGTH_MAX_MM))
            return lensrt_table_parse_failf(r, "lens %s %s is out of range: expected a length in [%g, %g] mm", keys[i], r->tok[2],
                                            LENGTH_MIN_MM, LENGTH_MAX_MM);
        if ((i == 5 || i == 6) && !(fabs(v) <= LENGTH_MAX_MM))
            return lensrt_table_parse_failf(r, "lens %s %s is out of range: expected a distance in [%g, %g] mm", keys[i], r->tok[2],
                                            -LENGTH_MAX_MM, LENGTH_MAX_MM);
        if (i == 7 && !(v >= SQUEEZE_MIN && v <= SQUEEZE_MAX))
            return lensrt_table_parse_failf(r, "lens squeeze %s is out of range: expected a squeeze in [%g, %g]", r->tok[2],
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
        return lensrt_table_parse_failf(r, "trust %s '%s' after a system: the trust lines come before the first "
                              "system", key, value);
    if (!n_lens)
        return lensrt_table_parse_failf(r, "trust %s '%s' before the lens lines: the trust lines follow them",
                                        key, value);
    for (i = 0; i < *n_trust; i++)
        if (strcmp(key, TRUST_KEYS[i]) == 0)
            return lensrt_table_parse_failf(r, "trust %s '%s' appears twice (each trust key once: " TRUST_ORDER ")",
                                            key, value);
    if (*n_trust == TRUST_LINES)
        return lensrt_table_parse_failf(r, "unknown trust key '%s' (value '%s') after the %d trust lines (" TRUST_ORDER ")",
                                        key, value, TRUST_LINES);
    if (strcmp(key, TRUST_KEYS[*n_trust]) != 0)
        return lensrt_table_parse_failf(r, "expected '%s' (trust line %d of %d: " TRUST_ORDER "), found trust %s '%s'",
                                        TRUST_FORMS[*n_trust], *n_trust + 1, TRUST_LINES, key, value);
    if (r->n_tok != 3)
        return lensrt_table_parse_failf(r, "expected '%s' (3 fields), found %d fields", TRUST_FORMS[*n_trust], r->n_tok);
    if (*n_trust == 1) {
        lensrt_table_decode_field(r->tok[2]);
        snprintf(lens->psf_vs_exact_cell, sizeof lens->psf_vs_exact_cell, "%s", r->tok[2]);
    } else {
        const double lo = *n_trust == 0 ? PSF_VS_EXACT_MIN : PSF_TARGET_MIN;
        const double hi = *n_trust == 0 ? PSF_VS_EXACT_MAX : PSF_TARGET_MAX;
        if (!lensrt_table_parse_real(value, &v))
            return lensrt_table_parse_failf(r, "trust %s '%s' is not a finite number", key, value);
        if (!(v >= lo && v <= hi))
            return lensrt_table_parse_failf(r, "trust %s %s is out of range: expected a number in [%g, %g]", key, value, lo, hi);
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
        return lensrt_table_parse_failf(r, "ghost %s '%s' after a system: the ghost lines come before the first system", key,
                                        value);
    if (n_trust < TRUST_LINES)
        return lensrt_table_parse_failf(r, "ghost %s '%s' before the trust lines end: the ghost lines follow them", key, value);
    for (i = 0; i < *n_ghost; i++)
        if (strcmp(key, GHOST_KEYS[i]) == 0)
            return lensrt_table_parse_failf(r, "ghost %s '%s' appears twice (each ghost key once: " GHOST_ORDER ")", key, value);
    if (*n_ghost == GHOST_LINES)
        return lensrt_table_parse_failf(r, "unknown ghost key '%s' (value '%s') after the %d ghost lines (" GHOST_ORDER ")", key,
                                        value, GHOST_LINES);
    if (strcmp(key, GHOST_KEYS[*n_ghost]) != 0)
        return lensrt_table_parse_failf(r, "expected '%s' (ghost line %d of %d: " GHOST_ORDER "), found ghost %s '%s'",
                                        GHOST_FORMS[*n_ghost], *n_ghost + 1, GHOST_LINES, key, value);
    if (r->n_tok != 3)
        return lensrt_table_parse_failf(r, "expected '%s' (3 fields), found %d fields", GHOST_FORMS[*n_ghost], r->n_tok);
    switch (*n_ghost) {
    case 0: /* a model surface index */
        if (!lensrt_table_parse_int(value, 0, 1000000, &lens->ghost_first))
            return lensrt_table_parse_failf(r, "ghost first '%s' is not a surface index (an integer >= 0)", value);
        break;
    case 1: /* the second reflection lies behind the first */
        if (!lensrt_table_parse_int(value, 0, 1000000, &lens->ghost_second))
            return lensrt_table_parse_failf(r, "ghost second '%s' is not a surface index (an integer >= 0)", value);
        if (lens->ghost_second <= lens->ghost_first)
            return lensrt_table_parse_failf(r, "ghost second '%s' is not after ghost first %d (a ghost (i, j) needs i < j)", value,
                                            lens->ghost_first);
        break;
    case 2:
        if (strcmp(r->tok[2], "-") == 0) r->tok[2][0] = '\0';
        lensrt_table_decode_field(r->tok[2]);
        if (!label_matches(r->tok[2], lens->ghost_first, lens->ghost_second))
            return lensrt_table_parse_failf(r, "ghost label '%s' does not number ghost first %d and ghost second %d: expected '%d-%d' "
                                  "(or one less for a surface behind the stop surface the loader inserts: '%d-%d', "
                                  "'%d-%d')", r->tok[2], lens->ghost_first, lens->ghost_second, lens->ghost_first,
                                            lens->ghost_second, lens->ghost_first, lens->ghost_second - 1,
                                            lens->ghost_first > 0 ? lens->ghost_first - 1 : 0, lens->ghost_second - 1);
        snprintf(lens->ghost_label, sizeof lens->ghost_label, "%s", r->tok[2]);
        break;
    default:
        if (strcmp(value, "P_o") == 0) lens->ghost_side = LENSRT_SYSTEM_OBJECT;
        else if (strcmp(value, "P_s") == 0) lens->ghost_side = LENSRT_SYSTEM_SENSOR;
        else return lensrt_table_parse_failf(r, "ghost side '%s' is neither P_o nor P_s (the system that is the ghost half)", value);
        lens->ghost = 1;
        break;
    }
    ++*n_ghost;
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
            if (!lensrt_table_ascii_alnum(base[i]) && base[i] != '-' && base[i] != '_') return;
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
    if (!lensrt_table_next_line(&r) || r.n_tok != 2 || strcmp(r.tok[0], "lensfit-poly-table") != 0 ||
        !lensrt_table_parse_int(r.tok[1], 1, 1000, &version))
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
    while (res == LENSRT_SUCCESS && lensrt_table_next_line(&r)) {
        if (strcmp(r.tok[0], "lens") == 0) {
            if (n_trust || n_systems) {
                res = lensrt_table_parse_failf(&r, "lens %s '%s' after the %s: the lens lines come first",
                                               r.n_tok > 1 ? r.tok[1] : "", r.n_tok > 2 ? r.tok[2] : "",
                                               n_systems ? "systems" : "trust lines");
                break;
            }
            n_lens++;
            res = read_lens_line(&r, lens, &seen);
        } else if (strcmp(r.tok[0], "trust") == 0) {
            if (n_ghost) {
                res = lensrt_table_parse_failf(&r, "trust %s '%s' after the ghost lines: the trust lines come first",
                                               r.n_tok > 1 ? r.tok[1] : "", r.n_tok > 2 ? r.tok[2] : "");
                break;
            }
            res = read_trust_line(&r, lens, n_lens, n_systems, &n_trust);
        } else if (strcmp(r.tok[0], "ghost") == 0) {
            res = read_ghost_line(&r, lens, n_trust, n_systems, &n_ghost);
        } else if (strcmp(r.tok[0], "system") == 0) {
            lensrt_system *sys;
            if (n_trust < TRUST_LINES) {
                res = lensrt_table_parse_failf(&r, "missing trust line: expected '%s' (trust line %d of %d: " TRUST_ORDER
                                      "), found '%s %s'", TRUST_FORMS[n_trust], n_trust + 1, TRUST_LINES,
                                               r.tok[0], r.n_tok > 1 ? r.tok[1] : "");
                break;
            }
            if (n_ghost && n_ghost < GHOST_LINES) {
                res = lensrt_table_parse_failf(&r, "missing ghost line: expected '%s' (ghost line %d of %d: " GHOST_ORDER
                                      "), found '%s %s'", GHOST_FORMS[n_ghost], n_ghost + 1, GHOST_LINES,
                                               r.tok[0], r.n_tok > 1 ? r.tok[1] : "");
                break;
            }
            n_systems++;
            if (r.n_tok > 1 && strcmp(r.tok[1], "P_o") == 0) sys = &lens->p_o;
            else if (r.n_tok > 1 && strcmp(r.tok[1], "P_s") == 0) sys = &lens->p_s;
            else if (r.n_tok > 1 && strcmp(r.tok[1], "P_clip") == 0) sys = &lens->p_clip;
            else { res = lensrt_table_parse_fail(&r, "unknown system '%s' (P_o, P_s, or P_clip in a ghost table)", r.n_tok > 1 ? r.tok[1] : ""); break; }
            if (sys->n_inputs) { res = lensrt_table_parse_fail(&r, "system %s appears twice", sys->name); break; }
            if (sys == &lens->p_clip) {
                // Only a ghost table clips, after its two systems, with 1..4 pairs
                int n_out = 0;
                if (!lens->ghost) {
                    res = lensrt_table_parse_failf(&r, "system P_clip '%s' in a table without ghost lines (P_clip belongs to a "
                                          "ghost table: ghost first, second, label and side before the systems)",
                                                   r.n_tok > 3 ? r.tok[3] : "");
                    break;
                }
                if (!lens->p_o.n_inputs || !lens->p_s.n_inputs) {
                    res = lensrt_table_parse_failf(&r, "system P_clip before system %s: P_clip comes third, after P_o and P_s",
                                                   !lens->p_o.n_inputs ? "P_o" : "P_s");
                    break;
                }
                if (r.n_tok == 4 && lensrt_table_parse_int(r.tok[3], 0, 1000000, &n_out) && (n_out > 2 * LENSRT_MAX_CLIP_PAIRS || n_out % 2)) {
                    res = lensrt_table_parse_failf(&r, "system P_clip: %d outputs: expected an even count of 2..%d (pairs x, y; "
                                          "at most %d clip tests)", n_out, 2 * LENSRT_MAX_CLIP_PAIRS, LENSRT_MAX_CLIP_PAIRS);
                    break;
                }
            }
            res = lensrt_table_read_system(&r, sys, &pr[sys == &lens->p_o ? 0 : sys == &lens->p_s ? 1 : 2]);
        } else {
            res = lensrt_table_parse_fail(&r, "unexpected line starting with '%s'", r.tok[0]);
        }
    }
    if (res == LENSRT_SUCCESS && (!lens->p_o.n_inputs || !lens->p_s.n_inputs))
        res = lensrt_fail(ctx, LENSRT_ERROR_PARSE, "%s:%d: the table ends without system %s (it needs P_o and P_s)",
                          r.name, r.line, !lens->p_o.n_inputs ? "P_o" : "P_s");
    if (res == LENSRT_SUCCESS) res = lensrt_table_check_system(ctx, r.name, &lens->p_o, P_O_INPUTS, P_O_OUTPUTS);
    if (res == LENSRT_SUCCESS) res = lensrt_table_check_system(ctx, r.name, &lens->p_s, P_S_INPUTS, P_S_OUTPUTS);
    if (res == LENSRT_SUCCESS) res = lensrt_table_check_shared_inputs(ctx, r.name, lens);
    if (res == LENSRT_SUCCESS && n_ghost && n_ghost < GHOST_LINES)
        res = lensrt_fail(ctx, LENSRT_ERROR_PARSE, "%s: missing ghost line '%s' (ghost line %d of %d: " GHOST_ORDER ")",
                          r.name, GHOST_FORMS[n_ghost], n_ghost + 1, GHOST_LINES);
    if (res == LENSRT_SUCCESS && lens->p_clip.n_inputs) res = lensrt_table_check_clip(ctx, r.name, lens);
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
    if (res == LENSRT_SUCCESS) res = lensrt_table_check_probes(ctx, r.name, &lens->p_o, &pr[0]);
    if (res == LENSRT_SUCCESS) res = lensrt_table_check_probes(ctx, r.name, &lens->p_s, &pr[1]);
    if (res == LENSRT_SUCCESS && lens->p_clip.n_inputs) res = lensrt_table_check_probes(ctx, r.name, &lens->p_clip, &pr[2]);
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
