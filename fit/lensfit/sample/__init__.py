"""Declared fitting domains and the traced samples that P_o and P_s are fitted to."""

from lensfit.sample.domain import Domain, default_domain
from lensfit.sample.rays import (
    OUTPUTS_O,
    OUTPUTS_S,
    Samples,
    SamplingError,
    sample_object_side,
    sample_sensor_side,
)

__all__ = ["Domain", "default_domain", "OUTPUTS_O", "OUTPUTS_S", "Samples", "SamplingError",
           "sample_object_side", "sample_sensor_side"]
