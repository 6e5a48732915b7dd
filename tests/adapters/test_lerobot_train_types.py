"""``lerobot-train`` steps the student type of every declared LeRobot type by SnapFlow's objective: its action expert
and phi_s train, its VLM or encoders stay frozen, the checkpoint says distilled; snapflow's own ``distill`` trains
the same teacher too."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
import torch

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")

from snapflow.adapters.lerobot_types import PLUGIN_LEROBOT, lerobot_loads_plugins  # noqa: E402
from tests.helpers import run_tiny_lerobot_train  # noqa: E402

PLUGINS = pytest.mark.skipif(
    not lerobot_loads_plugins(),
    reason=f"lerobot-train imports third-party policies from lerobot {PLUGIN_LEROBOT} on",
)


def _two_lerobot_train_steps(teacher, tmp_path: Path, processor_stats: dict | None = None, processors=()) -> Path:
    """``teacher`` (a LeRobot policy) saved with its processors (LeRobot's own of ``processor_stats``, or
    ``processors``), written as its student, stepped twice by ``lerobot-train`` on a tiny dataset and by snapflow's
    own ``distill``; checks what moved. Returns the names of the tensors that moved."""
    from lerobot.policies.factory import make_pre_post_processors
    from safetensors.torch import load_file

    from snapflow.cli import main
    from snapflow.sources import open_policy
    from snapflow.training.lerobot_student import write_student
    from tests.lerobot_tiny import write_tiny_dataset

    data = write_tiny_dataset(tmp_path / "data", episodes=2, frames=8)
    teacher.save_pretrained(tmp_path / "teacher")
    for processor in processors or make_pre_post_processors(teacher.config, dataset_stats=processor_stats):
        processor.save_pretrained(tmp_path / "teacher")
    student = write_student(str(tmp_path / "teacher"), tmp_path / "student")
    checkpoint = run_tiny_lerobot_train(student, data, tmp_path / "run", 2, 4, "--log_freq=1")
    config = json.loads((checkpoint / "config.json").read_text())
    assert config["type"] == f"snapflow_{teacher.config.type}" and config["distilled"] is True
    before, after = load_file(student / "model.safetensors"), load_file(checkpoint / "model.safetensors")
    moved = {name for name in before if not torch.equal(before[name], after[name])}
    assert any(".target_time_embedding." in name for name in moved), "phi_s trained"

    # snapflow's own trainer distils it too
    arguments = ["--policy", str(tmp_path / "teacher"), "--dataset", str(data), "--output", str(tmp_path / "own")]
    assert main(["distill", *arguments, "--steps", "2", "--batch-size", "4", "--no-progress"]) == 0
    opened = open_policy(tmp_path / "own" / "lerobot_policy")
    assert opened.distilled and opened.policy_type == f"snapflow_{teacher.config.type}"
    return moved


@pytest.mark.slow
@PLUGINS
@pytest.mark.parametrize("policy_type", ["pi0", "pi05"])
def test_lerobot_train_steps_a_pi_student_by_snapflows_objective(policy_type, vlm_directory, tmp_path, monkeypatch):
    """LeRobot's own ``lerobot-train`` entry point, in this process: a tiny pi policy builds only while its PaliGemma
    config builders are swapped for tiny ones, which a subprocess would not have (it would build the 2B model). Two
    steps of the ``snapflow_pi0`` / ``snapflow_pi05`` student train the action expert and phi_s, PaliGemma frozen."""
    from lerobot.scripts import lerobot_train
    from safetensors.torch import load_file

    from tests.lerobot_tiny import IMAGE_SIZE, save_tiny_pi_student, tiny_pi_configs, write_tiny_dataset

    data = write_tiny_dataset(tmp_path / "data", episodes=2, frames=8)
    student = save_tiny_pi_student(policy_type, vlm_directory, tmp_path / "student", image_size=IMAGE_SIZE)
    arguments = [f"--policy.path={student}", "--dataset.repo_id=local/tiny", f"--dataset.root={data}"]
    arguments += ["--steps=2", "--batch_size=4", "--num_workers=0", "--save_freq=2", "--log_freq=1"]
    arguments += ["--wandb.enable=false", "--policy.device=cpu", "--policy.push_to_hub=false"]
    monkeypatch.setattr(sys, "argv", ["lerobot-train", *arguments, f"--output_dir={tmp_path / 'run'}"])
    with tiny_pi_configs(policy_type):
        lerobot_train.main()
    checkpoint = tmp_path / "run" / "checkpoints" / "last" / "pretrained_model"
    config = json.loads((checkpoint / "config.json").read_text())
    assert config["type"] == f"snapflow_{policy_type}" and config["distilled"] is True
    before, after = load_file(student / "model.safetensors"), load_file(checkpoint / "model.safetensors")
    moved = {name for name in before if not torch.equal(before[name], after[name])}
    assert any(".target_time_embedding." in name for name in moved), "phi_s trained"
    assert any(".gemma_expert." in name for name in moved), "the action expert trained"
    assert not any(".paligemma." in name for name in moved), "PaliGemma stays frozen"


@pytest.mark.slow
@PLUGINS
def test_lerobot_train_steps_an_xvla_student_by_snapflows_objective(vlm_directory, tmp_path):
    """A type beyond the pi0 family: X-VLA, stepped by ``lerobot-train`` with its own optimizer (learning rates by
    parameter name), only the action expert and phi_s training; snapflow's run checkpoints save Florence-2's shared
    embedding once."""
    from tests.lerobot_tiny_xvla import build_tiny_xvla

    moved = _two_lerobot_train_steps(build_tiny_xvla(tokenizer=str(vlm_directory)), tmp_path)
    assert any(name.startswith("model.transformer.") for name in moved), "the action expert trained"
    assert not any(name.startswith("model.vlm.") for name in moved), "Florence-2 stays frozen"


@pytest.mark.slow
@PLUGINS
def test_lerobot_train_steps_a_multi_task_dit_student_by_snapflows_objective(clip_directory, tmp_path):
    """Multi-task DiT, whose flow runs the other way and whose batches carry an observation-steps axis from the
    dataset: its diffusion transformer and phi_s train, CLIP's encoders stay frozen."""
    from tests.lerobot_tiny_multi_task_dit import build_tiny_multi_task_dit, unit_statistics

    moved = _two_lerobot_train_steps(build_tiny_multi_task_dit(clip_directory), tmp_path, unit_statistics())
    assert any(name.startswith("noise_predictor.transformer_blocks.") for name in moved), "the expert trained"
    assert not any(name.startswith("observation_encoder.") for name in moved), "the encoders stay frozen"


