"""Closed-loop success of a LeRobot policy (opened as every command opens one) in LeRobot's own simulated environments
(pusht, aloha, libero, metaworld, ...), through LeRobot's env factory and ``eval_policy_all`` rollout, once per
sampling mode. The numbers are LeRobot's: ``pc_success`` over ``n_episodes``, rewards, per task and suite."""

from __future__ import annotations

import os
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import torch

from snapflow.adapters.lerobot.evaluation import LoadedLeRobotPolicy
from snapflow.adapters.lerobot.libero import packaged_initial_states
from snapflow.adapters.lerobot.local_vlm import saved_processors
from snapflow.envs.libero import SUITES, Libero, suite_of
from snapflow.errors import InvalidInputError
from snapflow.flow.modes import SamplingMode
from snapflow.inference.fast_paths import apply_fast_path
from snapflow.policies.loaded import CheckpointError
from snapflow.reporting.files import recorded_path, write_json, write_text
from snapflow.reporting.tables import markdown_table
from snapflow.sources import open_policy


def make_lerobot_env_config(env_type: str, task: str | None = None, image_size: int | None = None) -> Any:
    """LeRobot's registered ``EnvConfig`` for ``env_type``, with its default task unless one is given. For LIBERO,
    ``task`` may also name snapflow's LIBERO tasks of one suite (``libero_spatial_0,libero_spatial_3``: LeRobot's
    suite and ``task_ids``), and ``image_size`` sets the cameras' side (LeRobot renders 360 pixels by default)."""
    from lerobot.envs.configs import EnvConfig

    choices = sorted(EnvConfig.get_known_choices())
    if env_type not in choices:
        raise InvalidInputError(f"unknown LeRobot environment {env_type!r}; LeRobot knows {', '.join(choices)}")
    options: dict[str, Any] = {"task": task} if task else {}
    if env_type == "libero":
        if task and task not in SUITES:
            named = [suite_of(name) for name in Libero().resolve_tasks(task)]
            suites = {suite for suite, _ in named}
            if len(suites) != 1:
                raise InvalidInputError(f"--env-task names tasks of one LIBERO suite at a time, got {sorted(suites)}")
            options.update(task=suites.pop(), task_ids=[index for _, index in named])
        if image_size:
            options.update(observation_height=image_size, observation_width=image_size)
    return EnvConfig.get_choice_class(env_type)(**options)


def evaluate_in_lerobot_env(
    policy_directory: str | Path,
    env_type: str,
    modes: list[SamplingMode],
    episodes: int,
    task: str | None = None,
    n_action_steps: int | None = None,
    n_envs: int = 1,
    seed: int = 1000,
    max_episode_steps: int | None = None,
    device: str | None = None,
    fast_path: str | None = None,
) -> dict[str, Any]:
    """Run ``episodes`` rollouts per mode and return ``{"modes": {name: LeRobot's eval info + NFE}, ...}``.

    ``n_action_steps`` actions of each predicted chunk are executed before re-planning (default: the policy's
    own setting); ``max_episode_steps`` cuts episodes short of the environment's own limit (quick checks);
    ``fast_path`` names a registered fast path the policy runs in (:func:`snapflow.inference.apply_fast_path`), which
    LeRobot's rollout reaches through the adapter's sampling.
    """
    os.environ.setdefault("MUJOCO_GL", "egl")  # Meta-World and ALOHA render off-screen
    from lerobot.envs.factory import make_env
    from lerobot.envs.utils import close_envs
    from lerobot.scripts.lerobot_eval import eval_policy_all

    if episodes < 1 or n_envs < 1:
        raise InvalidInputError("episodes and n_envs must be at least 1")
    adapter, modes = _open_lerobot_policy(policy_directory, modes)
    policy = adapter.policy
    chunk = adapter.action_shape[0]
    n_action_steps = n_action_steps or policy.config.n_action_steps
    if not 1 <= n_action_steps <= chunk:
        raise InvalidInputError(
            f"n_action_steps must be between 1 and the policy's chunk size {chunk}, got {n_action_steps}"
        )
    policy.config.n_action_steps = n_action_steps
    device = device or ("cuda" if torch.cuda.is_available() else "cpu")
    policy.config.device = device
    policy.to(device).eval()
    if fast_path:
        apply_fast_path(adapter, fast_path)

    cameras = [feature.shape[-1] for feature in policy.config.image_features.values()]
    env_config = make_lerobot_env_config(env_type, task, cameras[0] if cameras else None)
    preprocessor, postprocessor = saved_processors(policy.config, policy_directory, device)
    env_preprocessor, env_postprocessor = adapter.env_processors(env_config, policy.config)
    with packaged_initial_states() if env_type == "libero" else nullcontext():
        try:
            environments = make_env(env_config, n_envs=n_envs)
        except ModuleNotFoundError as missing:
            raise InvalidInputError(_missing_env_package(env_type, env_config, missing)) from None
    if max_episode_steps:
        for suite in environments.values():
            for vector_env in suite.values():
                vector_env.set_attr("_max_episode_steps", max_episode_steps)
    results: dict[str, Any] = {}
    try:
        for mode in modes:
            adapter.use_sampling_mode(mode)
            with torch.no_grad():
                info = eval_policy_all(
                    environments,
                    policy,
                    env_preprocessor,
                    env_postprocessor,
                    preprocessor,
                    postprocessor,
                    n_episodes=episodes,
                    start_seed=seed,
                )
            results[mode.name] = {"nfe": mode.num_steps, **info}
    finally:
        close_envs(environments)
    return {
        "policy": recorded_path(policy_directory),
        "policy_type": adapter.policy_type,
        "env": env_type,
        "task": env_config.task,
        "episodes_per_task": episodes,
        "n_action_steps": n_action_steps,
        "chunk_size": chunk,
        "n_envs": n_envs,
        "start_seed": seed,
        "max_episode_steps": max_episode_steps,
        "device": device,
        "fast_path": fast_path,
        "modes": results,
    }


