"""Parts of the particle filter (:mod:`graphtrack.estimate.particle_filter`):
the projection of every hypothesis (projection) and the vectorised pixel model
(pixel_model)."""
