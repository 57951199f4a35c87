/* Chief rays through the fitted polynomials (internal, core/image_point.c). */
#ifndef LENSRT_IMAGE_POINT_H
#define LENSRT_IMAGE_POINT_H

#include "render.h"

/* Where the total phase P_o + P_s of the light (direction cosines lx, ly) is stationary
 * at the stop centre, on the sensor shifted by focus_offset_mm: Newton's method. */
lensrt_result lensrt_polynomial_image_point(lensrt_context ctx, lensrt_lens lens, const lensrt_light *light,
                                            double lx, double ly, double wavelength_nm, double focus_offset_mm,
                                            double xy_mm[2]);

#endif /* LENSRT_IMAGE_POINT_H */
