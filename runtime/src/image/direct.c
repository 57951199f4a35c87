/* The direct layer (image.h; lensrt.h, LENSRT_IMAGE_DIRECT): every pixel's light through
 * its own field point's PSF, as a sum of FFT convolutions, one per bank node.
 *
 * 1. Nodes and weights. The slice's field grid (field_x_deg x field_y_deg, with its
 *    mirror image where desc.mirror asks: image.h) is the set of nodes. Input pixel
 *    (i, j) sees the pinhole field (atan(x / f_x), atan(y / f_y)), so in t = tan(field)
 *    its coordinates are simply (x / f_x, y / f_y): linear in i and j.
 *    Its weight at node (a, b) is the bilinear hat function over the grid in t,
 *    hat_a(t_x) hat_b(t_y): a partition of unity, continuous across the cells (no
 *    seams), separable (one weight per column and one per row), non-zero at <= 4 nodes.
 * 2. Warp. The pixel's light lands where the lens images its field point: the chief
 *    point at the reference wavelength (the bank's nearest to 550 nm), interpolated from
 *    the nodes' chief points by the bank reader's own rule, the Lagrange cubic in
 *    (t_x, t_y) through 4 x 4 nodes (lensrt_bank_psf: exact without distortion, a cubic
 *    in it). Node k's layer L_k receives the pixel's value times its weight at k,
 *    splatted at the landing point by the quadratic B-spline's 3 x 3 taps (they sum to
 *    1: power is kept, and so is the centroid; their spread is 1/4 squared pixels per
 *    axis wherever the point lands, undone in step 3).
 * 3. Kernels. Node k's kernel for channel c is
 *        K = S * sum_l w[c][l] PSF_{k,l}(shifted by chief_{k,l} - chief_{k,ref}) / norm_c,
 *        norm_c = sum_l w[c][l] axis_power[l],
 *    PSF_{k,l} being lensrt_bank_psf at the node's own field and wavelength l (the
 *    node's channel bit for bit), so a lossless axis keeps a pixel's value and
 *    vignetting and transmission come from the PSFs' own power. The sub-pixel shifts
 *    (lateral colour, and half a pixel along an axis of even PSF size, whose pixel
 *    centres lie half a pixel off its chief point) are B-spline taps too. S (taps.c)
 *    undoes, to second order in the pitch, the constant spread the two sets of taps add,
 *    less the one a pixel's box has more than the point it is splatted as. Built once,
 *    at creation.
 * 4. Convolution. Each node's layer covers only the landing points of its pixels (its
 *    <= 2 x 2 cells, warped); it is convolved with the kernel by FFT, padded to the full
 *    linear size (no wrap-around), two channels packed in one complex transform, and the
 *    part that falls on the frame added to the direct layer. Nodes run in parallel in
 *    batches (OpenMP), each into a buffer of its own slot, the buffers added in node
 *    order: the result does not depend on the number of threads. */
#include "image.h"

#include "../internal.h"
#include "fft.h"
#include "taps.h"

#include <math.h>
#include <string.h>
#ifdef LENSRT_OPENMP
#include <omp.h>
#endif

#define DIRECT_PI 3.14159265358979323846
#define DIRECT_REFERENCE_NM 550.0
/* Nodes convolved at once (one per thread, at most) */
#define DIRECT_MAX_SLOTS 64

/* One node that receives light: its pixels, rectangles and kernels. */
typedef struct node_part {
    int ix, iy;                 /* its place in the field grid */
    int i0, i1, j0, j1;         /* input pixels of non-zero weight: [i0, i1) x [j0, j1) */
    int sx0, sy0, sw, sh;       /* its layer: pixels (sx0, sy0) .. + (sw, sh) of the frame's grid */
    int ox0, oy0, ow, oh;       /* what its convolution puts on the frame */
    const image_fft_plan *px, *py; /* the transform: px->n x py->n >= (sw + kw - 1) x (sh + kh - 1) */
    float *kernels;             /* n_channels x kh x kw, offset (a - kcx, b - kcy) pixels */
} node_part;

struct image_direct {
    int nx, ny;                 /* the field grid */
    double *tx, *ty;            /* tan of its angles */
    int n_parts;
    node_part *parts;
    int kw, kh, kcx, kcy;       /* the kernels' grid and centre (every node's the same) */
    float *kernels;             /* n_parts x n_channels x kh x kw */
    int *col_cell, *row_cell;   /* hat weights: node cell gets 1 - frac, cell + 1 gets frac */
    double *col_frac, *row_frac;
    float *land;                /* n_channels x per input pixel, its landing point (u, v) in
                                   pixel indices: the channel's own chief point */
    image_fft_plan **plans;     /* every size used, once */
    int n_plans;
    int slots;                  /* nodes done at once */
    size_t max_layer, max_fft, max_out; /* per slot: floats of a layer and an output, complex values */
    float *layer, *out;         /* slots x n_channels x max_layer (max_out) */
    double *data, *kbuf, *work; /* slots x 2 max_fft */
};

/* ---------------------------------------------------------------- weights ----- */

/* The cell of a grid in t (ascending) holding t and the fraction along it: node `cell`
 * gets 1 - frac, node cell + 1 gets frac (a one-value grid: cell 0, frac 0). */
