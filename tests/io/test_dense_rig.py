"""Dense rig files: NPZ + JSON sidecar round trip, and every malformed file refused."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skincap.deform.dense.rig import DenseRig
from skincap.errors import FormatError, OutputExistsError, ValidationError
from skincap.io.dense_rig import read_dense_rig, write_dense_rig


def _rig() -> DenseRig:
    rng = np.random.default_rng(0)
    alpha = rng.random((6, 2))
    beta = rng.random((10, 2))
    return DenseRig(
        vertices=rng.normal(size=(10, 3)),
        faces=np.array([[0, 1, 2], [2, 3, 4]]),
        labels=[f"M{i}" for i in range(6)],
        reference=rng.normal(size=(6, 3)),
        surface_faces=np.array([[0, 1, 2], [3, 4, 5]]),
        marker_parts=np.array([0, 0, 0, 1, 1, 1]),
        marker_weights=alpha / alpha.sum(1, keepdims=True),
        vertex_weights=beta / beta.sum(1, keepdims=True),
        settings={"n_parts": 2, "reference_frame": 0},
    )


def test_round_trip_is_exact(tmp_path) -> None:
    rig = _rig()
    written = write_dense_rig(tmp_path / "r.npz", rig.to_arrays(), list(rig.labels), rig.settings)
    assert [p.name for p in written] == ["r.npz", "r.json"]
    arrays, labels, settings = read_dense_rig(tmp_path / "r.npz")
    back = DenseRig.from_arrays(arrays, labels, settings)
    for name, value in rig.to_arrays().items():
        np.testing.assert_array_equal(getattr(back, name), value)
    assert back.labels == rig.labels and back.settings == rig.settings
    with pytest.raises(OutputExistsError):
        write_dense_rig(tmp_path / "r.npz", rig.to_arrays(), list(rig.labels), rig.settings)


def test_columns_of_another_marker_set_is_refused() -> None:
    rig = _rig()
    np.testing.assert_array_equal(rig.columns_of(["x", *reversed(rig.labels)]), [6, 5, 4, 3, 2, 1])
    with pytest.raises(ValidationError, match="another marker set"):
        rig.columns_of(["M0", "M1"])


def test_malformed_rigs_are_refused(tmp_path) -> None:
    rig = _rig()
    path = tmp_path / "r.npz"
    write_dense_rig(path, rig.to_arrays(), list(rig.labels), rig.settings)
    sidecar = json.loads(path.with_suffix(".json").read_text())

    def rewrite(meta: dict, arrays: dict | None = None) -> None:
        path.with_suffix(".json").write_text(json.dumps(meta))
        if arrays is not None:
            with open(path, "wb") as fh:
                np.savez(fh, **arrays)

    rewrite({**sidecar, "version": 99})
    with pytest.raises(FormatError, match="version"):
        read_dense_rig(path)
    rewrite({**sidecar, "labels": sidecar["labels"][:5]})
    with pytest.raises(FormatError, match="disagrees"):
        read_dense_rig(path)
    pickled = {**rig.to_arrays(), "faces": np.array([object()] * 6, dtype=object).reshape(2, 3)}
    rewrite(sidecar, pickled)
    with pytest.raises(FormatError, match="not a readable NPZ|int array"):
        read_dense_rig(path)
    path.with_suffix(".json").unlink()
    with pytest.raises(FormatError, match="sidecar"):
        read_dense_rig(path)
    with pytest.raises(FormatError, match=".npz"):
        write_dense_rig(tmp_path / "r.rig", rig.to_arrays(), list(rig.labels), {})


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b'{"format": "\xff"}', r"r\.json.*not UTF-8 text \(byte 12\)"),
        (b"[" * 100_000, r"r\.json.*nested too deeply"),
        (b'{"format": ', r"r\.json.*invalid rig sidecar JSON"),
    ],
)
def test_hostile_sidecar_bytes_are_one_format_error(tmp_path, content, message) -> None:
    rig = _rig()
    path = tmp_path / "r.npz"
    write_dense_rig(path, rig.to_arrays(), list(rig.labels), rig.settings)
    path.with_suffix(".json").write_bytes(content)
    with pytest.raises(FormatError, match=message):
        read_dense_rig(path)


def test_marker_parts_out_of_range_and_a_rig_without_parts_are_refused(tmp_path) -> None:
    rig = _rig()
    path = tmp_path / "r.npz"
    write_dense_rig(path, rig.to_arrays(), list(rig.labels), rig.settings)
    good = rig.to_arrays()
    for change, message in [
        (
            {"marker_parts": np.array([0, 0, 0, 1, 1, 2])},
            r"marker_parts: expected -1 \(none\) or a part 0\.\.1",
        ),
        ({"marker_parts": np.array([0, 0, -2, 1, 1, 1])}, "marker_parts: expected -1"),
        (
            {"marker_weights": np.zeros((6, 0)), "vertex_weights": np.zeros((10, 0))},
            "marker_weights: the rig has no parts",
        ),
    ]:
        with open(path, "wb") as fh:
            np.savez(fh, **{**good, **change})
        with pytest.raises(FormatError, match=r"r\.npz: " + message):
            read_dense_rig(path)
    with open(path, "wb") as fh:  # -1: a marker in no part, as the builder writes it
        np.savez(fh, **{**good, "marker_parts": np.array([0, -1, 0, 1, 1, 1])})
    assert read_dense_rig(path)[0]["marker_parts"][1] == -1


@pytest.mark.parametrize("compressed", [False, True])
def test_an_npy_header_declaring_more_than_its_member_holds_is_refused(tmp_path, compressed):
    """A header claiming shape (2**40, 3) made np.load allocate 24 TiB before reading
    (MemoryError); now the declared size is checked against the member's first."""
    import io
    import re
    import zipfile

    rig = _rig()
    path = tmp_path / "r.npz"
    write_dense_rig(path, rig.to_arrays(), list(rig.labels), rig.settings)
    src = zipfile.ZipFile(io.BytesIO(path.read_bytes()))
    mode = zipfile.ZIP_DEFLATED if compressed else zipfile.ZIP_STORED
    with zipfile.ZipFile(path, "w", compression=mode) as dst:
        for info in src.infolist():
            raw = src.read(info)
            if info.filename == "vertices.npy":
                raw = re.sub(rb"'shape': \([^)]*\)", b"'shape': (1099511627776, 3)", raw)
            dst.writestr(info.filename, raw)
    with pytest.raises(
        FormatError, match=r"vertices: the header declares shape \(1099511627776, 3\)"
    ):
        read_dense_rig(path)


def test_a_zip_member_claiming_more_bytes_than_deflate_can_make_is_refused(tmp_path):
    rig = _rig()
    path = tmp_path / "r.npz"
    write_dense_rig(path, rig.to_arrays(), list(rig.labels), rig.settings)
    data = bytearray(path.read_bytes())
    # the central directory's uncompressed size of the first member: 2**32 - 1 bytes
    first = data.index(b"PK\x01\x02")
    data[first + 24 : first + 28] = (2**32 - 1).to_bytes(4, "little")
    path.write_bytes(bytes(data))
    with pytest.raises(FormatError, match="the archive claims 4294967295 bytes"):
        read_dense_rig(path)
