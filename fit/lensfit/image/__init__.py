"""A whole HDR image through the lens (issue 38).

frame (the input EXR: a linear pinhole render, its channels, depth and geometry) ->
bank (the lens's PSFs over the frame's field, built on Dask once and cached) ->
lensrt_image (C: each pixel's light moved to its chief point and spread by its own
field point's PSF; the sources' ghosts) -> layers (the output EXR: direct, flare and
one layer per ghost, and a preview PNG).
"""
