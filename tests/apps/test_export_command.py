"""`radar4dgs export RUN --format ply` on one tiny trained run: the file read back holds the model's
Gaussians (static exactly, dynamic moved by the field to the asked time), and bad inputs are named."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from radar4dgs.apps.export import default_export_path, export_run
from radar4dgs.apps.ply import read_gaussians_ply
from radar4dgs.cli import main
from radar4dgs.evaluate.reconstruction import load_run
from radar4dgs.model.motion_models import temporal_visibility

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def numpy(tensor: torch.Tensor) -> np.ndarray:
    return tensor.detach().float().cpu().numpy()


def test_static_part_is_the_static_gaussians_exactly(trained, model):
    result = export_run(trained, part="static")
    assert result.path == trained / "export" / "scene_static_t0.ply"
    ply = read_gaussians_ply(result.path)
    static = model.static.params
    assert len(ply["means"]) == len(model.static) == result.n_static and result.n_dynamic == 0
    np.testing.assert_array_equal(ply["means"], numpy(static["means"]))
    np.testing.assert_array_equal(ply["log_scales"], numpy(static["log_scales"]))
    np.testing.assert_array_equal(ply["opacity_logits"], numpy(static["opacity_logits"]))
    np.testing.assert_allclose(ply["rgb"], numpy(torch.sigmoid(static["colors"])), atol=1e-6)
    quats = numpy(static["quats"] / static["quats"].norm(dim=-1, keepdim=True))
    np.testing.assert_allclose(ply["quats"], quats, atol=1e-7)


def test_all_part_moves_the_dynamic_gaussians_with_the_field(trained, model, tmp_path):
    assert model.dynamic is not None and len(model.dynamic) > 0 and model.field is not None
    n_static, n_dynamic = len(model.static), len(model.dynamic)
    canonical = model.dynamic.params["means"]
    at_half = read_gaussians_ply(export_run(trained, part="all", time=0.5, out=tmp_path / "half.ply").path)
    at_zero = read_gaussians_ply(export_run(trained, part="all", time=0.0, out=tmp_path / "zero.ply").path)
    assert len(at_half["means"]) == model.num_gaussians == n_static + n_dynamic
    np.testing.assert_array_equal(at_half["means"][:n_static], numpy(model.static.params["means"]))
    with torch.no_grad():
        expected_half = numpy(model.field(canonical, 0.5))
        expected_zero = numpy(model.field(canonical, 0.0))
    np.testing.assert_allclose(at_half["means"][n_static:], expected_half, rtol=0, atol=1e-6)
    np.testing.assert_allclose(at_zero["means"][n_static:], expected_zero, rtol=0, atol=1e-6)
    # The time matters (the objects moved between t=0 and t=0.5) ...
    assert np.abs(at_half["means"][n_static:] - at_zero["means"][n_static:]).max() > 1e-3
    # ... positions move, rotations, scales and colours are the stored ones ...
    for key in ("quats", "log_scales", "rgb"):
        np.testing.assert_array_equal(at_half[key], at_zero[key])
    # ... and a dynamic Gaussian's opacity is its stored one times its visibility at that time, with the
    # held-out window of the model's training-frame times (t = 0.5 may lie between two of them).
    np.testing.assert_array_equal(at_half["opacity_logits"][:n_static], at_zero["opacity_logits"][:n_static])
    assert model.key_times and model.window_fraction > 0
    with torch.no_grad():
        stored = torch.sigmoid(model.dynamic.params["opacity_logits"])
        for exported, time in ((at_half, 0.5), (at_zero, 0.0)):
            flat = model.window_fraction * min(abs(time - key) for key in model.key_times)
            visible = temporal_visibility(model.dynamic.params["tau"], model.dynamic.params["log_lifespan"], time,
                                          flat)
            np.testing.assert_allclose(1 / (1 + np.exp(-exported["opacity_logits"][n_static:])),
                                       numpy(stored * visible), rtol=1e-4, atol=1e-6)
    quats = model.dynamic.params["quats"]
    np.testing.assert_allclose(at_half["quats"][n_static:], numpy(quats / quats.norm(dim=-1, keepdim=True)),
                               atol=1e-7)


def test_cli_default_path_and_a_model_without_dynamics(trained, model, tmp_path, capsys):
    assert main(["export", str(trained), "--time", "1", "--sh-degree", "0"]) == 0
    out = capsys.readouterr().out
    assert f"{model.num_gaussians} Gaussians" in out and "positions only" in out
    path = default_export_path(trained, "all", 1.0)
    assert path.name == "scene_all_t1.ply" and read_gaussians_ply(path)["sh_degree"] == 0

    static_only = load_run(trained)  # a fresh copy: the module's model stays intact
    static_only.model.dynamic = None
    result = export_run(static_only, part="all", out=tmp_path / "static_only.ply")
    assert result.n_dynamic == 0 and len(read_gaussians_ply(result.path)["means"]) == len(model.static)


def test_bad_inputs_give_clear_errors(trained, tmp_path, capsys):
    with pytest.raises(ValueError, match="unknown export format 'obj'; supported: ply"):
        export_run(trained, fmt="obj")
    # The command line refuses it before running, in one line.
    assert main(["export", str(trained), "--format", "obj"]) == 2
    assert "invalid choice 'obj' for argument '--format'" in capsys.readouterr().err
    with pytest.raises(ValueError, match="unknown part 'dynamic'"):
        export_run(trained, part="dynamic")
    for bad in (1.5, -0.1, float("nan")):
        with pytest.raises(ValueError, match=r"--time must be a normalised scene time in \[0, 1\]"):
            export_run(trained, time=bad)
    assert main(["export", str(trained), "--time", "2"]) == 1
    assert "--time must be a normalised scene time in [0, 1]" in capsys.readouterr().err
    assert not (trained / "export" / "scene_all_t2.ply").exists()

    empty = tmp_path / "run_without_model"
    empty.mkdir()
    (empty / "config.json").write_text((trained / "config.json").read_text())
    with pytest.raises(FileNotFoundError, match="model.pt: missing; is .* a finished `radar4dgs train` run"):
        export_run(empty)
    assert main(["export", str(empty)]) == 1
    assert "model.pt: missing" in capsys.readouterr().err


def test_a_pvg_run_exports_its_gaussians_where_and_as_visible_as_they_are_at_that_time(
        tiny_trained_run, tmp_path, one_torch_thread):
    from radar4dgs.train.trainer import train_run
    from radar4dgs.train.variants import variant_config

    scene = tiny_trained_run / "scene"
    config = variant_config("tiny", "pvg", threads=1, optim={"iterations": 6},
                            init={"points_per_frame": 300, "max_static": 1500})
    state = train_run(scene, scene / "prepared", tmp_path / "pvg", config, progress=False)
    for time in (0.2, 0.9):
        path = export_run(tmp_path / "pvg", time=time, out=tmp_path / f"pvg_{time}.ply").path
        data = read_gaussians_ply(path)
        with torch.no_grad():
            expected = state.model.set_at("static", time)
        np.testing.assert_allclose(data["means"], expected["means"].numpy(), rtol=0, atol=1e-6)
        opacity = 1.0 / (1.0 + np.exp(-data["opacity_logits"].astype(np.float64)))
        np.testing.assert_allclose(opacity, expected["opacities"].numpy().clip(1e-6, 1 - 1e-6), rtol=1e-4, atol=1e-6)
