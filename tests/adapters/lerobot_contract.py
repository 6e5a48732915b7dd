"""The adapter contract of a LeRobot policy type (:class:`LeRobotAdapterContract`): the checks every policy under
SnapFlow passes (:class:`tests.adapters.contract.FlowPolicyContract`) and what only LeRobot has (its own sampler,
training forward and action API). Each type's class says how to build it offline (``tests/lerobot_tiny*.py``)."""

from __future__ import annotations

import contextlib
import json
from pathlib import Path
from typing import Any, ClassVar

import pytest
import torch
from torch import Tensor, nn

from snapflow import NAIVE_1, SNAPFLOW_1, SamplingMode, SnapFlowObjective, sample_actions
from snapflow.protocol import map_tensors
from tests.adapters.contract import TEACHER_10, FlowPolicyContract
from tests.lerobot_tiny import randomise_target_time


class LeRobotAdapterContract(FlowPolicyContract):
    """A LeRobot policy of ``policy_type`` under its adapter, built offline at tiny size (tests/lerobot_tiny.py)."""

    policy_type: ClassVar[str]
    #: the fast paths' capabilities beyond those every adapter has (CompiledParts, PromptPaddingTrim)
    capabilities: ClassVar[frozenset[str]] = frozenset()
    #: the width of the action ``select_action`` returns: the robot's 4 (EVO1's is padded; its post-processor cuts it)
    selected_action_width: ClassVar[int] = 4
    #: inductor's numerics are checked on SmolVLA (and the built-in policies); the other types' graph capture alone
    compile_backend: ClassVar[str] = "aot_eager"

    @pytest.fixture(autouse=True)
    def _tiny_vlm(self, vlm_directory: Path) -> None:  # also skips the class where LeRobot is not installed
        self.vlm_directory = vlm_directory

    def build_lerobot(self) -> nn.Module:
        from tests.lerobot_tiny import build_tiny_pi, build_tiny_smolvla

        return (
            build_tiny_smolvla(self.vlm_directory) if self.policy_type == "smolvla" else build_tiny_pi(self.policy_type)
        )

    def lerobot_own_sample(self, lerobot: nn.Module, observation: Any, noise: Tensor, steps: int) -> Tensor:
        """``steps`` Euler steps by LeRobot's own sampler of ``lerobot`` (a policy, wrapped or not)."""
        from tests.lerobot_tiny import lerobot_sample

        return lerobot_sample(lerobot, observation, noise, steps)

    def lerobot_own_flow_matching_loss(
        self, lerobot: nn.Module, observation: Any, actions: Tensor, noise: Tensor, time: Tensor
    ) -> Tensor:
        """The flow-matching loss LeRobot's own training forward computes for these noise and times."""
        from tests.lerobot_tiny import model_inputs

        return lerobot.model.forward(*model_inputs(lerobot, observation), actions, noise, time).mean()

    def entry_weights(self, observation: Any, actions: Tensor) -> Tensor:
        """Which entries of the padded chunks the policy's own loss weighs: every one by default."""
        return torch.ones_like(actions)

    def lerobot_chunk(self, lerobot: nn.Module, observation: Any, noise: Tensor) -> Tensor:
        """LeRobot's action API's chunk from ``noise`` (drawn by :meth:`noise_like` with seed 0)."""
        return lerobot.predict_action_chunk(observation, noise=noise)

    def build(self) -> nn.Module:
        from snapflow.adapters.lerobot import wrap_policy

        return wrap_policy(self.build_lerobot())

    def reference_sample(self, observation: Any, noise: Tensor, steps: int) -> Tensor:
        return self.lerobot_own_sample(self.build_lerobot(), observation, noise, steps)

    def observations(self, batch_size: int) -> dict[str, Any]:
        """``batch_size`` observations as the policy's pre-processor hands them to the model (SmolVLA's by default)."""
        from tests.lerobot_tiny import tiny_batch

        return tiny_batch(batch_size)

    @staticmethod
    def rows(observation: dict[str, Any], rows: slice) -> dict[str, Any]:
        """The observations of ``rows`` (a batch whose every value leads with its rows, by default)."""
        return {key: value[rows] for key, value in observation.items()}

    def make_batch(self, policy: nn.Module) -> tuple[Any, Tensor]:
        batch = self.observations(self.batch_size)
        return batch, policy.action_targets(batch)

    def save(self, policy: nn.Module, directory: Path) -> None:
        from snapflow.adapters.lerobot import save_distilled

        save_distilled(policy, directory)

    def load(self, directory: Path) -> nn.Module:
        from snapflow.adapters.lerobot import load_distilled

        return load_distilled(directory)

    def loading(self) -> contextlib.AbstractContextManager:
        from tests.lerobot_tiny import tiny_pi_configs

        return tiny_pi_configs(self.policy_type) if self.policy_type in ("pi0", "pi05") else contextlib.nullcontext()

    # ---- what only LeRobot policies have ----------------------------------------------------------------------
    def test_cutting_the_prompts_padding_changes_no_chunk(self, policy, batch):
        from snapflow.adapters.lerobot.base import OBS_LANGUAGE_ATTENTION_MASK as MASK
        from snapflow.adapters.lerobot.base import OBS_LANGUAGE_TOKENS as TOKENS

        randomise_target_time(policy)
        observation, actions = batch
        if not policy.masks_prompt_padding:  # a policy that attends to its padding keeps it
            assert policy.without_prompt_padding(observation, multiple=1) is observation
            return
        mask, noise = observation[MASK], self.noise_like(actions)
        longest = int(mask.sum(dim=1).max())
        cut = policy.without_prompt_padding(observation, multiple=1)
        assert cut[MASK].shape[1] == cut[TOKENS].shape[1] == longest < mask.shape[1]
        for mode in (TEACHER_10, SNAPFLOW_1):  # padding is masked out everywhere: rounding apart, the same chunk
            torch.testing.assert_close(
                sample_actions(policy, cut, noise, mode), sample_actions(policy, observation, noise, mode)
            )
        assert policy.without_prompt_padding(observation, multiple=4)[MASK].shape[1] == min(
            -(-longest // 4) * 4, mask.shape[1]
        )
        left_padded = {**observation, MASK: mask.flip(1), TOKENS: observation[TOKENS].flip(1)}
        assert policy.without_prompt_padding(left_padded, multiple=1) is left_padded, "only right padding is cut"

    def test_lerobot_sampling_reads_s_as_t_so_phi_s_changes_only_the_jump(self, policy, batch):
        randomise_target_time(policy)
        noise = self.noise_like(batch[1])
        # LeRobot's own sampler passes a (B,) time, read as s = t: it is exactly our teacher mode
        assert torch.equal(
            sample_actions(policy, batch[0], noise, NAIVE_1),
            self.lerobot_own_sample(policy.policy, batch[0], noise, 1),
        )
        assert not torch.allclose(
            sample_actions(policy, batch[0], noise, SNAPFLOW_1), sample_actions(policy, batch[0], noise, NAIVE_1)
        )

    def test_loss_equals_a_hand_computation_from_the_policys_own_outputs(self, policy, batch):
        randomise_target_time(policy)
        observation, actions = batch
        lerobot = policy.policy
        noise, time = self.noise_like(actions), torch.rand(2, generator=torch.Generator().manual_seed(1))
        output = SnapFlowObjective()(policy, observation, actions, noise=noise, time=time)

        fm_rows, sc_rows = self.rows(observation, slice(None, 2)), self.rows(observation, slice(2, None))
        # FM branch: LeRobot's own joint training forward returns the elementwise squared errors
        fm = self.lerobot_own_flow_matching_loss(lerobot, fm_rows, actions[:2], noise[:2], time)
        # consistency target: two LeRobot Euler steps from x_1 land on x_1 - target
        target = noise[2:] - self.lerobot_own_sample(lerobot, sc_rows, noise[2:], 2)
        jump = policy.velocity(noise[2:], torch.ones(2), torch.zeros(2), policy.encode(sc_rows))
        weights = self.entry_weights(observation, actions)[2:]  # each row's mean over the entries its loss weighs
        sc = ((jump - target).pow(2) * weights).flatten(1).sum(1).div(weights.flatten(1).sum(1)).mean()
        assert torch.allclose(output.flow_matching_loss, fm, atol=1e-5)
        assert torch.allclose(output.consistency_loss, sc, atol=1e-5)
        assert torch.allclose(output.loss, 0.5 * fm + 0.5 * 0.1 * sc, atol=1e-5)

    def test_the_frozen_vlm_pass_keeps_no_graph_even_where_the_vlm_could_learn(self, policy, batch):
        from tests.lerobot_tiny import model_inputs

        observation, actions = batch
        for parameter in policy.parameters():  # nothing frozen, not even what LeRobot's config freezes itself
            parameter.requires_grad_(True)
        leaves: list[Tensor] = []
        map_tensors(policy.encode(observation), leaves.append)
        assert leaves and not any(leaf.requires_grad for leaf in leaves), "the VLM's cache must carry no graph"
        SnapFlowObjective()(policy, observation, actions, generator=torch.Generator().manual_seed(0)).loss.backward()
        expert = {id(parameter) for parameter in policy.expert_parameters()}
        reached = sorted(
            name
            for name, parameter in policy.named_parameters()
            if id(parameter) not in expert and parameter.grad is not None
        )
        assert not reached, f"the VLM learned: {reached[:5]}"
        # the adapter hands LeRobot's model what LeRobot's own predict_action_chunk hands it
        for ours, theirs in zip(
            policy.model_inputs(observation), model_inputs(policy.policy, observation), strict=True
        ):
            if isinstance(ours, dict):
                pairs = [(ours[key], theirs[key]) for key in sorted(ours.keys() | theirs.keys())]
            elif isinstance(ours, (list, tuple)):
                pairs = list(zip(ours, theirs, strict=True))
            else:
                pairs = [(ours, theirs)]
            assert all(torch.equal(a, b) if torch.is_tensor(a) else a == b for a, b in pairs)  # EVO1's task: text

    def test_the_adapters_own_state_dict_holds_each_tensor_once(self, policy):
        # safetensors refuses tensors saved under two names: the adapter adds no second name, to phi_s or anything
        # else (LeRobot's own ties, as Florence-2's shared embedding, are saved once by LeRobot's writer)
        lerobot_names = {id(tensor): name for name, tensor in policy.policy.state_dict(keep_vars=True).items()}
        names: dict[int, list[str]] = {}
        for name, tensor in policy.state_dict(keep_vars=True).items():
            names.setdefault(id(tensor), []).append(name)
        assert all(len(aliases) == 1 or lerobot_names.get(key) for key, aliases in names.items())
        assert sum(len(aliases) for aliases in names.values()) == len(policy.policy.state_dict())
        state = policy.state_dict()
        assert sum("target_time_embedding" in key for key in state) == 4, "phi_s: two layers, weight and bias, once"

    def test_lerobot_action_api_samples_one_step_by_default_and_the_teacher_on_request(self, policy, batch, tmp_path):
        from snapflow.adapters.lerobot import load_distilled, save_distilled

        randomise_target_time(policy)
        save_distilled(policy, tmp_path / "distilled")
        with self.loading():
            reloaded = load_distilled(tmp_path / "distilled")
        observation, actions = batch
        noise = self.noise_like(actions)
        one_step = self.lerobot_chunk(reloaded.policy, observation, noise)
        assert torch.equal(one_step, sample_actions(policy, observation, noise, SNAPFLOW_1))
        # LeRobot's queue of n_action_steps actions
        assert reloaded.policy.select_action(observation).shape == (self.batch_size, self.selected_action_width)
        reloaded.use_sampling_mode(TEACHER_10)
        teacher = self.lerobot_chunk(reloaded.policy, observation, noise)
        assert torch.equal(teacher, sample_actions(policy, observation, noise, TEACHER_10))
        assert not torch.allclose(teacher, one_step)

    def test_it_claims_exactly_the_fast_path_capabilities_its_type_declares(self, policy):
        """The fast paths ask a policy by ``isinstance`` what it can do (no probing by name): every adapter names
        its compiled parts and trims its prompt's padding; the others are each type's own (their effect is checked
        in tests/adapters/test_lerobot.py)."""
        from snapflow import protocol

        assert isinstance(policy, protocol.CompiledParts) and isinstance(policy, protocol.PromptPaddingTrim)
        assert all(callable(getattr(policy, name)) for name in policy.compiled_methods)
        optional = ("VisionPrecision", "HostSyncFree", "FusedOneStep", "OwnNoise")
        assert {name for name in optional if isinstance(policy, getattr(protocol, name))} == self.capabilities

    def test_a_bare_teacher_samples_the_types_own_steps_set_by_its_own_field(self, policy, batch, tmp_path):
        """``sampling_mode=teacher`` samples as many Euler steps as the type's own field says (``teacher-K``
        exactly K), and ``lerobot-eval`` sets a teacher's steps through that same field."""
        from snapflow.adapters.lerobot import load_distilled, save_distilled
        from snapflow.evaluation.lerobot_eval import mode_arguments

        field = type(policy).steps_field
        assert type(policy).own_steps(policy.policy.config) == (getattr(policy.policy.config, field) or 4)  # GR00T's
        randomise_target_time(policy)
        save_distilled(policy, tmp_path / "distilled")
        with self.loading():
            reloaded = load_distilled(tmp_path / "distilled")
        reloaded.policy.config.sampling_mode = "teacher"
        setattr(reloaded.policy.config, field, 3)
        observation, actions = batch
        noise = self.noise_like(actions)
        chunk = self.lerobot_chunk(reloaded.policy, observation, noise)
        assert torch.equal(chunk, sample_actions(policy, observation, noise, SamplingMode(3, jump=False)))
        teacher = tmp_path / "teacher"
        teacher.mkdir()
        (teacher / "config.json").write_text(json.dumps({"type": self.policy_type}))
        assert mode_arguments(teacher, SamplingMode(3, jump=False)) == [f"--policy.{field}=3"]

    @pytest.mark.slow
    def test_distillation_lowers_the_consistency_loss(self, policy):
        parameters = policy.expert_parameters()
        trainable = {id(p) for p in parameters}
        for parameter in policy.parameters():
            parameter.requires_grad_(id(parameter) in trainable)
        observation = self.observations(8)
        actions = policy.action_targets(observation)
        # a random tiny teacher has a large FM loss and a small consistency loss: weight the latter up so that a few
        # steps show it falling before the FM updates move the teacher's own two-step target
        objective = SnapFlowObjective(consistency_weight=1.0)
        noise, time = (
            torch.randn(8, *policy.action_shape, generator=torch.Generator().manual_seed(1)),
            torch.rand(4, generator=torch.Generator().manual_seed(3)),
        )

        def consistency() -> float:
            with torch.no_grad():
                return objective(policy, observation, actions, noise=noise, time=time).consistency_loss.item()

        before = consistency()
        optimizer = torch.optim.AdamW(parameters, lr=1e-3)
        generator = torch.Generator().manual_seed(2)
        for _ in range(15):
            optimizer.zero_grad()
            objective(policy, observation, actions, generator=generator).loss.backward()
            optimizer.step()
        assert consistency() < 0.8 * before

    @pytest.mark.slow
    def test_bench_cli_times_a_distilled_lerobot_policy(self, policy, tmp_path):

        from snapflow.adapters.lerobot import save_distilled
        from snapflow.cli import main

        directory = save_distilled(policy, tmp_path / "distilled")
        output = tmp_path / "bench"
        with self.loading():
            assert (
                main(
                    [
                        "bench",
                        "--policy",
                        str(directory),
                        "--warmup",
                        "1",
                        "--repeats",
                        "2",
                        "--no-profile",
                        "--batch-sizes",
                        "1,2",
                        "--distill-batch-sizes",
                        "2",
                        "--output",
                        str(output),
                    ]
                )
                == 0
            )
        report = json.loads((output / "bench.json").read_text())
        assert report["details"]["policy_type"] == self.policy_type
        # the plan of a full run: a distillation step at batch 2 and the throughput at batch 1 and 2
        (step,) = report["distill_step"]["rows"]
        assert (
            step["batch_size"] == 2
            and 0 < step["step_ms_median"] <= step["step_ms_p90"]
            and step["peak_memory_gib"] > 0
        )
        assert list(report["throughput"]) == ["1", "2"] and 0 < report["jump_to_teacher_pass_ratio"]
        expert_tensors = {id(p): p for module in policy.expert_modules() for p in module.parameters()}  # each once
        expert = sum(parameter.numel() for parameter in expert_tensors.values())
        assert report["details"]["expert_parameters"] == expert
        assert report["details"]["parameters"] == sum(parameter.numel() for parameter in policy.parameters()) > expert
        latency = report["latency"]
        # the policy's own steps first (the speedups' reference), then the teacher's 10, 5 and 2, and the jump
        steps = list(dict.fromkeys((type(policy).own_steps(policy.policy.config), 10, 5, 2)))
        assert list(latency["modes"]) == [*(f"teacher-{count}" for count in steps), "snapflow-1"]
        assert [latency["modes"][name]["nfe"] for name in latency["modes"]] == [*steps, 1]
        assert latency["prefix"]["repeats"] == 2 and latency["warmup"] == 1
        assert all(
            entry["denoising"]["repeats"] == 2 and 0 < entry["denoising"]["median_ms"] <= entry["denoising"]["p90_ms"]
            for entry in latency["modes"].values()
        )

        # a student type never distilled (as lerobot-train leaves one whose config says so) is timed at its naive
        # step, under that name, never as SnapFlow's
        from snapflow.benchmark.subjects import make_subject
        from snapflow.flow.modes import NAIVE_1

        (directory / "snapflow.json").unlink()
        config = json.loads((directory / "config.json").read_text())
        (directory / "config.json").write_text(json.dumps({**config, "distilled": False}))
        with self.loading():
            assert make_subject(str(directory), None, torch.device("cpu"), torch.float32).one_step == NAIVE_1
