"""The `cooploc` command line (DESIGN §6): list, run, view, reproduce.

The CLI only parses and calls `cooploc.experiment` / `cooploc.reproduce`. Every
mistake a user can make on the command line (unknown scenario, estimator or key, a
bad value) ends in one line on stderr and exit code 2, without a traceback.
"""

from __future__ import annotations

import functools
import sys
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
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"{option} takes key=value, got {item!r}")
        out[key.strip()] = value.strip()
    return out


def _estimator_pairs(items: list[str]) -> dict[str, dict[str, str]]:
    out: dict[str, dict[str, str]] = {}
    for key, value in _pairs(items, "--est-set").items():
        name, sep, field = key.partition(".")
        if not sep or not field:
            raise ConfigError(f"--est-set takes EST.key=value, got {key}={value!r}")
        out.setdefault(name, {})[field] = value
    return out


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
    scenario: Annotated[str, typer.Argument(help="Scenario preset, see `cooploc list`.")] = "",
    estimator: Annotated[list[str], typer.Option("-e", "--estimator",
                                                 help="Estimator to run (repeat).")] = [],  # noqa: B006
    runs: Annotated[int, typer.Option(help="Monte Carlo runs.")] = 10,
    seed: Annotated[int, typer.Option(help="The one seed of every number.")] = 0,
    set_: Annotated[list[str], typer.Option("--set", help="Scenario parameter key=value.")] = [],  # noqa: B006
    est_set: Annotated[list[str], typer.Option("--est-set",
                                               help="Estimator parameter EST.key=value.")] = [],  # noqa: B006
    out: Annotated[Path | None, typer.Option(help="Results folder [default: results/SCENARIO].")] = None,
    backend: Annotated[str, typer.Option(help="serial, processes or dask.")] = "processes",
    workers: Annotated[int | None, typer.Option(help="Worker processes [default: all cores].")] = None,
    config: Annotated[Path | None, typer.Option(help="Rerun a config.toml of a results folder.")] = None,
    progress: Annotated[bool, typer.Option(help="Show a progress bar.")] = True,
    view: Annotated[bool, typer.Option("--view", help="Also write view.html (see `cooploc view`).")] = False,
) -> None:
    """Run estimators on a scenario for N Monte Carlo runs and write a results folder."""
    from cooploc.experiment import ExperimentConfig
    from cooploc.results import run_to_folder

    if config is not None:
        if not config.is_file():
            raise ConfigError(f"--config: no such file {str(config)!r}")
        if sys.version_info >= (3, 11):
            import tomllib
        else:  # pragma: no cover - Python 3.10
            import tomli as tomllib
        try:
            data = tomllib.loads(config.read_text())
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"--config: {config} is not valid TOML: {exc}") from None
        cfg = ExperimentConfig.from_dict(data)
    else:
        if not scenario:
            raise ConfigError("name a scenario (see `cooploc list`) or give --config")
        cfg = ExperimentConfig.build(
            scenario, estimator, scenario_overrides=_pairs(set_, "--set"),
            estimator_overrides=_estimator_pairs(est_set), runs=runs, seed=seed,
            backend=backend, workers=workers,
        )
    folder = out or Path("results") / cfg.scenario
    try:
        run_to_folder(cfg, folder, progress=progress)  # run by run: Ctrl-C keeps the finished runs
    except KeyboardInterrupt:
        _print_summary(folder)
        raise typer.Exit(130) from None
    if view:
        from cooploc.view import link_in_report, write_view

        link_in_report(folder, write_view(folder).name)
    _print_summary(folder)


def _print_summary(folder: Path) -> None:
    import json

    summary = json.loads((folder / "summary.json").read_text())
    table = Table(title=f"{summary['scenario']}: {summary['runs']} runs, seed {summary['seed']}")
    table.add_column("estimator")
    from cooploc.plots import shown_ids

    ids = shown_ids(sorted({v for e in summary["estimators"].values() for v in e["vehicle_rmse"]}, key=int))
    for vid in ids:
        table.add_column(f"vehicle {vid} RMSE \\[m]", justify="right")
    table.add_column("all vehicles \\[m]", justify="right")
    table.add_column("steps/s", justify="right")
    for name, est in summary["estimators"].items():
        cells = [f"{est['vehicle_rmse'][v]:.3f}" if v in est["vehicle_rmse"] else "–"
                 for v in ids]
        all_v = est["vehicle_rmse_all"]
        sps = est["steps_per_second"]
        table.add_row(name, *cells, "–" if all_v is None else f"{all_v:.3f}",
                      "–" if sps is None else f"{sps:.0f}")
    console = Console()
    console.print(table)
    from rich.markup import escape

    from cooploc.plots import run_notes

    for note in run_notes(summary):  # failed / diverged estimator-runs, an unfinished experiment
        console.print(f"[bold red]![/] {escape(note)}", highlight=False)
    console.print(f"results: {folder}/ (summary.json, errors.parquet, config.toml, report.md, figures)")


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
    paper: Annotated[str, typer.Argument(help="Paper experiment, see `cooploc list`.")],
    runs: Annotated[int | None, typer.Option(help="Runs per point [default: the paper's].")] = None,
    seed: Annotated[int, typer.Option(help="The one seed of every number.")] = 0,
    out: Annotated[Path | None,
                   typer.Option(help="Output folder [default: results/reproduce-PAPER].")] = None,
    backend: Annotated[str, typer.Option(help="serial, processes or dask.")] = "processes",
    workers: Annotated[int | None, typer.Option(help="Worker processes.")] = None,
    quick: Annotated[bool, typer.Option(help="Small version to check the pipeline.")] = False,
    progress: Annotated[bool, typer.Option(help="Show progress bars.")] = True,
) -> None:
    """Reproduce a paper's figures: PNG files and a Markdown report beside the paper's numbers."""
    from cooploc.experiment import BACKENDS
    from cooploc.reproduce import ReproduceOptions, get_experiment

    experiment = get_experiment(paper)
    if runs is not None and runs < 1:
        raise ConfigError(f"runs must be a positive integer, got {runs}")
    if backend not in BACKENDS:
        raise ConfigError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    folder = out or Path("results") / f"reproduce-{paper}"
    experiment.run(ReproduceOptions(folder, runs, seed, backend, workers, quick, progress))
    Console().print(f"{experiment.title}: report at {folder / 'report.md'}")


def main() -> None:
    """Entry point of the `cooploc` console script."""
    app()


if __name__ == "__main__":
    main()
