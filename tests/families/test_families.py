"""The policy families: one contract every family inherits, and the one place that says which family a type, a spec
or a sweep's run table belongs to."""

from __future__ import annotations

import json
from pathlib import Path
from typing import ClassVar

import pytest
import torch

from snapflow.adapters.lerobot_config import LeRobotSpec
from snapflow.benchmark.bench import one_step_actions, run_bench
from snapflow.benchmark.subjects import make_subject
from snapflow.errors import InvalidInputError
from snapflow.families import FAMILIES, PolicyFamily, TeacherOptions, family_of, register_family, teacher_types
from snapflow.families.builtin import BuiltinFamily
from snapflow.families.lerobot import LeRobotFamily
from snapflow.flow.modes import SNAPFLOW_1
from snapflow.policies.mlp.configuration import MLPPolicyConfig


class FamilyContract:
    """What every registered family keeps: its declarations agree with the registry, its default teacher spec is its
    own and records under its run key, and it refuses what it does not take by name."""

    family: ClassVar[PolicyFamily]
    other_source: ClassVar[dict[str, str]]  # the other family's source flags, which this one refuses
    small_architecture: ClassVar[str]  # one of its architectures that builds in seconds (with :meth:`vlm`)

    def vlm(self, folder: Path) -> str | None:
        """Where its small architecture reads a VLM's config from, written into ``folder``; None for none."""
        return None

    def test_it_is_registered_once_and_owns_its_teacher_types(self):
        assert [family.name for family in FAMILIES].count(self.family.name) == 1
        assert self.family.teacher_types()
        assert all(family_of(name) is self.family for name in self.family.teacher_types())
        assert set(self.family.teacher_types()) <= set(self.family.architectures())  # bench builds what it trains

    def test_snapflows_trainer_and_evaluator_come_first(self):
        assert self.family.trainers[0] == "snapflow" and self.family.evaluators[0] == "snapflow"

    def test_its_default_teacher_spec_is_its_own_and_records_under_its_run_key(self):
        spec = self.family.teacher_spec("[runs.t] x", {}, "metaworld", ("reach-v3",))
        assert family_of(spec) is self.family and family_of({self.family.run_key: {}}) is self.family
        record = self.family.teacher_record(spec)
        assert list(record) == [self.family.run_key] and json.loads(json.dumps(record)) == record

    def test_it_refuses_a_trainer_it_does_not_have(self):
        with pytest.raises(InvalidInputError, match=f"does not distil a {self.family.title} policy"):
            self.family.check_trainer("accelerate")

    def test_it_refuses_the_other_familys_source(self):
        with pytest.raises(InvalidInputError, match="trains on"):
            self.family.source(self.other_source.get("data"), self.other_source.get("dataset"), None)

    def test_its_random_architecture_is_an_opened_policy_that_bench_times_at_its_one_step(self, tmp_path):
        """``snapflow bench --architecture``: the family builds it, the opened policy makes its own subject."""
        architecture = self.small_architecture
        subject = make_subject(None, architecture, torch.device("cpu"), torch.float32, self.vlm(tmp_path))
        assert subject.name == f"{architecture} (full size, random weights)"
        assert subject.details["policy_type"] == architecture and subject.one_step == SNAPFLOW_1
        assert subject.details["parameters"] == sum(parameter.numel() for parameter in subject.policy.parameters())
        assert one_step_actions(subject).shape == subject.noise.shape
        report = run_bench(subject, warmup=0, repeats=1, profile=False)
        assert list(report.latency.modes)[-1] == "snapflow-1"

    def test_its_policy_path_is_inside_the_run_folder(self, tmp_path):
        for trainer in self.family.trainers:
            path = self.family.policy_path(tmp_path, trainer)
            assert path == tmp_path or tmp_path in path.parents


