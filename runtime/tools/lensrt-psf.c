/* lensrt-psf: render a point spread function through a fitted lens to EXR and PNG.
 *
 *   lensrt-psf --lens 0001 --f-number 8 --light -6,-4 --samples 65536 -o psf.exr --png psf.png
 *
 * The samples are rendered as two independent halves (seeds S and S + HALF_SEED_STEP)
 * whose phasor sums are then added, so the image comes with an estimate of its own Monte
 * Carlo error (mc_error_estimate below), printed on stdout; --target-error doubles the
 * samples until the estimate is below a target. Progress and an estimate of the time
 * left go to stderr; bad input ends with a message and exit status 2, a failed render
 * with 1, and no output file is written then. */
#include "lensrt.h"

#include <dirent.h>
#include <errno.h>
#include <locale.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#ifndef LENSRT_GENERATED_DIR
#define LENSRT_GENERATED_DIR "generated"
#endif

#define MAX_LIGHTS 64
#define MAX_WAVELENGTHS 4096
/* The second half's seed is the first's plus this (2^64 / golden ratio, odd): far from
 * the small seeds people pick by hand, so a render with --seed 2 does not repeat the
 * second half of one with --seed 1 (lensrt_render_merge refuses equal seeds only). */
#define HALF_SEED_STEP 0x9E3779B97F4A7C15ULL
/* --target-error: largest samples per wavelength (both halves) when none is given. */
#define DEFAULT_MAX_SAMPLES (1LL << 24)

static void usage(FILE *f)
{
    fprintf(f,
        "usage: lensrt-psf --lens ID|TABLE -o OUT.exr [options]\n"
        "  --lens ID|TABLE        lens id in the generated folder (e.g. 0001: its lens's folder), a\n"
        "                         folder's whole name (a variant's: 0001-angenieux-double-gauss-uncoated)\n"
        "                         or a .table file\n"
        "  --generated DIR        folder of generated lenses (default: $LENSRT_GENERATED or %s)\n"
        "  -o, --output FILE      spectral EXR to write\n"
        "  --png FILE             PNG preview (log tone map) to write\n"
        "  --decades D            PNG tone map range below the peak (default 5)\n"
        "  --resolution WxH       pixels (default 256x256)\n"
        "  --size W[xH]           window on the sensor in mm (default 0.2)\n"
        "  --center X,Y           window centre in mm (default: the first light's chief ray)\n"
        "  --focus Z              sensor shift z_S in mm, + away from the lens (default 0)\n"
        "  --f-number N           (default: the widest the lens was fitted for)\n"
        "  --blades N             polygonal aperture with N blades (default: circle)\n"
        "  --curvature K          blade curvature, 0 straight .. 1 round (default 0)\n"
        "  --rotation DEG         blade rotation (default 0)\n"
        "  --wavelengths N|A,B,.. count uniform over the fitted range, or a list in nm (default 16)\n"
        "  --wavelength NM        one wavelength in nm (--wavelengths 550 is a count of 550)\n"
        "  --light X,Y[,D[,I]]    field angles of the chief ray (deg; +Y is imaged at +y, as in Zemax),\n"
        "                         distance from the first vertex (mm, 0 or inf: infinity) and\n"
        "                         intensity; repeat for several (default 0,0)\n"
        "  --samples N            aperture samples per wavelength (default 65536), rendered as two\n"
        "                         independent halves whose difference estimates the Monte Carlo error\n"
        "  --target-error E       double the samples until the estimated relative L2 error is <= E\n"
        "                         (e.g. 0.01), starting from --samples\n"
        "  --max-samples N        stop doubling there (default 16777216); warns if E was not reached\n"
        "  --no-estimate          one sample sequence, no halves and no error estimate\n"
        "  --seed S               (default 1; the second half uses S + 0x9E3779B97F4A7C15)\n",
        LENSRT_GENERATED_DIR);
    /* In two parts: C99 compilers need take no string literal over 4095 characters */
    fprintf(f,
        "  --sampler sobol|random|stratified (default sobol; random with --estimator unbiased)\n"
        "  --estimator paper|unbiased (default paper; unbiased needs independent samples)\n"
        "  --threads N            OpenMP threads (default: all)\n"
        "  --device cpu|gl        where to splat (default cpu); gl: OpenGL 4.3 compute shaders\n"
        "  --gl-platform auto|egl-device|egl-surfaceless|glfw\n"
        "                         where the GL context comes from (default auto: in that order)\n"
        "  --save-phasors FILE    write the phasor sums (to resume or merge later)\n"
        "  --resume FILE          start from saved phasor sums of the same scene\n"
        "  --merge FILE           add phasor sums of the same scene rendered with another seed\n"
        "  --ghost TABLE          also render this ghost table of the same lens (repeatable; each ghost once)\n"
        "  --flares DIR           also render every ghost_*.table in DIR (sorted by name; one folder)\n"
        "                         a ghost whose footprint (where its rays land, plus 30 wavelengths\n"
        "                         x f-number of diffraction) misses the window is skipped, said on\n"
        "                         stdout (and left out of the flare layer; none left: no such layer)\n"
        "                         with ghosts: -o OUT.exr holds the total (direct + ghosts) in its\n"
        "                         unprefixed channels and layers direct. and flare. (the ghosts'\n"
        "                         sum); --png shows the total\n"
        "  --integrator montecarlo|cells|fourier|auto\n"
        "                         default: auto, or montecarlo with --samples, --max-samples,\n"
        "                         --seed, --sampler, --estimator, --no-estimate, --save-phasors,\n"
        "                         --resume, --merge or --device gl\n"
        "                         montecarlo: the samples above; cells: the deterministic\n"
        "                         integrator (closed-form integrals over a triangle mesh of the\n"
        "                         aperture), its error estimated from a mesh half as fine;\n"
        "                         fourier: a Gauss rule over the aperture and one non-uniform FFT\n"
        "                         per tile of pixels, its error estimated against 1.25 x the nodes\n"
        "                         (refuses apertures a clip cuts); auto: fourier, refined while that\n"
        "                         helps, else cells, refined to --max-rings: every image it keeps\n"
        "                         has an estimate within --target-error (default 1%% for auto),\n"
        "                         else it fails (exit 5, nothing written)\n"
        "  --nodes N              fourier: Gauss nodes per side of each aperture sector (default 0:\n"
        "                         chosen from the phase's slope over the aperture, 1.4 per wave,\n"
        "                         or with --target-error E the rule for E: 1.33 per wave at 1%%);\n"
        "                         --target-error refines them (x 1.25) until the estimate is <= E\n"
        "  --max-nodes N          fourier: stop refining there (default 2730)\n"
        "  --rings N              cells: mesh rings (6 N^2 triangles, blades N^2 each; default 32);\n"
        "                         --target-error refines them (x 1.25 .. 2, from the estimate)\n"
        "                         until the estimate is <= E\n"
        "  --max-rings N          cells: stop doubling there (default 1024)\n"
        "  --pixel-filter box|point  box (default): each pixel the mean intensity over its area,\n"
        "                         by the midpoint rule on sub-pixel points; point: the intensity\n"
        "                         at the pixel's centre (lensrt before 0.8.0)\n"
        "  --pixel-samples N|NxM  box: sub-pixel points per pixel and axis, 1..16 (default 0:\n"
        "                         chosen from the rays' spread, so that a feature's power does not\n"
        "                         depend on its sub-pixel position; README \"The model\")\n"
        "  --quiet                no progress (the error estimate is still printed on stdout)\n"
        "  --allow-empty          write an image that is zero everywhere (else refused: exit 4)\n"
        "exit status: 0 done, 1 failed, 2 bad input, 3 no GL device (--device gl) or unsupported,\n"
        "             4 the image is zero everywhere (no light passes: nothing written),\n"
        "             5 --integrator auto did not reach the target error (nothing written)\n");
}

static int bad(const char *option, const char *value, const char *expected)
{
    fprintf(stderr, "lensrt-psf: %s: %s, got '%s'\n", option, expected, value ? value : "(nothing)");
    return 2;
}

/* A number as written on a command line anywhere: "1.5", whatever LANG or LC_NUMERIC
 * say. The command never calls setlocale, so it runs in the "C" locale already; strtod
 * is nevertheless run in an explicit "C" locale (this thread only, POSIX 2008 uselocale,
 * the previous locale restored after), so that options keep their meaning if the
 * command ever adopts the environment's locale (de_DE would read "1.5" as 1). */
static int parse_double(const char *s, double *v)
{
    char *end;
    int err;
    locale_t c_locale, saved = (locale_t)0;
    if (!s) return 0;
    c_locale = newlocale(LC_ALL_MASK, "C", (locale_t)0);
    if (c_locale) saved = uselocale(c_locale);
    errno = 0;
    *v = strtod(s, &end);
    err = errno;
    if (c_locale) {
        uselocale(saved);
        freelocale(c_locale);
    }
    return end != s && *end == '\0' && err == 0 && isfinite(*v);
}

static int parse_long(const char *s, long long lo, long long hi, long long *v)
{
    char *end;
    if (!s) return 0;
    errno = 0;
    *v = strtoll(s, &end, 10);
    return end != s && *end == '\0' && errno == 0 && *v >= lo && *v <= hi;
}

/* Split "a,b,c" (or "axb") into up to n doubles; returns the count or -1. The word "inf"
 * gives INFINITY, which only a light's distance accepts (as infinity): every other
 * number, and any other spelling of a non-finite value, is refused (-1 or by the caller),
 * never read as 0. */
