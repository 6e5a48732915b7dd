"""A folder packed as one file to commit: deterministic bytes, hidden leftovers out, unpacked whole or not at all."""

from __future__ import annotations

import io
import tarfile

import pytest

from snapflow.reporting.packed import pack_folder, unpack_folder


def make_folder(root, name="part"):
    folder = root / name
    (folder / "videos" / "cam").mkdir(parents=True)
    (folder / "meta.json").write_text('{"episodes": 2}\n')
    (folder / "videos" / "cam" / "file-000.mp4").write_bytes(bytes(range(256)) * 40)
    (folder / ".job.json.pending").write_text("{}\n")  # a runner's pending record
    (folder / ".lerobot.tmp-abc" / "dataset").mkdir(parents=True)  # a killed writer's staging folder
    (folder / ".lerobot.tmp-abc" / "dataset" / "frame.png").write_bytes(b"png")
    return folder


def test_a_pack_holds_the_visible_files_and_the_same_folder_packs_to_the_same_bytes(tmp_path):
    folder = make_folder(tmp_path)
    first = pack_folder(folder, tmp_path / "first.tar").read_bytes()
    (folder / "meta.json").touch()  # a later time changes nothing: no times, owners or order of the disk recorded
    again = make_folder(tmp_path, "elsewhere")
    assert pack_folder(folder, tmp_path / "second.tar").read_bytes() == first
    assert pack_folder(again, tmp_path / "third.tar").read_bytes() == first, "the folder's own path is not recorded"
    with tarfile.open(tmp_path / "first.tar") as archive:
        assert archive.getnames() == ["meta.json", "videos/cam/file-000.mp4"]

    restored = unpack_folder(tmp_path / "first.tar", tmp_path / "restored")
    assert sorted(path.relative_to(restored).as_posix() for path in restored.rglob("*") if path.is_file()) == [
        "meta.json",
        "videos/cam/file-000.mp4",
    ]
    assert (restored / "videos/cam/file-000.mp4").read_bytes() == bytes(range(256)) * 40


def test_a_pack_that_cannot_be_read_leaves_the_folder_as_it_was(tmp_path):
    target = tmp_path / "target"
    target.mkdir()
    (target / "kept.txt").write_text("before\n")
    (tmp_path / "broken.tar").write_bytes(b"not a tar at all" * 64)
    with pytest.raises(tarfile.ReadError):
        unpack_folder(tmp_path / "broken.tar", target)
    assert (target / "kept.txt").read_text() == "before\n"
    assert [path.name for path in tmp_path.iterdir() if path.name.startswith(".")] == [], "no staging folder left"


def test_a_member_outside_the_folder_is_refused(tmp_path):
    with tarfile.open(tmp_path / "evil.tar", "w") as archive:
        info = tarfile.TarInfo("../outside.txt")
        info.size = 3
        archive.addfile(info, io.BytesIO(b"bad"))
    with pytest.raises(tarfile.OutsideDestinationError):
        unpack_folder(tmp_path / "evil.tar", tmp_path / "target")
    assert not (tmp_path / "outside.txt").exists()