static void hat_cell(const double *g, int n, double t, int *cell, double *frac)
{
    int lo = 0, hi = n - 1;
    if (n == 1 || t <= g[0]) {
        *cell = 0;
        *frac = 0.0;
        return;
    }
    if (t >= g[n - 1]) {
        *cell = n - 2;
        *frac = 1.0;
        return;
    }
    while (hi - lo > 1) {
        const int mid = (lo + hi) / 2;
        if (g[mid] <= t) lo = mid;
        else hi = mid;
    }
    *cell = lo;
    *frac = (t - g[lo]) / (g[lo + 1] - g[lo]);
}

/* The hat weight of node a at a column or row of that cell and fraction. */
static double hat_weight(int a, int cell, double frac)
{
    return a == cell ? 1.0 - frac : a == cell + 1 ? frac : 0.0;
}

/* The bank reader's field weights (io/bank.c, field_weights), in t: the Lagrange
 * polynomial through 4 grid values around the cell (the cell's two and one on each side,
 * or the 4 nearest at an end; all of them on a grid of fewer). */
static void lagrange(const double *g, int n, int cell, double t, int *first, int *count, double w[4])
{
    const int lo = n <= 4 ? 0 : cell - 1 < 0 ? 0 : cell - 1 > n - 4 ? n - 4 : cell - 1;
    int a, c;
    *first = lo;
    *count = n < 4 ? n : 4;
    for (a = 0; a < *count; a++) {
        w[a] = 1.0;
        for (c = 0; c < *count; c++)
            if (c != a) w[a] *= (t - g[lo + c]) / (g[lo + a] - g[lo + c]);
    }
}

static double tan_deg(double deg)
{
    return tan(deg * (DIRECT_PI / 180.0));
}

/* ---------------------------------------------------------------- set-up ----- */

/* The plan for length n (made once, kept in d->plans); NULL: out of memory. */
static const image_fft_plan *plan_for(lensrt_context ctx, struct image_direct *d, int n)
{
    int i;
    for (i = 0; i < d->n_plans; i++)
        if (d->plans[i]->n == n) return d->plans[i];
    d->plans[d->n_plans] = image_fft_plan_create(ctx, n);
    return d->plans[d->n_plans] ? d->plans[d->n_plans++] : NULL;
}

/* The chief point of node (ix, iy) of the frame's field grid at wavelength l (the bank
 * node's own: exact at a node), and its PSF into psf (the bank's size): a node of the
 * grid's mirror image (image.h, desc.mirror) takes its bank node's PSF mirrored and its
 * chief point's coordinate negated, exactly (each window is centred on its chief point). */
static lensrt_result node_psf(struct lensrt_image_s *im, int ix, int iy, int l, float *psf, size_t count,
                              double chief[2])
{
    lensrt_bank_query q = LENSRT_BANK_QUERY_INIT;
    lensrt_bank_info info = LENSRT_BANK_INFO_INIT;
    lensrt_result res;
    int i, j;
    if ((res = lensrt_bank_get_info(im->desc.bank, &info)) != LENSRT_SUCCESS) return res;
    q.field_x_deg = info.field_x_deg[im->bank_x[ix]];
    q.field_y_deg = info.field_y_deg[im->bank_y[iy]];
    q.wavelength_nm = im->wavelengths_nm[l];
    q.f_number = im->desc.f_number;
    q.focus_offset_mm = im->desc.focus_offset_mm;
    q.distance_mm = im->desc.distance_mm;
    if ((res = lensrt_bank_psf(im->desc.bank, &q, psf, count, chief)) != LENSRT_SUCCESS) return res;
    if (im->sign_x[ix] < 0) {
        chief[0] = -chief[0];
        for (j = 0; j < info.height; j++)
            for (i = 0; i < info.width / 2; i++) {
                float *row = psf + (size_t)j * (size_t)info.width, t = row[i];
                row[i] = row[info.width - 1 - i];
                row[info.width - 1 - i] = t;
            }
    }
    if (im->sign_y[iy] < 0) {
        chief[1] = -chief[1];
        for (j = 0; j < info.height / 2; j++)
            for (i = 0; i < info.width; i++) {
                float *a = psf + (size_t)j * (size_t)info.width + (size_t)i;
                float *b = psf + (size_t)(info.height - 1 - j) * (size_t)info.width + (size_t)i, t = *a;
                *a = *b;
                *b = t;
            }
    }
    return LENSRT_SUCCESS;
}

/* Step 1 and 2's fixed parts: the hat cells of every column and row, and every pixel's
 * landing point in each channel from the nodes' chief points of that channel (chief_ch:
 * ny x nx x n_channels x 2). */
