import numpy as np
import pytest

from asg.io.pcd import read_pcd, write_pcd


def test_pcd_round_trip_with_open3d(tmp_path):
    o3d = pytest.importorskip("open3d")
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(500, 4)).astype(np.float32)
    path = tmp_path / "c.pcd"
    write_pcd(path, pts)
    assert np.array_equal(read_pcd(path), pts)
    cloud = o3d.t.io.read_point_cloud(str(path))
    assert np.allclose(cloud.point.positions.numpy(), pts[:, :3])
    assert np.allclose(cloud.point.intensity.numpy().ravel(), pts[:, 3])


def _npz_with_member(path, name: str, payload: bytes, compress: int = 0) -> None:
    """An .npz holding one member ``name`` of raw bytes ``payload``."""
    import zipfile

    with zipfile.ZipFile(path, "w", compression=compress) as archive:
        archive.writestr(name, payload)


def _npy_header(shape: tuple, dtype: str = "<f8") -> bytes:
    import io

    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": dtype, "fortran_order": False, "shape": shape})
    return buf.getvalue()


def test_an_npz_is_read_as_numpy_reads_it(tmp_path):
    """load_npz gives np.load's arrays: dtypes, shapes, Fortran order, scalars, strings, empty arrays."""
    from sumo_scenarios.npz import load_npz

    arrays = {"f": np.arange(12.0).reshape(3, 4), "F": np.asfortranarray(np.arange(6, dtype=np.int32).reshape(2, 3)),
              "b": np.array([True, False]), "s": np.array("settings text"), "e": np.zeros((0, 7)),
              "u8": np.arange(5, dtype=np.uint8)}
    np.savez(tmp_path / "a.npz", **arrays)
    np.savez_compressed(tmp_path / "c.npz", **arrays)
    for name, bound in (("a.npz", 0), ("c.npz", 1 << 20)):
        read = load_npz(tmp_path / name, bound)
        assert read.keys() == arrays.keys()
        for k, v in arrays.items():
            assert read[k].dtype == v.dtype and read[k].shape == v.shape and np.array_equal(read[k], v)
        read["f"][0, 0] = -1.0  # writable, as np.load's arrays are


@pytest.mark.parametrize("make,needle", [
    # a header declaring 10^12 float64 in a member of 128 bytes: np.load allocates 8 TB first
    (lambda p: _npz_with_member(p, "x.npy", _npy_header((10 ** 12,))), "declares 8000000000000 bytes of data and holds 0"),
    (lambda p: _npz_with_member(p, "x.npy", _npy_header((4,)) + b"\0" * 8), "declares 32 bytes of data and holds 8"),
    # 64 MB of zeros deflated to about 64 kB
    (lambda p: _npz_with_member(p, "x.npy", _npy_header((8 << 20,)) + bytes(64 << 20), compress=8), "unpacks to"),
    (lambda p: np.savez(p, x=np.array([{"a": 1}], dtype=object)), "holds Python objects"),
    (lambda p: _npz_with_member(p, "notes.txt", b"hello"), "not an array"),
])
def test_a_hostile_npz_is_refused_before_anything_is_allocated(tmp_path, make, needle):
    from sumo_scenarios.npz import load_npz

    path = tmp_path / "h.npz"
    make(path)
    with pytest.raises(ValueError, match=needle):
        load_npz(path)


def test_a_truncated_npz_is_an_error_numpy_names(tmp_path):
    import zipfile

    from sumo_scenarios.npz import load_npz

    np.savez(tmp_path / "a.npz", x=np.arange(1000.0))
    data = (tmp_path / "a.npz").read_bytes()
    (tmp_path / "t.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises((zipfile.BadZipFile, EOFError, OSError, ValueError)):
        load_npz(tmp_path / "t.npz")


def test_an_npz_whose_index_claims_more_than_the_file_holds_is_refused(tmp_path):
    """A stored member whose header declares 2 GiB of data and whose sizes in the zip index were
    raised to match, in a file of a few hundred bytes: reading it would ask the file for 2 GiB at
    once. It is refused from the index."""
    import struct

    from sumo_scenarios.npz import load_npz

    header = _npy_header((2 ** 28,))
    _npz_with_member(tmp_path / "a.npz", "x.npy", header)
    data = bytearray((tmp_path / "a.npz").read_bytes())
    claimed = struct.pack("<II", len(header) + 8 * 2 ** 28, len(header) + 8 * 2 ** 28)
    data[18:26] = claimed  # the local header's compressed and uncompressed sizes
    central = data.rindex(b"PK\x01\x02")
    data[central + 20:central + 28] = claimed  # the central directory's
    (tmp_path / "a.npz").write_bytes(bytes(data))
    with pytest.raises(ValueError, match="sizes the file does not hold"):
        load_npz(tmp_path / "a.npz")
