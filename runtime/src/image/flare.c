/* The flare layers (image.h): a stub until the flare helper's branch is merged (issue
 * 38; its flare.c replaces this file). create succeeds, run zeroes the ghost layers and
 * finds no sources. */
#include "image.h"

#include <string.h>

lensrt_result image_flare_create(struct lensrt_image_s *im)
{
    im->flare = NULL;
    return LENSRT_SUCCESS;
}

void image_flare_destroy(struct lensrt_image_s *im)
{
    im->flare = NULL;
}

lensrt_result image_flare_run(struct lensrt_image_s *im, const float *input, float *ghosts)
{
    (void)input;
    // One layer of n_channels planes per ghost, zeroed; no sources, no renders
    if (im->desc.n_ghosts > 0)
        memset(ghosts, 0, (size_t)im->desc.n_ghosts * (size_t)im->desc.n_channels * im->plane * sizeof(float));
    im->stats.n_sources = 0;
    im->stats.n_ghost_renders = 0;
    im->stats.seconds_flares = 0.0;
    return LENSRT_SUCCESS;
}
