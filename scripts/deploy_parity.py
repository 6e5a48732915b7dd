"""How far each part of the ``deploy`` fast path moves a one-step chunk from the eager policy's, added one at a time on
the same inputs: the vision tower in bfloat16, then TF32 (on a GPU), then the prefix and velocity compiled, then the
one-step chunk fused into one graph (``deploy`` whole). Issue 46 found pi0.5's full chunk 0.020 from eager under
``deploy`` against the stated 0.01, with bfloat16 vision and TF32 alone at 0.0044: this says which part adds what.

    python scripts/deploy_parity.py --architecture pi05 --dtype bfloat16 --output OUTPUT   # on a GPU
    python scripts/deploy_parity.py --architecture minivla --device cpu --output OUTPUT     # the chain on a CPU

Writes ``OUTPUT/parity.json``: each stage's largest and mean absolute difference to eager (normalised units) and to
the stage before, with the machine and versions.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from snapflow.benchmark.architectures import architectures
from snapflow.benchmark.bench import one_step_actions
from snapflow.benchmark.subjects import make_subject
from snapflow.inference.compile import compile_policy, fuse_one_step
from snapflow.inference.deploy import DEPLOY_ACTION_BOUND
from snapflow.reporting.files import write_json
from snapflow.reporting.machine import machine


def stages(policy: torch.nn.Module, cuda: bool) -> list[tuple[str, callable]]:
    """The parts of ``deploy`` in the order it applies them (those that apply to this policy and device)."""
    parts = []
    if callable(getattr(policy, "run_vision_in", None)):
        parts.append(("vision tower in bfloat16", lambda: policy.run_vision_in(torch.bfloat16)))
    if cuda:

        def tf32() -> None:
            torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = True
            torch.set_float32_matmul_precision("high")

        parts.append(("+ TF32", tf32))
    parts.append(
        ("+ prefix and velocity compiled (reduce-overhead)", lambda: compile_policy(policy, "reduce-overhead"))
    )
    parts.append(("+ one-step chunk as one graph (deploy)", lambda: fuse_one_step(policy, "reduce-overhead")))
    return parts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--architecture", choices=architectures(), required=True)
    parser.add_argument("--dtype", choices=["float32", "bfloat16"], default="float32")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--output", type=Path, required=True)
    args = parser.parse_args()
    device = torch.device(args.device)
    subject = make_subject(None, args.architecture, device, getattr(torch, args.dtype))
    eager = one_step_actions(subject)
    rows, previous = [], eager
    for name, apply in stages(subject.policy, device.type == "cuda"):
        apply()
        actions = one_step_actions(subject)
        rows.append(
            {
                "stage": name,
                "max_abs_to_eager": (actions - eager).abs().max().item(),
                "mean_abs_to_eager": (actions - eager).abs().mean().item(),
                "max_abs_to_previous": (actions - previous).abs().max().item(),
            }
        )
        previous = actions
        print(rows[-1], flush=True)
    write_json(
        args.output / "parity.json",
        {
            "subject": subject.name,
            "dtype": args.dtype,
            "bound": DEPLOY_ACTION_BOUND,
            "eager_abs_max": eager.abs().max().item(),
            "stages": rows,
            "machine": machine(),
        },
    )


if __name__ == "__main__":
    main()