static int parse_list(const char *s, char sep, double *out, int n)
{
    char buf[8192], *p, *q;
    int k = 0;
    if (!s || strlen(s) >= sizeof buf) return -1;
    strcpy(buf, s);
    for (p = buf; k < n; p = q + 1) {
        q = strchr(p, sep);
        if (q) *q = '\0';
        if (strcmp(p, "inf") == 0) out[k++] = INFINITY;
        else if (!parse_double(p, &out[k++])) return -1;
        if (!q) return k;
    }
    return -1;
}

/* Whether the first n values of a parsed list are finite. */
static int all_finite(const double *t, int n)
{
    int k;
    for (k = 0; k < n; k++)
        if (!isfinite(t[k])) return 0;
    return 1;
}

static int file_exists(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0 && S_ISREG(st.st_mode);
}

/* Whether a file can be created next to `path` (checked before rendering, so that an
 * unwritable output fails at once and not after the render). */
static int writable(const char *path)
{
    char probe[4096];
    FILE *f;
    struct stat st;
    // An empty name or a folder would pass the probe and fail only after the render
    if (!path[0]) {
        errno = ENOENT;
        return 0;
    }
    if (stat(path, &st) == 0 && S_ISDIR(st.st_mode)) {
        errno = EISDIR;
        return 0;
    }
    // The library refuses to replace a link, a device, a FIFO or a socket (io/atomic_file.c):
    // say so now rather than after the render
    if (lstat(path, &st) == 0 && !S_ISREG(st.st_mode)) {
        errno = S_ISLNK(st.st_mode) ? ELOOP : EEXIST;
        return 0;
    }
    if (snprintf(probe, sizeof probe, "%s.probe-%ld", path, (long)time(NULL)) >= (int)sizeof probe) return 0;
    f = fopen(probe, "wb");
    if (!f) return 0;
    fclose(f);
    remove(probe);
    return 1;
}

/* Whether `end` (what follows `<prefix><pid>`) names one of this tool's own files:
 * `suffix`, or the library's temporary of it (`suffix.tmp-...`, io/atomic_file.c). */
static int own_suffix(const char *end, const char *suffix)
{
    const size_t n = strlen(suffix);
    return strncmp(end, suffix, n) == 0 && (end[n] == '\0' || strncmp(end + n, ".tmp-", 5) == 0);
}

/* Remove what runs of this tool that were killed (kill -9) left next to `base`: the error
 * estimate's halves `<base>.mc-<pid>-a.phasors` and `-b.phasors`, the staged outputs
 * `<base>.stage-<pid>`, and the library's temporaries of either: those whose process no
 * longer exists (a live run's files are never touched). */
static void remove_stale(const char *base, const char *kind)
{
    char dir[4096], prefix[4096], path[8300];
    const char *slash = strrchr(base, '/');
    DIR *d;
    struct dirent *e;
    size_t np;
    if (slash) {
        if ((size_t)(slash - base) >= sizeof dir) return;
        memcpy(dir, base, (size_t)(slash - base));
        dir[slash - base] = '\0';
        if (!dir[0]) strcpy(dir, "/");
    } else {
        strcpy(dir, ".");
    }
    if (snprintf(prefix, sizeof prefix, "%s.%s-", slash ? slash + 1 : base, kind) >= (int)sizeof prefix) return;
    np = strlen(prefix);
    if (!(d = opendir(dir))) return;
    while ((e = readdir(d)) != NULL) {
        char *end;
        long pid;
        if (strncmp(e->d_name, prefix, np) != 0) continue;
        pid = strtol(e->d_name + np, &end, 10);
        if (pid <= 0 || end == e->d_name + np || (pid_t)pid == getpid()) continue;
        if (strcmp(kind, "mc") == 0 ? !own_suffix(end, "-a.phasors") && !own_suffix(end, "-b.phasors")
                                    : !own_suffix(end, "")) continue;
        // Only a process that no longer exists: kill(pid, 0) fails with ESRCH
        if (kill((pid_t)pid, 0) == 0 || errno != ESRCH) continue;
        if (snprintf(path, sizeof path, "%s/%s", dir, e->d_name) < (int)sizeof path) remove(path);
    }
    closedir(d);
}

/* Find the table of a lens named by its id ID (generated/<ID>-*\/lens<ID>.table) or by
 * its whole folder name (generated/<ID>-<name>/lens<ID>.table: an exact folder name wins).
 * Of the folders of one id, a lens's variants are named after it (`<folder>-uncoated`):
 * the id names the folder every other one extends. Returns how many folders match (0:
 * none, 1: path holds its table, more: ambiguous (two lenses share the id), and
 * `choices` lists them, comma-separated, in name order for a stable message). */
static int find_table(const char *dir, const char *arg, char *path, size_t size, char *choices, size_t csize)
{
    DIR *d = opendir(dir);
    struct dirent *e;
    char names[16][256];
    size_t n = strlen(arg);
    int found = 0, exact = -1, k, j;
    if (choices && csize) choices[0] = '\0';
    if (!d) return 0;
    while ((e = readdir(d)) != NULL) {
        const char *dash = strchr(e->d_name, '-');
        const size_t id_len = dash ? (size_t)(dash - e->d_name) : strlen(e->d_name);
        char candidate[4096];
        int is_exact = strcmp(e->d_name, arg) == 0;
        // The id is the folder name's part before its first '-'
        if (!is_exact && (strncmp(e->d_name, arg, n) != 0 || n != id_len)) continue;
        if (snprintf(candidate, sizeof candidate, "%s/%s/lens%.*s.table", dir, e->d_name, (int)id_len, e->d_name) >=
                (int)sizeof candidate ||
            !file_exists(candidate) || strlen(e->d_name) >= sizeof names[0])
            continue;
        if (is_exact) {
            exact = found < 16 ? found : 15;
            snprintf(path, size, "%s", candidate);
        }
        if (found < 16) snprintf(names[found], sizeof names[0], "%s", e->d_name);
        if (found == 0 && exact < 0) snprintf(path, size, "%s", candidate);
        found++;
    }
    closedir(d);
    if (exact >= 0) return 1;
    if (found > 1 && found <= 16) {
        // The lens of its variants: the one name each other name extends with '-...'
        for (k = 0; k < found; k++) {
            const size_t nk = strlen(names[k]);
            int all = 1;
            for (j = 0; j < found && all; j++)
                all = j == k || (strncmp(names[j], names[k], nk) == 0 && names[j][nk] == '-');
            if (all) {
                const char *dash = strchr(names[k], '-');
                const int id_len = dash ? (int)(dash - names[k]) : (int)strlen(names[k]);
                snprintf(path, size, "%s/%s/lens%.*s.table", dir, names[k], id_len, names[k]);
                return 1;
            }
        }
    }
    if (found > 1 && choices && csize) {
        // Sorted (insertion: a handful of names), so the message does not depend on readdir
        const int m = found < 16 ? found : 16;
        char tmp[256];
        for (k = 1; k < m; k++)
            for (j = k; j > 0 && strcmp(names[j - 1], names[j]) > 0; j--) {
                memcpy(tmp, names[j], sizeof tmp);
                memcpy(names[j], names[j - 1], sizeof tmp);
                memcpy(names[j - 1], tmp, sizeof tmp);
            }
        for (k = 0; k < m; k++) {
            const size_t at = strlen(choices);
            snprintf(choices + at, csize - at, "%s%s", k ? ", " : "", names[k]);
        }
    }
    return found;
}

typedef struct progress_state {
    int quiet;
    /* The run() in progress is the part [base, base + span] of the current round. */
    double base, span;
    double round_start; /* seconds (monotonic clock) when the round began */
    const char *label;  /* e.g. "2 x 8192 samples" */
} progress_state;