static void set_up_warp(struct lensrt_image_s *im, struct image_direct *d, const lensrt_bank_info *info,
                        const double *chief_ch)
{
    const int w = im->desc.width, h = im->desc.height, nc = im->desc.n_channels;
    const double px = info->pixel_x_mm, py = info->pixel_y_mm;
    int i, j;
    for (i = 0; i < w; i++)
        hat_cell(d->tx, d->nx, (im->desc.center_x_mm + (i + 0.5 - 0.5 * w) * px) / im->desc.focal_x_mm,
                 &d->col_cell[i], &d->col_frac[i]);
    for (j = 0; j < h; j++)
        hat_cell(d->ty, d->ny, (im->desc.center_y_mm + (0.5 * h - j - 0.5) * py) / im->focal_y_mm, &d->row_cell[j],
                 &d->row_frac[j]);
    for (j = 0; j < h; j++) {
        const double ty = (im->desc.center_y_mm + (0.5 * h - j - 0.5) * py) / im->focal_y_mm;
        double wy[4];
        int y0, ny, a, b;
        lagrange(d->ty, d->ny, d->row_cell[j], ty, &y0, &ny, wy);
        for (i = 0; i < w; i++) {
            const double tx = (im->desc.center_x_mm + (i + 0.5 - 0.5 * w) * px) / im->desc.focal_x_mm;
            double wx[4];
            int x0, nx, ch;
            lagrange(d->tx, d->nx, d->col_cell[i], tx, &x0, &nx, wx);
            for (ch = 0; ch < nc; ch++) {
                double cx = 0.0, cy = 0.0;
                float *u = d->land + 2 * ((size_t)ch * im->plane + (size_t)j * (size_t)w + (size_t)i);
                for (b = 0; b < ny; b++)
                    for (a = 0; a < nx; a++) {
                        const size_t node = (size_t)(y0 + b) * (size_t)d->nx + (size_t)(x0 + a);
                        const double *c = chief_ch + 2 * (node * (size_t)nc + (size_t)ch);
                        cx += wy[b] * wx[a] * c[0];
                        cy += wy[b] * wx[a] * c[1];
                    }
                // In pixel indices of the frame's grid (row 0 at +y)
                u[0] = (float)((cx - im->desc.center_x_mm) / px + 0.5 * w - 0.5);
                u[1] = (float)((im->desc.center_y_mm - cy) / py + 0.5 * h - 0.5);
            }
        }
    }
}

/* A part's pixels, layer and output rectangles (0: it has none). */
static int set_up_part(const struct lensrt_image_s *im, const struct image_direct *d, node_part *p)
{
    const int w = im->desc.width, h = im->desc.height;
    double umin = 1e300, umax = -1e300, vmin = 1e300, vmax = -1e300;
    int i, j, c, sx1, sy1;
    p->i0 = p->j0 = -1;
    for (i = 0; i < w; i++)
        if (hat_weight(p->ix, d->col_cell[i], d->col_frac[i]) > 0.0) {
            if (p->i0 < 0) p->i0 = i;
            p->i1 = i + 1;
        }
    for (j = 0; j < h; j++)
        if (hat_weight(p->iy, d->row_cell[j], d->row_frac[j]) > 0.0) {
            if (p->j0 < 0) p->j0 = j;
            p->j1 = j + 1;
        }
    if (p->i0 < 0 || p->j0 < 0) return 0;
    // The landing points' box, one more pixel each side for the B-spline taps, cut to
    // where a kernel can still reach the frame
    for (c = 0; c < im->desc.n_channels; c++)
        for (j = p->j0; j < p->j1; j++)
            for (i = p->i0; i < p->i1; i++) {
                const float *u = d->land + 2 * ((size_t)c * im->plane + (size_t)j * (size_t)w + (size_t)i);
                umin = u[0] < umin ? u[0] : umin;
                umax = u[0] > umax ? u[0] : umax;
                vmin = u[1] < vmin ? u[1] : vmin;
                vmax = u[1] > vmax ? u[1] : vmax;
            }
    p->sx0 = (int)floor(umin + 0.5) - 1;
    p->sy0 = (int)floor(vmin + 0.5) - 1;
    sx1 = (int)floor(umax + 0.5) + 1;
    sy1 = (int)floor(vmax + 0.5) + 1;
    if (p->sx0 < d->kcx - d->kw + 1) p->sx0 = d->kcx - d->kw + 1;
    if (p->sy0 < d->kcy - d->kh + 1) p->sy0 = d->kcy - d->kh + 1;
    if (sx1 > w - 1 + d->kcx) sx1 = w - 1 + d->kcx;
    if (sy1 > h - 1 + d->kcy) sy1 = h - 1 + d->kcy;
    if (sx1 < p->sx0 || sy1 < p->sy0) return 0;
    p->sw = sx1 - p->sx0 + 1;
    p->sh = sy1 - p->sy0 + 1;
    // Its output: layer pixel s and kernel pixel a give frame pixel s + a - kc
    p->ox0 = p->sx0 - d->kcx < 0 ? 0 : p->sx0 - d->kcx;
    p->oy0 = p->sy0 - d->kcy < 0 ? 0 : p->sy0 - d->kcy;
    p->ow = (sx1 + d->kw - 1 - d->kcx > w - 1 ? w - 1 : sx1 + d->kw - 1 - d->kcx) - p->ox0 + 1;
    p->oh = (sy1 + d->kh - 1 - d->kcy > h - 1 ? h - 1 : sy1 + d->kh - 1 - d->kcy) - p->oy0 + 1;
    return p->ow > 0 && p->oh > 0;
}

/* Step 3: a part's kernels (see the top). shifts: n_channels x n_wavelengths x 2 pixel
 * shifts of this node (each wavelength's chief point from its channel's); acc: n_channels x kw x kh scratch, psf: the bank's size. */
