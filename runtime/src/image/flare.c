/* The flare layers of an image through the lens (lensrt.h, "an image through the lens";
 * the shared object in image.h).
 *
 *   sources  the input's pixels whose channel sum exceeds the threshold, grouped into
 *            8-connected components by a breadth-first fill (a queue, no recursion);
 *            each sits at its power-weighted field point (the tangents of its pixels'
 *            fields averaged, then atan) and carries its channels' sums V_c; the
 *            brightest max_sources are kept
 *   renders  per source and ghost table: a unit light at the source's field, the bank's
 *            wavelengths, on a coarse grid of flare_downsample frame pixels per side
 *            that covers the frame, cut down to the ghost's footprint (a ghost whose
 *            footprint misses the frame is not rendered), integrated as lensrt-psf's
 *            --integrator auto does: the Fourier integrator refined while it helps,
 *            then the cells integrator
 *   layers   each coarse image bilinearly interpolated between its pixel centres onto
 *            the frame's pixels (zero outside its window) and added to the ghost's
 *            layer, channel c weighted by V_c over the axis PSF's power in that channel
 *            (the direct layer's normalisation) */
#include "../internal.h"
#include "image.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

/* The description's defaults (lensrt.h). */
#define FLARE_MAX_SOURCES 16
#define FLARE_THRESHOLD_FRACTION (1.0 / 16.0)
#define FLARE_TARGET_ERROR 0.02
#define FLARE_DOWNSAMPLE 4

/* lensrt-psf's --integrator auto (runtime/tools/lensrt-psf.c), with its defaults: the
 * Fourier rule refined up to FOURIER_MAX_NODES per side, given up as soon as refining
 * cannot help (an estimate of FOURIER_UNRESOLVED or more says the rule does not resolve
 * the phase at all, or a refinement did not halve it); then cells from CELLS_RINGS,
 * refined up to CELLS_MAX_RINGS. */
#define FOURIER_MAX_NODES 2730
#define FOURIER_UNRESOLVED 0.3
#define CELLS_RINGS 32
#define CELLS_MAX_RINGS 1024

/* A ghost's footprint is widened by this many wavelengths x f-number of diffraction
 * (its edge has fallen to about 1e-4 of the image's level there; lensrt.h,
 * lensrt_render_footprint), as lensrt-psf's --flares does. */
#define FOOTPRINT_MARGIN 30.0

#define DEGREES 57.295779513082320876798 /* per radian */

/* A source while the sources are sought: its power, its tangent-weighted sums, its
 * pixels and which row of image_flare.light holds its channels' sums. */
struct flare_source {
    double power, sum_tx, sum_ty;
    int32_t pixels;
    int slot;
};

struct image_flare {
    /* The description's values, defaults applied */
    int max_sources, downsample;
    double target;
    lensrt_aperture aperture;    /* the ghost renders' */
    double pitch_x, pitch_y;     /* the frame's pixels (the bank's pitch x oversample), mm */
    /* The coarse grid: coarse_w x coarse_h pixels of downsample x pitch, centred on the
     * frame's centre. Frame column i sits between coarse columns col_k[i] and
     * col_k[i] + 1, at col_t[i] from the first (rows likewise, row 0 at the top). */
    int coarse_w, coarse_h;
    int *col_k, *row_k;
    double *col_t, *row_t;
    /* Source search: a flag per pixel (above the threshold and in no source yet) and
     * the queue of the fill, which ends holding the whole source's pixels */
    unsigned char *mark;
    size_t *queue;
    struct flare_source *kept;   /* the brightest so far, brightest first */
    int n_kept;
    double *light;               /* max_sources x n_channels: V_c by slot */
    double *coef;                /* n_channels x n_wavelengths: one source's weights */
    double *axis;                /* n_channels: sum_l w[c][l] axis_power[l] */
    double *pixel;               /* n_wavelengths: one frame pixel of a ghost image */
};

/* -------------------------------------------------------------------- set-up ----- */

