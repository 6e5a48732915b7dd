"""``deploy``, the recommended fast path of a distilled student: fast by default on a GPU.

- The vision tower in bfloat16 where the policy keeps it in float32 (LeRobot's pi0 and pi0.5 do under bfloat16):
  the bfloat16 rounding of the image features moves the actions by less than :data:`DEPLOY_ACTION_BOUND`.
- TF32 matrix products for what stays in float32, where the policy runs on a CUDA GPU (LeRobot leaves it off). TF32
  is a switch of the process, not of the policy: everything else the process runs in float32 on the GPU uses it too.
- The prefix pass and the velocity compiled with CUDA graphs (``reduce-overhead``; the teacher's N-step modes and
  LeRobot's own sampling run them), and the one-step chunk, prefix and jump, as one graph of its own
  (:func:`snapflow.inference.compile.fuse_one_step`): one replay a chunk, nothing copied between the two.
- What would keep the chunk out of one graph replaced by its capturable equivalent where the policy has one (a
  LeRobot policy's ``without_host_syncs``: SmolVLM's vision embeddings index their position ids by a boolean mask).
- The prompt's padding cut before the prefix where the policy can (a LeRobot policy's
  ``without_prompt_padding``: LeRobot's pi0.5 pads every prompt to 200 tokens), to a multiple of 16 tokens so that
  the graphs meet few shapes: padding is masked out of every attention, so only rounding changes.

LeRobot's own precision stays one flag away: ``compile-reduce-overhead`` compiles the same passes without changing
what runs in which precision. Compiled code is cached on disk by torch (``$TORCHINDUCTOR_CACHE_DIR``, by default in
the temporary directory): a second process compiles from that cache, not from scratch (``snapflow bench
--compile-cache`` times both).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from torch import nn

#: the most ``deploy`` may move a one-step chunk's actions (normalised units, max over the chunk) against the same
#: policy run eagerly: bfloat16 image features and TF32 rounding, nothing else. ``snapflow bench`` measures it on
#: every subject it times; the tests hold it on the tiny LeRobot policies.
DEPLOY_ACTION_BOUND = 0.01


def deploy(policy: nn.Module) -> nn.Module:
    """The ``deploy`` fast path (see the module's description) on ``policy``, in place; returns it."""
    import torch

    from snapflow.inference.compile import compile_policy, fuse_one_step
    from snapflow.protocol import HostSyncFree, PromptPaddingTrim, VisionPrecision

    if isinstance(policy, VisionPrecision):
        policy.run_vision_in(torch.bfloat16)
    if isinstance(policy, HostSyncFree):
        policy.without_host_syncs()
    if any(parameter.is_cuda for parameter in policy.parameters()):
        torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = True
        torch.set_float32_matmul_precision("high")
    compile_policy(policy, "reduce-overhead")
    fuse_one_step(policy, "reduce-overhead")
    if isinstance(policy, PromptPaddingTrim):  # outside the graphs: the cut is decided by the data
        trim, encode, chunk = policy.without_prompt_padding, policy.encode, policy.one_step_chunk
        policy.encode = lambda batch: encode(trim(batch))
        policy.one_step_chunk = lambda observation, noise: chunk(trim(observation), noise)
    return policy


__all__ = ["DEPLOY_ACTION_BOUND", "deploy"]
