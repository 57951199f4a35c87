/* The scene of a render (internal, core/scene.c). */
#ifndef LENSRT_SCENE_H
#define LENSRT_SCENE_H

#include "render.h"

/* The description's own checks (ranges, enumerations, combinations), before anything is
 * allocated. */
lensrt_result lensrt_scene_check_desc(lensrt_context ctx, const lensrt_render_desc *d, const lensrt_lens_info *info);
/* Pixel centres, lights, stop, the window's check, the sampled region and its measure,
 * for a render whose description, lights and wavelengths are copied in. */
lensrt_result lensrt_scene_place(lensrt_render r, const lensrt_lens_info *info);
/* The grid of r->sx x r->sy points per pixel (core/render.h): its size, pitch and point
 * centres (r->xs, r->ys, allocated for it). */
void lensrt_scene_grid(lensrt_render r);
/* P_o's (x_O, y_O) of a light: the direction cosines from the lens towards it, along
 * (-tan x, -tan y, 1) (the field angles are the chief ray's; lensrt.h, lensrt_light). */
void lensrt_light_direction(const lensrt_light *l, double *x, double *y);

#endif /* LENSRT_SCENE_H */