static lensrt_result build_kernels(struct lensrt_image_s *im, struct image_direct *d, node_part *p,
                                   const lensrt_bank_info *info, const double *shifts, const int *used,
                                   double *acc, double *line, float *psf)
{
    const int nc = im->desc.n_channels, nl = im->n_wavelengths, bw = info->width, bh = info->height;
    const size_t kn = (size_t)d->kw * (size_t)d->kh, count = (size_t)bw * (size_t)bh;
    const int ox = d->kcx - bw / 2, oy = d->kcy - bh / 2; /* the PSF's pixel (0, 0) on the kernel grid */
    int c, l, i, j;
    double chief[2];
    lensrt_result res;
    memset(acc, 0, (size_t)nc * kn * sizeof(double));
    for (l = 0; l < nl; l++) {
        if (!used[l]) continue;
        if ((res = node_psf(im, p->ix, p->iy, l, psf, count, chief)) != LENSRT_SUCCESS) return res;
        for (c = 0; c < nc; c++) {
            // The PSF moved by (sx, sy) pixels, from the channel's chief point to its own,
            // by the quadratic B-spline's 3 x 3 taps (image_bspline_taps: a constant spread of
            // 1/4 squared pixels per axis, undone with the others by image_sharpen()). A
            // band-limited shift (a phase ramp) rings: these PSFs are box-filtered at the
            // frame's pitch, not band-limited; bilinear taps blur by f(1 - f), which
            // changes with the shift
            const double sx = shifts[2 * ((size_t)c * (size_t)nl + (size_t)l)];
            const double sy = shifts[2 * ((size_t)c * (size_t)nl + (size_t)l) + 1];
            const double wc = im->channel_weights[(size_t)c * (size_t)nl + (size_t)l];
            double tx[3], ty[3];
            int gx, gy, a, b;
            double *k = acc + (size_t)c * kn;
            if (wc == 0.0) continue;
            image_bspline_taps(sx, &gx, tx);
            image_bspline_taps(sy, &gy, ty);
            for (j = 0; j < bh; j++)
                for (i = 0; i < bw; i++) {
                    const double v = wc * (double)psf[(size_t)j * (size_t)bw + (size_t)i];
                    if (v == 0.0) continue;
                    for (b = 0; b < 3; b++)
                        for (a = 0; a < 3; a++) {
                            // The kernel grid is padded by the largest shift and the taps'
                            // and sharpening's reach (set_up_chiefs): none falls off it
                            const int x = i + ox + gx + a, y = j + oy + gy + b;
                            k[(size_t)y * (size_t)d->kw + (size_t)x] += tx[a] * ty[b] * v;
                        }
                }
        }
    }
    for (c = 0; c < nc; c++) image_sharpen(acc + (size_t)c * kn, d->kw, d->kh, line);
    // Each channel divided by its spectrum's power on the axis
    for (c = 0; c < nc; c++) {
        double norm = 0.0;
        size_t o;
        for (l = 0; l < nl; l++) norm += im->channel_weights[(size_t)c * (size_t)nl + (size_t)l] * im->axis_power[l];
        for (o = 0; o < kn; o++) p->kernels[(size_t)c * kn + o] = (float)(acc[(size_t)c * kn + o] / norm);
    }
    return LENSRT_SUCCESS;
}

/* The scratch of the kernels' set-up (freed at its end). */
typedef struct kernel_scratch {
    double *shifts, *acc, *line;
    float *psf;
    int *used;
} kernel_scratch;

static void free_scratch(lensrt_context ctx, kernel_scratch *s)
{
    lensrt_free(ctx, s->shifts);
    lensrt_free(ctx, s->acc);
    lensrt_free(ctx, s->line);
    lensrt_free(ctx, s->psf);
    lensrt_free(ctx, s->used);
}

/* Which wavelengths any channel uses, the reference one, every node's chief points
 * (chief: ny x nx x n_wavelengths x 2) and the kernels' grid: the bank's PSF size, or,
 * when any channel needs a shift, a transform size padded by the largest shift. */
static lensrt_result set_up_chiefs(struct lensrt_image_s *im, struct image_direct *d, const lensrt_bank_info *info,
                                   kernel_scratch *s, double *chief, int *ref)
{
    const int nl = im->n_wavelengths, nc = im->desc.n_channels, bw = info->width, bh = info->height;
    const double half_x = bw % 2 == 0 ? 0.5 : 0.0, half_y = bh % 2 == 0 ? 0.5 : 0.0;
    double most_x = 0.0, most_y = 0.0;
    int l, c, k;
    lensrt_result res;
    // The reference wavelength: the bank's nearest to 550 nm
    *ref = 0;
    for (l = 1; l < nl; l++)
        if (fabs(im->wavelengths_nm[l] - DIRECT_REFERENCE_NM) < fabs(im->wavelengths_nm[*ref] - DIRECT_REFERENCE_NM))
            *ref = l;
    for (l = 0; l < nl; l++)
        for (c = 0; c < nc; c++)
            if (im->channel_weights[(size_t)c * (size_t)nl + (size_t)l] > 0.0) s->used[l] = 1;
    s->used[*ref] = 1;
    // Every node's chief points (the bank reader's own at the node: exact)
    for (k = 0; k < d->nx * d->ny; k++)
        for (l = 0; l < nl; l++)
            if (s->used[l] &&
                (res = node_psf(im, k % d->nx, k / d->nx, l, s->psf, (size_t)bw * (size_t)bh,
                                chief + 2 * ((size_t)k * (size_t)nl + (size_t)l))) != LENSRT_SUCCESS)
                return res;
    // The largest shift (chief_l - chief_ref in pixels, plus the half pixel of an even size)
    for (k = 0; k < d->nx * d->ny; k++)
        for (l = 0; l < nl; l++) {
            const double *cl = chief + 2 * ((size_t)k * (size_t)nl + (size_t)l);
            const double *cr = chief + 2 * ((size_t)k * (size_t)nl + (size_t)*ref);
            const double sx = (cl[0] - cr[0]) / info->pixel_x_mm + half_x;
            const double sy = -(cl[1] - cr[1]) / info->pixel_y_mm + half_y;
            if (!s->used[l]) continue;
            most_x = fabs(sx) > most_x ? fabs(sx) : most_x;
            most_y = fabs(sy) > most_y ? fabs(sy) : most_y;
        }
    if (!(most_x < 0.25 * LENSRT_MAX_RESOLUTION && most_y < 0.25 * LENSRT_MAX_RESOLUTION))
        return lensrt_fail(im->ctx, LENSRT_ERROR_OUT_OF_DOMAIN, "lensrt_image_create: the bank's chief points differ "
                           "by %g x %g pixels between its wavelengths; at most %d", most_x, most_y,
                           LENSRT_MAX_RESOLUTION / 4);
    {
        // A channel's chief point is a mean of its wavelengths': a shift from it is at
        // most twice the largest from the reference; the B-spline taps reach one pixel
        // beyond it, image_sharpen() one more, and one spare
        const int pad_x = (int)ceil(2.0 * most_x) + 3, pad_y = (int)ceil(2.0 * most_y) + 3;
        d->kw = image_fft_good_size(bw + 2 * pad_x);
        d->kh = image_fft_good_size(bh + 2 * pad_y);
        d->kcx = pad_x + bw / 2;
        d->kcy = pad_y + bh / 2;
    }
    return LENSRT_SUCCESS;
}