void image_flare_destroy(struct lensrt_image_s *im)
{
    struct image_flare *f = im ? im->flare : NULL;
    if (!f) return;
    lensrt_free(im->ctx, f->col_k);
    lensrt_free(im->ctx, f->row_k);
    lensrt_free(im->ctx, f->col_t);
    lensrt_free(im->ctx, f->row_t);
    lensrt_free(im->ctx, f->mark);
    lensrt_free(im->ctx, f->queue);
    lensrt_free(im->ctx, f->kept);
    lensrt_free(im->ctx, f->light);
    lensrt_free(im->ctx, f->coef);
    lensrt_free(im->ctx, f->axis);
    lensrt_free(im->ctx, f->pixel);
    lensrt_free(im->ctx, f);
    im->flare = NULL;
}

/* Where frame pixel n (of `frame` per axis) falls between the coarse grid's pixel
 * centres (of `coarse`, `ds` frame pixels each, both grids centred on the same point):
 * u = (n + 0.5 - frame / 2) / ds + coarse / 2 - 0.5 in coarse pixels. */
static void coarse_position(int n, int frame, int coarse, int ds, int *k, double *t)
{
    double u = ((double)n + 0.5 - 0.5 * frame) / ds + 0.5 * coarse - 0.5, fl = floor(u);
    *k = (int)fl;
    *t = u - fl;
}

lensrt_result image_flare_create(struct lensrt_image_s *im)
{
    const lensrt_image_desc *d = &im->desc;
    lensrt_context ctx = im->ctx;
    lensrt_bank_info bi = LENSRT_BANK_INFO_INIT;
    struct image_flare *f;
    lensrt_result res;
    int n;
    im->flare = NULL;
    if (d->n_ghosts == 0) return LENSRT_SUCCESS;
    if (!d->bank) return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "image: bank: NULL (its pitch and f-numbers "
                                     "place the ghost renders)");
    if ((res = lensrt_bank_get_info(d->bank, &bi)) != LENSRT_SUCCESS) return res;
    if (!(f = lensrt_calloc(ctx, 1, sizeof *f)))
        return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "image: out of memory for the flare's state");
    im->flare = f;
    f->max_sources = d->max_sources > 0 ? d->max_sources : FLARE_MAX_SOURCES;
    f->downsample = d->flare_downsample > 0 ? d->flare_downsample : FLARE_DOWNSAMPLE;
    f->target = d->flare_target_error > 0 ? d->flare_target_error : FLARE_TARGET_ERROR;
    // The frame's pitch: the bank's times oversample (image.c; a caller that fills the
    // object without it, the bank's)
    f->pitch_x = im->pitch_x_mm > 0.0 ? im->pitch_x_mm : bi.pixel_x_mm;
    f->pitch_y = im->pitch_y_mm > 0.0 ? im->pitch_y_mm : bi.pixel_y_mm;
    // The ghosts' aperture: the description's, or (radius and f-number both 0) a circle
    // at the bank slice's f-number
    f->aperture = d->aperture;
    if (d->aperture.radius_mm == 0 && d->aperture.f_number == 0) {
        memset(&f->aperture, 0, sizeof f->aperture);
        f->aperture.shape = LENSRT_APERTURE_CIRCLE;
        f->aperture.f_number = d->f_number > 0 ? d->f_number : bi.n_f_numbers > 0 ? bi.f_numbers[0] : 0.0;
    }
    // The coarse grid covers the frame: ceil(frame / downsample) coarse pixels per axis
    f->coarse_w = (int)((d->width + f->downsample - 1) / f->downsample);
    f->coarse_h = (int)((d->height + f->downsample - 1) / f->downsample);
    f->col_k = lensrt_calloc(ctx, (size_t)d->width, sizeof *f->col_k);
    f->col_t = lensrt_calloc(ctx, (size_t)d->width, sizeof *f->col_t);
    f->row_k = lensrt_calloc(ctx, (size_t)d->height, sizeof *f->row_k);
    f->row_t = lensrt_calloc(ctx, (size_t)d->height, sizeof *f->row_t);
    f->mark = lensrt_calloc(ctx, im->plane, 1);
    f->queue = lensrt_calloc(ctx, im->plane, sizeof *f->queue);
    f->kept = lensrt_calloc(ctx, (size_t)f->max_sources, sizeof *f->kept);
    f->light = lensrt_calloc(ctx, (size_t)f->max_sources * (size_t)d->n_channels, sizeof *f->light);
    f->coef = lensrt_calloc(ctx, (size_t)d->n_channels * (size_t)im->n_wavelengths, sizeof *f->coef);
    f->axis = lensrt_calloc(ctx, (size_t)d->n_channels, sizeof *f->axis);
    f->pixel = lensrt_calloc(ctx, (size_t)im->n_wavelengths, sizeof *f->pixel);
    if (!f->col_k || !f->col_t || !f->row_k || !f->row_t || !f->mark || !f->queue || !f->kept || !f->light ||
        !f->coef || !f->axis || !f->pixel) {
        image_flare_destroy(im);
        return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "image: out of memory for the flare's state (%d x %d pixels)",
                           (int)d->width, (int)d->height);
    }
    for (n = 0; n < d->width; n++) coarse_position(n, d->width, f->coarse_w, f->downsample, &f->col_k[n], &f->col_t[n]);
    for (n = 0; n < d->height; n++) coarse_position(n, d->height, f->coarse_h, f->downsample, &f->row_k[n], &f->row_t[n]);
    return LENSRT_SUCCESS;
}