class TestBuiltinFamily(FamilyContract):
    family = FAMILIES[0]
    other_source: ClassVar[dict[str, str]] = {"dataset": "some/dataset"}
    small_architecture = "mlp"

    def test_a_built_in_architecture_reads_no_vlm(self):
        with pytest.raises(InvalidInputError, match="--vlm: the built-in mlp reads no VLM"):
            self.family.random_policy("mlp", "cpu", "some/vlm")

    def test_a_run_folder_is_its_own_policy(self, tmp_path):
        assert self.family.policy_path(tmp_path) == tmp_path

    def test_a_sweeps_policy_table_sizes_the_policy_for_the_benchmark(self):
        spec = self.family.teacher_spec(
            "[runs.t] policy", {"type": "mlp", "hidden_dim": 64}, "metaworld", ("reach-v3", "push-v3")
        )
        assert spec == MLPPolicyConfig(observation_dim=39 + 2, action_dim=4, chunk_length=8, hidden_dim=64)
        assert self.family.teacher_record(spec) == {"policy": {"type": "mlp", **spec.to_dict()}}

    def test_lerobots_options_are_refused_by_name(self, tmp_path):
        with pytest.raises(InvalidInputError, match="a built-in teacher takes no smolvlm"):
            self.family.teacher_spec_for(
                "mlp", self.family.source(str(tmp_path), None, None), TeacherOptions(smolvlm="tiny")
            )


@pytest.mark.lerobot
class TestLeRobotFamily(FamilyContract):
    family = FAMILIES[1]
    other_source: ClassVar[dict[str, str]] = {"data": "demonstrations"}
    small_architecture = "smolvla"  # at LeRobot's defaults around a tiny SmolVLM, written offline

    def vlm(self, folder: Path) -> str | None:
        from snapflow.adapters.lerobot.smolvlm import words_of, write_smolvlm
        from snapflow.adapters.lerobot_config import SMOLVLM_SIZES

        return str(write_smolvlm(folder / "vlm", words_of(["pick up the bowl"]), SMOLVLM_SIZES["tiny"]))

    def test_each_trainer_leaves_the_policy_where_open_policy_reads_it(self, tmp_path):
        assert self.family.policy_path(tmp_path, "snapflow") == tmp_path / "lerobot_policy"
        last = tmp_path / "lerobot-train" / "checkpoints" / "last" / "pretrained_model"
        assert self.family.policy_path(tmp_path, "lerobot-train") == last

    def test_its_teacher_spec_defaults_are_the_specs_and_a_given_option_overrides_one(self, tmp_path):
        source = self.family.source(None, str(tmp_path), None)
        assert source.dataset == tmp_path and source.repo_id == f"local/{tmp_path.name}"
        spec = self.family.teacher_spec_for("smolvla", source, TeacherOptions(chunk_length=4, image_size=32))
        assert spec == LeRobotSpec("smolvla", chunk_size=4, image_size=32)
        assert spec.size.image_size == 32
        with pytest.raises(InvalidInputError, match="a LeRobot teacher takes no state_dim, policy_options"):
            self.family.teacher_spec_for("smolvla", source, TeacherOptions(state_dim=4, policy_options={"a": 1}))

    def test_a_mistyped_dataset_folder_is_named_before_lerobot_loads(self, tmp_path):
        with pytest.raises(FileNotFoundError, match="missing"):
            self.family.source(None, str(tmp_path / "missing"), None)


def test_the_families_are_built_in_then_lerobot():
    assert [type(family) for family in FAMILIES] == [BuiltinFamily, LeRobotFamily]
    assert teacher_types() == [*FAMILIES[0].teacher_types(), *FAMILIES[1].teacher_types()]


def test_a_run_table_names_one_family_or_none_for_the_default():
    assert family_of({}) is FAMILIES[0] and family_of({"lerobot": {}}) is FAMILIES[1]
    with pytest.raises(InvalidInputError, match="give 'policy' or 'lerobot', not both"):
        family_of({"policy": {}, "lerobot": {}})


def test_an_unknown_type_or_spec_is_a_programming_error_naming_what_is_known():
    with pytest.raises(ValueError, match="no policy family has a policy type 'pusht'; known: .*minivla.*pi05"):
        family_of("pusht")
    with pytest.raises(ValueError, match="no policy family claims"):
        family_of(Path("."))


def test_a_family_is_registered_once():
    with pytest.raises(ValueError, match="registered already"):
        register_family(BuiltinFamily())
