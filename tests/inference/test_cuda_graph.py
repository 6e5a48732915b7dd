"""``CudaGraphReplay``, the one CUDA graph a ``deploy`` chunk replays: on a GPU only (CI has none; the lent GPU
machine runs this file before it times anything, ``scripts/gpu_latency.sh``)."""

from __future__ import annotations

import pytest
import torch

from snapflow.inference.compile import CudaGraphReplay

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA graphs need a CUDA GPU")


def chunk(observation: dict[str, torch.Tensor], noise: torch.Tensor) -> torch.Tensor:
    """A stand-in for a one-step chunk: a prefix from the observation, then a jump that reads it."""
    prefix = torch.tanh(observation["image"].flatten(1) @ observation["weight"]).sum(dim=1, keepdim=True)
    return noise - prefix[:, :, None] * noise.square()


def observation(batch: int, generator: torch.Generator) -> dict[str, torch.Tensor]:
    return {
        "image": torch.randn(batch, 3, 8, 8, generator=generator).cuda(),
        "weight": torch.randn(192, 16, generator=generator).cuda(),
    }


@pytest.mark.parametrize("compiled", [False, True], ids=["eager", "torch.compile"])
def test_every_replay_equals_the_function_on_its_own_arguments(compiled):
    function = torch.compile(chunk, dynamic=False) if compiled else chunk
    replay = CudaGraphReplay(function)
    generator = torch.Generator().manual_seed(0)
    outputs = []
    for _ in range(3):  # new values each call: the graph reads its arguments, not the ones it was captured with
        arguments = (observation(2, generator), torch.randn(2, 4, 3, generator=generator).cuda())
        outputs.append(replay(*arguments))
        torch.testing.assert_close(outputs[-1], chunk(*arguments), rtol=1e-5, atol=1e-5)
    assert len(replay.graphs) == 1
    assert not torch.equal(outputs[0], outputs[1]), "each output is a copy the next replay leaves alone"


def test_a_new_shape_is_captured_as_a_graph_of_its_own():
    replay = CudaGraphReplay(chunk)
    generator = torch.Generator().manual_seed(1)
    for batch in (1, 2, 1):
        arguments = (observation(batch, generator), torch.randn(batch, 4, 3, generator=generator).cuda())
        torch.testing.assert_close(replay(*arguments), chunk(*arguments), rtol=1e-5, atol=1e-5)
    assert len(replay.graphs) == 2


def test_a_graph_captured_in_inference_mode_replays_outside_it():
    """``snapflow bench`` captures under ``torch.inference_mode``; ``sample_actions`` runs under ``torch.no_grad``."""
    replay = CudaGraphReplay(chunk)
    generator = torch.Generator().manual_seed(2)
    with torch.inference_mode():
        replay(observation(1, generator), torch.randn(1, 4, 3, generator=generator).cuda())
    arguments = (observation(1, generator), torch.randn(1, 4, 3, generator=generator).cuda())
    with torch.no_grad():
        torch.testing.assert_close(replay(*arguments), chunk(*arguments), rtol=1e-5, atol=1e-5)


def test_a_function_no_graph_can_hold_runs_as_it_is_and_the_device_goes_on():
    """A shape read from the data (a host synchronisation) ends the capture: the function runs uncaptured, with a
    warning that says why, and graphs captured afterwards replay as before."""

    def positive_mean(observation: dict[str, torch.Tensor], noise: torch.Tensor) -> torch.Tensor:
        image = observation["image"]
        return noise + image[image > 0].mean()

    replay = CudaGraphReplay(positive_mean)
    generator = torch.Generator().manual_seed(3)
    arguments = (observation(1, generator), torch.randn(1, 4, 3, generator=generator).cuda())
    with pytest.warns(UserWarning, match="runs without a CUDA graph: it cannot be captured"):
        torch.testing.assert_close(replay(*arguments), positive_mean(*arguments))
    torch.testing.assert_close(replay(*arguments), positive_mean(*arguments))
    assert replay.graphs == {next(iter(replay.graphs)): None}
    test_a_new_shape_is_captured_as_a_graph_of_its_own()