@pytest.mark.slow
@PLUGINS
def test_lerobot_train_steps_a_groot_student_by_snapflows_objective(groot_checkpoint, tmp_path):
    """GR00T N1.7 (LeRobot >= 0.6), its flow the other way and its batches packed by its own processors (the tiny
    Qwen3-VL's): its action encoder, DiT, action decoder and phi_s train; Qwen3-VL and the prefix stay frozen."""
    pytest.importorskip("lerobot.policies.groot.groot_n1_7", reason="LeRobot's GR00T N1.7 arrived in lerobot 0.6")
    from tests.lerobot_tiny_groot import build_tiny_groot, tiny_groot_processors

    teacher = build_tiny_groot(groot_checkpoint)
    moved = _two_lerobot_train_steps(teacher, tmp_path, processors=tiny_groot_processors(teacher))
    assert all(name.startswith("_groot_model.action_head.") for name in moved), "Qwen3-VL stays frozen"
    expert = {"action_encoder", "position_embedding", "model", "action_decoder"}  # the prefix's state encoder, vlln
    assert {name.split(".")[2] for name in moved} == expert, "the expert trains, the rest of the prefix is frozen"


@pytest.mark.slow
@PLUGINS
def test_lerobot_train_steps_an_evo1_student_by_snapflows_objective(evo1_vlm, tmp_path):
    """EVO1 (LeRobot >= 0.6.1), its flow the other way from its own uniform noise, its batches padded and masked by its
    own processors: its action encoder, transformer blocks, output head and phi_s train; InternVL3 and the state
    encoder (the prefix's state token) stay frozen."""
    from tests.lerobot_tiny_evo1 import build_tiny_evo1, tiny_evo1_processors

    teacher = build_tiny_evo1(evo1_vlm)
    moved = _two_lerobot_train_steps(teacher, tmp_path, processors=tiny_evo1_processors(teacher))
    assert all(name.startswith("model.") for name in moved)
    parts = {name.split(".")[2] if name.startswith("model.action_head.") else name.split(".")[1] for name in moved}
    expert = {"action_encoder", "transformer_blocks", "norm_out", "seq_pool_proj", "mlp_head", "target_time_embedding"}
    assert parts == expert, "the expert trains; InternVL3 and the state encoder are frozen"


@pytest.mark.slow
@PLUGINS
def test_lerobot_train_steps_an_eo1_student_by_snapflows_objective(eo1_vlm, tmp_path):
    """EO-1 (LeRobot >= 0.6.1), its training batches' prompts right-padded by its own processors: the Qwen2.5 decoder
    layers (which run the action span, and the prefix too), the action projections, the time MLP and phi_s train; the
    vision tower, the token embedding and the state's projection, which run in the prefix alone, stay frozen."""
    from tests.lerobot_tiny_eo1 import build_tiny_eo1, tiny_eo1_processors

    teacher = build_tiny_eo1(eo1_vlm)
    moved = _two_lerobot_train_steps(teacher, tmp_path, processors=tiny_eo1_processors(teacher))
    assert all(name.startswith("model.") for name in moved)
    assert any(".language_model.layers." in name for name in moved), "the decoder layers trained"
    heads = {"action_in_proj", "action_time_mlp_in", "action_time_mlp_out", "action_out_proj", "target_time_embedding"}
    assert heads <= {name.split(".")[1] for name in moved}, "the action projections, the time MLP and phi_s trained"
    frozen = (".visual.", ".embed_tokens.", "lm_head", "state_proj")
    assert not [name for name in moved if any(part in name for part in frozen)], "the prefix alone stays frozen"


