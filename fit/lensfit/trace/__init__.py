"""Spectral float64 ray tracing: surfaces, refraction, Fresnel and coatings, paths."""