/* ------------------------------------------------------------------- sources ----- */

/* Pixel p's light: its channels' sum. */
static double channel_sum(const float *input, size_t plane, int n_channels, size_t p)
{
    double s = 0.0;
    int c;
    for (c = 0; c < n_channels; c++) s += (double)input[(size_t)c * plane + p];
    return s;
}

/* Offer a source whose pixels are queue[0 .. n - 1] to the kept list: kept when there is
 * room or it outshines the dimmest (equal powers keep the order found), its channels'
 * sums computed then. */
static void offer_source(struct lensrt_image_s *im, const float *input, const struct flare_source *s, size_t n)
{
    struct image_flare *f = im->flare;
    const int nc = im->desc.n_channels;
    int pos, slot, c;
    size_t k;
    if (f->n_kept == f->max_sources && !(s->power > f->kept[f->n_kept - 1].power)) return;
    for (pos = f->n_kept; pos > 0 && f->kept[pos - 1].power < s->power; pos--) continue;
    // The slot of the source that falls off the end, or a new one
    slot = f->n_kept == f->max_sources ? f->kept[f->n_kept - 1].slot : f->n_kept;
    if (f->n_kept < f->max_sources) f->n_kept++;
    memmove(&f->kept[pos + 1], &f->kept[pos], (size_t)(f->n_kept - 1 - pos) * sizeof *f->kept);
    f->kept[pos] = *s;
    f->kept[pos].slot = slot;
    for (c = 0; c < nc; c++) {
        double v = 0.0;
        const float *plane = input + (size_t)c * im->plane;
        for (k = 0; k < n; k++) v += (double)plane[f->queue[k]];
        f->light[(size_t)slot * (size_t)nc + (size_t)c] = v;
    }
}

/* The sources of the input: pixels above the threshold, 8-connected, each filled from
 * its first pixel in row-major order by a queue that ends holding all its pixels. */
static void find_sources(struct lensrt_image_s *im, const float *input)
{
    struct image_flare *f = im->flare;
    const lensrt_image_desc *d = &im->desc;
    const int w = d->width, h = d->height, nc = d->n_channels;
    double threshold = d->flare_threshold;
    size_t p;
    int i;
    if (!(threshold > 0)) {
        double top = 0.0;
        for (p = 0; p < im->plane; p++) {
            double s = channel_sum(input, im->plane, nc, p);
            if (s > top) top = s;
        }
        threshold = top * FLARE_THRESHOLD_FRACTION;
    }
    for (p = 0; p < im->plane; p++) f->mark[p] = channel_sum(input, im->plane, nc, p) > threshold;
    f->n_kept = 0;
    for (p = 0; p < im->plane; p++) {
        struct flare_source s;
        size_t head = 0, tail = 0;
        if (!f->mark[p]) continue;
        memset(&s, 0, sizeof s);
        f->mark[p] = 0;
        f->queue[tail++] = p;
        while (head < tail) {
            const size_t q = f->queue[head++];
            const int qi = (int)(q % (size_t)w), qj = (int)(q / (size_t)w);
            const double power = channel_sum(input, im->plane, nc, q);
            // The pixel's centre on the sensor and the tangents of its field (lensrt.h)
            const double x = d->center_x_mm + ((double)qi + 0.5 - 0.5 * w) * f->pitch_x;
            const double y = d->center_y_mm + (0.5 * h - (double)qj - 0.5) * f->pitch_y;
            int di, dj;
            s.power += power;
            s.sum_tx += power * x / d->focal_x_mm;
            s.sum_ty += power * y / im->focal_y_mm;
            s.pixels++;
            for (dj = -1; dj <= 1; dj++)
                for (di = -1; di <= 1; di++) {
                    const int ni = qi + di, nj = qj + dj;
                    size_t nq;
                    if (ni < 0 || ni >= w || nj < 0 || nj >= h) continue;
                    nq = (size_t)nj * (size_t)w + (size_t)ni;
                    if (!f->mark[nq]) continue;
                    f->mark[nq] = 0;
                    f->queue[tail++] = nq;
                }
        }
        offer_source(im, input, &s, tail);
    }
    // The kept sources, brightest first, for the caller (lensrt_image_get_source)
    for (i = 0; i < f->n_kept; i++) {
        const struct flare_source *s = &f->kept[i];
        lensrt_image_source *o = &im->sources[i];
        memset(o, 0, sizeof *o);
        o->struct_size = sizeof *o;
        o->field_x_deg = atan(s->sum_tx / s->power) * DEGREES;
        o->field_y_deg = atan(s->sum_ty / s->power) * DEGREES;
        o->power = s->power;
        o->pixels = s->pixels;
    }
    im->stats.n_sources = f->n_kept;
}

