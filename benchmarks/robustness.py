"""Robustness run for issue #13: hundreds of hostile cases through the real `meshdeform` CLI.

    PYTHONPATH=$PWD /work/main/.venv/bin/python benchmarks/robustness.py --cases 300 --seed 13 --jobs 2
    PYTHONPATH=/other/checkout /work/main/.venv/bin/python benchmarks/robustness.py --checkout /other/checkout

The cases (mutated meshes and recipes, odd encodings, path tricks, `-o` mistypes; see
tests/robustness_corpus.py) are made at run time and never stored. Each runs in a fresh folder
in its own process, with a 10 s time limit and a 6 GB address-space limit, and passes when it
exits 0 or 2, prints at most one line on stderr and no traceback, changes nothing outside its
output folder and leaves no output when it fails. Prints a table per category, the slowest case
and every failure with its reason and a reproducer (the command line and a kept copy of the case
folder under --keep). Exit status 1 when any case fails. Numba kernels are compiled first
(untimed) into the shared cache, as a user's second run finds them.
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import robustness_corpus as corpus


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", type=int, default=300, help="number of cases (default 300)")
    parser.add_argument("--seed", type=int, default=13, help="corpus seed (default 13)")
    parser.add_argument("--jobs", type=int, default=2, help="cases run at a time (default 2)")
    parser.add_argument("--checkout", type=Path, default=corpus.REPO, help="the meshdeform checkout to run")
    parser.add_argument("--python", default=sys.executable, help="the Python that runs the CLI")
    parser.add_argument("--keep", type=Path, default=Path("robustness-failures"), help="copies of failing cases")
    parser.add_argument("--category", action="append", help="only these categories (repeatable)")
    parser.add_argument("--quiet", action="store_true", help="no line per case")
    parser.add_argument("--report", type=Path, help="write every outcome (argv, exit, stderr, reasons) as JSON here")
    args = parser.parse_args()

    cases = corpus.generate(args.cases, args.seed, categories=args.category)
    with tempfile.TemporaryDirectory(prefix="meshdeform-robustness-") as tmp:
        warm = corpus.warm_up(Path(tmp), checkout=args.checkout, python=args.python)
        print(f"warm-up (Numba kernels into {corpus.default_cache_dir()}): {warm:.1f} s")
        done = [0]

        def progress(outcome: corpus.Outcome) -> None:
            done[0] += 1
            if not args.quiet:
                status = "ok  " if outcome.passed else "FAIL"
                print(f"[{done[0]:4d}/{len(cases)}] {status} {outcome.seconds:5.1f} s  exit {outcome.exit_code}  "
                      f"{outcome.case.name}: {outcome.case.description[:70]}"
                      + ("" if outcome.passed else f"  <- {'; '.join(outcome.reasons)[:120]}"), flush=True)  # fmt: skip

        started = time.perf_counter()
        outcomes = corpus.run_cases(
            cases, Path(tmp), jobs=args.jobs, checkout=args.checkout, python=args.python,
            keep=args.keep.resolve(), on_done=progress,
        )  # fmt: skip
        elapsed = time.perf_counter() - started

    if args.report:
        records = [
            {"name": o.case.name, "category": o.case.category, "description": o.case.description,
             "argv": o.case.shown_argv(o.root), "exit": o.exit_code, "seconds": round(o.seconds, 2),
             "stderr": o.stderr, "reasons": o.reasons, "kept": str(o.root) if o.root else None}
            for o in outcomes
        ]  # fmt: skip
        args.report.write_text(json.dumps(records, indent=1) + "\n")
    table: dict[str, list[int]] = collections.defaultdict(lambda: [0, 0])
    for o in outcomes:
        table[o.case.category][0 if o.passed else 1] += 1
    print(f"\n{'category':<16} {'cases':>6} {'pass':>6} {'fail':>6}")
    for category in corpus.CATEGORIES:
        if category in table:
            ok, bad = table[category]
            print(f"{category:<16} {ok + bad:>6} {ok:>6} {bad:>6}")
    failed = [o for o in outcomes if not o.passed]
    print(f"{'all':<16} {len(outcomes):>6} {len(outcomes) - len(failed):>6} {len(failed):>6}")
    slowest = max(outcomes, key=lambda o: o.seconds)
    print(f"\n{len(cases)} cases in {elapsed:.1f} s ({args.jobs} at a time); slowest {slowest.seconds:.1f} s: "
          f"{slowest.case.name} ({slowest.case.description[:80]})")  # fmt: skip
    reasons = collections.Counter(r.split(":")[0] for o in failed for r in o.reasons)
    if reasons:
        print("failed checks: " + ", ".join(f"{r} x{n}" for r, n in reasons.most_common()))
    for o in failed:
        last = [line for line in o.stderr.splitlines() if line.strip()]
        print(f"\nFAIL {o.case.name} [{o.case.category}] {o.case.description}")
        print(f"  reasons: {'; '.join(o.reasons)}")
        print(
            f"  exit {o.exit_code} in {o.seconds:.1f} s; stderr ({len(last)} lines): {last[-1][:200] if last else ''}"
        )
        print(f"  reproduce: cd {o.root / o.case.cwd if o.root else '?'} && {o.case.shown_argv(o.root)}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
