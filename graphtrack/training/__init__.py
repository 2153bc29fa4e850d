"""Training the learned detector (:mod:`graphtrack.detect.learned`) on simulated frames.

- :mod:`.labels`: ground-truth shaft edge segments of a frame (undistorted px)
  from truth.csv + robot + the joint readings, and the line / junction target
  heatmaps drawn from them;
- :mod:`.data`: domain-randomised recordings from :func:`graphtrack.sim.simulate`
  (both scenes, ``randomize=True``) turned into a training set;
- :mod:`.fit`: the training loop (``graphtrack train``).
"""