/* -------------------------------------------------------------------- renders ----- */

/* A ghost render's failure, naming the source (its index and field point) and the
 * ghost, with the library's own message after it. */
static lensrt_result ghost_fail(struct lensrt_image_s *im, lensrt_result res, int s, int g, const char *what)
{
    char why[LENSRT_ERROR_SIZE];
    lensrt_lens_info gi = LENSRT_LENS_INFO_INIT;
    const lensrt_image_source *src = &im->sources[s];
    snprintf(why, sizeof why, "%s", lensrt_context_last_error(im->ctx));
    lensrt_lens_get_info(im->ghosts[g], &gi);
    return lensrt_fail(im->ctx, res, "image: flare: source %d (field %g, %g deg) through ghost %d (%s): %s%s%s", s,
                       src->field_x_deg, src->field_y_deg, g, gi.ghost_label ? gi.ghost_label : "", what,
                       why[0] ? ": " : "", why);
}

/* Integrate a render to `target` as lensrt-psf's --integrator auto does: the Fourier
 * rule for the target (lensrt_render_fourier_nodes), refined by LENSRT_FOURIER_FINER
 * while that helps; where a clip cuts the aperture (LENSRT_ERROR_UNSUPPORTED), the rule
 * would exceed FOURIER_MAX_NODES or its estimate stays above the target, the cells
 * integrator from CELLS_RINGS, refined from its estimate (the error falls as
 * 1 / rings^2) up to CELLS_MAX_RINGS. *err: the estimate of the image the render keeps
 * (the last integral's); *reached: it is within the target. A first rule above
 * FOURIER_MAX_NODES goes to cells at once, where lensrt-psf would try it (ghost 0-2 on
 * a frame-wide window asked for 4095 per side, 6 x 4095^2 nodes, and ran out of 24 GB). */
static lensrt_result integrate_auto(lensrt_render r, double target, double *err, int *reached)
{
    lensrt_result res;
    int32_t nodes = 0;
    int rings = CELLS_RINGS;
    double last = -1.0;
    *reached = 0;
    res = lensrt_render_fourier_nodes(r, target, &nodes);
    while (res == LENSRT_SUCCESS && nodes <= FOURIER_MAX_NODES) {
        if ((res = lensrt_render_integrate_fourier(r, nodes, err, NULL, NULL)) != LENSRT_SUCCESS) break;
        if (*err <= target) {
            *reached = 1;
            return LENSRT_SUCCESS;
        }
        // The next rule's estimate takes 1.25 times its nodes again
        if ((int)ceil(LENSRT_FOURIER_FINER * ceil(LENSRT_FOURIER_FINER * nodes)) > FOURIER_MAX_NODES ||
            *err >= FOURIER_UNRESOLVED || (last >= 0 && *err > 0.5 * last))
            break;
        last = *err;
        nodes = (int32_t)ceil(LENSRT_FOURIER_FINER * nodes);
    }
    if (res != LENSRT_SUCCESS && res != LENSRT_ERROR_UNSUPPORTED) return res;
    for (;;) {
        double grow;
        if ((res = lensrt_render_integrate(r, rings, err, NULL, NULL)) != LENSRT_SUCCESS) return res;
        if (*err <= target) {
            *reached = 1;
            return LENSRT_SUCCESS;
        }
        // The mesh that should reach the target with 10% to spare: 1.25 to 2 times the
        // rings, doubling from 1.6 on (a doubling reuses the last two meshes)
        grow = 1.1 * sqrt(*err / target);
        grow = grow > 1.6 ? 2.0 : grow < 1.25 ? 1.25 : grow;
        if ((int)ceil(rings * grow) > CELLS_MAX_RINGS) return LENSRT_SUCCESS;
        rings = (int)ceil(rings * grow);
    }
}

