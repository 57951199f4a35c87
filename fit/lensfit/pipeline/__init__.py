"""A fit from start to finish, as ``lensfit fit`` runs it (:mod:`~lensfit.pipeline.stage`):
its checkpoints (:mod:`~lensfit.pipeline.cache`) and progress bar
(:mod:`~lensfit.pipeline.progress`); and ``make bench``'s sweep of default fits over lensdb
(:mod:`~lensfit.pipeline.sweep`)."""
