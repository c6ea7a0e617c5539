"""Shared test setup: import gma_ffc first so its single-threaded BLAS default applies, and give
the real-time tests their retries."""

import pytest
from hypothesis import settings

import gma_ffc  # noqa: F401  (sets OPENBLAS_NUM_THREADS before numpy loads)

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
        if item.get_closest_marker("realtime") is not None and item.get_closest_marker("flaky") is None:
            item.add_marker(pytest.mark.flaky(reruns=REALTIME_RERUNS, reruns_delay=1.0))


@pytest.fixture(scope="session")
def piezo_csv(tmp_path_factory: pytest.TempPathFactory):
    """The measured piezo recording (tests/measured.py): ../shared's, else the vendored copy; an
    error, never a skip, when neither is there."""
    from measured import piezo_csv as find

    return find(tmp_path_factory.mktemp("measured"))