/* Add a coarse ghost image (n_wavelengths planes of cw x ch coarse pixels, the coarse
 * grid's pixels x0.. and y0..) to a ghost layer: each frame pixel takes the bilinear
 * interpolation between the four coarse pixel centres around it (a coarse pixel outside
 * the window counting 0), and channel c adds sum_l coef[c][l] G_l. */
static void add_ghost(struct lensrt_image_s *im, const float *img, int x0, int y0, int cw, int ch, float *layer)
{
    const struct image_flare *f = im->flare;
    const int w = im->desc.width, h = im->desc.height, nc = im->desc.n_channels, nl = im->n_wavelengths;
    const size_t cplane = (size_t)cw * (size_t)ch;
    int i, j, c, l;
    for (j = 0; j < h; j++) {
        const int kj = f->row_k[j] - y0;
        const double tj = f->row_t[j];
        if (kj < -1 || kj >= ch) continue;
        for (i = 0; i < w; i++) {
            const int ki = f->col_k[i] - x0;
            const double ti = f->col_t[i];
            const size_t p = (size_t)j * (size_t)w + (size_t)i;
            // The four neighbours' weights, 0 for one outside the window (its index then
            // clamped into the window, only to stay valid)
            const int in_l = ki >= 0, in_r = ki + 1 < cw, in_t = kj >= 0, in_b = kj + 1 < ch;
            const double w00 = in_l && in_t ? (1 - ti) * (1 - tj) : 0.0, w10 = in_r && in_t ? ti * (1 - tj) : 0.0;
            const double w01 = in_l && in_b ? (1 - ti) * tj : 0.0, w11 = in_r && in_b ? ti * tj : 0.0;
            const size_t c0 = (size_t)(in_l ? ki : 0), c1 = (size_t)(in_r ? ki + 1 : cw - 1);
            const size_t r0 = (size_t)(in_t ? kj : 0) * (size_t)cw, r1 = (size_t)(in_b ? kj + 1 : ch - 1) * (size_t)cw;
            if (ki < -1 || ki >= cw || (w00 == 0 && w10 == 0 && w01 == 0 && w11 == 0)) continue;
            for (l = 0; l < nl; l++) {
                const float *g = img + (size_t)l * cplane;
                f->pixel[l] = w00 * g[r0 + c0] + w10 * g[r0 + c1] + w01 * g[r1 + c0] + w11 * g[r1 + c1];
            }
            for (c = 0; c < nc; c++) {
                const double *k = f->coef + (size_t)c * (size_t)nl;
                double v = 0.0;
                for (l = 0; l < nl; l++) v += k[l] * f->pixel[l];
                layer[(size_t)c * im->plane + p] += (float)v;
            }
        }
    }
}

/* The index of the coarse pixel holding coordinate v (in coarse pixels from the grid's
 * first edge), clamped to lo .. hi. */
static int coarse_index(double v, int lo, int hi)
{
    if (!(v >= lo)) return lo;
    if (v >= hi) return hi;
    return (int)floor(v);
}

/* Source s (kept index) through ghost g, added to the ghost's layer: skipped (nothing
 * added, *rendered 0) when the ghost's footprint misses the frame. */
