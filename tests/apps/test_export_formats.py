"""`radar4dgs export --format gsplat | nerfstudio | colmap | ply --up y | --times` on the shared tiny
run: what other tools read back equals the run's Gaussians and the scene's cameras."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from radar4dgs.apps.export import export_run, gaussians_for_export
from radar4dgs.apps.export_cameras import opencv_world_to_camera, read_colmap_images
from radar4dgs.apps.export_splats import Z_UP_TO_Y_UP, apply_up
from radar4dgs.apps.ply import SH_C0, read_gaussians_ply
from radar4dgs.cli import main
from radar4dgs.io.scene import normalized_times, read_scene

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def scene(tiny_trained_run):
    return read_scene(tiny_trained_run / "scene")


def test_plyfile_reads_the_ply_as_written(trained, model, tmp_path):
    plyfile = pytest.importorskip("plyfile")
    path = export_run(trained, part="static", out=tmp_path / "s.ply").path
    vertex = plyfile.PlyData.read(str(path))["vertex"]
    names = [p.name for p in vertex.properties]
    assert names[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert sum(n.startswith("f_rest_") for n in names) == 45 and names[-4:] == ["rot_0", "rot_1", "rot_2", "rot_3"]
    params = model.static.params
    xyz = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1)
    np.testing.assert_array_equal(xyz, params["means"].detach().numpy())
    np.testing.assert_array_equal(vertex["opacity"], params["opacity_logits"].detach().numpy())
    rgb = 0.5 + SH_C0 * np.stack([vertex[f"f_dc_{k}"] for k in range(3)], axis=1)
    np.testing.assert_allclose(rgb, torch.sigmoid(params["colors"]).detach().numpy(), atol=1e-6)


def test_gsplat_checkpoint_has_the_names_and_shapes_gsplats_viewer_reads(trained, model, tmp_path):
    result = export_run(trained, "gsplat", time=0.5, out=tmp_path / "ckpt.pt")
    ckpt = torch.load(result.path, map_location="cpu", weights_only=True)
    assert set(ckpt) == {"step", "splats"} and ckpt["step"] == 20
    splats = ckpt["splats"]
    n = model.num_gaussians
    assert {k: tuple(v.shape) for k, v in splats.items()} == {
        "means": (n, 3), "quats": (n, 4), "scales": (n, 3), "opacities": (n,), "sh0": (n, 1, 3), "shN": (n, 15, 3)}
    assert all(v.dtype == torch.float32 for v in splats.values())
    # What simple_viewer.py does with them: cat([sh0, shN], -2) -> degree sqrt(16) - 1 = 3.
    assert int(np.sqrt(torch.cat([splats["sh0"], splats["shN"]], dim=-2).shape[-2]) - 1) == 3
    expected = gaussians_for_export(model, "all", 0.5)
    np.testing.assert_array_equal(splats["means"].numpy(), expected["means"])
    np.testing.assert_array_equal(splats["scales"].numpy(), expected["log_scales"])
    np.testing.assert_array_equal(splats["opacities"].numpy(), expected["opacity_logits"])
    np.testing.assert_allclose(0.5 + SH_C0 * splats["sh0"][:, 0].numpy(), expected["rgb"], atol=1e-6)
    assert not splats["shN"].any()


def test_ply_up_y_rotates_z_up_to_y_up(trained, model, tmp_path):
    assert (Z_UP_TO_Y_UP @ [0.0, 0.0, 1.0]).tolist() == [0.0, 1.0, 0.0]  # world up becomes +y
    assert (Z_UP_TO_Y_UP @ [1.0, 0.0, 0.0]).tolist() == [1.0, 0.0, 0.0]  # forward stays
    known = {"means": np.array([[1.0, 2.0, 3.0]], np.float32), "quats": np.array([[1.0, 0, 0, 0]], np.float32)}
    turned = apply_up(known, "y")
    np.testing.assert_allclose(turned["means"], [[1.0, 3.0, -2.0]], atol=1e-6)
    # The identity rotation becomes the world rotation itself: its matrix maps z to y.
    w, x, y, z = turned["quats"][0].astype(np.float64)
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    np.testing.assert_allclose(R, Z_UP_TO_Y_UP, atol=1e-6)

    result = export_run(trained, part="static", up="y")
    assert result.path.name == "scene_static_t0_yup.ply"
    ply = read_gaussians_ply(result.path)
    np.testing.assert_allclose(ply["means"], model.static.params["means"].detach().numpy() @ Z_UP_TO_Y_UP.T, atol=1e-5)


def test_times_writes_one_ply_per_frame_at_its_time(trained, model, scene, tmp_path):
    result = export_run(trained, times=True, out=tmp_path / "frames")
    assert [p.name for p in result.files] == [f"{f.name}.ply" for f in scene.frames]
    last = read_gaussians_ply(result.files[-1])
    expected = gaussians_for_export(model, "all", float(normalized_times(scene)[-1]))
    np.testing.assert_array_equal(last["means"], expected["means"])


def test_nerfstudio_transforms_equal_the_scenes_cameras(trained, scene, tmp_path, capsys):
    assert main(["export", str(trained), "--format", "nerfstudio", "--out", str(tmp_path / "ns")]) == 0
    assert "nerfstudio dataset" in capsys.readouterr().out
    meta = json.loads((tmp_path / "ns" / "transforms.json").read_text())
    assert (meta["w"], meta["h"]) == (scene.camera.width, scene.camera.height)
    K = scene.camera.K
    assert (meta["fl_x"], meta["fl_y"], meta["cx"] - 0.5, meta["cy"] - 0.5) == pytest.approx(
        (K[0, 0], K[1, 1], K[0, 2], K[1, 2]), abs=1e-9)
    assert len(meta["frames"]) == len(scene)
    times = normalized_times(scene)
    for i, frame in enumerate(meta["frames"]):
        assert (tmp_path / "ns" / frame["file_path"]).is_file()
        w2c = opencv_world_to_camera(np.array(frame["transform_matrix"]))
        np.testing.assert_allclose(w2c, scene.world_to_camera(i), atol=1e-9)
        # OpenGL axes: the camera looks down its -z, which is the scene camera's +z (forward).
        forward = np.linalg.inv(scene.world_to_camera(i))[:3, 2]
        np.testing.assert_allclose(-np.array(frame["transform_matrix"])[:3, 2], forward, atol=1e-9)
        assert frame["time"] == pytest.approx(times[i])
    assert len(meta["test_filenames"]) == len(scene.test_indices) and meta["ply_file_path"] == "sparse_pc.ply"
    header = (tmp_path / "ns" / "sparse_pc.ply").read_bytes()[:400]
    assert b"property uchar red" in header and b"element vertex " in header


def test_colmap_images_equal_the_scenes_poses(trained, scene, tmp_path):
    result = export_run(trained, "colmap", out=tmp_path / "colmap", link_images=True)
    sparse = result.path / "sparse" / "0"
    camera = (sparse / "cameras.txt").read_text().splitlines()[-1].split()
    K = scene.camera.K
    assert camera[:4] == ["1", "PINHOLE", str(scene.camera.width), str(scene.camera.height)]
    np.testing.assert_allclose([float(v) for v in camera[4:]], [K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5])
    poses = read_colmap_images(sparse / "images.txt")
    assert list(poses) == [p.name for p in scene.image_files]
    for i, name in enumerate(poses):
        np.testing.assert_allclose(poses[name], scene.world_to_camera(i), atol=1e-9)
        assert (result.path / "images" / name).is_symlink()
    points = [line for line in (sparse / "points3D.txt").read_text().splitlines() if not line.startswith("#")]
    assert len(points) > 100 and len(points[0].split()) == 8
    for name in ("cameras.bin", "images.bin", "points3D.bin"):
        assert (sparse / name).stat().st_size > 0


def test_bad_combinations_are_refused_in_one_line(trained, tmp_path, capsys):
    with pytest.raises(ValueError, match="--up and --times apply to the Gaussian formats"):
        export_run(trained, "colmap", up="y")
    if not torch.cuda.is_available():
        assert main(["export", str(trained), "--format", "splat", "--out", str(tmp_path / "x.splat")]) == 1
        err = capsys.readouterr().err
        assert "needs gsplat on a CUDA machine" in err and len(err.strip().splitlines()) == 1
        assert not (tmp_path / "x.splat").exists()
