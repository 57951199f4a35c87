"""Declared fitting domains and the traced samples that P_o and P_s are fitted to."""

from lensfit.sample.aim import Aimed, SamplingError, aim_object_side, aim_sensor_side
from lensfit.sample.domain import Domain, default_domain
from lensfit.sample.rays import (
    OUTPUTS_O,
    OUTPUTS_S,
    Samples,
    sample_object_side,
    sample_sensor_side,
)

__all__ = ["Domain", "default_domain", "OUTPUTS_O", "OUTPUTS_S", "Aimed", "Samples",
           "SamplingError", "aim_object_side", "aim_sensor_side", "sample_object_side",
           "sample_sensor_side"]
