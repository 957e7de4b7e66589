"""The streamed LAS/LAZ reader and writer of dense/point_cloud_io.py against the whole-file ones, on a small
cloud read in chunks smaller than it: the same points, colours and attributes, in the same order; the
streamed writer leaves no partial file when it fails; bad files are named."""

from __future__ import annotations

import numpy as np
import pytest

from georef_core.dense.point_cloud_io import (copy_point_cloud, dense_cloud_header, dense_points, iter_point_cloud,
                                              open_point_cloud, point_chunks, point_cloud_writer, read_point_cloud,
                                              write_point_cloud)
from georef_core.errors import InputFileError


def _cloud(n: int, seed: int = 5):
    rng = np.random.default_rng(seed)
    xyz = np.column_stack([rng.uniform(447900, 448100, n), rng.uniform(5411900, 5412100, n), rng.uniform(90, 130, n)])
    return xyz, rng.integers(0, 256, (n, 3)).astype(np.uint8), rng.integers(2, 14, n)


@pytest.mark.parametrize("suffix", [".laz", ".las"])
def test_chunked_reader_gives_the_whole_readers_cloud(tmp_path, suffix):
    xyz, rgb, views = _cloud(2500)
    path = write_point_cloud(tmp_path / f"p{suffix}", xyz, rgb, 32631, n_views=views)
    whole_xyz, whole_rgb, crs, las = read_point_cloud(path)
    chunks = list(iter_point_cloud(path, chunk_points=1000))
    assert [len(c[0]) for c in chunks] == [1000, 1000, 500]
    assert np.array_equal(np.concatenate([c[0] for c in chunks]), whole_xyz)
    assert np.array_equal(np.concatenate([c[1] for c in chunks]), whole_rgb)
    assert np.array_equal(np.concatenate([np.asarray(c[2].user_data) for c in chunks]), np.asarray(las.user_data))
    assert np.max(np.abs(whole_xyz - xyz)) <= 0.0005 + 1e-9 and np.array_equal(whole_rgb, rgb)
    with open_point_cloud(path) as reader:
        assert reader.header.point_count == 2500 and reader.header.parse_crs() == crs
    # a streamed copy in the other encoding (the API serves the LAZ as LAS so): the same cloud
    other = tmp_path / ("copy.las" if suffix == ".laz" else "copy.laz")
    assert copy_point_cloud(path, other, chunk_points=1000) == 2500
    c_xyz, c_rgb, c_crs, c_las = read_point_cloud(other)
    assert c_las.header.are_points_compressed == (other.suffix == ".laz")
    assert np.array_equal(c_xyz, whole_xyz) and np.array_equal(c_rgb, whole_rgb) and c_crs == crs
    assert np.array_equal(np.asarray(c_las.user_data), np.asarray(las.user_data))


def test_streamed_writer_assembles_chunks_as_the_whole_writer_does(tmp_path):
    xyz, rgb, views = _cloud(3000, seed=8)
    whole = write_point_cloud(tmp_path / "whole.laz", xyz, rgb, 32631, n_views=views)
    header = dense_cloud_header(32631, np.floor(xyz.min(axis=0)))
    with point_cloud_writer(tmp_path / "streamed.laz", header) as writer:
        for a in range(0, 3000, 700):
            writer.write_points(dense_points(header, xyz[a:a + 700], rgb[a:a + 700], n_views=views[a:a + 700]))
    assert not (tmp_path / "streamed.laz.part.laz").exists()
    a_xyz, a_rgb, a_crs, a_las = read_point_cloud(whole)
    b_xyz, b_rgb, b_crs, b_las = read_point_cloud(tmp_path / "streamed.laz")
    assert np.array_equal(a_xyz, b_xyz) and np.array_equal(a_rgb, b_rgb) and a_crs == b_crs
    assert np.array_equal(a_las.user_data, b_las.user_data) and np.array_equal(a_las.classification,
                                                                               b_las.classification)
    assert np.allclose(a_las.header.mins, b_las.header.mins) and np.allclose(a_las.header.maxs, b_las.header.maxs)

    # a failure while writing: no file under the final name, no partial file left
    with pytest.raises(RuntimeError):
        with point_cloud_writer(tmp_path / "failed.laz", header) as writer:
            writer.write_points(dense_points(header, xyz[:10], rgb[:10]))
            raise RuntimeError("stopped")
    assert not (tmp_path / "failed.laz").exists() and not (tmp_path / "failed.laz.part.laz").exists()


def test_bad_files_are_named(tmp_path):
    with pytest.raises(InputFileError, match="missing.laz.*not found"):
        list(iter_point_cloud(tmp_path / "missing.laz"))
    (tmp_path / "text.las").write_text("not a point cloud\n")
    with pytest.raises(InputFileError, match="text.las.*not a readable LAS/LAZ"):
        list(iter_point_cloud(tmp_path / "text.las"))
    # a LAZ cut short: the header reads, the points do not
    xyz, rgb, _ = _cloud(20000, seed=9)
    path = write_point_cloud(tmp_path / "cut.laz", xyz, rgb, 32631)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputFileError, match="cut.laz"):
        with open_point_cloud(path) as reader:
            for _ in point_chunks(reader, path, 4000):
                pass
