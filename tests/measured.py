"""The measured piezo recording for the tests: `../shared`'s copy when the checkout sits beside
it, else the copy vendored in tests/fixtures (xz, with its licence and origin beside it). Neither
is an error, not a skip: a clean clone must run the measured-data tests too."""

from __future__ import annotations

import lzma
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED_PIEZO = ROOT.parent / "shared" / "data" / "real" / "piezo_150V_1Hz" / "piezo_150V_1Hz.csv"
VENDORED_PIEZO = ROOT / "tests" / "fixtures" / "piezo_150V_1Hz.csv.xz"


def vendored_piezo_bytes() -> bytes:
    return lzma.decompress(VENDORED_PIEZO.read_bytes())


def piezo_csv(folder: Path) -> Path:
    """The recording's path: `../shared`'s, else the vendored copy unpacked into `folder`."""
    if SHARED_PIEZO.exists():
        return SHARED_PIEZO
    if not VENDORED_PIEZO.exists():
        raise FileNotFoundError(f"the measured piezo recording is in neither {SHARED_PIEZO} nor {VENDORED_PIEZO}")
    path = folder / SHARED_PIEZO.name
    path.write_bytes(vendored_piezo_bytes())
    return path


YAN9A = {run: ROOT / "tests" / "fixtures" / f"piezo_yan9a_{run}.csv.xz" for run in ("model", "later")}


def yan9a_csv(run: str, folder: Path) -> Path:
    """A second measured piezo's run ("model" or "later", tests/fixtures/piezo_yan9a.README.md)
    unpacked into `folder`: vendored only, it has no copy in ../shared."""
    path = folder / f"piezo_yan9a_{run}.csv"
    path.write_bytes(lzma.decompress(YAN9A[run].read_bytes()))
    return path
