"""What every package of lensfit shares: its errors (:mod:`~lensfit.common.errors`), whole
writes of files and folders (:mod:`~lensfit.common.atomic`) and a strict JSON reader
(:mod:`~lensfit.common.strict_json`)."""