static double now_seconds(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* Progress of a round (one or two run() calls); the time left from the round's pace. */
static int on_progress(double fraction, double eta, void *user)
{
    progress_state *ps = user;
    double done = ps->base + ps->span * fraction, elapsed = now_seconds() - ps->round_start;
    if (ps->span < 1.0) eta = done > 0.0 ? elapsed * (1.0 - done) / done : 0.0;
    if (!ps->quiet) fprintf(stderr, "\rlensrt-psf: %s: %5.1f%%, %.0f s left   ", ps->label, 100.0 * done, eta);
    return 0;
}

/* The auto integrator's target when --target-error is not given: every image it keeps
 * has an error estimate within it (the project's 1%). */
#define AUTO_TARGET 0.01
/* A Fourier estimate at or above this says the rule does not resolve the phase at all
 * (lensrt.h): auto goes to the cells integrator rather than refine it. */
#define FOURIER_UNRESOLVED 0.3

/* The cells integrator (lensrt_render_integrate) from `rings` on, refining while a target
 * error is set, not reached and max_rings allows; *used and *err: the last mesh and its
 * estimate, *reached whether it is within the target (or none is set). Strict (auto):
 * a target missed at max_rings is left to the caller (it fails); else a warning. */
static lensrt_result integrate_cells(lensrt_render r, int rings, int max_rings, double target, int strict,
                                     progress_state *ps, const char *what, int *used, double *err, int *reached)
{
    char label[128];
    lensrt_result res;
    *reached = 0;
    for (;;) {
        snprintf(label, sizeof label, "%s, %d rings", what, rings);
        ps->label = label;
        ps->round_start = now_seconds();
        ps->base = 0.0;
        ps->span = 1.0;
        res = lensrt_render_integrate(r, rings, err, on_progress, ps);
        if (!ps->quiet) fprintf(stderr, "\n");
        if (res != LENSRT_SUCCESS) return res;
        *used = rings;
        if (!ps->quiet) fprintf(stderr, "lensrt-psf: %s: cells error estimate %.3g%%\n", label, 100.0 * *err);
        if (target <= 0 || *err <= target) {
            *reached = 1;
            return LENSRT_SUCCESS;
        }
        // The mesh that should reach the target (the error falls as 1 / rings^2), with
        // 10% to spare, 1.25 to 2 times the rings; from 1.6 on, doubling (it reuses the
        // last two meshes for the estimate, so costs no more)
        {
            double f = 1.1 * sqrt(*err / target);
            int next = f > 1.6 ? 2 * rings : (int)ceil(rings * (f < 1.25 ? 1.25 : f));
            if (next > max_rings) {
                if (!strict)
                    fprintf(stderr, "lensrt-psf: warning: --target-error %g not reached within --max-rings %d (%s): "
                            "the estimate is %.3g%%\n", target, max_rings, what, 100.0 * *err);
                return LENSRT_SUCCESS;
            }
            rings = next;
        }
    }
}

/* The Fourier integrator (lensrt_render_integrate_fourier) from `nodes` on (0: the
 * library's choice: for the target when `choose`, else its default rule,
 * lensrt_render_fourier_nodes), refining by LENSRT_FOURIER_FINER (each step reuses the
 * last one's finer rule) while a target error is set, not reached and max_nodes allows;
 * *used and *err: the last rule and its estimate, *reached whether it is within the
 * target. Strict (auto) stops refining, target missed, as soon as refining cannot help
 * much: an estimate of FOURIER_UNRESOLVED or more (the rule does not resolve the phase),
 * one that a refinement did not halve, or max_nodes; else a warning at max_nodes. */
static lensrt_result integrate_fourier(lensrt_render r, int nodes, int max_nodes, double target, int choose,
                                       int strict, progress_state *ps, const char *what, int *used, double *err,
                                       int *reached)
{
    char label[128];
    lensrt_result res;
    double last = -1.0;
    *reached = 0;
    if (nodes == 0 && target > 0 && choose) {
        int32_t chosen = 0;
        if ((res = lensrt_render_fourier_nodes(r, target, &chosen)) != LENSRT_SUCCESS) return res;
        nodes = chosen;
    }
    for (;;) {
        if (nodes) snprintf(label, sizeof label, "%s, %d nodes", what, nodes);
        else snprintf(label, sizeof label, "%s, nodes from the phase", what);
        ps->label = label;
        ps->round_start = now_seconds();
        ps->base = 0.0;
        ps->span = 1.0;
        res = lensrt_render_integrate_fourier(r, nodes, err, on_progress, ps);
        if (!ps->quiet) fprintf(stderr, "\n");
        if (res != LENSRT_SUCCESS) return res;
        {
            // The rule used (the library's choice when nodes is 0)
            lensrt_render_stats st = LENSRT_RENDER_STATS_INIT;
            lensrt_render_get_stats(r, &st);
            *used = nodes = st.fourier_nodes;
        }
        snprintf(label, sizeof label, "%s, %d nodes", what, nodes);
        if (!ps->quiet) fprintf(stderr, "lensrt-psf: %s: Fourier error estimate %.3g%%\n", label, 100.0 * *err);
        if (target <= 0 || *err <= target) {
            *reached = 1;
            return LENSRT_SUCCESS;
        }
        if ((int)ceil(LENSRT_FOURIER_FINER * ceil(LENSRT_FOURIER_FINER * nodes)) > max_nodes) {
            if (!strict)
                fprintf(stderr, "lensrt-psf: warning: --target-error %g not reached within --max-nodes %d (%s): "
                        "the estimate is %.3g%%\n", target, max_nodes, what, 100.0 * *err);
            return LENSRT_SUCCESS;
        }
        if (strict && (*err >= FOURIER_UNRESOLVED || (last >= 0 && *err > 0.5 * last))) return LENSRT_SUCCESS;
        last = *err;
        nodes = (int)ceil(LENSRT_FOURIER_FINER * nodes);
    }
}

/* A deterministic integral of one render: cells (kind 1), Fourier (2), or auto (3):
 * Fourier, refined while that helps, then cells where a clip cuts the aperture or the
 * Fourier estimate stays above the target, refined up to max_rings. *used_kind says
 * which ran last (1 or 2), *used its rings or nodes, *err its estimate. *reached: the
 * estimate is within the target (always, without one); auto never keeps an image whose
 * estimate misses it: the caller fails, *why saying what was tried. */
static lensrt_result integrate_det(lensrt_context ctx, lensrt_render r, int kind, const long long *steps,
                                   double target, int choose, progress_state *ps, const char *what, int *used_kind,
                                   int *used, double *err, int *reached, char *why, size_t n_why)
{
    lensrt_result res;
    const int strict = kind == 3;
    why[0] = '\0';
    if (kind != 1) {
        *used_kind = 2;
        res = integrate_fourier(r, (int)steps[2], (int)steps[3], target, choose, strict, ps, what, used, err, reached);
        if (res == LENSRT_SUCCESS && (*reached || !strict)) return res;
        if (kind != 3 || (res != LENSRT_SUCCESS && res != LENSRT_ERROR_UNSUPPORTED)) return res;
        if (res == LENSRT_SUCCESS) {
            snprintf(why, n_why, "Fourier %.3g%% at %d nodes, ", 100.0 * *err, *used);
            if (!ps->quiet)
                fprintf(stderr, "lensrt-psf: %s: the Fourier estimate %.3g%% at %d nodes is above the target %.3g%%: "
                        "the cells integrator instead\n", what, 100.0 * *err, *used, 100.0 * target);
        } else if (!ps->quiet)
            fprintf(stderr, "lensrt-psf: %s: %s: the cells integrator instead\n", what, lensrt_context_last_error(ctx));
    }
    *used_kind = 1;
    return integrate_cells(r, (int)steps[0], (int)steps[1], target, strict, ps, what, used, err, reached);
}

/* The relative L2 Monte Carlo error of an image rendered as two independent halves.
 *
 * Per pixel and wavelength, half k (N/2 samples, seed of its own) estimates the field as
 * the mean U_k of its phasors; over the random shift of the Sobol points (or the random
 * points) U_k is unbiased for the true field U_0 and the halves are independent with the
 * same variance. The image written is I = |(U_1 + U_2) / 2|^2 (sums added), the halves
 * alone give I_k = |U_k|^2. With d = (U_1 + U_2) / 2 - U_0,
 *
 *   I - I_0 = 2 Re(conj(U_0) d) + |d|^2:
 *
 *   * the first term has mean 0, and (I_1 - I_2) / 2 = Re(conj(U_0) (U_1 - U_2)) + ... has
 *     the same variance ((U_1 - U_2) / 2 and d both have half a half's variance);
 *   * the second is the bias of |mean|^2, E|d|^2 > 0. The difference of the halves does
 *     not see it when their error patterns have equal magnitudes, which is what the Sobol
 *     sampler gives before N resolves the integrand (the aliasing of its point structure
 *     is the same for every shift; only its phase changes). By the parallelogram law
 *     b = (I_1 + I_2) / 2 - I = |U_1 - U_2|^2 / 4, whose expectation is exactly E|d|^2.
 *
 *   estimate^2 = (||I_1 - I_2||^2 / 4 + ||b||^2) / ||I||^2   (sums over pixels and
 *                                                              wavelengths)
 *
 * Once N resolves the integrand b is of second order and this is ||I_1 - I_2|| / ||I_1 +
 * I_2||. With the unbiased estimator every image is unbiased, b is noise of mean 0 and
 * is left out. Checked against 2^20- and 2^21-sample references on the three `make demo`
 * scenes (64 x 64, three seeds each, 256 to 131072 samples): 0.6 to 1.4 times the true
 * error from 0.2% to 50%, where the first term alone was 3x too low for f/2 below 65536
 * samples. The estimate is itself random (one shift per half and wavelength). Returns
 * -1 when the image is black (no relative error). */
static double mc_error_estimate(const float *i1, const float *i2, const float *all, size_t n, int paper)
{
    double d2 = 0.0, b2 = 0.0, a2 = 0.0;
    size_t k;
    for (k = 0; k < n; k++) {
        double d = (double)i1[k] - (double)i2[k];
        double b = 0.5 * ((double)i1[k] + (double)i2[k]) - (double)all[k];
        d2 += d * d;
        b2 += b * b;
        a2 += (double)all[k] * (double)all[k];
    }
    if (!(a2 > 0.0) || !isfinite(a2)) return -1.0;
    return sqrt((0.25 * d2 + (paper ? b2 : 0.0)) / a2);
}

#define MAX_GHOSTS 256

/* Append to paths[*n] (malloc'd copies) every ghost_*.table in dir, sorted by name; 0 and
 * a message when the folder cannot be read or there are too many. */
static int collect_flares(const char *dir, char **paths, int *n)
{
    struct dirent **list = NULL;
    int count = scandir(dir, &list, NULL, alphasort), k, ok = 1;
    if (count < 0) {
        fprintf(stderr, "lensrt-psf: --flares: cannot read folder '%s': %s\n", dir, strerror(errno));
        return 0;
    }
    for (k = 0; k < count; k++) {
        const char *name = list[k]->d_name;
        size_t len = strlen(name);
        char path[4096];
        if (ok && len > 12 && strncmp(name, "ghost_", 6) == 0 && strcmp(name + len - 6, ".table") == 0 &&
            snprintf(path, sizeof path, "%s/%s", dir, name) < (int)sizeof path && file_exists(path)) {
            if (*n >= MAX_GHOSTS) {
                fprintf(stderr, "lensrt-psf: --flares: more than %d ghost tables in '%s'\n", MAX_GHOSTS, dir);
                ok = 0;
            } else if (!(paths[(*n)++] = strdup(path))) {
                ok = 0;
            }
        }
        free(list[k]);
    }
    free(list);
    return ok;
}

/* A ghost table named twice (--ghost T --ghost T, a symbolic link to T, another relative
 * path to T, or --flares DIR with --ghost DIR/T) would be rendered twice and its flare
 * added twice: refused, naming the file and both spellings. The same file is the same
 * device and inode (stat follows links); a path that stat cannot read is left to the
 * loader's own message. Returns 1 when every table is named once. */
static int refuse_repeated_ghosts(char *const *paths, int n)
{
    dev_t dev[MAX_GHOSTS];
    ino_t ino[MAX_GHOSTS];
    unsigned char have[MAX_GHOSTS];
    int i, j;
    for (i = 0; i < n; i++) {
        struct stat st;
        have[i] = stat(paths[i], &st) == 0;
        if (!have[i]) continue;
        dev[i] = st.st_dev;
        ino[i] = st.st_ino;
        for (j = 0; j < i; j++)
            if (have[j] && dev[j] == dev[i] && ino[j] == ino[i]) {
                fprintf(stderr, "lensrt-psf: --ghost: ghost table '%s' is given twice (as '%s' and '%s', the same "
                        "file): its flare would be added twice; give it once\n", paths[j], paths[j], paths[i]);
                return 0;
            }
    }
    return 1;
}

/* OUT.exr -> OUT.<what>.exr (the stem is OUT without a trailing ".exr"). */
static void on_log(lensrt_log_level level, const char *message, void *user)
{
    progress_state *ps = user;
    if (level == LENSRT_LOG_INFO && ps->quiet) return;
    // Errors are printed once, by the failing step (lensrt_context_last_error)
    if (level == LENSRT_LOG_ERROR) return;
    fprintf(stderr, "lensrt-psf: %s%s\n", level == LENSRT_LOG_ERROR ? "" : level == LENSRT_LOG_WARNING ? "warning: " : "",
            message);
}

/* Auto's failure, one line: the image whose estimate missed the target after Fourier
 * (why: what it gave, or empty) and cells up to max_rings; nothing is written. */
static void target_missed(const char *what, double err, double target, int asked, int rings, long long max_rings,
                          const char *why)
{
    fprintf(stderr, "lensrt-psf: %s: --integrator auto did not reach the target error %.3g%%%s (%scells %.3g%% at %d "
            "rings, --max-rings %lld); nothing written\n", what, 100.0 * target, asked ? "" : " (its default)", why,
            100.0 * err, rings, max_rings);
}

/* Whether a ghost's render can be skipped: its footprint (lensrt_render_footprint),
 * widened by FOOTPRINT_MARGIN wavelengths x f-number of diffraction at the longest
 * wavelength, misses the window, or no ray of it passes its clips; said on stdout. A
 * footprint the library cannot find keeps the ghost (said unless quiet). */
#define FOOTPRINT_MARGIN 30.0
static int ghost_misses(lensrt_context ctx, lensrt_render r, const char *label, const double win[4], int quiet)
{
    lensrt_render_stats st = LENSRT_RENDER_STATS_INIT;
    const double *wl = lensrt_render_wavelengths(r);
    double box[4], lambda = 0.0, margin;
    int w;
    lensrt_render_get_stats(r, &st);
    if (lensrt_render_footprint(r, box) != LENSRT_SUCCESS) {
        if (!quiet) fprintf(stderr, "lensrt-psf: ghost %s: %s: rendered\n", label, lensrt_context_last_error(ctx));
        return 0;
    }
    if (box[0] > box[1]) {
        printf("Ghost %s skipped: no ray of it passes its clips to the sensor\n", label);
        return 1;
    }
    for (w = 0; w < st.n_wavelengths; w++)
        if (wl[w] > lambda) lambda = wl[w];
    margin = FOOTPRINT_MARGIN * lambda * 1e-6 * st.f_number;
    if (box[1] + margin < win[0] || box[0] - margin > win[1] || box[3] + margin < win[2] || box[2] - margin > win[3]) {
        printf("Ghost %s skipped: its footprint (x %.4g..%.4g mm, y %.4g..%.4g mm) and %.3g mm of diffraction "
               "around it miss the window (x %.4g..%.4g mm, y %.4g..%.4g mm)\n", label, box[0], box[1], box[2], box[3],
               margin, win[0], win[1], win[2], win[3]);
        return 1;
    }
    return 0;
}

int main(int argc, char **argv)
{
    const char *lens_arg = NULL, *out = NULL, *png = NULL, *gen = getenv("LENSRT_GENERATED");
    const char *save = NULL, *resume = NULL, *merge = NULL;
    double size[2] = {0.2, 0.0}, center[2] = {0, 0}, decades = 5.0, focus = 0.0, fnum = 0.0;
    double wl[MAX_WAVELENGTHS];
    lensrt_light lights[MAX_LIGHTS];
    int n_lights = 0, n_wl = 0, have_center = 0, width = 256, height = 256, quiet = 0, i, rc = 1, allow_empty = 0;
    long long samples = 65536, seed = 1, threads = 0, blades = 0, max_samples = 0;
    double target = 0.0, det_target = 0.0;
    int estimate = 1, cells = -1, mc_option = 0; /* cells -1: the default (after the options) */
    int pixel_filter = LENSRT_PIXEL_FILTER_BOX, pixel_samples[2] = {0, 0};
    long long rings = 32, max_rings = 0, nodes = 0, max_nodes = 0;
    int used_kind = 0;
    double curvature = 0.0, rotation = 0.0;
    lensrt_sampler sampler = LENSRT_SAMPLER_DEFAULT;
    lensrt_estimator estimator = LENSRT_ESTIMATOR_PAPER;
    lensrt_device device = LENSRT_DEVICE_CPU;
    lensrt_gl_platform gl_platform = LENSRT_GL_PLATFORM_AUTO;
    lensrt_context_init init;
    lensrt_context ctx = NULL;
    lensrt_lens lens = NULL;
    lensrt_render render = NULL, render_b = NULL;
    float *img_a = NULL, *img_b = NULL, *img_all = NULL;
    char tmp_a[4200] = "", tmp_b[4200] = "", stage[3][4200] = {"", "", ""};
    const char *targets[3] = {NULL, NULL, NULL}; /* --save-phasors, -o, --png */
    double mc_error = -1.0;
    int cells_rings = 0;
    uint64_t mc_samples = 0;
    lensrt_render_desc desc;
    lensrt_render_stats st = LENSRT_RENDER_STATS_INIT;
    lensrt_result res;
    progress_state ps = {0};
    char table[4096];
    /* Ghosts (--ghost, --flares): their tables, lenses and renders; renders[0] is the
     * direct render, renders[1 ..] the ghosts' (what the image sums take) */
    char *ghost_paths[MAX_GHOSTS];
    const char *flares_dir = NULL;
    lensrt_lens ghost_lens[MAX_GHOSTS];
    lensrt_render renders[MAX_GHOSTS + 1];
    /* the renders whose images are kept: the direct one, then the ghosts not skipped */
    lensrt_render kept[MAX_GHOSTS + 1];
    int n_kept = 1;
    int n_ghosts = 0, n_ghost_args = 0;
    if (!gen) gen = LENSRT_GENERATED_DIR;
    memset(ghost_lens, 0, sizeof ghost_lens);
    memset(renders, 0, sizeof renders);

    // Options
    for (i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        double t[4];
        long long n;
        int k;
        if (strcmp(a, "-h") == 0 || strcmp(a, "--help") == 0) { usage(stdout); return 0; }
        if (strcmp(a, "--quiet") == 0) { quiet = 1; continue; }
        if (strcmp(a, "--no-estimate") == 0) { estimate = 0; mc_option = 1; continue; }
        if (strcmp(a, "--allow-empty") == 0) { allow_empty = 1; continue; }
        if (!v) return bad(a, NULL, "needs a value");
        i++;
        // Options only Monte Carlo takes: with one, the default integrator is Monte Carlo
        if (strcmp(a, "--save-phasors") == 0 || strcmp(a, "--resume") == 0 || strcmp(a, "--merge") == 0 ||
            strcmp(a, "--samples") == 0 || strcmp(a, "--max-samples") == 0 || strcmp(a, "--seed") == 0 ||
            strcmp(a, "--sampler") == 0 || strcmp(a, "--estimator") == 0)
            mc_option = 1;
        if (strcmp(a, "--lens") == 0) lens_arg = v;
        else if (strcmp(a, "--generated") == 0) gen = v;
        else if (strcmp(a, "-o") == 0 || strcmp(a, "--output") == 0) out = v;
        else if (strcmp(a, "--png") == 0) png = v;
        else if (strcmp(a, "--save-phasors") == 0) save = v;
        else if (strcmp(a, "--resume") == 0) resume = v;
        else if (strcmp(a, "--merge") == 0) merge = v;
        else if (strcmp(a, "--ghost") == 0) {
            if (n_ghosts >= MAX_GHOSTS) return bad(a, v, "at most 256 ghost tables");
            ghost_paths[n_ghosts++] = (char *)v; /* not freed: only --flares paths are copies */
        } else if (strcmp(a, "--flares") == 0) {
            // One folder: a second would silently replace the first (ghost tables of
            // more folders are named with --ghost)
            if (flares_dir) return bad(a, v, "given twice (one folder; name other ghost tables with --ghost)");
            flares_dir = v;
        }
        else if (strcmp(a, "--decades") == 0) { if (!parse_double(v, &decades) || decades <= 0) return bad(a, v, "expected a positive number"); }
        else if (strcmp(a, "--focus") == 0) { if (!parse_double(v, &focus)) return bad(a, v, "expected a number (mm)"); }
        else if (strcmp(a, "--f-number") == 0) { if (!parse_double(v, &fnum) || fnum <= 0) return bad(a, v, "expected a positive f-number"); }
        else if (strcmp(a, "--curvature") == 0) { if (!parse_double(v, &curvature) || curvature < 0 || curvature > 1) return bad(a, v, "expected a number in [0, 1]"); }
        else if (strcmp(a, "--rotation") == 0) { if (!parse_double(v, &rotation)) return bad(a, v, "expected degrees"); }
        else if (strcmp(a, "--blades") == 0) { if (!parse_long(v, 3, 64, &blades)) return bad(a, v, "expected 3..64 blades"); }
        else if (strcmp(a, "--samples") == 0) { if (!parse_long(v, 1, (long long)1 << 40, &samples)) return bad(a, v, "expected a positive sample count"); }
        else if (strcmp(a, "--target-error") == 0) { if (!parse_double(v, &target) || target <= 0 || target >= 1) return bad(a, v, "expected a relative error in (0, 1), e.g. 0.01"); }
        else if (strcmp(a, "--max-samples") == 0) { if (!parse_long(v, 2, (long long)1 << 40, &max_samples)) return bad(a, v, "expected a sample count >= 2"); }
        else if (strcmp(a, "--rings") == 0) { if (!parse_long(v, 2, LENSRT_MAX_RINGS, &rings)) return bad(a, v, "expected 2..4096 rings"); }
        else if (strcmp(a, "--max-rings") == 0) { if (!parse_long(v, 2, LENSRT_MAX_RINGS, &max_rings)) return bad(a, v, "expected 2..4096 rings"); }
        else if (strcmp(a, "--nodes") == 0) { if (!parse_long(v, 0, LENSRT_MAX_FOURIER_NODES, &nodes)) return bad(a, v, "expected 0 (chosen) or 1..4096 nodes"); }
        else if (strcmp(a, "--max-nodes") == 0) { if (!parse_long(v, 1, LENSRT_MAX_FOURIER_NODES, &max_nodes)) return bad(a, v, "expected 1..4096 nodes"); }
        else if (strcmp(a, "--pixel-filter") == 0) {
            if (strcmp(v, "box") == 0) pixel_filter = LENSRT_PIXEL_FILTER_BOX;
            else if (strcmp(v, "point") == 0) pixel_filter = LENSRT_PIXEL_FILTER_POINT;
            else return bad(a, v, "expected box or point");
        } else if (strcmp(a, "--pixel-samples") == 0) {
            k = parse_list(v, 'x', t, 2);
            if (k < 1 || t[0] < 0 || t[0] > LENSRT_MAX_PIXEL_SAMPLES || t[0] != floor(t[0]) ||
                (k == 2 && (t[1] < 0 || t[1] > LENSRT_MAX_PIXEL_SAMPLES || t[1] != floor(t[1]))))
                return bad(a, v, "expected N or NxM sub-pixel points per axis, whole numbers 0 (chosen) .. 16");
            pixel_samples[0] = (int)t[0];
            pixel_samples[1] = k == 2 ? (int)t[1] : (int)t[0];
        }
        else if (strcmp(a, "--integrator") == 0) {
            if (strcmp(v, "cells") == 0) cells = 1;
            else if (strcmp(v, "montecarlo") == 0) cells = 0;
            else if (strcmp(v, "fourier") == 0) cells = 2;
            else if (strcmp(v, "auto") == 0) cells = 3;
            else return bad(a, v, "expected montecarlo, cells, fourier or auto");
        }
        else if (strcmp(a, "--seed") == 0) { if (!parse_long(v, 0, (long long)9e18, &seed)) return bad(a, v, "expected a non-negative integer"); }
        else if (strcmp(a, "--threads") == 0) { if (!parse_long(v, 1, 1024, &threads)) return bad(a, v, "expected 1..1024"); }
        else if (strcmp(a, "--resolution") == 0) {
            k = parse_list(v, 'x', t, 2);
            if (k != 2 || t[0] < 1 || t[1] < 1 || t[0] > 65536 || t[1] > 65536 || t[0] != floor(t[0]) || t[1] != floor(t[1]))
                return bad(a, v, "expected WxH with positive whole numbers");
            width = (int)t[0];
            height = (int)t[1];
        } else if (strcmp(a, "--size") == 0) {
            k = parse_list(v, 'x', t, 2);
            if (k < 1 || !all_finite(t, k) || t[0] <= 0 || (k == 2 && t[1] <= 0)) return bad(a, v, "expected W or WxH in mm, positive and finite");
            size[0] = t[0];
            size[1] = k == 2 ? t[1] : 0.0;
        } else if (strcmp(a, "--center") == 0) {
            if (parse_list(v, ',', center, 2) != 2 || !all_finite(center, 2)) return bad(a, v, "expected X,Y in mm, finite");
            have_center = 1;
        } else if (strcmp(a, "--light") == 0) {
            k = parse_list(v, ',', t, 4);
            if (k < 2 || n_lights >= MAX_LIGHTS) return bad(a, v, "expected X,Y[,DISTANCE[,INTENSITY]] (at most 64 lights)");
            // Only the distance may be inf (the light at infinity, as 0)
            if (!all_finite(t, 2) || (k > 3 && !isfinite(t[3]))) return bad(a, v, "field angles and intensity must be finite numbers (only the distance may be inf)");
            if (k > 2 && isinf(t[2])) {
                if (t[2] < 0) return bad(a, v, "the distance must be positive, 0 or inf");
                t[2] = 0.0;
            }
            { const lensrt_light zero_light = LENSRT_LIGHT_INIT; lights[n_lights] = zero_light; }
            lights[n_lights].field_x_deg = t[0];
            lights[n_lights].field_y_deg = t[1];
            lights[n_lights].distance_mm = k > 2 ? t[2] : 0.0;
            lights[n_lights].intensity = k > 3 ? t[3] : 0.0;
            if (k > 3 && t[3] <= 0) return bad(a, v, "intensity must be positive");
            n_lights++;
        } else if (strcmp(a, "--wavelengths") == 0) {
            if (parse_long(v, 1, MAX_WAVELENGTHS, &n)) n_wl = (int)n;
            else if (strchr(v, ',') && (k = parse_list(v, ',', wl, MAX_WAVELENGTHS)) > 0 && all_finite(wl, k)) n_wl = -k;
            else return bad(a, v, "expected a count (1..4096) or a comma-separated list in nm (one wavelength: --wavelength NM)");
        } else if (strcmp(a, "--wavelength") == 0) {
            // One wavelength in nm: "--wavelengths 550" is a count of 550
            if (!parse_double(v, &wl[0]) || wl[0] <= 0) return bad(a, v, "expected one wavelength in nm, e.g. 550");
            n_wl = -1;
        } else if (strcmp(a, "--sampler") == 0) {
            if (strcmp(v, "sobol") == 0) sampler = LENSRT_SAMPLER_SOBOL;
            else if (strcmp(v, "random") == 0) sampler = LENSRT_SAMPLER_RANDOM;
            else if (strcmp(v, "stratified") == 0) sampler = LENSRT_SAMPLER_STRATIFIED;
            else return bad(a, v, "expected sobol, random or stratified");
        } else if (strcmp(a, "--device") == 0) {
            if (strcmp(v, "cpu") == 0) device = LENSRT_DEVICE_CPU;
            else if (strcmp(v, "gl") == 0) device = LENSRT_DEVICE_GL;
            else return bad(a, v, "expected cpu or gl");
        } else if (strcmp(a, "--gl-platform") == 0) {
            if (strcmp(v, "auto") == 0) gl_platform = LENSRT_GL_PLATFORM_AUTO;
            else if (strcmp(v, "egl-device") == 0) gl_platform = LENSRT_GL_PLATFORM_EGL_DEVICE;
            else if (strcmp(v, "egl-surfaceless") == 0) gl_platform = LENSRT_GL_PLATFORM_EGL_SURFACELESS;
            else if (strcmp(v, "glfw") == 0) gl_platform = LENSRT_GL_PLATFORM_GLFW;
            else return bad(a, v, "expected auto, egl-device, egl-surfaceless or glfw");
        } else if (strcmp(a, "--estimator") == 0) {
            if (strcmp(v, "paper") == 0) estimator = LENSRT_ESTIMATOR_PAPER;
            else if (strcmp(v, "unbiased") == 0) estimator = LENSRT_ESTIMATOR_UNBIASED;
            else return bad(a, v, "expected paper or unbiased");
        } else {
            fprintf(stderr, "lensrt-psf: unknown option '%s'\n", a);
            usage(stderr);
            return 2;
        }
    }
    if (!lens_arg) return bad("--lens", NULL, "a lens id or table is required");
    // The default integrator: auto (Fourier, cells where a clip cuts the aperture), or
    // Monte Carlo when an option only it takes is given or the device is GL
    if (cells < 0) cells = mc_option || device == LENSRT_DEVICE_GL ? 0 : 3;
    if (cells && (resume || merge || save || !estimate || estimator == LENSRT_ESTIMATOR_UNBIASED || max_samples)) {
        fprintf(stderr, "lensrt-psf: --integrator %s takes no --resume, --merge, --save-phasors, --no-estimate, "
                "--estimator unbiased or --max-samples (those are Monte Carlo's)\n",
                cells == 1 ? "cells" : cells == 2 ? "fourier" : "auto");
        return 2;
    }
    if ((cells == 0 || cells == 2) && max_rings) {
        fprintf(stderr, "lensrt-psf: --max-rings goes with --integrator cells or auto\n");
        return 2;
    }
    if (cells < 2 && max_nodes) {
        fprintf(stderr, "lensrt-psf: --max-nodes goes with --integrator fourier or auto\n");
        return 2;
    }
    if (!max_nodes) max_nodes = nodes > 2730 ? nodes : 2730;
    if (max_nodes < nodes) {
        fprintf(stderr, "lensrt-psf: --max-nodes %lld is below --nodes %lld\n", max_nodes, nodes);
        return 2;
    }
    if (!max_rings) max_rings = rings > 1024 ? rings : 1024;
    // What the deterministic integrators aim at: --target-error, or for auto its default
    det_target = target > 0 ? target : cells == 3 ? AUTO_TARGET : 0.0;
    if (max_rings < rings) {
        fprintf(stderr, "lensrt-psf: --max-rings %lld is below --rings %lld\n", max_rings, rings);
        return 2;
    }
    if (!out && !png && !save) return bad("-o", NULL, "an output (-o, --png or --save-phasors) is required");
    if (target > 0 && (!estimate || resume || merge || samples < 2)) {
        fprintf(stderr, "lensrt-psf: --target-error needs the two halves: not with --no-estimate, --resume, --merge or --samples 1\n");
        return 2;
    }
    if (max_samples && target <= 0) {
        fprintf(stderr, "lensrt-psf: --max-samples goes with --target-error\n");
        return 2;
    }
    if (estimator == LENSRT_ESTIMATOR_UNBIASED && !resume && !merge &&
        (estimate && samples >= 2 ? samples < 4 : samples < 2)) {
        // Its image needs 2 samples per render: checked here, not after the render
        fprintf(stderr, "lensrt-psf: --estimator unbiased needs 2 samples per image: --samples %lld is too few "
                "(at least 4 for the two halves, 2 with --no-estimate)\n", samples);
        return 2;
    }
    if (!max_samples) max_samples = samples > DEFAULT_MAX_SAMPLES ? samples : DEFAULT_MAX_SAMPLES;
    if (pixel_filter == LENSRT_PIXEL_FILTER_POINT && (pixel_samples[0] > 1 || pixel_samples[1] > 1)) {
        fprintf(stderr, "lensrt-psf: --pixel-samples %dx%d with --pixel-filter point, which samples the pixel's "
                "centre only\n", pixel_samples[0], pixel_samples[1]);
        return 2;
    }
    if (max_samples < samples) {
        fprintf(stderr, "lensrt-psf: --max-samples %lld is below --samples %lld\n", max_samples, samples);
        return 2;
    }
    ps.quiet = quiet;
    // Ghosts: the tables (--ghost, then --flares' folder sorted), one render each
    n_ghost_args = n_ghosts;
    if (flares_dir && !collect_flares(flares_dir, ghost_paths, &n_ghosts)) {
        rc = 2;
        goto done_args;
    }
    if (flares_dir && n_ghosts == n_ghost_args) {
        fprintf(stderr, "lensrt-psf: --flares: no ghost_*.table in '%s'\n", flares_dir);
        rc = 2;
        goto done_args;
    }
    if (!refuse_repeated_ghosts(ghost_paths, n_ghosts)) {
        rc = 2;
        goto done_args;
    }
    if (n_ghosts && (save || resume || merge)) {
        fprintf(stderr, "lensrt-psf: --save-phasors, --resume and --merge keep one render's sums: not with --ghost "
                "or --flares\n");
        rc = 2;
        goto done_args;
    }
    {
        const char *outs[3];
        int k;
        outs[0] = targets[1] = out;
        outs[1] = targets[2] = png;
        outs[2] = targets[0] = save;
        for (k = 0; k < 3; k++)
            if (outs[k] && !writable(outs[k])) {
                fprintf(stderr, "lensrt-psf: cannot write '%s': %s\n", outs[k],
                        errno == ELOOP ? "it is a symbolic link (give the link's target)"
                        : errno == EEXIST ? "it exists and is not a regular file"
                                          : strerror(errno));
                rc = 2;
                goto done_args;
            }
    }

    // Context and lens: an id names generated/<id>-*/lens<id>.table
    { const lensrt_context_init zero_init = LENSRT_CONTEXT_INIT; init = zero_init; }
    init.log_fn = on_log;
    init.user_data = &ps;
    init.threads = (int)threads;
    init.gl_platform = gl_platform;
    if ((res = lensrt_context_create(&init, &ctx)) != LENSRT_SUCCESS) {
        fprintf(stderr, "lensrt-psf: %s\n", lensrt_result_string(res));
        rc = 1;
        goto done_args;
    }
    if (strstr(lens_arg, ".table")) {
        // A regular file only: a FIFO would block, a folder is no table
        struct stat lst;
        if (stat(lens_arg, &lst) == 0 && !S_ISREG(lst.st_mode)) {
            fprintf(stderr, "lensrt-psf: --lens: '%s' is not a regular file\n", lens_arg);
            rc = 2;
            goto done;
        }
        snprintf(table, sizeof table, "%s", lens_arg);
    }
    else {
        char choices[2048];
        const int matches = find_table(gen, lens_arg, table, sizeof table, choices, sizeof choices);
        if (matches == 0) {
            fprintf(stderr, "lensrt-psf: --lens: unknown lens '%s': no %s/%s-*/lens%s.table (see --generated)\n",
                    lens_arg, gen, lens_arg, lens_arg);
            rc = 2;
            goto done;
        }
        if (matches > 1) {
            fprintf(stderr, "lensrt-psf: --lens: '%s' is ambiguous: %d folders of %s match (%s); name one whole\n",
                    lens_arg, matches, gen, choices);
            rc = 2;
            goto done;
        }
    }
    if ((res = lensrt_lens_load(ctx, table, &lens)) != LENSRT_SUCCESS) goto fail_input;
    // Each ghost: a ghost table of this lens (the same lens name and focal length)
    for (i = 0; i < n_ghosts; i++) {
        lensrt_lens_info li = LENSRT_LENS_INFO_INIT, gi = LENSRT_LENS_INFO_INIT;
        struct stat gst;
        if (stat(ghost_paths[i], &gst) == 0 && !S_ISREG(gst.st_mode)) {
            fprintf(stderr, "lensrt-psf: --ghost: '%s' is not a regular file\n", ghost_paths[i]);
            rc = 2;
            goto done;
        }
        if ((res = lensrt_lens_load(ctx, ghost_paths[i], &ghost_lens[i])) != LENSRT_SUCCESS) goto fail_input;
        lensrt_lens_get_info(lens, &li);
        lensrt_lens_get_info(ghost_lens[i], &gi);
        if (!gi.ghost) {
            fprintf(stderr, "lensrt-psf: --ghost: '%s' is not a ghost table (it has no ghost lines)\n", ghost_paths[i]);
            rc = 2;
            goto done;
        }
        if (strcmp(gi.name, li.name) != 0 || gi.focal_length_mm != li.focal_length_mm) {
            fprintf(stderr, "lensrt-psf: --ghost: '%s' (lens '%s', focal length %.17g mm) is a ghost of another lens "
                    "than '%s' (lens '%s', focal length %.17g mm)\n", ghost_paths[i], gi.name, gi.focal_length_mm,
                    table, li.name, li.focal_length_mm);
            rc = 2;
            goto done;
        }
        {   /* two files of the same ghost of this lens (a copy, another fit of it) */
            int j;
            for (j = 0; j < i; j++) {
                lensrt_lens_info hj = LENSRT_LENS_INFO_INIT;
                lensrt_lens_get_info(ghost_lens[j], &hj);
                if (hj.ghost_first == gi.ghost_first && hj.ghost_second == gi.ghost_second) {
                    fprintf(stderr, "lensrt-psf: --ghost: ghost %s of lens '%s' is given twice (as '%s' and '%s'): "
                            "its flare would be added twice; give it once\n", gi.ghost_label, gi.name,
                            ghost_paths[j], ghost_paths[i]);
                    rc = 2;
                    goto done;
                }
            }
        }
    }

    // Scene
    { const lensrt_render_desc zero_desc = LENSRT_RENDER_DESC_INIT; desc = zero_desc; }
    desc.lens = lens;
    desc.sensor.width = width;
    desc.sensor.height = height;
    desc.sensor.width_mm = size[0];
    desc.sensor.height_mm = size[1];
    desc.sensor.focus_offset_mm = focus;
    desc.aperture.f_number = fnum;
    if (blades) {
        desc.aperture.shape = LENSRT_APERTURE_BLADES;
        desc.aperture.blades = (int)blades;
        desc.aperture.blade_curvature = curvature;
        desc.aperture.rotation_deg = rotation;
    }
    desc.lights = n_lights ? lights : NULL;
    desc.n_lights = n_lights;
    if (n_wl < 0) {
        desc.wavelengths_nm = wl;
        desc.n_wavelengths = -n_wl;
    } else {
        desc.n_wavelengths = n_wl;
    }
    desc.sampler = sampler;
    desc.estimator = estimator;
    desc.seed = (uint64_t)seed;
    desc.device = device;
    desc.pixel_filter = pixel_filter;
    desc.pixel_samples_x = pixel_samples[0];
    desc.pixel_samples_y = pixel_samples[1];
    if (device == LENSRT_DEVICE_GL) {
        // The device first: a machine without GL says so before any other work
        lensrt_gl_info gi = LENSRT_GL_INFO_INIT;
        if ((res = lensrt_context_gl_info(ctx, &gi)) != LENSRT_SUCCESS) goto fail_input;
        if (!quiet) fprintf(stderr, "lensrt-psf: device gl: %s, GL_RENDERER %s, GL_VERSION %s\n", gi.platform, gi.renderer, gi.version);
    }
    if (!have_center) {
        lensrt_light axis = LENSRT_LIGHT_INIT;
        lensrt_lens_info info = LENSRT_LENS_INFO_INIT;
        lensrt_lens_get_info(lens, &info);
        res = lensrt_lens_image_point(ctx, lens, n_lights ? &lights[0] : &axis,
                                      0.5 * (info.wavelength_min_nm + info.wavelength_max_nm), focus, center);
        if (res != LENSRT_SUCCESS) goto fail_input;
    }
    desc.sensor.center_x_mm = center[0];
    desc.sensor.center_y_mm = center[1];
    if (estimate && (resume || merge || samples < 2)) {
        // The halves of resumed or merged sums are unknown: one render, no estimate
        if (!quiet) fprintf(stderr, "lensrt-psf: no Monte Carlo error estimate with --resume, --merge or 1 sample\n");
        estimate = 0;
    }
    if ((res = lensrt_render_create(ctx, &desc, &render)) != LENSRT_SUCCESS) goto fail_input;
    if (estimate && !cells) {
        lensrt_render_desc half = desc;
        half.seed = (uint64_t)seed + HALF_SEED_STEP;
        if ((res = lensrt_render_create(ctx, &half, &render_b)) != LENSRT_SUCCESS) goto fail_input;
    }
    // The ghosts' renders: the same scene through each ghost table (made now, so that a
    // scene a ghost cannot render is refused before any work)
    renders[0] = kept[0] = render;
    for (i = 0; i < n_ghosts; i++) {
        lensrt_render_desc gd = desc;
        gd.lens = ghost_lens[i];
        if ((res = lensrt_render_create(ctx, &gd, &renders[1 + i])) != LENSRT_SUCCESS) {
            // Said with the ghost's file: the library's message names the lens, which
            // the direct table and every ghost share
            fprintf(stderr, "lensrt-psf: --ghost %s: %s\n", ghost_paths[i], lensrt_context_last_error(ctx));
            rc = res == LENSRT_ERROR_NO_DEVICE || res == LENSRT_ERROR_UNSUPPORTED ? 3 : 2;
            goto done;
        }
    }
    if (resume && (res = lensrt_render_load(render, resume)) != LENSRT_SUCCESS) goto fail_input;
    if (merge && (res = lensrt_render_merge(render, merge)) != LENSRT_SUCCESS) goto fail_input;

    // Render
    if (!quiet && cells == 1)
        fprintf(stderr, "lensrt-psf: %s, window %g mm at (%g, %g) mm, cells integrator from %lld rings\n",
                table, size[0], center[0], center[1], rings);
    else if (!quiet && cells)
        fprintf(stderr, "lensrt-psf: %s, window %g mm at (%g, %g) mm, Fourier integrator%s%s\n", table, size[0],
                center[0], center[1], nodes ? "" : " (nodes from the phase)",
                cells == 3 ? " (cells where a clip cuts or its estimate stays above the target)" : "");
    else if (!quiet)
        fprintf(stderr, "lensrt-psf: %s, window %g mm at (%g, %g) mm, %lld samples per wavelength%s\n",
                table, size[0], center[0], center[1], samples, estimate ? " in two halves" : "");
    ps.round_start = now_seconds();
    if (cells) {
        const long long steps[4] = {rings, max_rings, nodes, max_nodes};
        int reached = 0;
        char why[128];
        if ((res = integrate_det(ctx, render, cells, steps, det_target, target > 0, &ps, "direct", &used_kind,
                                 &cells_rings, &mc_error, &reached, why, sizeof why)) != LENSRT_SUCCESS) {
            // A device or lens the integrator does not take (GL, one-dimensional): exit 3
            if (res == LENSRT_ERROR_UNSUPPORTED) goto fail_input;
            goto fail;
        }
        if (!reached && cells == 3) {
            target_missed("the direct image", mc_error, det_target, target > 0, cells_rings, max_rings, why);
            rc = 5;
            goto done;
        }
    } else if (!estimate) {
        ps.base = 0.0;
        ps.span = 1.0;
        ps.label = "rendering";
        res = lensrt_render_run(render, (uint64_t)samples, on_progress, &ps);
        if (!quiet) fprintf(stderr, "\n");
        if (res != LENSRT_SUCCESS) goto fail;
    } else {
        // Rounds: both halves get `step` more samples, then the estimate; with a target
        // the next round doubles both. The halves' sums are added (B saved, merged into
        // A); when another round may follow A is saved first and restored after.
        uint64_t step_a = (uint64_t)(samples - samples / 2), step_b = (uint64_t)(samples / 2), n_a = 0, n_b = 0;
        const char *base = out ? out : png ? png : save;
        char label[64];
        size_t n;
        lensrt_render_get_stats(render, &st);
        n = (size_t)st.n_wavelengths * (size_t)st.width * (size_t)st.height;
        img_a = malloc(n * sizeof *img_a);
        img_b = malloc(n * sizeof *img_b);
        img_all = malloc(n * sizeof *img_all);
        if (!img_a || !img_b || !img_all) {
            fprintf(stderr, "lensrt-psf: out of memory for the error estimate (3 x %zu floats)\n", n);
            goto done;
        }
        remove_stale(base, "mc");
        snprintf(tmp_a, sizeof tmp_a, "%s.mc-%ld-a.phasors", base, (long)getpid());
        snprintf(tmp_b, sizeof tmp_b, "%s.mc-%ld-b.phasors", base, (long)getpid());
        for (;;) {
            int more = target > 0 && 2 * (n_a + n_b + step_a + step_b) <= (uint64_t)max_samples;
            snprintf(label, sizeof label, "%llu samples", (unsigned long long)(n_a + n_b + step_a + step_b));
            ps.label = label;
            ps.round_start = now_seconds();
            ps.base = 0.0;
            ps.span = 0.5;
            res = lensrt_render_run(render, step_a, on_progress, &ps);
            ps.base = 0.5;
            if (res == LENSRT_SUCCESS) res = lensrt_render_run(render_b, step_b, on_progress, &ps);
            if (!quiet) fprintf(stderr, "\n");
            if (res != LENSRT_SUCCESS) goto fail;
            n_a += step_a;
            n_b += step_b;
            if ((res = lensrt_render_image(render, img_a, n)) != LENSRT_SUCCESS ||
                (res = lensrt_render_image(render_b, img_b, n)) != LENSRT_SUCCESS ||
                (more && (res = lensrt_render_save(render, tmp_a)) != LENSRT_SUCCESS) ||
                (res = lensrt_render_save(render_b, tmp_b)) != LENSRT_SUCCESS ||
                (res = lensrt_render_merge(render, tmp_b)) != LENSRT_SUCCESS ||
                (res = lensrt_render_image(render, img_all, n)) != LENSRT_SUCCESS)
                goto fail;
            mc_error = mc_error_estimate(img_a, img_b, img_all, n, estimator != LENSRT_ESTIMATOR_UNBIASED);
            mc_samples = n_a + n_b;
            if (target <= 0) break;
            if (!quiet) {
                if (mc_error >= 0) fprintf(stderr, "lensrt-psf: %s: Monte Carlo error estimate %.3g%%\n", label, 100.0 * mc_error);
                else fprintf(stderr, "lensrt-psf: %s: the image is black, no relative error\n", label);
            }
            if (mc_error <= target) break; /* reached, or black (-1): more samples cannot help */
            if (!more) {
                fprintf(stderr, "lensrt-psf: warning: --target-error %g not reached within --max-samples %lld: "
                        "the estimate is %.3g%%\n", target, max_samples, 100.0 * mc_error);
                break;
            }
            if ((res = lensrt_render_load(render, tmp_a)) != LENSRT_SUCCESS) goto fail;
            step_a = n_a;
            step_b = n_b;
        }
    }
    lensrt_render_get_stats(render, &st);
    if (!quiet)
        fprintf(stderr, "lensrt-psf: pixel filter %s, %d x %d points per pixel\n",
                st.pixel_filter == LENSRT_PIXEL_FILTER_POINT ? "point" : "box", st.pixel_samples_x, st.pixel_samples_y);
    if (!quiet && cells)
        fprintf(stderr, "lensrt-psf: %.2f s, %s integrator (%d %s), f/%.3g, stop radius %.4g mm\n", st.seconds,
                used_kind == 2 ? "Fourier" : "cells", cells_rings, used_kind == 2 ? "nodes" : "rings", st.f_number,
                st.stop_radius_mm);
    else if (!quiet)
        fprintf(stderr, "lensrt-psf: %.2f s, %.3g splats/s, f/%.3g, stop radius %.4g mm\n", st.seconds,
                st.splats_per_second, st.f_number, st.stop_radius_mm);
    // Ghosts: as many samples per wavelength as the direct image has, one sequence each
    if (n_ghosts) {
        const size_t n = (size_t)st.n_wavelengths * (size_t)st.width * (size_t)st.height;
        const uint64_t ghost_samples = st.samples_per_wavelength;
        float *direct_img = malloc(n * sizeof *direct_img), *ghost_img = malloc(n * sizeof *ghost_img);
        double direct_power = 0.0;
        // The window on the sensor (x0, x1, y0, y1 mm): its height by the pixels' aspect
        // when --size gives one number
        const double win_h = size[1] > 0 ? size[1] : size[0] * height / width;
        const double window[4] = {center[0] - 0.5 * size[0], center[0] + 0.5 * size[0], center[1] - 0.5 * win_h,
                                  center[1] + 0.5 * win_h};
        size_t k;
        char label[600];
        if (!direct_img || !ghost_img || lensrt_render_image(render, direct_img, n) != LENSRT_SUCCESS) {
            free(direct_img);
            free(ghost_img);
            fprintf(stderr, "lensrt-psf: %s\n", lensrt_context_last_error(ctx)[0] ? lensrt_context_last_error(ctx) : "out of memory");
            goto done;
        }
        for (k = 0; k < n; k++) direct_power += direct_img[k];
        for (i = 0; i < n_ghosts; i++) {
            lensrt_lens_info gi = LENSRT_LENS_INFO_INIT;
            lensrt_render_stats gs = LENSRT_RENDER_STATS_INIT;
            double power = 0.0;
            lensrt_lens_get_info(ghost_lens[i], &gi);
            snprintf(label, sizeof label, "ghost %s (%d of %d)", gi.ghost_label, i + 1, n_ghosts);
            ps.label = label;
            ps.round_start = now_seconds();
            ps.base = 0.0;
            ps.span = 1.0;
            // A ghost whose footprint, widened by its diffraction, misses the window: skipped
            // (said on stdout with the estimates), its image left out of the outputs
            if (ghost_misses(ctx, renders[1 + i], gi.ghost_label, window, quiet)) continue;
            kept[n_kept++] = renders[1 + i];
            if (cells) {
                const long long steps[4] = {rings, max_rings, nodes, max_nodes};
                int gr = 0, gk = 0, reached = 0;
                double ge = -1.0;
                char why[128], what[80];
                res = integrate_det(ctx, renders[1 + i], cells, steps, det_target, target > 0, &ps, gi.ghost_label,
                                    &gk, &gr, &ge, &reached, why, sizeof why);
                if (res == LENSRT_SUCCESS && !reached && cells == 3) {
                    snprintf(what, sizeof what, "ghost %s", gi.ghost_label);
                    target_missed(what, ge, det_target, target > 0, gr, max_rings, why);
                    free(direct_img);
                    free(ghost_img);
                    rc = 5;
                    goto done;
                }
                if (res == LENSRT_SUCCESS)
                    printf("%s error estimate, ghost %s: %.3g%% relative L2 (%d %s)\n", gk == 2 ? "Fourier" : "Cells",
                           gi.ghost_label, 100.0 * ge, gr, gk == 2 ? "nodes" : "rings");
            } else {
                res = lensrt_render_run(renders[1 + i], ghost_samples, on_progress, &ps);
                if (!quiet) fprintf(stderr, "\n");
            }
            if (res == LENSRT_SUCCESS) res = lensrt_render_image(renders[1 + i], ghost_img, n);
            if (res != LENSRT_SUCCESS) {
                free(direct_img);
                free(ghost_img);
                goto fail;
            }
            for (k = 0; k < n; k++) power += ghost_img[k];
            lensrt_render_get_stats(renders[1 + i], &gs);
            if (!quiet)
                fprintf(stderr, "lensrt-psf: ghost %s (surfaces %d, %d; %s): %.2f s, power in the window %.3g of the "
                        "direct image's\n", gi.ghost_label, gi.ghost_first, gi.ghost_second, ghost_paths[i], gs.seconds,
                        direct_power > 0 ? power / direct_power : 0.0);
        }
        free(direct_img);
        free(ghost_img);
    }

    // Outputs, each written atomically; with ghosts one EXR whose unprefixed channels are
    // the total and whose layers are the direct image and the flare (the ghosts' sum)
    // An image that is zero everywhere (an absurd stop, a light outside every pupil) is
    // refused, not written, unless asked for
    if (!allow_empty) {
        lensrt_render_stats es = LENSRT_RENDER_STATS_INIT;
        size_t n, k;
        float *sum;
        int empty = 1;
        lensrt_render_get_stats(render, &es);
        n = (size_t)es.n_wavelengths * (size_t)es.width * (size_t)es.height;
        if (!(sum = malloc(n * sizeof *sum))) {
            fprintf(stderr, "lensrt-psf: out of memory for the image (%zu floats)\n", n);
            goto done;
        }
        if ((res = lensrt_renders_image(kept, n_kept, sum, n)) != LENSRT_SUCCESS) {
            free(sum);
            goto fail;
        }
        for (k = 0; k < n && empty; k++) empty = sum[k] == 0.0f;
        free(sum);
        if (empty) {
            char why[64] = "";
            if (fnum > 0) snprintf(why, sizeof why, "a stop of f/%g, ", fnum);
            fprintf(stderr, "lensrt-psf: the image is zero everywhere: no light reaches the window (%slights outside "
                    "every pupil, or the window off the image); nothing written (--allow-empty writes it)\n", why);
            rc = 4;
            goto done;
        }
    }
    // Each is staged as `<target>.stage-<pid>` and renamed over its target only when
    // every one is written: a failed run leaves no output (nor a stage)
    for (i = 0; i < 3; i++)
        if (targets[i]) {
            remove_stale(targets[i], "stage");
            snprintf(stage[i], sizeof stage[i], "%s.stage-%ld", targets[i], (long)getpid());
        }
    if (save && (res = lensrt_render_save(render, stage[0])) != LENSRT_SUCCESS) goto fail;
    if (out && !n_ghosts && (res = lensrt_render_write_exr(render, stage[1])) != LENSRT_SUCCESS) goto fail;
    if (out && n_ghosts) {
        // Layers direct and flare (the ghosts kept); every ghost skipped: direct alone
        lensrt_exr_layer layers[2] = {LENSRT_EXR_LAYER_INIT, LENSRT_EXR_LAYER_INIT};
        layers[0].name = "direct";
        layers[0].renders = kept;
        layers[0].n_renders = 1;
        layers[1].name = "flare";
        layers[1].renders = kept + 1;
        layers[1].n_renders = n_kept - 1;
        if ((res = lensrt_layers_write_exr(layers, n_kept > 1 ? 2 : 1, stage[1])) != LENSRT_SUCCESS) goto fail;
    }
    if (png && (res = lensrt_renders_write_png(kept, n_kept, stage[2], decades)) != LENSRT_SUCCESS) goto fail;
    for (i = 0; i < 3; i++) {
        struct stat tst;
        if (!targets[i]) continue;
        // The target's permission bits, as the library keeps them when it replaces a file
        if (stat(targets[i], &tst) == 0 && S_ISREG(tst.st_mode)) chmod(stage[i], tst.st_mode & 07777);
        if (rename(stage[i], targets[i]) != 0) {
            fprintf(stderr, "lensrt-psf: cannot rename '%s' to '%s': %s\n", stage[i], targets[i], strerror(errno));
            rc = 1;
            goto done;
        }
        stage[i][0] = '\0';
    }
    if (cells && used_kind == 2)
        printf("Fourier error estimate: %.3g%% relative L2 (%d nodes against %d)\n", 100.0 * mc_error, cells_rings,
               (int)ceil(LENSRT_FOURIER_FINER * cells_rings));
    else if (cells)
        printf("Cells error estimate: %.3g%% relative L2 (%d rings against %d)\n", 100.0 * mc_error, cells_rings,
               cells_rings / 2);
    else if (estimate && mc_error >= 0)
        printf("Monte Carlo error estimate: %.3g%% relative L2 (two independent halves, %llu samples per wavelength)\n",
               100.0 * mc_error, (unsigned long long)mc_samples);
    else if (estimate)
        printf("Monte Carlo error estimate: none, the image is black\n");
    rc = 0;
    goto done;
fail_input:
    rc = res == LENSRT_ERROR_NO_DEVICE || res == LENSRT_ERROR_UNSUPPORTED ? 3 : 2;
fail:
    fprintf(stderr, "lensrt-psf: %s\n", lensrt_context_last_error(ctx)[0] ? lensrt_context_last_error(ctx)
                                                                        : lensrt_result_string(res));
done:
    for (i = 0; i < 3; i++)
        if (stage[i][0]) remove(stage[i]);
    if (tmp_a[0]) remove(tmp_a);
    if (tmp_b[0]) remove(tmp_b);
    free(img_a);
    free(img_b);
    free(img_all);
    for (i = 0; i < n_ghosts; i++) {
        lensrt_render_destroy(renders[1 + i]);
        lensrt_lens_destroy(ctx, ghost_lens[i]);
    }
    lensrt_render_destroy(render_b);
    lensrt_render_destroy(render);
    lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
done_args:
    for (i = n_ghost_args; i < n_ghosts; i++) free(ghost_paths[i]);
    return rc;
}
