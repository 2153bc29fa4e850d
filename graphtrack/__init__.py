"""graphtrack: track dVRK surgical tools in endoscope video.

The lumped error E (camera-from-base, 4x4) corrects everything between the
nominal hand-eye calibration and the noisy joint readings q~:

    camera_T_link_j = E . T_1(q~_1) ... T_j(q~_j)

Units: metres and radians everywhere (handeye.yaml and the stereo baseline are
millimetres on disk and converted on load).
"""
__version__ = "0.1.0"
