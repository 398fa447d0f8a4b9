"""The shared output guard: inputs through links, dangling links, folders, multi-file outputs."""

from __future__ import annotations

import os

import pytest

from skincap.errors import FormatError, OutputExistsError
from skincap.io._common import atomic_output
from skincap.io.output_safety import (
    check_output,
    check_outputs,
    guard_outputs,
    is_protected_input,
    protect_inputs,
)


@pytest.fixture
def source(tmp_path):
    path = tmp_path / "in.c3d"
    path.write_bytes(b"original input bytes")
    return path


def _write(path, text="new", *, force=False):
    with atomic_output(path, force=force) as tmp:
        tmp.write_text(text)


def test_atomic_output_refuses_a_protected_input_even_with_force(source):
    with protect_inputs([source]), pytest.raises(FormatError, match="is the input"):
        _write(source, force=True)
    assert source.read_bytes() == b"original input bytes"
    assert [p.name for p in source.parent.iterdir()] == ["in.c3d"]  # no .part left


def test_symbolic_link_to_an_input_is_refused(source, tmp_path):
    link = tmp_path / "link.c3d"
    link.symlink_to(source)
    with protect_inputs([source]), pytest.raises(FormatError, match="symbolic link to the input"):
        _write(link, force=True)
    assert source.read_bytes() == b"original input bytes" and link.is_symlink()


def test_input_given_through_a_link_protects_its_target(source, tmp_path):
    link = tmp_path / "link.c3d"
    link.symlink_to(source)
    with protect_inputs([link]), pytest.raises(FormatError, match="through a link"):
        _write(source, force=True)


def test_linked_folder_is_seen_through(source, tmp_path):
    alias = tmp_path / "alias"
    alias.symlink_to(tmp_path, target_is_directory=True)
    with protect_inputs([source]), pytest.raises(FormatError, match="the input"):
        _write(alias / "in.c3d", force=True)


def test_hard_link_to_an_input_is_refused(source, tmp_path):
    twin = tmp_path / "twin.c3d"
    os.link(source, twin)
    with protect_inputs([source]), pytest.raises(FormatError, match="hard link to the input"):
        _write(twin, force=True)
    assert twin.read_bytes() == b"original input bytes"


def test_dangling_symbolic_link_is_refused_not_replaced(tmp_path):
    link = tmp_path / "out.c3d"
    link.symlink_to(tmp_path / "missing" / "target.c3d")
    for force in (False, True):
        with pytest.raises(FormatError, match="symbolic link to a missing file"):
            _write(link, force=force)
    assert link.is_symlink() and not link.exists()


def test_folder_as_a_file_output_is_refused(tmp_path):
    (tmp_path / "out.c3d").mkdir()
    with pytest.raises(FormatError, match="is a folder"):
        check_output(tmp_path / "out.c3d", force=True)


def test_existing_output_needs_force(tmp_path):
    target = tmp_path / "out.c3d"
    target.write_text("old")
    with pytest.raises(OutputExistsError):
        _write(target)
    _write(target, "new", force=True)
    assert target.read_text() == "new"


def test_two_outputs_naming_one_file_are_refused(tmp_path):
    with pytest.raises(FormatError, match="is also the output"):
        check_outputs([tmp_path / "a.json", tmp_path / "." / "a.json"])


def test_guard_checks_every_output_before_the_block_runs(source, tmp_path):
    first, second = tmp_path / "x.pc2", tmp_path / "x.obj"
    second.write_text("exists")
    ran = []
    with pytest.raises(OutputExistsError), guard_outputs([source], [first, second]):
        ran.append(True)
    assert not ran and not first.exists()


def test_guard_refuses_an_output_in_a_missing_folder_before_the_block_runs(source, tmp_path):
    """animate --save-rig rig.npz -o missing/x.pc2 wrote the rig, then failed on the cache."""
    rig, cache = tmp_path / "rig.npz", tmp_path / "missing" / "x.pc2"
    ran = []
    with pytest.raises(FormatError, match="folder .*missing.* does not exist"):
        with guard_outputs([source], [rig, cache]):
            ran.append(True)
    assert not ran and not rig.exists()
    made = tmp_path / "made"  # a folder the block makes holds its outputs, even nested
    with guard_outputs([source], [made / "a.json", made / "plots" / "b.png"], folders=[made]):
        ran.append(True)
    assert ran == [True]


def test_folder_input_protects_its_files_but_takes_new_ones(tmp_path):
    folder = tmp_path / "take"
    (folder / "truth").mkdir(parents=True)
    (folder / "truth" / "markers.c3d").write_text("truth")
    with protect_inputs([folder]):
        assert is_protected_input(folder / "truth" / "markers.c3d")
        with pytest.raises(FormatError):
            _write(folder / "truth" / "markers.c3d", force=True)
        _write(folder / "report.json")  # a new file modifies no input
    assert not is_protected_input(folder / "truth" / "markers.c3d")  # the block ended


def test_protection_nests_and_ends_with_its_block(source, tmp_path):
    other = tmp_path / "other.bvh"
    other.write_text("x")
    with protect_inputs([source]):
        with protect_inputs([other]):
            assert is_protected_input(source) and is_protected_input(other)
        assert is_protected_input(source) and not is_protected_input(other)
    assert not is_protected_input(source)


def test_a_folder_the_block_made_is_removed_when_it_fails(tmp_path):
    """'skincap demo --frames 1e14' made its output folder, then failed: the empty
    folder stayed behind. A folder that did not exist before the block goes again."""
    from skincap.errors import ValidationError

    new = tmp_path / "new" / "deeper"
    old = tmp_path / "old"
    old.mkdir()
    (old / "keep.txt").write_text("x")
    with pytest.raises(ValidationError, match="half-way"):
        with guard_outputs([], [new / "a.txt"], folders=[new, old], force=True):
            new.mkdir(parents=True)
            (new / "a.txt").write_text("partial")
            (old / "b.txt").write_text("partial")
            raise ValidationError("failed half-way")
    assert not new.exists()
    assert (old / "keep.txt").read_text() == "x"  # a folder that was there stays
    # and one the block completes is kept
    with guard_outputs([], [new / "a.txt"], folders=[new]):
        new.mkdir(parents=True)
        (new / "a.txt").write_text("done")
    assert (new / "a.txt").read_text() == "done"
