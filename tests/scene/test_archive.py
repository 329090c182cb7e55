"""Zip archives read within limits (orchestration/scene/archive.py): the table of contents is
checked before anything is inflated, a member is never inflated past what it declares, and no
member is unpacked outside the folder it is unpacked into."""
import io
import struct
import zipfile

import pytest

from orchestration.scene import archive


def zipped(members: dict, compression=zipfile.ZIP_DEFLATED) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression) as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return buf.getvalue()


def test_extract_unpacks_every_member(tmp_path):
    src = tmp_path / "a.zip"
    src.write_bytes(zipped({"modelDescription.xml": b"<x/>", "binaries/linux64/m.so": b"\1" * 5000,
                            "resources/": b""}))
    dest = archive.extract(src, tmp_path / "out")
    assert (dest / "modelDescription.xml").read_bytes() == b"<x/>"
    assert (dest / "binaries" / "linux64" / "m.so").read_bytes() == b"\1" * 5000
    assert (dest / "resources").is_dir()


@pytest.mark.parametrize("name", ["../evil.txt", "a/../../evil.txt", "/abs/evil.txt",
                                  "C:/evil.txt", "a\\..\\evil.txt"])
def test_extract_refuses_a_member_outside_the_folder(tmp_path, name):
    src = tmp_path / "a.zip"
    src.write_bytes(zipped({"ok.txt": b"ok", name: b"evil"}))
    with pytest.raises(archive.ArchiveError, match=r"^a.zip: member .* is not a relative path "
                                                   r"inside the archive$"):
        archive.extract(src, tmp_path / "out" / "in")
    assert not list(tmp_path.rglob("evil.txt"))


@pytest.mark.parametrize("names", [("a", "a/b"), ("x/", "x"), ("d" * 300,)],
                         ids=["file-then-folder", "folder-then-file", "name-too-long"])
def test_a_member_that_cannot_be_a_file_there_is_one_line(tmp_path, names):
    """Members whose names collide as file and folder, or a name longer than the file system
    takes: an ArchiveError naming the member (raw FileExistsError, IsADirectoryError and
    ENAMETOOLONG before, a traceback of flexpend check)."""
    src = tmp_path / "a.zip"
    src.write_bytes(zipped({n: b"" if n.endswith("/") else b"data" for n in names}))
    with pytest.raises(archive.ArchiveError, match=r"^a.zip: member '.*' cannot be unpacked: "):
        archive.extract(src, tmp_path / "out")


def test_a_member_is_never_inflated_past_its_declared_size(tmp_path):
    """The table of contents says 100 bytes, the member holds 50,000: reading stops at 100 (and
    the damage is then one line, not an exception of zipfile or zlib)."""
    data = zipped({"m.bin": b"\7" * 50_000})
    at = data.index(b"PK\x01\x02")
    (tmp_path / "a.zip").write_bytes(data[:at + 24] + struct.pack("<I", 100) + data[at + 28:])
    with archive.checked_archive(tmp_path / "a.zip") as (zf, infos):
        assert infos[0].file_size == 100
        with pytest.raises(archive.ArchiveError, match=r"^a.zip: member 'm.bin' cannot be read: "
                                                       r"Bad CRC-32"):
            archive.read_member(zf, infos[0], "a.zip")
        with pytest.raises(archive.ArchiveError, match="cannot be read"):
            archive.copy_member(zf, infos[0], tmp_path / "m.bin", "a.zip")
    assert (tmp_path / "m.bin").stat().st_size <= 100


def test_read_member_caps_what_it_reads_whole(tmp_path):
    (tmp_path / "a.zip").write_bytes(zipped({"big.xml": b" " * 2000}, zipfile.ZIP_STORED))
    with archive.checked_archive(tmp_path / "a.zip") as (zf, _):
        assert archive.read_member(zf, "big.xml", "a.zip", limit=2000) == b" " * 2000
        with pytest.raises(archive.ArchiveError, match="inflates to 2000 bytes; the limit is "
                                                       "1999 bytes for a file read whole$"):
            archive.read_member(zf, "big.xml", "a.zip", limit=1999)


def test_the_limits_are_inclusive(tmp_path, monkeypatch):
    (tmp_path / "a.zip").write_bytes(zipped({f"{i}": b"x" * 10 for i in range(5)},
                                            zipfile.ZIP_STORED))
    for name, at_limit, message in (("MAX_MEMBERS", 5, "6 members"),
                                    ("MAX_MEMBER_BYTES", 10, "inflates to"),
                                    ("MAX_TOTAL_BYTES", 50, "together")):
        monkeypatch.setattr(archive, name, at_limit)
        with archive.checked_archive(tmp_path / "a.zip") as (_, infos):
            assert len(infos) == 5
        monkeypatch.setattr(archive, name, at_limit - 1)
        with pytest.raises(archive.ArchiveError, match=message if name != "MAX_MEMBERS"
                           else "5 members; the limit is 4"):
            with archive.checked_archive(tmp_path / "a.zip"):
                pass
        monkeypatch.undo()


def test_not_a_zip_is_one_line(tmp_path):
    (tmp_path / "a.fmu").write_bytes(b"hello")
    with pytest.raises(archive.ArchiveError, match=r"^a.fmu: not a zip archive: "):
        archive.check_fmu_archive(tmp_path / "a.fmu")


def test_a_symbolic_link_member_is_refused_before_anything_is_unpacked(tmp_path):
    """A member whose mode is a symbolic link (its data, the target) is refused by the FMU check
    and by extract: unpacked as a file it would hold a path, not a library; as a link, point
    anywhere."""
    import stat

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("modelDescription.xml", b"<x/>")
        link = zipfile.ZipInfo("binaries/linux64/m.so")
        link.create_system = 3
        link.external_attr = (stat.S_IFLNK | 0o777) << 16
        zf.writestr(link, str(tmp_path / "elsewhere.so"))
    (tmp_path / "a.fmu").write_bytes(buf.getvalue())
    message = r"^a.fmu: member 'binaries/linux64/m.so' is a symbolic link"
    with pytest.raises(archive.ArchiveError, match=message):
        archive.check_fmu_archive(tmp_path / "a.fmu")
    with pytest.raises(archive.ArchiveError, match=message):
        archive.extract(tmp_path / "a.fmu", tmp_path / "out")
    assert not (tmp_path / "out" / "binaries").exists()


@pytest.mark.parametrize("name", ["../evil.txt", "/abs/evil.txt"])
def test_the_fmu_check_refuses_a_member_outside_the_folder(tmp_path, name):
    (tmp_path / "a.fmu").write_bytes(zipped({"modelDescription.xml": b"<x/>", name: b"evil"}))
    with pytest.raises(archive.ArchiveError, match="is not a relative path inside the archive"):
        archive.check_fmu_archive(tmp_path / "a.fmu")