void image_direct_destroy(struct lensrt_image_s *im)
{
    struct image_direct *d = im->direct;
    lensrt_context ctx = im->ctx;
    int i;
    if (!d) return;
    for (i = 0; i < d->n_plans; i++) image_fft_plan_destroy(ctx, d->plans[i]);
    lensrt_free(ctx, d->plans);
    lensrt_free(ctx, d->tx);
    lensrt_free(ctx, d->ty);
    lensrt_free(ctx, d->parts);
    lensrt_free(ctx, d->kernels);
    lensrt_free(ctx, d->col_cell);
    lensrt_free(ctx, d->row_cell);
    lensrt_free(ctx, d->col_frac);
    lensrt_free(ctx, d->row_frac);
    lensrt_free(ctx, d->land);
    lensrt_free(ctx, d->layer);
    lensrt_free(ctx, d->out);
    lensrt_free(ctx, d->data);
    lensrt_free(ctx, d->kbuf);
    lensrt_free(ctx, d->work);
    lensrt_free(ctx, d);
    im->direct = NULL;
}

#define DIRECT_OOM(what) lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "lensrt_image_create: out of memory for %s", what)

lensrt_result image_direct_create(struct lensrt_image_s *im)
{
    lensrt_context ctx = im->ctx;
    lensrt_bank_info info = LENSRT_BANK_INFO_INIT;
    struct image_direct *d;
    kernel_scratch s;
    double *chief = NULL, *chief_ch = NULL;
    const int nc = im->desc.n_channels, nl = im->n_wavelengths;
    int i, k, c, ref = 0, nthreads = 1;
    size_t kn, nodes;
    lensrt_result res;
    memset(&s, 0, sizeof s);
    if ((res = lensrt_bank_get_info(im->desc.bank, &info)) != LENSRT_SUCCESS) return res;
    d = im->direct = lensrt_calloc(ctx, 1, sizeof *d);
    if (!d) return DIRECT_OOM("the direct layer");
    d->nx = im->grid_nx;
    d->ny = im->grid_ny;
    nodes = (size_t)d->nx * (size_t)d->ny;
    // The grid in t = tan(field), the hat cells and landing points, the nodes' chief points
    d->tx = lensrt_alloc(ctx, (size_t)d->nx * sizeof(double));
    d->ty = lensrt_alloc(ctx, (size_t)d->ny * sizeof(double));
    d->col_cell = lensrt_alloc(ctx, (size_t)im->desc.width * sizeof(int));
    d->col_frac = lensrt_alloc(ctx, (size_t)im->desc.width * sizeof(double));
    d->row_cell = lensrt_alloc(ctx, (size_t)im->desc.height * sizeof(int));
    d->row_frac = lensrt_alloc(ctx, (size_t)im->desc.height * sizeof(double));
    d->land = lensrt_alloc(ctx, 2 * (size_t)nc * im->plane * sizeof(float));
    d->parts = lensrt_calloc(ctx, nodes, sizeof *d->parts);
    d->plans = lensrt_calloc(ctx, 2 * nodes + 2, sizeof *d->plans);
    chief = lensrt_alloc(ctx, nodes * (size_t)nl * 2 * sizeof(double));
    s.used = lensrt_calloc(ctx, (size_t)nl, sizeof(int));
    s.shifts = lensrt_alloc(ctx, 2 * (size_t)nc * (size_t)nl * sizeof(double));
    s.psf = lensrt_alloc(ctx, (size_t)info.width * (size_t)info.height * sizeof(float));
    if (!d->tx || !d->ty || !d->col_cell || !d->col_frac || !d->row_cell || !d->row_frac || !d->land || !d->parts ||
        !d->plans || !chief || !s.used || !s.shifts || !s.psf) {
        res = DIRECT_OOM("the field grid and the landing points");
        goto done;
    }
    for (i = 0; i < d->nx; i++) d->tx[i] = tan_deg(im->grid_x_deg[i]);
    for (i = 0; i < d->ny; i++) d->ty[i] = tan_deg(im->grid_y_deg[i]);
    if ((res = set_up_chiefs(im, d, &info, &s, chief, &ref)) != LENSRT_SUCCESS) goto done;
    // Each channel's chief point at each node, for its warp: its wavelengths' chief points
    // weighted by the channel's light there (w[c][l] times the axis PSF's power), so that
    // a channel of one wavelength lands exactly where that wavelength's chief ray does
    chief_ch = lensrt_alloc(ctx, nodes * (size_t)nc * 2 * sizeof(double));
    if (!chief_ch) {
        res = DIRECT_OOM("the chief points");
        goto done;
    }
    for (k = 0; k < (int)nodes; k++)
        for (c = 0; c < nc; c++) {
            double sum = 0.0, cx = 0.0, cy = 0.0;
            int l;
            for (l = 0; l < nl; l++) {
                const double a = im->channel_weights[(size_t)c * (size_t)nl + (size_t)l] * im->axis_power[l];
                const double *cl = chief + 2 * ((size_t)k * (size_t)nl + (size_t)l);
                if (a <= 0.0) continue;
                sum += a;
                cx += a * cl[0];
                cy += a * cl[1];
            }
            if (!(sum > 0.0)) { // no power on the axis in this channel: the reference's
                cx = chief[2 * ((size_t)k * (size_t)nl + (size_t)ref)];
                cy = chief[2 * ((size_t)k * (size_t)nl + (size_t)ref) + 1];
                sum = 1.0;
            }
            chief_ch[2 * ((size_t)k * (size_t)nc + (size_t)c)] = cx / sum;
            chief_ch[2 * ((size_t)k * (size_t)nc + (size_t)c) + 1] = cy / sum;
        }
    set_up_warp(im, d, &info, chief_ch);
    // The parts: nodes whose light reaches the frame, their rectangles and transform sizes
    for (k = 0; k < (int)nodes; k++) {
        node_part *p = &d->parts[d->n_parts];
        p->ix = k % d->nx;
        p->iy = k / d->nx;
        if (!set_up_part(im, d, p)) continue;
        if (!(p->px = plan_for(ctx, d, image_fft_good_size(p->sw + d->kw - 1))) ||
            !(p->py = plan_for(ctx, d, image_fft_good_size(p->sh + d->kh - 1)))) {
            res = DIRECT_OOM("the FFT plans");
            goto done;
        }
        if ((size_t)p->sw * (size_t)p->sh > d->max_layer) d->max_layer = (size_t)p->sw * (size_t)p->sh;
        if ((size_t)p->ow * (size_t)p->oh > d->max_out) d->max_out = (size_t)p->ow * (size_t)p->oh;
        if ((size_t)p->px->n * (size_t)p->py->n > d->max_fft) d->max_fft = (size_t)p->px->n * (size_t)p->py->n;
        d->n_parts++;
    }
    // The kernels (step 3), node by node
    kn = (size_t)d->kw * (size_t)d->kh;
    d->kernels = lensrt_alloc(ctx, (size_t)(d->n_parts > 0 ? d->n_parts : 1) * (size_t)nc * kn * sizeof(float));
    s.acc = lensrt_alloc(ctx, (size_t)nc * kn * sizeof(double));
    s.line = lensrt_alloc(ctx, (size_t)(d->kw > d->kh ? d->kw : d->kh) * sizeof(double));
    if (!d->kernels || !s.acc || !s.line) {
        res = DIRECT_OOM("the kernels");
        goto done;
    }
    for (k = 0; k < d->n_parts; k++) {
        node_part *p = &d->parts[k];
        const size_t node = (size_t)p->iy * (size_t)d->nx + (size_t)p->ix;
        int l;
        for (c = 0; c < nc; c++) {
            const double *cr = chief_ch + 2 * (node * (size_t)nc + (size_t)c);
            for (l = 0; l < nl; l++) {
                const double *cl = chief + 2 * (node * (size_t)nl + (size_t)l);
                double *sh = s.shifts + 2 * ((size_t)c * (size_t)nl + (size_t)l);
                sh[0] = (cl[0] - cr[0]) / info.pixel_x_mm + (info.width % 2 == 0 ? 0.5 : 0.0);
                sh[1] = -(cl[1] - cr[1]) / info.pixel_y_mm + (info.height % 2 == 0 ? 0.5 : 0.0);
            }
        }
        p->kernels = d->kernels + (size_t)k * (size_t)nc * kn;
        if ((res = build_kernels(im, d, p, &info, s.shifts, s.used, s.acc, s.line, s.psf)) != LENSRT_SUCCESS)
            goto done;
    }
    // The slots' buffers: one node at a time per thread
#ifdef LENSRT_OPENMP
    nthreads = ctx->threads > 0 ? ctx->threads : omp_get_max_threads();
#endif
    if (nthreads > DIRECT_MAX_SLOTS) nthreads = DIRECT_MAX_SLOTS;
    d->slots = nthreads < d->n_parts ? nthreads : d->n_parts > 0 ? d->n_parts : 1;
    d->layer = lensrt_alloc(ctx, (size_t)d->slots * (size_t)nc * (d->max_layer + 1) * sizeof(float));
    d->out = lensrt_alloc(ctx, (size_t)d->slots * (size_t)nc * (d->max_out + 1) * sizeof(float));
    d->data = lensrt_alloc(ctx, (size_t)d->slots * 2 * (d->max_fft + 1) * sizeof(double));
    d->kbuf = lensrt_alloc(ctx, (size_t)d->slots * 2 * (d->max_fft + 1) * sizeof(double));
    d->work = lensrt_alloc(ctx, (size_t)d->slots * 2 * (d->max_fft + 1) * sizeof(double));
    if (!d->layer || !d->out || !d->data || !d->kbuf || !d->work) res = DIRECT_OOM("the convolutions' buffers");
done:
    free_scratch(ctx, &s);
    lensrt_free(ctx, chief);
    lensrt_free(ctx, chief_ch);
    if (res != LENSRT_SUCCESS) image_direct_destroy(im);
    return res;
}

