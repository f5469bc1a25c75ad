"""`radar4dgs train` before it trains: a run folder of another config is refused saying what
differs (--force overwrites), a finished run is not trained over without --resume or --force, and
a prepared folder of another scene is refused."""

from __future__ import annotations

import json

import pytest

from radar4dgs.apps.train import check_prepared_scene, existing_run_conflict
from radar4dgs.config import preset, save_config
from radar4dgs.model.config import TrainConfig


def make_run(run, config, finished: bool = True):
    run.mkdir(parents=True)
    save_config(config, run / "config.json")
    (run / "run.json").write_text("{}")
    if finished:
        (run / "model.pt").write_bytes(b"model")
    else:
        (run / "checkpoints").mkdir()
        (run / "checkpoints" / "last.pt").write_bytes(b"checkpoint")


def test_a_run_of_another_config_is_refused_with_what_differs(tmp_path):
    config = preset(TrainConfig, "tiny")
    assert existing_run_conflict(tmp_path / "nothing", config, resume=False) is None
    run = tmp_path / "run"
    make_run(run, preset(TrainConfig, "tiny", optim={"iterations": 7}, threads=3))
    for resume in (False, True):
        conflict = existing_run_conflict(run, config, resume=resume)
        assert conflict.startswith(f"{run / 'config.json'}: the run there was trained with another config "
                                   f"(optim.iterations: 7 != {config.optim.iterations})")
        assert "pass --force to overwrite it" in conflict and "threads" not in conflict


@pytest.mark.parametrize("finished", [True, False])
def test_a_run_of_the_same_config_needs_resume_or_force(tmp_path, finished):
    config = preset(TrainConfig, "tiny")
    run = tmp_path / "run"
    make_run(run, preset(TrainConfig, "tiny", threads=5), finished=finished)  # threads do not count
    conflict = existing_run_conflict(run, config, resume=False)
    assert conflict.startswith(f"{run}: holds a {'finished run' if finished else 'run (checkpoint'}")
    assert "--resume to continue it, --force to train it again" in conflict
    assert existing_run_conflict(run, config, resume=True) is None
    # A folder whose training never reached a checkpoint holds nothing to keep: trained anew.
    for path in (run / "model.pt", run / "checkpoints" / "last.pt"):
        path.unlink(missing_ok=True)
    assert existing_run_conflict(run, config, resume=False) is None


def test_force_deletes_only_a_run_folder(tmp_path):
    from radar4dgs.apps.reuse import remove_run

    run = tmp_path / "run"
    make_run(run, preset(TrainConfig, "tiny"))
    (run / "renders").mkdir()
    remove_run(run)
    assert not run.exists()
    other = tmp_path / "prepared"
    other.mkdir()
    (other / "config.json").write_text("{}")
    with pytest.raises(ValueError, match="not a run folder"):
        remove_run(other)
    assert (other / "config.json").is_file()


def test_a_prepared_folder_of_another_scene_is_refused(tmp_path):
    scene, prepared = tmp_path / "scene", tmp_path / "prepared"
    scene.mkdir()
    (scene / "scene.json").write_text('{"name": "a"}')
    (prepared / "radar").mkdir(parents=True)
    (prepared / "radar" / "stage.json").write_text(json.dumps({"scene": "0" * 64}))
    with pytest.raises(ValueError, match=r"prepared/radar: prepared for another scene.json than"):
        check_prepared_scene(scene, prepared)
    import hashlib

    (prepared / "radar" / "stage.json").write_text(
        json.dumps({"scene": hashlib.sha256((scene / "scene.json").read_bytes()).hexdigest()}))
    check_prepared_scene(scene, prepared)  # its own scene: accepted
