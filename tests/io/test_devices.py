import pytest
import torch

from radar4dgs.io.devices import resolve_device


@pytest.mark.parametrize("available, expected", [(False, "cpu"), (True, "cuda")])
def test_auto_is_cuda_only_when_torch_sees_a_gpu(monkeypatch, available, expected):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: available)
    assert resolve_device("auto") == torch.device(expected)


@pytest.mark.parametrize("spec", ["cpu", "cuda", "cuda:1", torch.device("cpu")])
def test_explicit_devices_pass_through(spec):
    assert resolve_device(spec) == torch.device(spec)
