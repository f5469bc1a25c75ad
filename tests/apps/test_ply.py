"""Standard 3DGS .ply export: exact float32 round trip, header layout, file size, bad inputs."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from radar4dgs.apps.ply import SH_C0, property_names, read_gaussians_ply, write_gaussians_ply

torch.set_num_threads(1)


def random_gaussians(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {
        "means": rng.normal(0, 10, (n, 3)),
        "quats": rng.normal(0, 1, (n, 4)),
        "log_scales": rng.normal(-3, 1, (n, 3)),
        "opacity_logits": rng.normal(0, 2, n),
        "rgb": rng.uniform(0, 1, (n, 3)),
    }


def read_header(path) -> tuple[list[str], int]:
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    return data[:end].decode("ascii").splitlines(), end


def test_round_trip_is_exact_in_float32(tmp_path):
    g = random_gaussians(257)
    path = write_gaussians_ply(tmp_path / "out" / "splats.ply", **g)
    back = read_gaussians_ply(path)
    f32 = np.float32
    np.testing.assert_array_equal(back["means"], g["means"].astype(f32))
    np.testing.assert_array_equal(back["quats"], g["quats"].astype(f32))
    np.testing.assert_array_equal(back["log_scales"], g["log_scales"].astype(f32))
    np.testing.assert_array_equal(back["opacity_logits"], g["opacity_logits"].astype(f32))
    np.testing.assert_array_equal(back["f_dc"], ((g["rgb"] - 0.5) / SH_C0).astype(f32))
    np.testing.assert_array_equal(back["normals"], np.zeros((257, 3), f32))
    np.testing.assert_array_equal(back["f_rest"], np.zeros((257, 3, 15), f32))
    np.testing.assert_allclose(back["rgb"], g["rgb"], atol=1e-6)
    assert back["sh_degree"] == 3
    for key in ("means", "quats", "log_scales", "opacity_logits", "f_dc", "rgb"):
        assert back[key].dtype == np.float32
    # No temporary file left beside the output.
    assert [p.name for p in path.parent.iterdir()] == ["splats.ply"]


def test_torch_inputs_match_numpy_inputs(tmp_path):
    g = random_gaussians(31, seed=1)
    write_gaussians_ply(tmp_path / "np.ply", **g)
    write_gaussians_ply(tmp_path / "torch.ply",
                        **{k: torch.from_numpy(v).float().requires_grad_(True) for k, v in g.items()})
    a, b = read_gaussians_ply(tmp_path / "np.ply"), read_gaussians_ply(tmp_path / "torch.ply")
    for key in ("means", "quats", "log_scales", "opacity_logits"):
        np.testing.assert_array_equal(a[key], b[key])
    np.testing.assert_allclose(a["f_dc"], b["f_dc"], atol=1e-6)


@pytest.mark.parametrize("degree, n_rest", [(0, 0), (1, 9), (3, 45)])
def test_header_order_and_file_size(tmp_path, degree, n_rest):
    n = 17
    path = write_gaussians_ply(tmp_path / "s.ply", **random_gaussians(n), sh_degree=degree)
    lines, header_size = read_header(path)
    assert lines[0] == "ply"
    assert lines[1] == "format binary_little_endian 1.0"
    assert f"element vertex {n}" in lines
    props = [line.split()[2] for line in lines if line.startswith("property")]
    assert all(line.split()[1] == "float" for line in lines if line.startswith("property"))
    expected = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
                + [f"f_rest_{i}" for i in range(n_rest)]
                + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])
    assert props == expected == property_names(degree)
    assert lines[-1] == "end_header"
    assert path.stat().st_size == header_size + n * len(expected) * 4
    back = read_gaussians_ply(path)
    assert back["sh_degree"] == degree
    assert back["f_rest"].shape == (n, 3, n_rest // 3)
    assert back["properties"] == expected


def test_rows_are_little_endian_float32_in_header_order(tmp_path):
    g = random_gaussians(3, seed=2)
    path = write_gaussians_ply(tmp_path / "s.ply", **g, sh_degree=0)
    _, header_size = read_header(path)
    rows = np.frombuffer(path.read_bytes()[header_size:], dtype="<f4").reshape(3, 17)
    np.testing.assert_array_equal(rows[:, 0:3], g["means"].astype(np.float32))
    np.testing.assert_array_equal(rows[:, 9], g["opacity_logits"].astype(np.float32))
    np.testing.assert_array_equal(rows[:, 13:17], g["quats"].astype(np.float32))


def test_empty_set_round_trips(tmp_path):
    path = write_gaussians_ply(tmp_path / "e.ply", **random_gaussians(0))
    back = read_gaussians_ply(path)
    assert back["means"].shape == (0, 3) and back["f_rest"].shape == (0, 3, 15)


def test_read_accepts_reordered_double_properties_without_normals(tmp_path):
    # Another tool's file: different order, doubles, no normals, degree 0.
    names = ["opacity", "x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "rot_0", "rot_1", "rot_2",
             "rot_3", "scale_0", "scale_1", "scale_2"]
    values = np.arange(2 * len(names), dtype="<f8").reshape(2, len(names))
    header = ("ply\nformat binary_little_endian 1.0\ncomment other tool\nelement vertex 2\n"
              + "".join(f"property double {n}\n" for n in names) + "end_header\n")
    path = tmp_path / "other.ply"
    path.write_bytes(header.encode() + values.tobytes())
    back = read_gaussians_ply(path)
    np.testing.assert_array_equal(back["means"], values[:, 1:4].astype(np.float32))
    np.testing.assert_array_equal(back["opacity_logits"], values[:, 0].astype(np.float32))
    np.testing.assert_array_equal(back["quats"], values[:, 7:11].astype(np.float32))
    np.testing.assert_array_equal(back["normals"], np.zeros((2, 3), np.float32))
    assert back["sh_degree"] == 0


def test_read_errors_name_the_file(tmp_path):
    path = tmp_path / "missing_opacity.ply"
    names = [n for n in property_names(0) if n != "opacity"]
    header = ("ply\nformat binary_little_endian 1.0\nelement vertex 1\n"
              + "".join(f"property float {n}\n" for n in names) + "end_header\n")
    path.write_bytes(header.encode() + np.zeros(len(names), "<f4").tobytes())
    with pytest.raises(ValueError, match=r"missing_opacity\.ply.*missing vertex properties \['opacity'\]"):
        read_gaussians_ply(path)

    good = write_gaussians_ply(tmp_path / "t.ply", **random_gaussians(4))
    truncated = tmp_path / "truncated.ply"
    truncated.write_bytes(good.read_bytes()[:-10])
    with pytest.raises(ValueError, match=r"truncated\.ply.*truncated"):
        read_gaussians_ply(truncated)

    ascii_ply = tmp_path / "ascii.ply"
    ascii_ply.write_text("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nend_header\n")
    with pytest.raises(ValueError, match=r"ascii\.ply.*not supported"):
        read_gaussians_ply(ascii_ply)

    not_ply = tmp_path / "image.ply"
    not_ply.write_bytes(b"\x89PNG\r\n")
    with pytest.raises(ValueError, match=r"image\.ply.*not a PLY"):
        read_gaussians_ply(not_ply)


@pytest.mark.parametrize("key, value, message", [
    ("means", np.zeros((5, 2)), r"means has shape \(5, 2\), expected \(5, 3\)"),
    ("quats", np.zeros((5, 3)), r"quats has shape \(5, 3\), expected \(5, 4\)"),
    ("opacity_logits", np.zeros((5, 1)), r"opacity_logits has shape \(5, 1\), expected \(5,\)"),
    ("log_scales", np.full((5, 3), np.nan), r"log_scales has 5 row\(s\) with NaN or inf"),
    ("rgb", np.full((5, 3), 255.0), r"rgb must lie in \[0, 1\]"),
    ("quats", np.zeros((5, 4)), r"zero quaternion"),
    ("means", np.full((5, 3), 1e300), r"means has values that overflow float32"),
])
def test_bad_inputs_raise_clear_errors(tmp_path, key, value, message):
    g = random_gaussians(5)
    g[key] = value
    with pytest.raises(ValueError, match=message):
        write_gaussians_ply(tmp_path / "bad.ply", **g)
    assert not (tmp_path / "bad.ply").exists()


def test_bad_degree_and_dtype(tmp_path):
    g = random_gaussians(2)
    for degree in (-1, 4, 1.5, True):
        with pytest.raises(ValueError, match="sh_degree"):
            write_gaussians_ply(tmp_path / "bad.ply", **g, sh_degree=degree)
    g["means"] = np.array([["a", "b", "c"], ["d", "e", "f"]])
    with pytest.raises(TypeError, match="means"):
        write_gaussians_ply(tmp_path / "bad.ply", **g)
