"""Real-time chunking through a student: LeRobot's guided RTC per Euler step in ``teacher-N`` (its own sampler's
output), prefix inpainting on the one jump (the executed prefix continues the previous chunk), never ignored."""

from __future__ import annotations

import json
import warnings

import pytest
import torch

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")

from tests.lerobot_tiny import build_tiny_smolvla, model_inputs, randomise_target_time, tiny_batch  # noqa: E402

DELAY, HORIZON = 2, 3


def _student(vlm_directory):
    from snapflow.adapters.lerobot.plugin import student_config, student_policy

    teacher = build_tiny_smolvla(vlm_directory)
    config = student_config(teacher.config)
    config.distilled = True
    student = student_policy("smolvla")(config)
    student.load_state_dict(teacher.state_dict(), strict=False)
    randomise_target_time(student.snapflow)
    return student


def _chunk(student, rtc: bool, **kwargs) -> torch.Tensor:
    from lerobot.policies.rtc.configuration_rtc import RTCConfig

    student.config.rtc_config = RTCConfig(enabled=True, execution_horizon=HORIZON) if rtc else None
    student.init_rtc_processor()  # as lerobot-rollout does after setting the config
    noise = torch.randn(4, 4, 4, generator=torch.Generator().manual_seed(3))
    return student.predict_action_chunk(tiny_batch(), noise=noise, **kwargs)


@pytest.mark.parametrize("mode", ["snapflow-1", "teacher-10"])
def test_rtc_changes_the_students_chunk_toward_the_previous_one(vlm_directory, mode):
    student = _student(vlm_directory)
    student.config.sampling_mode = mode
    prev = torch.randn(4, 4, 4, generator=torch.Generator().manual_seed(5))
    rtc = dict(inference_delay=DELAY, prev_chunk_left_over=prev, execution_horizon=HORIZON)
    without = _chunk(student, rtc=False, **rtc)
    with_rtc = _chunk(student, rtc=True, **rtc)
    assert (with_rtc - without).abs().max() > 0.1, "the previous chunk must change the chunk"
    before = (without[:, :DELAY] - prev[:, :DELAY]).abs().mean()
    assert (with_rtc[:, :DELAY] - prev[:, :DELAY]).abs().mean() < 0.5 * before
    assert torch.equal(_chunk(student, rtc=True), without), "no previous chunk (the first one): nothing to continue"
    if mode == "snapflow-1":  # inpainting: the executed prefix is the previous chunk's, the tail the jump's own
        assert torch.allclose(with_rtc[:, :DELAY], prev[:, :DELAY], atol=1e-6)
        assert torch.equal(with_rtc[:, HORIZON:], without[:, HORIZON:])
    else:  # LeRobot's own guided sampler, step for step
        student.config.num_steps = 10
        with torch.no_grad():
            lerobots = type(student.model).sample_actions(
                student.model,
                *model_inputs(student, tiny_batch()),
                noise=torch.randn(4, 4, 4, generator=torch.Generator().manual_seed(3)),
                **rtc,
            )
        assert torch.allclose(with_rtc, lerobots, atol=1e-6)


def test_inpainting_is_lerobots_guided_jump_at_weight_one_where_the_jump_moves_with_its_noise():
    from lerobot.policies.rtc.configuration_rtc import RTCConfig
    from lerobot.policies.rtc.modeling_rtc import RTCProcessor

    from snapflow.adapters.lerobot.rtc import inpaint_prefix

    noise, offset = torch.randn(2, 6, 3), torch.randn(2, 6, 3)
    prev = torch.randn(2, 5, 3)
    jump = noise + offset  # a = x_1 - v with v = -offset: its Jacobian in the noise is I
    blended = inpaint_prefix(jump, RTCProcessor(RTCConfig(enabled=True, execution_horizon=4)), prev, 1, 4)
    # LeRobot's linear schedule: 1 over the delay, then down to 0 at the horizon
    weights = torch.tensor([1.0, 0.75, 0.5, 0.25, 0.0, 0.0])[None, :, None]
    padded = torch.cat([prev, torch.zeros(2, 1, 3)], dim=1)
    assert torch.allclose(blended, jump + weights * (padded - jump))
    for weight, matches in [(1.0, True), (10.0, False)]:  # LeRobot's default clamp, 10, overshoots the prefix
        guided = RTCProcessor(RTCConfig(enabled=True, execution_horizon=4, max_guidance_weight=weight))
        velocity = guided.denoise_step(noise, prev, 1, 1.0, lambda x: -offset + 0 * x, 4)
        assert torch.allclose(noise - velocity, blended, atol=1e-6) is matches


