"""The `cooploc` command line (DESIGN §6): list, run, compare, view, reproduce.

The CLI only parses and calls `cooploc.experiment` / `cooploc.reproduce`. Every
mistake a user can make on the command line (unknown scenario, estimator or key, a
bad value) ends in one line on stderr and exit code 2, without a traceback.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer
from rich.console import Console
from rich.table import Table

from cooploc.errors import ConfigError, CooplocError

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="cooploc — cooperative localization of connected vehicles.",
    pretty_exceptions_enable=False,
)
F = TypeVar("F", bound=Callable[..., Any])


def _clean_errors(fn: F) -> F:
    """Turn cooploc's own errors into one line on stderr and exit code 2."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except CooplocError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from None

    return wrapper  # type: ignore[return-value]


def _pairs(items: list[str], option: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = (part.strip() for part in item.partition("="))
        if not sep or not key:
            raise ConfigError(f"{option} takes key=value, got {item!r}")
        if key in out:  # the last one winning would silently drop the first
            raise ConfigError(f"{option} gives {key!r} twice: {out[key]!r} and {value!r}")
        out[key] = value
    return out


def _estimator_pairs(items: list[str]) -> dict[str, dict[str, str]]:
    out: dict[str, dict[str, str]] = {}
    for key, value in _pairs(items, "--est-set").items():
        name, sep, field = key.partition(".")
        if not sep or not field:
            raise ConfigError(f"--est-set takes EST.key=value, got {key}={value!r}")
        out.setdefault(name, {})[field] = value
    return out


def _on_command_line(ctx: typer.Context, name: str) -> bool:
    """Whether option `name` was typed (not left at its default)."""
    source = ctx.get_parameter_source(name)  # typer's own click: compare by name, not identity
    return source is not None and source.name == "COMMANDLINE"


SCHEDULER_HELP = ("Address of a running Dask scheduler (tcp://HOST:PORT) to send the runs to; implies "
                  "--backend dask \\[default: $DASK_SCHEDULER_ADDRESS, else dask's scheduler-address, "
                  "else a local cluster].")
THREADS_HELP = ("BLAS/OpenMP/numba threads of the serial backend \\[default: the libraries' own, every "
                "core]; worker processes always run one thread each.")


def _backend_of(ctx: typer.Context, backend: str, scheduler: str | None) -> str:
    """The backend: a scheduler address given without --backend means dask."""
    return "dask" if scheduler is not None and not _on_command_line(ctx, "backend") else backend


def _check_threads(threads: int | None, backend: str) -> None:
    if threads is None:
        return
    if threads < 1:
        raise ConfigError(f"--threads must be a positive integer, got {threads}")
    if backend != "serial":
        raise ConfigError(f"--threads sets the threads of the serial backend; the {backend} backend runs "
                          f"one thread per worker (use --workers); got --threads {threads}")


def check_out(folder: Path, config: Any, overwrite: bool) -> None:
    """Refuse, before any run, an output folder that cannot be written or that holds the
    results of another configuration (unless `overwrite`).

    A folder holding a summary.json or config.toml is a results folder; it may be written
    over only by the same experiment (`ExperimentConfig.same_experiment`: backend and
    workers aside). The folder is created and a probe file written and removed in it.
    """
    import tempfile

    from cooploc.experiment import ExperimentConfig

    if folder.exists() and not folder.is_dir():
        raise ConfigError(f"--out: {str(folder)!r} is a file, not a folder")
    marks = [folder / "summary.json", folder / "config.toml"]
    if not overwrite and any(m.exists() for m in marks):
        try:
            previous = ExperimentConfig.read(marks[1])
        except CooplocError:
            previous = None
        if previous is None or not previous.same_experiment(config):
            raise ConfigError(f"{folder} holds the results of another configuration (see its config.toml); "
                              f"give --overwrite to replace them, or another --out")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        raise ConfigError(f"--out: cannot write to {str(folder)!r}: {exc.strerror or exc}") from None


@app.command("list")
@_clean_errors
def list_cmd() -> None:
    """Scenarios, presets and estimators with one-line descriptions."""
    from cooploc.estimators import estimators
    from cooploc.reproduce import experiments
    from cooploc.scenarios import presets

    console = Console()
    table = Table(title="Scenario presets", show_lines=False)
    table.add_column("preset")
    table.add_column("description")
    for name, preset in sorted(presets().items()):
        table.add_row(name, preset.summary)
    console.print(table)
    table = Table(title="Estimators")
    table.add_column("estimator")
    table.add_column("description")
    table.add_column("default preset")
    for name, cls in sorted(estimators().items()):
        table.add_row(name, cls.summary, cls.default_preset)
    console.print(table)
    table = Table(title="Paper experiments (cooploc reproduce)")
    table.add_column("paper")
    table.add_column("what")
    for name, exp in sorted(experiments().items()):
        table.add_row(name, exp.title)
    console.print(table)


@app.command()
@_clean_errors
def run(
    ctx: typer.Context,
    scenario: Annotated[str, typer.Argument(help="Scenario preset, see `cooploc list`.")] = "",
    estimator: Annotated[list[str], typer.Option("-e", "--estimator",
                                                 help="Estimator to run (repeat).")] = [],  # noqa: B006
    runs: Annotated[int, typer.Option(help="Monte Carlo runs.")] = 10,
    seed: Annotated[int, typer.Option(help="The one seed of every number.")] = 0,
    set_: Annotated[list[str], typer.Option("--set", help="Scenario parameter key=value.")] = [],  # noqa: B006
    est_set: Annotated[list[str], typer.Option("--est-set",
                                               help="Estimator parameter EST.key=value.")] = [],  # noqa: B006
    out: Annotated[str | None, typer.Option(
        help="Results folder \\[default: results/SCENARIO, or the folder of --config].")] = None,
    backend: Annotated[str, typer.Option(help="serial, processes or dask.")] = "processes",
    workers: Annotated[int | None, typer.Option(
        help="Worker processes, for processes and dask \\[default: all cores].")] = None,
    scheduler: Annotated[str | None, typer.Option(help=SCHEDULER_HELP)] = None,
    threads: Annotated[int | None, typer.Option(help=THREADS_HELP)] = None,
    resume: Annotated[bool, typer.Option(
        "--resume", help="Go on with an interrupted study in --out: its finished runs are kept, the "
                         "others run (the folder must hold the same experiment).")] = False,
    config: Annotated[Path | None, typer.Option(
        help="Rerun the config.toml of a results folder, into that folder; -e, --runs, --seed, --set, "
             "--est-set, --backend, --workers and --scheduler given with it override the file's "
             "values.")] = None,
    overwrite: Annotated[bool, typer.Option(
        help="Write over a results folder of another configuration (the same configuration "
             "may always be rerun into its own folder).")] = False,
    progress: Annotated[bool, typer.Option(help="Show a progress bar.")] = True,
    view: Annotated[bool, typer.Option("--view", help="Also write view.html (see `cooploc view`).")] = False,
) -> None:
    """Run estimators on a scenario for N Monte Carlo runs and write a results folder."""
    from cooploc.backends import limit_threads
    from cooploc.budget import check_memory, duration, estimate_seconds
    from cooploc.experiment import ExperimentConfig
    from cooploc.results import finished_runs, run_to_folder

    if out is not None and not out.strip():
        raise ConfigError(f"--out must name a folder, got {out!r}")
    if resume and overwrite:
        raise ConfigError("--resume keeps the finished runs of --out and --overwrite replaces them: give one")
    backend = _backend_of(ctx, backend, scheduler)
    if config is not None:
        if not config.is_file():
            raise ConfigError(f"--config: no such file {str(config)!r}")
        try:
            cfg = ExperimentConfig.read(config)
        except ConfigError as exc:
            raise ConfigError(f"--config: {exc}") from None
        if scenario and scenario != cfg.scenario:
            raise ConfigError(f"scenario {scenario!r} differs from {cfg.scenario!r} of --config {config}; "
                              f"leave it out to rerun the file's")
        given = {name: value for name, value in (("runs", runs), ("seed", seed), ("backend", backend),
                                                  ("workers", workers), ("scheduler", scheduler))
                 if _on_command_line(ctx, name)}
        if scheduler is not None:
            given["backend"] = backend
        cfg = cfg.with_overrides(estimator or None, scenario_overrides=_pairs(set_, "--set"),
                                 estimator_overrides=_estimator_pairs(est_set), **given)
        folder = Path(out) if out is not None else config.parent
    else:
        if not scenario:
            raise ConfigError("name a scenario (see `cooploc list`) or give --config")
        cfg = ExperimentConfig.build(
            scenario, estimator, scenario_overrides=_pairs(set_, "--set"),
            estimator_overrides=_estimator_pairs(est_set), runs=runs, seed=seed,
            backend=backend, workers=workers, scheduler=scheduler,
        )
        folder = Path(out) if out is not None else Path("results") / cfg.scenario
    _check_threads(threads, cfg.backend)
    check_memory(cfg)
    existed = folder.exists()
    if resume:
        finished_runs(folder, cfg)  # another experiment in the folder: refused, saying what differs
    check_out(folder, cfg, overwrite)
    seconds = estimate_seconds(cfg)
    if seconds >= 3600:  # not refused (a long study may be meant), but said before it starts
        typer.echo(f"note: this experiment needs at least {duration(seconds)} of computing", err=True)
    try:
        with limit_threads(threads):  # run by run: Ctrl-C keeps the finished runs, --resume goes on
            run_to_folder(cfg, folder, progress=progress, resume=resume)
    except KeyboardInterrupt:
        _print_summary(folder)
        raise typer.Exit(130) from None
    except ConfigError:
        if not existed:  # made by check_out; a refused configuration leaves no empty folder
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise
    if view:
        from cooploc.view import link_in_report, write_view

        link_in_report(folder, write_view(folder).name)
    _print_summary(folder)


def _print_summary(folder: Path) -> None:
    import json

    summary = json.loads((folder / "summary.json").read_text())
    from rich.markup import escape

    from cooploc.plots import run_notes, shown_ids

    ids = sorted({v for e in summary["estimators"].values() for v in e["vehicle_rmse"]}, key=int)
    candidates = shown_ids(ids)  # evenly spread over the ids, not only the first few
    console = Console()
    # Names and numbers are never cut: vehicle columns are left out until the table fits.
    for shown in range(len(candidates), -1, -1):
        table = _summary_table(summary, candidates[:shown])
        needed = sum(c.min_width or 0 for c in table.columns) + 3 * len(table.columns) + 1  # + borders
        if shown == 0 or needed <= console.width:
            break
    if len(ids) > shown:
        table.caption = f"{shown} of {len(ids)} vehicles shown; all in summary.json"
    console.print(table, width=max(console.width, needed), crop=False)
    for note in run_notes(summary):  # failed / diverged estimator-runs, an unfinished experiment
        console.print(f"[bold red]![/] {escape(note)}", highlight=False)
    console.print(f"results: {folder}/ (summary.json, errors.parquet, config.toml, report.md, figures)")


def _summary_table(summary: dict[str, Any], ids: list[str]) -> Table:
    """The terminal table of a summary: RMSE of the vehicles `ids`, pooled RMSE, speed."""
    table = Table(title=f"{summary['scenario']}: {summary['runs']} runs, seed {summary['seed']}")
    rows = []
    for name, est in summary["estimators"].items():
        all_v, sps = est["vehicle_rmse_all"], est["steps_per_second"]
        rows.append([name, *(f"{est['vehicle_rmse'][v]:.3f}" if v in est["vehicle_rmse"] else "–"
                             for v in ids),
                     "–" if all_v is None else f"{all_v:.3f}", "–" if sps is None else f"{sps:.0f}"])
    headers = ["estimator", *(f"vehicle {v} RMSE \\[m]" for v in ids), "all vehicles \\[m]", "steps/s"]
    for i, header in enumerate(headers):
        widest = max([len(row[i]) for row in rows] + [len(w) for w in header.replace("\\", "").split()])
        table.add_column(header, justify="left" if i == 0 else "right", no_wrap=i == 0, min_width=widest)
    for row in rows:
        table.add_row(*row)
    return table


@app.command()
@_clean_errors
def compare(
    ctx: typer.Context,
    scenario: Annotated[list[str], typer.Option(
        "-s", "--scenario", help="Scenario preset (repeat) \\[default: every preset but the SUMO cities, "
                                 "which run only when named].")] = [],  # noqa: B006
    estimator: Annotated[list[str], typer.Option(
        "-e", "--estimator", help="Estimator (repeat) \\[default: every registered one].")] = [],  # noqa: B006
    runs: Annotated[int, typer.Option(help="Monte Carlo runs per scenario.")] = 10,
    seed: Annotated[int, typer.Option(help="The one seed of every number.")] = 0,
    set_: Annotated[list[str], typer.Option(
        "--set", help="Scenario parameter key=value, for every scenario compared.")] = [],  # noqa: B006
    out: Annotated[Path, typer.Option(help="Output folder: one results folder per scenario, compare.md, "
                                           "compare.json, compare.png.")] = Path("results/compare"),
    backend: Annotated[str, typer.Option(help="serial, processes or dask.")] = "processes",
    workers: Annotated[int | None, typer.Option(
        help="Worker processes, for processes and dask \\[default: all cores].")] = None,
    scheduler: Annotated[str | None, typer.Option(help=SCHEDULER_HELP)] = None,
    threads: Annotated[int | None, typer.Option(help=THREADS_HELP)] = None,
    overwrite: Annotated[bool, typer.Option(
        help="Write over results folders of another configuration.")] = False,
    resume: Annotated[bool, typer.Option(
        "--resume", help="Go on with an interrupted comparison in --out: finished runs are kept.")] = False,
    progress: Annotated[bool, typer.Option(help="Show a progress bar.")] = True,
) -> None:
    """Run every estimator on every scenario whose sensors it needs: the method × scenario table."""
    from cooploc.backends import limit_threads
    from cooploc.budget import check_memory, duration, estimate_seconds
    from cooploc.compare import default_presets, plan, run_compare
    from cooploc.results import finished_runs

    if resume and overwrite:
        raise ConfigError("--resume keeps the finished runs of --out and --overwrite replaces them: give one")
    backend = _backend_of(ctx, backend, scheduler)
    _check_threads(threads, backend)
    plans = plan(scenario or default_presets(), estimator, scenario_overrides=_pairs(set_, "--set"),
                 runs=runs, seed=seed, backend=backend, workers=workers, scheduler=scheduler)
    configs = [p.config for p in plans if p.config is not None]
    for p in plans:  # every refusal before the first run
        if p.config is not None:
            check_memory(p.config)
            if resume:
                finished_runs(out / p.preset, p.config)
            check_out(out / p.preset, p.config, overwrite)
    seconds = sum(estimate_seconds(c) for c in configs)
    if seconds >= 3600:  # as `cooploc run`: said, not refused
        typer.echo(f"note: this comparison needs at least {duration(seconds)} of computing", err=True)
    try:
        with limit_threads(threads):
            folder = run_compare(plans, out, progress=progress, resume=resume)
    except KeyboardInterrupt:  # the finished runs are merged in their scenario's folder
        typer.echo(f"interrupted: compare.md not written; the finished scenarios are in {out}/", err=True)
        raise typer.Exit(130) from None
    for p in plans:
        ran = len(p.config.estimators) if p.config is not None else 0
        Console().print(f"{p.preset}: {ran} estimators run, {len(p.refused)} not applicable (reasons in "
                        f"compare.md)", highlight=False)
    Console().print(f"results: {folder}/ (compare.md, compare.json, compare.png, one folder per scenario)")


@app.command("view")
@_clean_errors
def view_cmd(
    results: Annotated[Path, typer.Argument(help="Results folder of `cooploc run`.")],
    run: Annotated[int, typer.Option(help="Which Monte Carlo run to show.")] = 0,
    out: Annotated[Path | None, typer.Option(
        help="Output file \\[default: RESULTS/view.html, or RESULTS/view.gif with --gif].")] = None,
    gif: Annotated[bool, typer.Option("--gif", help="Write an animation instead: .gif, or .mp4 "
                                                    "with --out X.mp4 where ffmpeg exists.")] = False,
) -> None:
    """Write one run of a results folder as an interactive, offline HTML page (or an animation)."""
    from cooploc.view import write_animation, write_view

    path = write_animation(results, run, out) if gif else write_view(results, run, out)
    Console().print(f"{'animation' if gif else 'view'}: {path} ({path.stat().st_size / 1e6:.1f} MB)")


@app.command()
@_clean_errors
def reproduce(
    ctx: typer.Context,
    paper: Annotated[str, typer.Argument(help="Paper experiment, see `cooploc list`.")],
    runs: Annotated[int | None, typer.Option(help="Runs per point \\[default: the paper's].")] = None,
    seed: Annotated[int, typer.Option(help="The one seed of every number.")] = 0,
    out: Annotated[Path | None,
                   typer.Option(help="Output folder \\[default: results/reproduce-PAPER].")] = None,
    backend: Annotated[str, typer.Option(help="serial, processes or dask.")] = "processes",
    workers: Annotated[int | None, typer.Option(
        help="Worker processes, for processes and dask \\[default: all cores].")] = None,
    scheduler: Annotated[str | None, typer.Option(help=SCHEDULER_HELP)] = None,
    threads: Annotated[int | None, typer.Option(help=THREADS_HELP)] = None,
    quick: Annotated[bool, typer.Option(help="Small version to check the pipeline.")] = False,
    progress: Annotated[bool, typer.Option(help="Show progress bars.")] = True,
    resume: Annotated[bool, typer.Option(
        "--resume", help="Go on with an interrupted reproduction in --out: its finished runs "
                         "(OUT/runs/) are kept, not run again.")] = False,
) -> None:
    """Reproduce a paper's figures: PNG files and a Markdown report beside the paper's numbers."""
    from cooploc.backends import limit_threads
    from cooploc.experiment import ExperimentConfig
    from cooploc.reproduce import ReproduceOptions, get_experiment

    experiment = get_experiment(paper)
    if runs is not None and runs < 1:
        raise ConfigError(f"runs must be a positive integer, got {runs}")
    backend = _backend_of(ctx, backend, scheduler)
    ExperimentConfig.check_backend(backend, workers, scheduler)
    _check_threads(threads, backend)
    folder = out or Path("results") / f"reproduce-{paper}"
    with limit_threads(threads):
        experiment.run(ReproduceOptions(folder, runs, seed, backend, workers, quick, progress,
                                        scheduler=scheduler, resume=resume))
    Console().print(f"{experiment.title}: report at {folder / 'report.md'}")


def main() -> None:
    """Entry point of the `cooploc` console script."""
    app()


if __name__ == "__main__":
    main()
