"""How far a fit can be trusted: its PSFs against exactly traced rays
(:mod:`~lensfit.trust.check`) and the fit-error report (:mod:`~lensfit.trust.report`)."""