def _missing_env_package(env_type: str, env_config: Any, missing: ModuleNotFoundError) -> str:
    """The one line that names the package LeRobot's environment ``env_type`` lacks, with its install command (the
    simulators snapflow installs itself by its own extras, the others by LeRobot's)."""
    package = getattr(env_config, "package_name", None) or missing.name or str(missing)
    distribution = "snapflow-vla" if env_type in ("libero", "metaworld") else "lerobot"
    install = f'pip install "{distribution}[{env_type}]"'
    return f"LeRobot's {env_type} environment needs {package}, which is not installed: {install}"


def _open_lerobot_policy(source: str | Path, modes: list[SamplingMode]) -> tuple[Any, list[SamplingMode]]:
    """The adapter of the LeRobot policy at ``source``, opened as every command opens one (a ``snapflow distill``
    student, a ``lerobot-train`` checkpoint of a student type, a teacher), and ``modes`` as it samples them (a bare
    ``teacher`` at its own steps): a jump mode of a policy never distilled, an export, or a built-in policy is
    refused by name."""
    opened = open_policy(source)
    if not isinstance(opened, LoadedLeRobotPolicy):
        raise CheckpointError(
            f"{source} is a {opened.policy_type} policy of snapflow's own: LeRobot's environments run LeRobot "
            "policies; evaluate it with snapflow eval --env instead"
        )
    if opened.exported:
        raise CheckpointError(
            f"{source} is a {opened.export['format']} export: LeRobot's rollout runs the PyTorch policy; give the "
            f"folder it was exported from ({opened.export['source']})"
        )
    return opened.policy, [opened.resolve_mode(mode) for mode in modes]


def lerobot_eval_table(report: dict[str, Any]) -> str:
    """Markdown summary: success rate with its episode count, rewards and wall time per sampling mode."""
    title = (
        f"{report['policy_type']} in LeRobot's {report['env']} ({report['task']}), {report['n_action_steps']} of "
        f"{report['chunk_size']} actions executed per chunk"
    )
    rows = [
        (
            name,
            info["nfe"],
            f"{info['overall']['pc_success']:.1f}%",
            info["overall"]["n_episodes"],
            f"{info['overall']['avg_max_reward']:.3f}",
            f"{info['overall']['avg_sum_reward']:.3f}",
            f"{info['overall']['eval_s']:.1f}",
        )
        for name, info in report["modes"].items()
    ]
    return (
        title
        + "\n\n"
        + markdown_table(["mode", "NFE", "success", "episodes", "avg max reward", "avg sum reward", "eval s"], rows)
    )


def write_lerobot_eval(report: dict[str, Any], output_dir: str | Path) -> Path:
    """``report.json`` (everything), ``report.md`` (the table) and, per mode, LeRobot's ``eval_info.json``."""
    output_dir = Path(output_dir)
    for name, info in report["modes"].items():
        write_json(output_dir / name / "eval_info.json", {key: value for key, value in info.items() if key != "nfe"})
    write_json(output_dir / "report.json", report)
    write_text(output_dir / "report.md", lerobot_eval_table(report) + "\n")
    return output_dir


__all__ = ["make_lerobot_env_config", "evaluate_in_lerobot_env", "lerobot_eval_table", "write_lerobot_eval"]
