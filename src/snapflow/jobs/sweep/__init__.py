"""Sweeps: the paper's experiments on MT10 from one TOML file, with seeds, caching and a report.

A sweep config names a demonstration set, the runs trained on it (teachers, and students distilled from
them, each with its own settings and seeds) and the tables to fill (rows = run x sampling mode x actions
per chunk). ``run_sweeps`` runs, on :mod:`snapflow.jobs.runner`, every job that is not done: collect -> train
teachers -> distill students -> evaluate, in dependency order and on several worker processes. A job is done when
its record holds its current full settings and those of the jobs it reads, so an interrupted sweep picks up where it
stopped, adding a seed or a row runs only what is new, and changing a setting re-runs exactly the jobs downstream of
it. ``write_results`` then turns the cached evaluations into ``results.json``, one PNG per table and Markdown tables,
which it writes between markers in a results page (``docs/results/<benchmark>.md``) and leaves the prose around them alone.

Config layout (see ``configs/sweeps/*.toml``)::

    name = "mt10-state"                 # output_dir = outputs/sweeps/<name>, results in docs/results/sweeps/<name>
    seeds = [0, 1, 2]                   # default seeds of every run and table
    [data]                              # env (snapflow.envs.factory), tasks (a set such as "mt10", the default, or a list), episodes_per_task,
                                        # image_size
    [runs.teacher]                      # a teacher: policy = {type = "minivla" | "mlp", fields of its config},
                                        # train = {TrainConfig fields}
    recipe = "paper"                    # the students' default recipe (snapflow.training.recipes.RECIPES)
    [runs.snapflow]                     # a student: teacher = "teacher", recipe, distill = {DistillSettings
                                        # fields}, train (both override the recipe's)
    [[tables]]                          # name, title, episodes_per_task, n_act, seeds, per_task, x_label,
                                        # reference (the row the others are compared with, paired),
                                        # first_variation (LIBERO: the first initial state), evaluator,
                                        # tasks (a subset of the data's, e.g. "libero_10_0,libero_10_1"),
                                        # per_set (each row on each named set of tasks: LIBERO's suites),
                                        # contrasts ([row, against] pairs: paired differences beside the reference's)
                                        # max_episode_steps (every episode cut there: a quick check of a sweep)
    rows = [{label = "...", run = "snapflow", mode = "snapflow-1", n_act = 4, series = "...", x = 1}]
                                        # sweep = "other.toml": the row reads that sweep's run and evaluations
                                        # (same env and tasks, so its cells pair), never runs them

Unless a run says otherwise, teachers train with ``TEACHER_TRAINING`` and students with the sweep's recipe (default:
``DEFAULT_RECIPE``), see :mod:`snapflow.training.recipes`.
"""

from snapflow._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "snapflow.jobs.sweep.specs": ["SweepConfig"],
        "snapflow.jobs.sweep.schema": ["load_sweep"],
        "snapflow.jobs.sweep.data_jobs": ["CollectJob", "DataJob"],
        "snapflow.jobs.sweep.training_jobs": ["TrainJob"],
        "snapflow.jobs.sweep.eval_jobs": ["EvalJob"],
        "snapflow.jobs.sweep.planning": ["jobs", "plan", "run_sweeps"],
        "snapflow.jobs.sweep.aggregate": ["SweepRow", "TableResult", "table_results"],
        "snapflow.jobs.sweep.markdown": ["replace_block"],
        "snapflow.jobs.sweep.results": ["write_results"],
    },
)
