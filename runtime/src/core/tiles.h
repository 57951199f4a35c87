/* Host-scheduled tiles (internal, core/tiles.c): the session between
 * lensrt_render_tiles_begin and lensrt_render_tiles_end. */
#ifndef LENSRT_TILES_H
#define LENSRT_TILES_H

#include "render.h"

typedef struct lensrt_tiles {
    uint64_t first, count;     /* the sample range [first, first + count) per wavelength */
    double t0;                 /* lensrt_seconds() at begin */
    uint32_t *cover;           /* per pixel: how many tiles claimed it (atomic) */
    double *sum0, *sumsq0;     /* the sums at begin, put back when the session fails */
    /* the pixels' set-up statistics of one pass, integers summed atomically by the tiles */
    uint64_t terms, clip, tau, dark;
    int32_t failed;            /* turned to 1 by the first failing tile (atomic) */
    lensrt_result failure;     /* its result and message, written by that tile only */
    char message[LENSRT_ERROR_SIZE];
} lensrt_tiles;

/* Record a tile's failure and return `result`. The first failure of the session is kept
 * (for tiles_end to report); safe from any thread; never writes the context's error. */
lensrt_result lensrt_tiles_fail(lensrt_render r, lensrt_result result, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 3, 4)))
#endif
    ;
/* Add a tile's pixel set-up statistics (over its pixels and every wavelength, one pass). */
void lensrt_tiles_add_stats(lensrt_render r, uint64_t terms, uint64_t clip, uint64_t tau, uint64_t dark);
/* LENSRT_SUCCESS when no tile session is open; else `what` is refused (message in the
 * context: called on the render's own thread). */
lensrt_result lensrt_tiles_idle(lensrt_render r, const char *what);
/* Free an open session without committing it (render destruction). */
void lensrt_tiles_free(lensrt_render r);

#endif /* LENSRT_TILES_H */
