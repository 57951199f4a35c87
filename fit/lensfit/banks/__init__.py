"""Banks of PSFs over a lens's field, focus, stops and wavelengths, rendered on Dask.

spec (what to render) -> run (plan, skip what is finished, tasks on Dask via engine) ->
node (one render by lensrt, atomic EXR and record) -> index (what renderers read:
lensrt_bank_open) and sheet (the contact sheet a person looks at first).
"""