/* ------------------------------------------------------------------- run ----- */

/* Step 2 for one part: its layer (n_channels planes of sw x sh) from the input. Returns
 * whether any light reached it. In float, as the layer is: each value is the input times
 * the hat weight times a tap, rounded once or twice (relative 1e-7). */
static int splat(const struct lensrt_image_s *im, const struct image_direct *d, const node_part *p,
                 const float *input, float *layer)
{
    const int w = im->desc.width, nc = im->desc.n_channels, sw = p->sw, sh = p->sh;
    const size_t lp = (size_t)sw * (size_t)sh;
    int i, j, c, lit = 0;
    memset(layer, 0, (size_t)nc * lp * sizeof(float));
    for (j = p->j0; j < p->j1; j++) {
        const float wy = (float)hat_weight(p->iy, d->row_cell[j], d->row_frac[j]);
        if (wy == 0.0f) continue;
        for (i = p->i0; i < p->i1; i++) {
            const size_t pix = (size_t)j * (size_t)w + (size_t)i;
            const float wt = wy * (float)hat_weight(p->ix, d->col_cell[i], d->col_frac[i]);
            if (wt == 0.0f) continue;
            for (c = 0; c < nc; c++) {
                const float val = input[(size_t)c * im->plane + pix];
                const float *land = d->land + 2 * ((size_t)c * im->plane + pix);
                double tx[3], ty[3];
                int x0, y0, ta, tb;
                float *l = layer + (size_t)c * lp;
                if (val == 0.0f) continue;
                lit = 1;
                // The B-spline's 3 x 3 taps (image_bspline_taps: they sum to 1, so the power
                // and the centroid are kept, and spread the light by a constant 1/4
                // squared pixels per axis, which the kernels undo)
                image_bspline_taps((double)land[0] - p->sx0, &x0, tx);
                image_bspline_taps((double)land[1] - p->sy0, &y0, ty);
                if (x0 >= 0 && x0 + 2 < sw && y0 >= 0 && y0 + 2 < sh) {
                    // The usual case: all nine taps in the layer
                    for (tb = 0; tb < 3; tb++) {
                        float *q = l + (size_t)(y0 + tb) * (size_t)sw + (size_t)x0;
                        const float vy = val * wt * (float)ty[tb];
                        q[0] += vy * (float)tx[0];
                        q[1] += vy * (float)tx[1];
                        q[2] += vy * (float)tx[2];
                    }
                    continue;
                }
                for (tb = 0; tb < 3; tb++)
                    for (ta = 0; ta < 3; ta++) {
                        const int x = x0 + ta, y = y0 + tb;
                        if (x >= 0 && x < sw && y >= 0 && y < sh)
                            l[(size_t)y * (size_t)sw + (size_t)x] += val * wt * (float)(tx[ta] * ty[tb]);
                    }
            }
        }
    }
    return lit;
}