def test_a_jumps_guidance_weight_acts_up_to_one_and_above_it_is_capped_out_loud():
    from lerobot.policies.rtc.configuration_rtc import RTCConfig
    from lerobot.policies.rtc.modeling_rtc import RTCProcessor

    from snapflow.adapters.lerobot.rtc import sample_with_rtc
    from snapflow.flow.modes import SNAPFLOW_1

    noise, offset, prev = torch.randn(1, 6, 3), torch.randn(1, 6, 3), torch.randn(1, 5, 3)
    chunks = {}
    for weight in (0.25, 0.5, 1.0, 10.0):
        processor = RTCProcessor(RTCConfig(enabled=True, execution_horizon=4, max_guidance_weight=weight))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            chunks[weight] = sample_with_rtc(lambda x, t, s: -offset + 0 * x, noise, SNAPFLOW_1, processor, prev, 1, 4)
        said = [str(warning.message) for warning in caught if "max_guidance_weight" in str(warning.message)]
        assert len(said) == (weight > 1), weight  # a cap is never silent
    free = noise + offset
    assert not torch.allclose(chunks[1.0], free)  # the prefix pulls the jump's own chunk
    for weight in (0.25, 0.5):  # a weight below 1 pulls that share of the way toward the prefix
        assert torch.allclose(chunks[weight] - free, weight * (chunks[1.0] - free), atol=1e-6)
    assert torch.equal(chunks[10.0], chunks[1.0])
    assert "max_guidance_weight 10 would throw a one-step jump 9 times the gap past" in said[0]
    assert "the jump inpaints the prefix at weight 1" in said[0]


def test_trained_rtc_is_refused_by_name(vlm_directory):
    from lerobot.policies.rtc.configuration_rtc import RTCConfig

    student = _student(vlm_directory)
    student.config.rtc_config = RTCConfig(enabled=True)
    student.config.rtc_config.mode = "trained"  # newer LeRobot's training-time RTC
    student.init_rtc_processor()
    prev = torch.zeros(4, 4, 4)
    with pytest.raises(ValueError, match="RTC mode 'trained' needs a policy trained with the previous chunk"):
        student.predict_action_chunk(tiny_batch(), inference_delay=1, prev_chunk_left_over=prev)


