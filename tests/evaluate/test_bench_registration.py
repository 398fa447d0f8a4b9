"""The registration benchmark function (for ``skincap bench animate``)."""

from __future__ import annotations

import pytest

from skincap.evaluate.bench.registration import registration_seconds


@pytest.mark.slow
def test_registration_seconds_reports_a_fit_and_its_cost() -> None:
    got = registration_seconds(n_vertices=5000, n_markers=120)
    assert 4000 <= got["vertices"] <= 6000 and got["markers"] == 120
    assert got["cpu_s"] > 0 and got["laplacian_lu_cpu_s"] > 0
    assert got["ratio_to_lu"] == pytest.approx(got["cpu_s"] / got["laplacian_lu_cpu_s"])
    # the scaled, shifted copy of the body is fitted: markers on the surface
    assert got["marker_distance_mean_m"] < 2e-3
