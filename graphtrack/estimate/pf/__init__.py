"""Parts of the particle filter (:mod:`graphtrack.estimate.particle_filter`):
the projection of every hypothesis (projection), the vectorised pixel model
(pixel_model), and synthetic scenes with exact ground truth for its tests and
benchmark (synthetic)."""