@pytest.mark.parametrize("mode", ["snapflow-1", "teacher-10"])
def test_trained_rtc_gives_a_student_distilled_with_known_prefixes_the_previous_chunk_in_every_pass(
    vlm_directory, mode
):
    from dataclasses import replace

    from lerobot.configs.types import RTCAttentionSchedule
    from lerobot.policies.rtc.configuration_rtc import RTCConfig

    from snapflow.adapters.lerobot.rtc import inpaint_prefix
    from snapflow.flow.known_prefix import sample_continuing
    from snapflow.flow.modes import SamplingMode

    student = _student(vlm_directory)
    student.config.distill = replace(student.config.distill, rtc_max_delay=DELAY)
    student.config.sampling_mode = mode
    prev = torch.randn(4, 4, 4, generator=torch.Generator().manual_seed(5))
    rtc = dict(inference_delay=DELAY, prev_chunk_left_over=prev, execution_horizon=HORIZON)
    without = _chunk(student, rtc=False, **rtc)
    noise = torch.randn(4, 4, 4, generator=torch.Generator().manual_seed(3))
    chunks = {}
    for schedule in (RTCAttentionSchedule.ZEROS, RTCAttentionSchedule.LINEAR):
        student.config.rtc_config = RTCConfig(
            enabled=True, execution_horizon=HORIZON, prefix_attention_schedule=schedule
        )
        student.config.rtc_config.mode = (
            "trained"  # newer LeRobot's field; set on 0.6's config as lerobot-rollout would
        )
        student.init_rtc_processor()
        chunks[schedule] = student.predict_action_chunk(tiny_batch(), noise=noise, **rtc)
    trained = chunks[RTCAttentionSchedule.ZEROS]
    assert torch.equal(trained[:, :DELAY], prev[:, :DELAY]), "the executed prefix is the previous chunk's, exactly"
    assert (trained[:, DELAY:] - without[:, DELAY:]).abs().max() > 1e-3, "and the rest is conditioned on it"
    adapter = student.snapflow
    with torch.no_grad():  # snapflow's own sampler on the adapter, the same chunk
        own = sample_continuing(adapter, adapter.encode(tiny_batch()), noise, SamplingMode.parse(mode), prev, DELAY)
    assert torch.allclose(trained, own, atol=1e-6), "no ramp: LeRobot's trained mode as it is"
    ramp = inpaint_prefix(own, student.rtc_processor, prev, DELAY, HORIZON)  # a jump blends as an untrained one does
    assert torch.allclose(chunks[RTCAttentionSchedule.LINEAR], ramp if mode == "snapflow-1" else own, atol=1e-6)
    with pytest.raises(ValueError, match="inference delay of 3 is past the 2 actions"):
        student.predict_action_chunk(tiny_batch(), noise=noise, **{**rtc, "inference_delay": 3})


def test_a_time_per_action_equal_to_the_rows_is_the_rows_velocity(vlm_directory):
    adapter = _student(vlm_directory).snapflow
    generator = torch.Generator().manual_seed(4)
    x, t, s = torch.randn(4, 4, 4, generator=generator), torch.rand(4, generator=generator), torch.zeros(4)
    with torch.no_grad():
        context = adapter.encode(tiny_batch())
        by_row = adapter.velocity(x, t, s, context)
        by_action = adapter.velocity_per_action(x, t[:, None].expand(-1, 4), s[:, None].expand(-1, 4), context)
    assert torch.allclose(by_row, by_action, atol=1e-6)


def test_the_boundary_benchmark_measures_every_row_on_recorded_chunks(vlm_directory, tmp_path):
    from dataclasses import replace

    from snapflow.benchmark.rtc import ROWS, TRAINED_ROWS, boundary_jumps, write_boundary_report

    student, trained = _student(vlm_directory), _student(vlm_directory)
    trained.config.distill = replace(trained.config.distill, rtc_max_delay=1)
    rows = boundary_jumps(student, tiny_batch(batch_size=5), executed=2, inference_delay=1, trained=trained)
    assert [row.name for row in rows] == [name for name, *_ in ROWS + TRAINED_ROWS]
    assert all(row.prefix_error < 1e-6 for row in rows[len(ROWS) :]), "a trained student is given the prefix"
    by_rtc = {row.rtc: row for row in rows}
    assert by_rtc["inpaint"].prefix_error < 1e-5 < by_rtc["off"].prefix_error
    assert by_rtc["guided"].prefix_error < rows[0].prefix_error
    write_boundary_report([rows, rows], {"chunk_size": 4}, tmp_path)
    table = (tmp_path / "rtc_boundary.md").read_text()
    assert "2 seed(s)" in table and "| 1.00 |" in table, "the guided teacher's row is its own unit"
    assert len(json.loads((tmp_path / "rtc_boundary.json").read_text())["seeds"]) == 2