/* The frame's part of a convolution (real part e = 0 or imaginary e = 1 of z, scaled)
 * into out (ow x oh): frame pixel (x, y) is the linear convolution's (x - sx0 + kcx,
 * y - sy0 + kcy). */
static void write_out(const struct image_direct *d, const node_part *p, const double *z, int fw, int e, double scale,
                      float *out)
{
    int i, j;
    for (j = 0; j < p->oh; j++) {
        const size_t row = (size_t)(p->oy0 + j - p->sy0 + d->kcy) * (size_t)fw;
        float *o = out + (size_t)j * (size_t)p->ow;
        const double *zr = z + 2 * (row + (size_t)(p->ox0 - p->sx0 + d->kcx)) + (size_t)e;
        for (i = 0; i < p->ow; i++) o[i] = (float)(zr[2 * (size_t)i] * scale);
    }
}

/* Step 4 for one part: its layer convolved with its kernels, the frame's part into out
 * (n_channels planes of ow x oh). Seconds of the kernels' transforms into *t_kernels. */
static void convolve(const struct lensrt_image_s *im, const struct image_direct *d, const node_part *p,
                     const float *layer, float *out, double *z, double *q, double *work, double *t_kernels)
{
    const int nc = im->desc.n_channels, fw = p->px->n, fh = p->py->n;
    const size_t fn = (size_t)fw * (size_t)fh, lp = (size_t)p->sw * (size_t)p->sh, kn = (size_t)d->kw * (size_t)d->kh;
    const double scale = 1.0 / (double)fn;
    int c, e, i, j;
    for (c = 0; c < nc; c += 2) {
        const int pair = c + 1 < nc ? 2 : 1;
        const double t0 = lensrt_seconds();
        if (pair == 1) {
            // An odd last channel: its layer and kernel packed in one transform (the
            // kernel's share counted with the convolutions)
            memset(z, 0, 2 * fn * sizeof(double));
            for (j = 0; j < p->sh; j++)
                for (i = 0; i < p->sw; i++)
                    z[2 * ((size_t)j * (size_t)fw + (size_t)i)] =
                        layer[(size_t)c * lp + (size_t)j * (size_t)p->sw + (size_t)i];
            for (j = 0; j < d->kh; j++)
                for (i = 0; i < d->kw; i++)
                    z[2 * ((size_t)j * (size_t)fw + (size_t)i) + 1] =
                        p->kernels[(size_t)c * kn + (size_t)j * (size_t)d->kw + (size_t)i];
            image_fft_2d_forward(p->px, p->py, z, work, p->sh > d->kh ? p->sh : d->kh);
            image_fft_packed_self_product(z, fw, fh);
            image_fft_2d_inverse(p->px, p->py, z, work, p->oy0 - p->sy0 + d->kcy, p->oh);
            write_out(d, p, z, fw, 0, scale, out + (size_t)c * (size_t)p->ow * (size_t)p->oh);
            continue;
        }
        // The kernels of channels c and c + 1, packed, padded, transformed
        memset(q, 0, 2 * fn * sizeof(double));
        for (e = 0; e < pair; e++)
            for (j = 0; j < d->kh; j++)
                for (i = 0; i < d->kw; i++)
                    q[2 * ((size_t)j * (size_t)fw + (size_t)i) + (size_t)e] =
                        p->kernels[(size_t)(c + e) * kn + (size_t)j * (size_t)d->kw + (size_t)i];
        image_fft_2d_forward(p->px, p->py, q, work, d->kh);
        *t_kernels += lensrt_seconds() - t0;
        // The layer's two channels the same way, their product, back
        memset(z, 0, 2 * fn * sizeof(double));
        for (e = 0; e < pair; e++)
            for (j = 0; j < p->sh; j++)
                for (i = 0; i < p->sw; i++)
                    z[2 * ((size_t)j * (size_t)fw + (size_t)i) + (size_t)e] =
                        layer[(size_t)(c + e) * lp + (size_t)j * (size_t)p->sw + (size_t)i];
        image_fft_2d_forward(p->px, p->py, z, work, p->sh);
        image_fft_packed_product(z, q, fw, fh);
        image_fft_2d_inverse(p->px, p->py, z, work, p->oy0 - p->sy0 + d->kcy, p->oh);
        for (e = 0; e < pair; e++)
            write_out(d, p, z, fw, e, scale, out + (size_t)(c + e) * (size_t)p->ow * (size_t)p->oh);
    }
}

