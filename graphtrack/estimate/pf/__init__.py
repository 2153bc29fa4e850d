"""Support for the particle filter (:mod:`graphtrack.estimate.particle_filter`):
synthetic scenes with exact ground truth for its tests and benchmark."""
