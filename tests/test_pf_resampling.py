"""Systematic resampling and log-weight handling."""
import numpy as np

from graphtrack.estimate.resampling import (effective_sample_size, normalize_log_weights,
                                            systematic_resample, weights_from_log)


def test_systematic_counts_match_weights():
    rng = np.random.default_rng(0)
    N = 1000
    w = rng.gamma(0.5, size=N)
    w /= w.sum()
    x = rng.standard_normal((N, 3))
    for trial in range(20):
        idx = systematic_resample(w, rng)
        assert idx.shape == (N,) and idx.min() >= 0 and idx.max() < N
        counts = np.bincount(idx, minlength=N)
        # low-variance property: every count within 1 of N w_i
        assert np.all(np.abs(counts - N * w) < 1.0 + 1e-9)
        # the weighted mean survives (|counts - N w| < 1 bounds the error by ~0.5 sqrt(N)/N)
        np.testing.assert_allclose(x[idx].mean(0), w @ x, atol=0.05)


def test_systematic_degenerate_and_uniform():
    rng = np.random.default_rng(1)
    w = np.zeros(10)
    w[3] = 1.0
    assert np.all(systematic_resample(w, rng) == 3)
    u = np.full(10, 0.1)
    assert sorted(systematic_resample(u, rng)) == list(range(10))


def test_log_weights_are_robust():
    lw = normalize_log_weights(np.array([-1e300, -1e300 - 1e290, np.nan, -np.inf]))
    w = np.exp(lw)
    assert np.isfinite(lw[:2]).all() and abs(w.sum() - 1) < 1e-12 and w[2] == 0 and w[3] == 0
    # tiny likelihoods everywhere never underflow to all-zero weights
    w = weights_from_log(np.array([-5000.0, -5001.0, -6000.0]))
    assert w[0] > 0.7 and abs(w.sum() - 1) < 1e-12
    # nothing finite: uniform
    np.testing.assert_allclose(weights_from_log(np.array([np.nan, -np.inf])), [0.5, 0.5])
    assert effective_sample_size(np.full(8, 1 / 8)) == 8.0


def test_kernel_shrinkage_keeps_the_clouds_mean_and_covariance():
    """Liu & West: a^2 Sigma + h^2 Sigma = Sigma; with the cap far above the spread the
    roughened cloud keeps its mean and covariance (up to sampling error); a cap below it
    limits the jitter's std on that axis to the cap."""
    from graphtrack.estimate.resampling import shrink_and_jitter
    rng = np.random.default_rng(0)
    mean, cov = np.array([1.0, -2.0]), np.array([[4.0, 1.2], [1.2, 1.0]])
    x = rng.multivariate_normal(mean, cov, 200_000)
    y = shrink_and_jitter(x, mean, cov, 0.5, np.full(2, 1e9), np.full(2, 1e-9), rng)
    np.testing.assert_allclose(y.mean(axis=0), mean, atol=0.02)
    np.testing.assert_allclose(np.cov(y.T), cov, atol=0.05)
    z = shrink_and_jitter(np.tile(mean, (200_000, 1)), mean, cov, 0.5, np.array([0.1, 1e9]), np.full(2, 1e-9), rng)
    np.testing.assert_allclose(z.std(axis=0), [0.1, 0.5 * 1.0], rtol=0.02)   # cap; h * sqrt(cov[1, 1])
