"""Memory and time of a large Monte Carlo study run with `cooploc run` (issue 17 item 3).

    python benchmarks/study_memory.py                      # 10,000 runs of gnss-kf on froehle2018
    python benchmarks/study_memory.py --runs 200 --backend dask --out-json benchmarks/results/x.json
    python benchmarks/study_memory.py --quick              # 40 runs, to check the script

Runs ``cooploc run froehle2018 -e gnss-kf --runs N --set n_steps=S`` as a child process and
samples, every `--every` seconds, the resident memory of the `cooploc` process and of its
whole process tree (workers included) and the number of runs written to the results folder
so far. Flat memory while the runs stream to disk is the claim: the JSON holds the samples,
the peaks, the memory in the first and the last tenth of the run phase, the wall time of
the study and of what follows the last run (the merge, to within one sample).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # `common` also when loaded from the file
from common import environment, write_json

MB = 1024 * 1024


def _tree_rss(process) -> tuple[int, int]:
    """(resident bytes of `process`, of it and all its descendants); 0 for what has ended."""
    import psutil

    own = total = 0
    try:
        own = total = process.memory_info().rss
        for child in process.children(recursive=True):
            try:
                total += child.memory_info().rss
            except psutil.Error:
                pass
    except psutil.Error:
        pass
    return own, total


def main(argv: list[str] | None = None) -> int:
    import psutil

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10_000)
    parser.add_argument("--steps", type=int, default=20, help="n_steps of the froehle2018 preset")
    parser.add_argument("--estimator", default="gnss-kf")
    parser.add_argument("--backend", default="processes")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--every", type=float, default=1.0, help="seconds between samples")
    parser.add_argument("--quick", action="store_true", help="40 runs, to check the script")
    parser.add_argument("--out-json", type=Path,
                        default=Path(__file__).parent / "results" / "study_memory.json")
    args = parser.parse_args(argv)
    runs = 40 if args.quick else args.runs
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "study"
        command = [sys.executable, "-m", "cooploc", "run", "froehle2018", "-e", args.estimator,
                   "--runs", str(runs), "--set", f"n_steps={args.steps}", "--seed", "1",
                   "--backend", args.backend, "--no-progress", "--out", str(folder)]
        if args.backend != "serial":
            command += ["--workers", str(args.workers)]
        start = time.perf_counter()
        child = subprocess.Popen(command, stdout=subprocess.DEVNULL)
        process = psutil.Process(child.pid)
        samples, last_part = [], None
        written = 0
        while child.poll() is None:
            own, total = _tree_rss(process)
            parts = folder / "runs"
            now = len(list(parts.glob("run-*.json"))) if parts.is_dir() else written
            if now >= runs and last_part is None:  # every run written: the merge starts
                last_part = time.perf_counter() - start
            written = max(written, now)
            samples.append({"t": round(time.perf_counter() - start, 2), "runs_written": written,
                            "rss_mb": round(own / MB, 1), "tree_rss_mb": round(total / MB, 1)})
            time.sleep(args.every)
        seconds = time.perf_counter() - start
        if child.returncode != 0:
            print(f"cooploc run failed with exit code {child.returncode}", file=sys.stderr)
            return 1
    running = [s for s in samples if 0 < s["runs_written"] < runs]
    tenth = max(len(running) // 10, 1)
    results = {
        **environment(), "command": " ".join(command[1:]), "runs": runs, "steps": args.steps,
        "seconds": seconds, "seconds_after_last_run": None if last_part is None else seconds - last_part,
        "peak_rss_mb": max(s["rss_mb"] for s in samples),
        "peak_tree_rss_mb": max(s["tree_rss_mb"] for s in samples),
        "rss_mb_first_tenth_of_runs": max((s["rss_mb"] for s in running[:tenth]), default=None),
        "rss_mb_last_tenth_of_runs": max((s["rss_mb"] for s in running[-tenth:]), default=None),
        "samples": samples,
    }
    print(f"{runs} runs in {seconds:.1f} s; peak RSS {results['peak_rss_mb']} MB (process), "
          f"{results['peak_tree_rss_mb']} MB (with workers); while running: "
          f"{results['rss_mb_first_tenth_of_runs']} MB in the first tenth, "
          f"{results['rss_mb_last_tenth_of_runs']} MB in the last")
    write_json(results, args.out_json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