static lensrt_result render_ghost(struct lensrt_image_s *im, int s, int g, float *layer, int *rendered)
{
    struct image_flare *f = im->flare;
    const lensrt_image_desc *d = &im->desc;
    const int nc = d->n_channels, nl = im->n_wavelengths, slot = f->kept[s].slot;
    const double px = f->pitch_x * f->downsample, py = f->pitch_y * f->downsample;
    lensrt_render_desc rd = LENSRT_RENDER_DESC_INIT;
    lensrt_light light = LENSRT_LIGHT_INIT;
    lensrt_render r = NULL;
    lensrt_result res;
    double box[4], err = -1.0, t0;
    int x0 = 0, y0 = 0, x1 = f->coarse_w - 1, y1 = f->coarse_h - 1, reached = 0, c, l;
    float *img;
    size_t count;
    *rendered = 0;
    light.field_x_deg = im->sources[s].field_x_deg;
    light.field_y_deg = im->sources[s].field_y_deg;
    light.distance_mm = d->distance_mm;
    light.intensity = 1.0;
    rd.lens = im->ghosts[g];
    rd.lights = &light;
    rd.n_lights = 1;
    rd.wavelengths_nm = im->wavelengths_nm;
    rd.n_wavelengths = nl;
    rd.aperture = f->aperture;
    rd.pixel_filter = LENSRT_PIXEL_FILTER_BOX;
    rd.sensor.focus_offset_mm = d->focus_offset_mm;
    // The footprint first, from a render of one coarse pixel (the footprint does not
    // depend on the window; no sums of the whole grid are allocated for it)
    rd.sensor.width = rd.sensor.height = 1;
    rd.sensor.width_mm = px;
    rd.sensor.height_mm = py;
    rd.sensor.center_x_mm = d->center_x_mm;
    rd.sensor.center_y_mm = d->center_y_mm;
    if ((res = lensrt_render_create(im->ctx, &rd, &r)) != LENSRT_SUCCESS) return ghost_fail(im, res, s, g, "render");
    if (lensrt_render_footprint(r, box) == LENSRT_SUCCESS) {
        // Widened by the diffraction of an edge at the longest wavelength, against the
        // frame's extent; a footprint the library cannot find keeps the whole grid
        lensrt_render_stats st = LENSRT_RENDER_STATS_INIT;
        const double hw = 0.5 * d->width * f->pitch_x, hh = 0.5 * d->height * f->pitch_y;
        double lambda = 0.0, m;
        lensrt_render_get_stats(r, &st);
        for (l = 0; l < nl; l++)
            if (im->wavelengths_nm[l] > lambda) lambda = im->wavelengths_nm[l];
        m = FOOTPRINT_MARGIN * lambda * 1e-6 * st.f_number;
        if (box[0] > box[1] || box[1] + m < d->center_x_mm - hw || box[0] - m > d->center_x_mm + hw ||
            box[3] + m < d->center_y_mm - hh || box[2] - m > d->center_y_mm + hh) {
            lensrt_render_destroy(r);
            return LENSRT_SUCCESS;
        }
        // The coarse pixels the widened footprint meets (row 0 at the top, +y)
        x0 = coarse_index((box[0] - m - d->center_x_mm) / px + 0.5 * f->coarse_w, 0, f->coarse_w - 1);
        x1 = coarse_index((box[1] + m - d->center_x_mm) / px + 0.5 * f->coarse_w, 0, f->coarse_w - 1);
        y0 = coarse_index(0.5 * f->coarse_h - (box[3] + m - d->center_y_mm) / py, 0, f->coarse_h - 1);
        y1 = coarse_index(0.5 * f->coarse_h - (box[2] - m - d->center_y_mm) / py, 0, f->coarse_h - 1);
    }
    lensrt_render_destroy(r);
    r = NULL;
    // The render of those coarse pixels, placed on the coarse grid
    rd.sensor.width = x1 - x0 + 1;
    rd.sensor.height = y1 - y0 + 1;
    rd.sensor.width_mm = rd.sensor.width * px;
    rd.sensor.height_mm = rd.sensor.height * py;
    rd.sensor.center_x_mm = d->center_x_mm + (0.5 * (x0 + x1 + 1) - 0.5 * f->coarse_w) * px;
    rd.sensor.center_y_mm = d->center_y_mm + (0.5 * f->coarse_h - 0.5 * (y0 + y1 + 1)) * py;
    t0 = lensrt_seconds();
    if ((res = lensrt_render_create(im->ctx, &rd, &r)) != LENSRT_SUCCESS) return ghost_fail(im, res, s, g, "render");
    if ((res = integrate_auto(r, f->target, &err, &reached)) != LENSRT_SUCCESS) {
        lensrt_render_destroy(r);
        return ghost_fail(im, res, s, g, "integral");
    }
    *rendered = 1;
    if (err > im->stats.worst_flare_error) im->stats.worst_flare_error = err;
    if (!reached)
        lensrt_log(im->ctx, LENSRT_LOG_WARNING, "image: flare: source %d through ghost %d: the error estimate %.3g%% is "
                   "above flare_target_error %.3g%% at %d rings (the image is kept)", s, g, 100.0 * err,
                   100.0 * f->target, CELLS_MAX_RINGS);
    count = (size_t)nl * (size_t)rd.sensor.width * (size_t)rd.sensor.height;
    if (!(img = lensrt_alloc(im->ctx, count * sizeof *img))) {
        lensrt_render_destroy(r);
        return lensrt_fail(im->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "image: flare: out of memory for a %d x %d ghost image",
                           (int)rd.sensor.width, (int)rd.sensor.height);
    }
    if ((res = lensrt_render_image(r, img, count)) != LENSRT_SUCCESS) {
        lensrt_free(im->ctx, img);
        lensrt_render_destroy(r);
        return ghost_fail(im, res, s, g, "image");
    }
    {
        lensrt_render_stats st = LENSRT_RENDER_STATS_INIT;
        lensrt_render_get_stats(r, &st);
        lensrt_log(im->ctx, LENSRT_LOG_INFO, "image: flare: source %d through ghost %d: %d x %d coarse pixels from (%d, %d), "
                   "%s %d, error estimate %.3g%%, %.2f s", s, g, (int)rd.sensor.width, (int)rd.sensor.height, x0,
                   y0, st.fourier_nodes ? "Fourier nodes" : "cells rings", st.fourier_nodes ? (int)st.fourier_nodes :
                   (int)st.cells_rings, 100.0 * err, lensrt_seconds() - t0);
    }
    lensrt_render_destroy(r);
    // Channel c's weights: V_c w[c][l] / sum_l w[c][l] axis_power[l]
    for (c = 0; c < nc; c++)
        for (l = 0; l < nl; l++)
            f->coef[(size_t)c * (size_t)nl + (size_t)l] = f->light[(size_t)slot * (size_t)nc + (size_t)c] *
                im->channel_weights[(size_t)c * (size_t)nl + (size_t)l] / f->axis[c];
    add_ghost(im, img, x0, y0, (int)rd.sensor.width, (int)rd.sensor.height, layer);
    lensrt_free(im->ctx, img);
    return LENSRT_SUCCESS;
}

