/* Which kind a lens is: the one place that reads lensrt_lens_s.analytic. The kinds'
 * operations (lens/fitted.c, lens/analytic.c) build on core/; what asks a lens's kind
 * (renders, scene checks, image points) comes through here, so that nothing the kinds use
 * depends back on them. */
#include "lens.h"

const lensrt_lens_ops *lensrt_lens_ops_of(lensrt_lens lens)
{
    return lens->analytic ? &lensrt_lens_analytic : &lensrt_lens_fitted;
}
