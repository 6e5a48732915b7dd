"""The one-time repair (issue 56) that made the SmolVLA policies kept by ``smolvla-libero-spatial-dart`` open on any
machine; kept as the record of how their folders were made.

Before it, every kept student named its SmolVLM by an absolute path of the machine that trained it, and the teachers
and the ``snapflow distill`` student were kept only as training checkpoints, whose processors came from a dataset
that is not committed. This script, run from the repository's root after ``snapflow checkpoints restore
docs/results/sweeps/smolvla-libero-spatial-dart`` (Python 3.12, lerobot 0.6.1):

1. writes each seed's SmolVLM again, as the sweep wrote it (``write_smolvlm`` of the words of LIBERO-Spatial's
   instructions in the dataset's task order, the suite's, at the recorded size), where the students' files name it,
   and checks it against them: the vocabulary the students' embedding holds, the prompt length their tokenizer pads to;
2. bundles it into every kept student's folder (:func:`~snapflow.adapters.lerobot.local_vlm.bundle_vlm`);
3. exports each teacher and the ``snapflow distill`` student as the policy folder their runs exported (``lerobot_policy``:
   LeRobot's layout, snapflow's marker, the processors with the dataset's statistics, which every student of the same
   data carries, and the SmolVLM) from the trained weights of their checkpoints: the raw weights, which is what the
   runs exported and what the committed evaluations and students read (the teachers' weight average was saved in
   their checkpoints but never exported), and keeps that folder in place of the checkpoint, as the sweep now does.

It has run once (commit 78f319a); the checkpoints it read left the archive's manifest then, and stay in history: the
manifest of commit efb20a6 names them, with the commits that hold them.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from safetensors import safe_open

from snapflow.adapters.lerobot.checkpoint import save_distilled, save_teacher
from snapflow.adapters.lerobot.local_vlm import BUNDLED_VLM, bundle_vlm
from snapflow.adapters.lerobot.registry import wrap_policy
from snapflow.adapters.lerobot.smolvlm import token_budget, words_of, write_smolvlm
from snapflow.adapters.lerobot_config import SmolVLMSize
from snapflow.envs.factory import make_benchmark
from snapflow.policies.checkpoint import load_state_strict, read_tensors
from snapflow.training.checkpoint import KEPT, TRAINING_WEIGHTS

RECORDS = Path("docs/results/sweeps/smolvla-libero-spatial-dart/records")
SEEDS = (0, 1, 2)
VAL_FRACTION = 0.1  # the sweep's held-out share, in every run's record
STUDENT_FIELDS = ("sampling_mode", "distilled", "distill", "steps_distilled")  # and every distill_* key
PROCESSOR_FILES = (
    "policy_preprocessor.json",
    "policy_postprocessor.json",
    "policy_preprocessor_step_5_normalizer_processor.safetensors",
    "policy_postprocessor_step_0_unnormalizer_processor.safetensors",
)


def students(seed: int) -> list[Path]:
    return [
        folder
        for run in ("lerobot-train", "lerobot-train-paper")
        if (folder := RECORDS / run / f"seed-{seed}" / "checkpoint" / "pretrained_model").is_dir()
    ]


def rebuild_smolvlm(seed: int, student: Path) -> tuple[Path, dict]:
    """The seed's SmolVLM written again where the student's config names it; that config."""
    config = json.loads((student / "config.json").read_text())
    vlm = Path(config["vlm_model_name"])
    record = json.loads(
        (RECORDS / "teacher" / f"seed-{seed}" / "checkpoint" / "step_0020000" / "policy.json").read_text()
    )
    libero = make_benchmark("libero")
    instructions = [libero.instruction(task) for task in libero.resolve_tasks("libero_spatial")]
    if not (vlm / "config.json").is_file():
        write_smolvlm(vlm, words_of(instructions), SmolVLMSize(**record["smolvlm"]))
    assert token_budget(instructions) == config["tokenizer_max_length"], "another set of instructions"
    vocabulary = json.loads((vlm / "config.json").read_text())["text_config"]["vocab_size"]
    with safe_open(student / "model.safetensors", "pt") as tensors:
        rows = tensors.get_slice("model.vlm_with_expert.vlm.model.text_model.embed_tokens.weight").get_shape()[0]
    assert rows == vocabulary, f"the students embed {rows} tokens, the rebuilt tokenizer has {vocabulary}"
    return vlm, config


def teacher_config_folder(student_config: dict, into: Path) -> Path:
    """A folder holding the teacher's LeRobot config: the student's, typed back as its teacher, with SmolVLA's own
    optimiser settings, as the teacher's run wrote them (snapflow's trainer writes its own nowhere in the config;
    those of the student are lerobot-train's)."""
    dropped = ("distill_", "optimizer_", "scheduler_")
    plain = {
        key: value for key, value in student_config.items() if key not in STUDENT_FIELDS and not key.startswith(dropped)
    }
    plain.update(type="smolvla", pretrained_path=None)
    into.mkdir(parents=True, exist_ok=True)
    (into / "config.json").write_text(json.dumps(plain, indent=4))
    return into


def export_run(checkpoint: Path, student_config: dict, processors: Path, output: Path, distilled: bool) -> None:
    """The run's policy folder, as its trainer exported it, from its checkpoint's trained weights."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.smolvla.modeling_smolvla import SmolVLAPolicy

    scratch = teacher_config_folder(student_config, output.parent / ".config-scratch")
    adapter = wrap_policy(SmolVLAPolicy(PreTrainedConfig.from_pretrained(scratch)))
    shutil.rmtree(scratch)
    weights = read_tensors(checkpoint / "policy.safetensors")
    if (checkpoint / TRAINING_WEIGHTS).is_file():  # a weight average was saved as the policy: the run exported these
        weights.update(read_tensors(checkpoint / TRAINING_WEIGHTS))
    load_state_strict(adapter, weights, checkpoint / "policy.safetensors")
    shutil.rmtree(output, ignore_errors=True)
    (save_distilled if distilled else save_teacher)(adapter, output, VAL_FRACTION)
    for name in PROCESSOR_FILES:
        shutil.copyfile(processors / name, output / name)
    assert bundle_vlm(output)


def keep_export(
    run: str, seed: int, checkpoint_name: str, student_config: dict, processors: Path, distilled: bool
) -> None:
    """Export the run kept at ``checkpoint_name`` and keep the export in the checkpoint's place."""
    kept = RECORDS / run / f"seed-{seed}" / "checkpoint"
    export_run(kept / checkpoint_name, student_config, processors, kept / "lerobot_policy", distilled)
    job = json.loads((RECORDS / run / f"seed-{seed}" / "job.json").read_text())
    note = {"checkpoint": "lerobot_policy", "job": {"config": job["config"], "dependencies": job["dependencies"]}}
    (kept / KEPT).write_text(json.dumps({**note, "finished": True}, indent=2) + "\n")
    shutil.rmtree(kept / checkpoint_name)


def main() -> None:
    for seed in SEEDS:
        folders = students(seed)
        vlm, config = rebuild_smolvlm(seed, folders[0])
        keep_export("teacher", seed, "step_0020000", config, folders[0], distilled=False)
        if seed == 0:
            keep_export("snapflow-distill", 0, "step_0004000", config, folders[0], distilled=True)
        for student in folders:
            bundle_vlm(student)
            assert (student / BUNDLED_VLM / "config.json").is_file()
        print(f"seed {seed}: SmolVLM {vlm} bundled into {len(folders)} student(s) and the exported runs")


if __name__ == "__main__":
    main()