def test_lerobot_train_steps_a_vla_jepa_student_by_snapflows_objective(vla_jepa_backbones, tmp_path):
    """VLA-JEPA (LeRobot >= 0.6.1), its flow the other way, its batches carrying each camera's and state's next frames
    for its world model: its action encoder, future tokens, position embedding, DiT, action decoder and phi_s train;
    Qwen3-VL, the state encoder and the world model (V-JEPA 2, its predictor) stay frozen."""
    from tests.lerobot_tiny_vla_jepa import build_tiny_vla_jepa, tiny_vla_jepa_processors

    teacher = build_tiny_vla_jepa(vla_jepa_backbones)
    moved = _two_lerobot_train_steps(teacher, tmp_path, processors=tiny_vla_jepa_processors(teacher))
    assert all(name.startswith("model.action_model.") for name in moved), "Qwen3-VL and the world model stay frozen"
    expert = {"action_encoder", "future_tokens", "position_embedding", "model", "action_decoder"}
    assert {name.split(".")[2] for name in moved} == expert, "the expert trains; the state encoder is frozen"


def test_lerobot_train_steps_a_molmoact2_student_by_snapflows_objective(molmoact2_checkpoint, tmp_path):
    """MolmoAct2 (LeRobot >= 0.6.1), its flow the other way from its own noise zero on the padded width, its batches
    packed by its own processors (the prompt with the discretised state, the image crops, the padding masks): its time
    MLP, action embedding, blocks, output layer and phi_s train; the VLM and the expert's context projections (the
    prefix, run once a chunk) stay frozen; snapflow's own ``distill`` trains a saved teacher folder too.

    ``lerobot-train`` 0.6.1 fine-tunes MolmoAct2 from its checkpoint (``--policy.type`` and
    ``--policy.checkpoint_path``), the student as the teacher: a saved folder (``--policy.path``), teacher or student,
    stops at LeRobot's override of its pre-processor's ``normalizer_processor``, which MolmoAct2's pipeline names
    ``molmoact2_masked_normalizer`` (fixed in LeRobot after 0.6.1, huggingface/lerobot#4249)."""
    from safetensors.torch import load_file

    from snapflow.cli import main
    from snapflow.sources import open_policy
    from tests.helpers import run_checked
    from tests.lerobot_tiny import write_tiny_dataset
    from tests.lerobot_tiny_molmoact2 import HORIZON, build_tiny_molmoact2, tiny_molmoact2_processors

    data = write_tiny_dataset(tmp_path / "data", episodes=2, frames=8)
    student = ["--policy.type=snapflow_molmoact2", f"--policy.checkpoint_path={molmoact2_checkpoint}"]
    student += ["--policy.action_mode=continuous", "--policy.inference_action_mode=continuous"]
    student += ["--policy.model_dtype=float32", f"--policy.chunk_size={HORIZON}", f"--policy.n_action_steps={HORIZON}"]
    run = ["--dataset.repo_id=local/tiny", f"--dataset.root={data}", f"--output_dir={tmp_path / 'run'}", "--steps=2"]
    run += ["--batch_size=4", "--num_workers=0", "--save_freq=2", "--log_freq=1", "--wandb.enable=false"]
    run += ["--policy.device=cpu", "--policy.push_to_hub=false"]
    lerobot_train = str(Path(sys.executable).with_name("lerobot-train"))
    finished = run_checked([lerobot_train, *student, *run], {"HF_HUB_OFFLINE": "1"})
    assert "consistency_loss" in finished.stderr, "LeRobot logs the objective's parts"
    checkpoint = tmp_path / "run" / "checkpoints" / "last" / "pretrained_model"
    config = json.loads((checkpoint / "config.json").read_text())
    assert config["type"] == "snapflow_molmoact2" and config["distilled"] is True
    before, after = load_file(molmoact2_checkpoint / "model.safetensors"), load_file(checkpoint / "model.safetensors")
    assert after["target_time_embedding.linear_out.weight"].any(), "phi_s trained"
    moved = {name for name in before if not torch.equal(before[name], after[f"model.{name}"])}
    expert = "model.action_expert."
    parts = {name[len(expert) :].split(".")[0] if name.startswith(expert) else name for name in moved}
    assert parts == {"time_embed", "action_embed", "blocks", "final_layer"}, (
        "the expert trains; the VLM and the context projections are frozen"
    )

    # snapflow's own trainer distils a saved teacher folder
    teacher = build_tiny_molmoact2(molmoact2_checkpoint)
    teacher.save_pretrained(tmp_path / "teacher")
    for processor in tiny_molmoact2_processors(teacher):
        processor.save_pretrained(tmp_path / "teacher")
    arguments = ["--policy", str(tmp_path / "teacher"), "--dataset", str(data), "--output", str(tmp_path / "own")]
    assert main(["distill", *arguments, "--steps", "2", "--batch-size", "4", "--no-progress"]) == 0
    opened = open_policy(tmp_path / "own" / "lerobot_policy")
    assert opened.distilled and opened.policy_type == "snapflow_molmoact2"
