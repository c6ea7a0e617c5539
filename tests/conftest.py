"""Shared test setup: import gma_ffc first so its single-threaded BLAS default applies, share the
CPUs among the xdist workers, and give the real-time tests their retries."""

import os

import pytest
from hypothesis import settings

import gma_ffc  # noqa: F401  (sets OPENBLAS_NUM_THREADS before numpy loads)


def _share_the_cpus() -> None:
    """Each xdist worker gets its share of the CPUs for a diagnosis' threads (`GMA_FFC_CPUS`, also in
    the CLI runs a test starts), unless the caller set it. Three workers on two cores already keep
    both busy; two search threads inside each only contend (a resonance diagnosis: 190 s of CPU with
    two threads, 113 s with one, the same result to the last digit)."""
    from gma_ffc.diagnose.selection import CPUS_ENV, usable_cpus

    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if workers > 1 and not os.environ.get(CPUS_ENV):
        os.environ[CPUS_ENV] = str(max(1, usable_cpus() // workers))


_share_the_cpus()

# `pytest --hypothesis-profile=slow`: a deeper run of the property tests that read it (the fuzz
# test through the CLI draws 300 recordings instead of CI's few)
settings.register_profile("slow", deadline=None)

# A real-time test runs a controller, an emulated device and its physics against the wall clock.
# A busy machine (the other xdist worker, another job on the CI host) can make one run late; a
# defect fails every run. So a failed real-time test runs again, up to twice, and only three
# failures in a row fail the suite; pytest's summary lists every rerun ("R").
REALTIME_RERUNS = 2


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if item.get_closest_marker("realtime") is not None:
            # one worker runs them all, one after another (`--dist loadgroup`, scripts/test.sh): they
            # mostly wait on the wall clock (about 270 s of wall for 90 s of CPU), and a third
            # worker on two cores keeps both cores busy meanwhile
            item.add_marker(pytest.mark.xdist_group("realtime"))
            if item.get_closest_marker("flaky") is None:
                item.add_marker(pytest.mark.flaky(reruns=REALTIME_RERUNS, reruns_delay=1.0))
    # the real-time group first, then the long tests, in their files' order: xdist hands tests out in
    # this order, and the five resonance diagnoses (45-110 s each, in a file late in the alphabet)
    # otherwise ran last, one worker finishing them while the other waited; the short tests now fill
    # in at the end
    items.sort(key=lambda item: (item.get_closest_marker("realtime") is None,
                                 item.get_closest_marker("slow") is None and item.get_closest_marker("nightly") is None))


@pytest.fixture(scope="session")
def session_folder(tmp_path_factory: pytest.TempPathFactory, worker_id: str):
    """A folder every xdist worker of this session shares (`session_cache`); a run without
    xdist has its own."""
    base = tmp_path_factory.getbasetemp()
    return (base if worker_id == "master" else base.parent) / "shared"


@pytest.fixture
def memoised_rounds(monkeypatch, session_folder):
    """diagnose's round searches and the cores it identifies again through a named delay, shared by
    every test that asks for them, on every xdist worker (`session_cache.memoised_score_round`,
    `memoised_reidentify`): test_diagnose_thresholds' moves that take the default path, and two
    diagnoses of the same recording and model through different doors (test_diagnose_cli)."""
    from session_cache import memoised_reidentify, memoised_score_round

    from gma_ffc.diagnose import selection

    monkeypatch.setattr(selection, "score_round", memoised_score_round(session_folder))
    monkeypatch.setattr(selection, "reidentify_through", memoised_reidentify(session_folder))


@pytest.fixture(scope="session")
def diagnosed(session_folder):
    """diagnosed(case name, scale) -> (model, recording, diagnosis) of a benchmark case, with
    `diagnose`'s defaults: computed once per session (`session_cache`), a fresh copy for each test.
    Its rounds' searches, and the core identified again through a named delay, are the ones
    test_diagnose_thresholds' moves on the default path make (`session_cache.memoised_score_round`,
    `memoised_reidentify`): each is computed once for both."""
    from session_cache import memoised_reidentify, memoised_score_round, once_per_session

    def run(name: str, scale: float = 0.5):
        def compute():
            from benchmarks import cases as bench
            from gma_ffc.diagnose import selection
            from gma_ffc.diagnose.engine import diagnose

            case = {c.name: c for c in bench.cases()}[name]
            model, rec = bench.make_case(case, scale=scale)
            search, reidentify = selection.score_round, selection.reidentify_through
            selection.score_round = memoised_score_round(session_folder)
            selection.reidentify_through = memoised_reidentify(session_folder)
            try:
                return model, rec, diagnose(model, [rec])
            finally:
                selection.score_round, selection.reidentify_through = search, reidentify
        return once_per_session(session_folder, f"diagnosed {name} at {scale!r}", compute)
    return run


@pytest.fixture(scope="session")
def piezo_csv(tmp_path_factory: pytest.TempPathFactory):
    """The measured piezo recording (tests/measured.py): ../shared's, else the vendored copy; an
    error, never a skip, when neither is there."""
    from measured import piezo_csv as find

    return find(tmp_path_factory.mktemp("measured"))


def pytest_terminal_summary(terminalreporter, exitstatus: int, config: pytest.Config) -> None:
    """Say so when the nightly tier was left out (xdist's summary does not count deselected tests)."""
    if "not nightly" in (config.getoption("markexpr", "") or ""):
        terminalreporter.write_line("the nightly tier (past never-tuned draws' cases, pyproject.toml's `nightly`) "
                                    "was left out: `scripts/test.sh --nightly` runs it too")
