"""Long drives (issue 26): the trainer reads a frame's targets when it is drawn and keeps a bounded
number of them (``TrainConfig.frame_cache``); the result does not depend on the cache size."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from radar4dgs.config import preset
from radar4dgs.model.config import TrainConfig
from radar4dgs.train.data import FrameMasks, FrameTargetCache
from radar4dgs.train.trainer import Trainer


def test_the_cache_keeps_the_most_recently_used_frames():
    loaded = []

    def load(k):
        loaded.append(k)
        return f"frame {k}"

    cache = FrameTargetCache(load, 5, size=2)
    assert len(cache) == 5 and cache[0] == "frame 0" and cache[-1] == "frame 4"
    assert cache[0] == "frame 0" and loaded == [0, 4]  # a hit
    cache[1]  # drops 4, the least recently used (0 was used after it)
    cache[0]
    cache[4]
    assert loaded == [0, 4, 1, 4] and cache.loads == 4
    assert [t for t in cache] == [f"frame {k}" for k in range(5)]
    with pytest.raises(IndexError):
        cache[5]
    every = FrameTargetCache(load, 3, size=0)  # 0 keeps every frame
    list(every), list(every)
    assert every.loads == 3
    with pytest.raises(ValueError, match="frame_cache must be >= 0"):
        FrameTargetCache(load, 3, size=-1)
    with pytest.raises(ValueError, match="frame_cache must be >= 0"):
        preset(TrainConfig, "tiny", frame_cache=-1)


def test_masks_are_read_when_asked_for():
    reads = []
    masks = FrameMasks(lambda i: reads.append(i) or np.full((2, 2), i == 3), [1, 3])
    assert list(masks) == [1, 3] and len(masks) == 2 and reads == []
    assert masks[3].all() and not masks[1].any() and reads == [3, 1]
    with pytest.raises(KeyError):
        masks[2]


def test_training_with_a_small_cache_gives_the_same_run(tiny_trained_run, tmp_path, one_torch_thread):
    scene = tiny_trained_run / "scene"
    states = {}
    for size in (0, 2):
        config = preset(TrainConfig, "tiny", threads=1, frame_cache=size, optim={"iterations": 6},
                        init={"points_per_frame": 300, "max_static": 1500, "max_dynamic": 300})
        trainer = Trainer(scene, scene / "prepared", tmp_path / f"run{size}", config, progress=False,
                          tensorboard=False)
        states[size] = trainer.train()
        held = trainer.targets.held
        assert held == (len(trainer.train_indices) if size == 0 else 2)
    a, b = (states[s].model.payload() for s in (0, 2))
    assert a["static"].keys() == b["static"].keys()
    for name in a["static"]:
        assert torch.equal(a["static"][name], b["static"][name]), name
    assert torch.equal(a["sky"], b["sky"])