/* ------------------------------------------------------------------------ run ----- */

lensrt_result image_flare_run(struct lensrt_image_s *im, const float *input, float *ghosts)
{
    const double start = lensrt_seconds();
    const size_t layer = (size_t)im->desc.n_channels * im->plane;
    lensrt_result res = LENSRT_SUCCESS;
    int s, g, c;
    im->stats.n_sources = 0;
    im->stats.n_ghost_renders = 0;
    im->stats.worst_flare_error = -1.0;
    im->stats.seconds_flares = 0.0;
    if (im->desc.n_ghosts == 0 || !im->flare) return LENSRT_SUCCESS;
    // Each channel's axis power, the denominator of its weights
    for (c = 0; c < im->desc.n_channels; c++) {
        const double *w = im->channel_weights + (size_t)c * (size_t)im->n_wavelengths;
        double sum = 0.0;
        int l;
        for (l = 0; l < im->n_wavelengths; l++) sum += w[l] * im->axis_power[l];
        if (!(sum > 0.0) || !isfinite(sum))
            return lensrt_fail(im->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "image: channel %d: its weights times the axis "
                               "PSF's power sum to %g: no flare can be scaled to it", c, sum);
        im->flare->axis[c] = sum;
    }
    memset(ghosts, 0, (size_t)im->desc.n_ghosts * layer * sizeof *ghosts);
    find_sources(im, input);
    for (s = 0; s < im->flare->n_kept && res == LENSRT_SUCCESS; s++)
        for (g = 0; g < im->desc.n_ghosts && res == LENSRT_SUCCESS; g++) {
            int rendered = 0;
            res = render_ghost(im, s, g, ghosts + (size_t)g * layer, &rendered);
            im->stats.n_ghost_renders += rendered;
        }
    im->stats.seconds_flares = lensrt_seconds() - start;
    return res;
}
