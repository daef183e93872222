"""Issue #13 "Safe on anyone's files": a fixed-seed sample of the robustness corpus through the CLI.

Two cases of every category of `tests/robustness_corpus.py` (mutated meshes and recipes, odd
encodings, path tricks, `-o` mistypes), each run as `meshdeform ...` in its own process and folder
with a 10 s time limit and a 6 GB address-space limit. Each must exit 0 or 2 with at most one
line on stderr and no traceback, change nothing outside its output folder and leave no output
when it fails. The full run of several hundred cases is `benchmarks/robustness.py`.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import robustness_corpus as corpus

#: the sample: two cases per category, the same ones on every run
SEED = 13
CASES = corpus.generate(2 * len(corpus.CATEGORIES), SEED, weighted=False)


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory: pytest.TempPathFactory) -> dict[str, corpus.Outcome]:
    """Every sample case run once, two at a time, after compiling the Numba kernels (untimed)."""
    workdir = tmp_path_factory.mktemp("robustness")
    corpus.warm_up(workdir)
    return {o.case.name: o for o in corpus.run_cases(CASES, workdir, jobs=2)}


def test_sample_spans_every_category() -> None:
    assert {case.category for case in CASES} == set(corpus.CATEGORIES)


def test_corpus_draws_every_registered_solver_and_only_registered_formats() -> None:
    from meshdeform.export import EXPORTERS
    from meshdeform.solvers import SOLVERS

    assert set(corpus.SOLVERS) == set(SOLVERS)
    assert set(corpus.RECIPE_FORMATS) <= set(EXPORTERS)


def test_corpus_is_deterministic() -> None:
    again = corpus.generate(len(CASES), SEED, weighted=False)
    assert [(c.argv, c.files, c.links) for c in again] == [(c.argv, c.files, c.links) for c in CASES]


def test_judge_catches_a_user_file_lost_and_output_left_after_failure(tmp_path: Path) -> None:
    """The checks themselves: a run that deleted a user file and failed leaving its folder is caught."""
    case = corpus.Case(name="x", category="output-folder", description="", argv=["simulate"], out="out")
    before = {"work": "dir", "work/notes.txt": "abc"}
    after = {"work": "dir", "work/out": "dir", "work/.out.partial-1": "dir"}
    reasons = corpus.judge(case, tmp_path, before, after, "work/out", False, 1, 0.5, "", "error: a\nTraceback\n")
    assert "removed: work/notes.txt" in reasons
    assert "exit code 1" in reasons
    assert "2 lines on stderr" in reasons
    assert "traceback" in reasons
    assert any(r.startswith("staging folder left") for r in reasons)
    assert any(r.startswith("output left after failure: work/out") for r in reasons)


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_case_is_handled_safely(case: corpus.Case, outcomes: dict[str, corpus.Outcome]) -> None:
    outcome = outcomes[case.name]
    if not outcome.passed:
        pytest.fail(
            f"{case.description}\n  {case.shown_argv()}\n  exit {outcome.exit_code} in {outcome.seconds:.1f} s: "
            f"{'; '.join(outcome.reasons)}\n  stderr: {outcome.stderr[-2000:]}",
            pytrace=False,
        )
