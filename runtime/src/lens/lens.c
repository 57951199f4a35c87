/* Which kind a lens is: the one place that reads lensrt_lens_s.analytic. */
#include "lens.h"

const lensrt_lens_ops *lensrt_lens_ops_of(lensrt_lens lens)
{
    return lens->analytic ? &lensrt_lens_analytic : &lensrt_lens_fitted;
}
