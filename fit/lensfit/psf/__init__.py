"""Point spread functions summed over aperture points, exactly traced and from the fitted
polynomials (:mod:`~lensfit.psf.psf`)."""