lensrt_result image_direct_run(struct lensrt_image_s *im, const float *input, float *direct)
{
    struct image_direct *d = im->direct;
    const int nc = im->desc.n_channels, w = im->desc.width;
    const size_t slot_layer = (size_t)nc * (d->max_layer + 1), slot_out = (size_t)nc * (d->max_out + 1);
    const size_t slot_fft = 2 * (d->max_fft + 1);
    double t_warp = 0.0, t_kernels = 0.0, t_convolve = 0.0, biggest = 0.0;
    int lit[DIRECT_MAX_SLOTS], first, n_nodes = 0;
    // The parts in batches of `slots`, each slot a node of its own; the slots' outputs
    // added in node order (the same sums whatever the threads)
    for (first = 0; first < d->n_parts; first += d->slots) {
        const int n = d->n_parts - first < d->slots ? d->n_parts - first : d->slots;
        double tk[DIRECT_MAX_SLOTS], tc, t0 = lensrt_seconds();
        int b;
        // Step 2: the layers
#ifdef LENSRT_OPENMP
#pragma omp parallel for schedule(static, 1) num_threads(n)
#endif
        for (b = 0; b < n; b++)
            lit[b] = splat(im, d, &d->parts[first + b], input, d->layer + (size_t)b * slot_layer);
        tc = lensrt_seconds();
        t_warp += tc - t0;
        // Step 4 (and the kernels' transforms): the convolutions
        for (b = 0; b < n; b++) tk[b] = 0.0;
#ifdef LENSRT_OPENMP
#pragma omp parallel for schedule(static, 1) num_threads(n)
#endif
        for (b = 0; b < n; b++)
            if (lit[b])
                convolve(im, d, &d->parts[first + b], d->layer + (size_t)b * slot_layer, d->out + (size_t)b * slot_out,
                         d->data + (size_t)b * slot_fft, d->kbuf + (size_t)b * slot_fft,
                         d->work + (size_t)b * slot_fft, &tk[b]);
        // Their sum, in node order
        for (b = 0; b < n; b++) {
            const node_part *part = &d->parts[first + b];
            const float *o = d->out + (size_t)b * slot_out;
            int c, j, i;
            if (!lit[b]) continue;
            n_nodes++;
            if ((double)part->px->n * part->py->n > biggest) {
                biggest = (double)part->px->n * part->py->n;
                im->stats.fft_width = part->px->n;
                im->stats.fft_height = part->py->n;
            }
            for (c = 0; c < nc; c++)
                for (j = 0; j < part->oh; j++) {
                    float *row = direct + (size_t)c * im->plane + (size_t)(part->oy0 + j) * (size_t)w + (size_t)part->ox0;
                    const float *src = o + (size_t)c * (size_t)part->ow * (size_t)part->oh + (size_t)j * (size_t)part->ow;
                    for (i = 0; i < part->ow; i++) row[i] += src[i];
                }
        }
        // The batch's wall time, the kernels' share of it by the slots' own clocks
        {
            const double wall = lensrt_seconds() - tc;
            double share = 0.0;
            for (b = 0; b < n; b++) share += tk[b];
            share = wall > 0.0 ? share / (double)n / wall : 0.0;
            share = share > 1.0 ? 1.0 : share;
            t_kernels += wall * share;
            t_convolve += wall * (1.0 - share);
        }
    }
    im->stats.seconds_warp = t_warp;
    im->stats.seconds_kernels = t_kernels;
    im->stats.seconds_convolve = t_convolve;
    im->stats.n_nodes = n_nodes;
    return LENSRT_SUCCESS;
}

void image_direct_clamp(float *layer, size_t n)
{
    size_t p;
    for (p = 0; p < n; p++)
        if (layer[p] < 0.0f) layer[p] = 0.0f;
}
