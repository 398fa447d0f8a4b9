"""The whole-body PCA fill's partial eigensolver against the whole decomposition."""

from __future__ import annotations

import numpy as np
import pytest

from skincap.cleanup import fill_pca as fill_pca_module
from skincap.cleanup.fill_pca import _leading_axes, _leading_axes_full, fill_pca


def _centred(rows: int, cols: int, rank: int, seed: int) -> np.ndarray:
    """(rows, cols) centred data: ``rank`` strong directions with falling variance, noise."""
    rng = np.random.default_rng(seed)
    scale = np.geomspace(10.0, 0.3, rank)
    y = (rng.normal(size=(rows, rank)) * scale) @ rng.normal(size=(rank, cols))
    y += 0.05 * rng.normal(size=(rows, cols))
    return y - y.mean(axis=0)


@pytest.mark.parametrize(("rows", "cols"), [(120, 300), (300, 90), (60, 60)])
@pytest.mark.parametrize("variance", [0.9, 0.99, 1.0])
@pytest.mark.parametrize("hint", [0, 3, 200])
def test_leading_axes_span_what_the_whole_decomposition_keeps(
    rows: int, cols: int, variance: float, hint: int
) -> None:
    c = _centred(rows, cols, rank=25, seed=rows + cols)
    fast, full = _leading_axes(c, variance, hint), _leading_axes_full(c, variance)
    assert fast.shape == full.shape  # the same number of axes kept
    # the same subspace (axes agree up to sign): equal projectors, orthonormal axes
    np.testing.assert_allclose(fast @ fast.T, full @ full.T, atol=1e-8)
    np.testing.assert_allclose(fast.T @ fast, np.eye(fast.shape[1]), atol=1e-9)


def test_fill_equals_the_fill_with_the_whole_decomposition(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(5)
    t = np.arange(200) / 100.0
    base = rng.normal(scale=0.2, size=(40, 3))
    modes = rng.normal(scale=0.04, size=(6, 40, 3))
    phase = np.sin(2 * np.pi * np.outer(t, [0.5, 0.8, 1.1, 1.7, 2.3, 3.1]) + np.arange(6))
    pos = base[None] + np.einsum("tk,knx->tnx", phase, modes)
    pos += 0.001 * rng.normal(size=pos.shape)
    gappy = pos.copy()
    for marker, start in ((3, 20), (11, 90), (25, 140), (30, 1)):
        gappy[start : start + 30, marker] = np.nan
    target = np.isnan(gappy[..., 0])
    fast = fill_pca(gappy, target)
    monkeypatch.setattr(
        fill_pca_module,
        "_leading_axes",
        lambda c, variance, hint=0: _leading_axes_full(c, variance),
    )
    reference = fill_pca(gappy, target)
    np.testing.assert_allclose(fast, reference, atol=1e-10)
    assert np.linalg.norm(fast[target] - pos[target], axis=-1).mean() < 0.01
