"""Judge `gma-ffc diagnose` on cases it has never seen: the alternative rig of scripts/unseen.

For every concealed case (scripts/unseen/cases.py) this runs the real command line, exactly as a
user would: `gma-ffc identify ident/*.csv -o model.yaml`, then
`gma-ffc diagnose --model model.yaml tests/*.csv --out diag/`, reads `diag/diagnosis.json`, and
only then opens the truth (manifest.yaml). It prints a per-case table, a confusion matrix (true
effect vs verdict), the detection rate, the false-alarm rate on null cases, held-out RMS before
and after (the json's rms_before_um / rms_after_um), run times, and the explanation of every
miss. Exit 0 when every case ran, 1 when a command failed or diagnose is not available, 2 on bad
options.

    .venv/bin/python scripts/unseen/bench_diagnose_unseen.py [--quick] [--cases KEY,...] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import cases as case_gen  # noqa: E402
from alt_plant import EFFECT_SETTINGS, EFFECTS, AltPlantConfig  # noqa: E402

NONE = "none"
SHORT = {"rate_dependence": "rate", "mechanical_dynamics": "mech", "thermal_drift": "therm", "creep": "creep",
         "time_delay": "delay", "stress_dependent_play": "sdplay", "saturation": "sat", NONE: "[]",
         "other": "other", "failed": "FAILED"}


@dataclass
class Outcome:
    case_id: str
    key: str = ""
    truth: list[str] = field(default_factory=list)
    levels: dict[str, str] = field(default_factory=dict)
    verdict: list[str] | None = None       # None: no usable diagnosis
    error: str = ""
    rms_before: float = math.nan
    rms_after: float = math.nan
    explanation: str = ""
    conclusive: bool | None = None          # the json's optional 'conclusive' flag
    candidates: list = field(default_factory=list)
    plant: dict = field(default_factory=dict)  # the truth's plant settings (from the manifest)
    loads_kg: list[float] = field(default_factory=list)
    identify_s: float = 0.0
    diagnose_s: float = 0.0

    @property
    def failed(self) -> bool:
        return self.verdict is None

    @property
    def exact(self) -> bool:
        return self.verdict is not None and set(self.verdict) == set(self.truth)

    @property
    def detected(self) -> bool:
        return self.verdict is not None and set(self.truth) <= set(self.verdict)


def cli_command() -> list[str]:
    """The installed console script next to this interpreter, else the package's module entry."""
    script = Path(sys.executable).with_name("gma-ffc")
    return [str(script)] if script.exists() else [sys.executable, "-m", "gma_ffc.cli"]


def diagnose_available(cli: list[str]) -> str:
    """'' when `gma-ffc diagnose` takes --model and --out, else why not."""
    try:
        r = subprocess.run(cli + ["diagnose", "--help"], capture_output=True, text=True, timeout=120)
    except (OSError, subprocess.TimeoutExpired) as e:
        return f"could not run {' '.join(cli)} diagnose --help: {e}"
    text = r.stdout + r.stderr
    if r.returncode != 0 or "--model" not in text or "--out" not in text:
        first = next((ln for ln in text.splitlines() if ln.strip()), "(no output)")
        return f"'gma-ffc diagnose --help' does not offer --model/--out (exit {r.returncode}): {first}"
    return ""


def _last_line(text: str) -> str:
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    return lines[-1] if lines else "(no output)"


def run_case(cli: list[str], case_dir: Path, timeout_s: float) -> Outcome:
    """identify + diagnose on one case folder; reads nothing but the case's own files."""
    out = Outcome(case_dir.name)
    model = case_dir / "model.yaml"
    diag = case_dir / "diag"
    ident = sorted(str(p) for p in (case_dir / "ident").glob("*.csv"))
    tests = sorted(str(p) for p in (case_dir / "tests").glob("*.csv"))
    t0 = time.perf_counter()
    try:
        r = subprocess.run(cli + ["identify", *ident, "-o", str(model)], capture_output=True, text=True,
                           timeout=timeout_s)
    except subprocess.TimeoutExpired:
        out.error = f"identify timed out after {timeout_s:.0f} s"
        return out
    out.identify_s = time.perf_counter() - t0
    if r.returncode != 0:
        out.error = f"identify exit {r.returncode}: {_last_line(r.stderr)}"
        return out
    t0 = time.perf_counter()
    try:
        r = subprocess.run(cli + ["diagnose", "--model", str(model), *tests, "--out", str(diag)],
                           capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        out.diagnose_s = time.perf_counter() - t0
        out.error = f"diagnose timed out after {timeout_s:.0f} s"
        return out
    out.diagnose_s = time.perf_counter() - t0
    if r.returncode != 0:
        out.error = f"diagnose exit {r.returncode}: {_last_line(r.stderr)}"
        return out
    try:
        d = json.loads((diag / "diagnosis.json").read_text())
    except (OSError, ValueError) as e:
        out.error = f"diagnose exited 0 but diagnosis.json is unusable: {e}"
        return out
    verdict = d.get("verdict")
    if not isinstance(verdict, list) or not all(isinstance(v, str) for v in verdict):
        out.error = f"diagnosis.json 'verdict' is not a list of effect names: {verdict!r}"
        return out
    out.verdict = verdict
    out.rms_before = _num(d.get("rms_before_um"))
    out.rms_after = _num(d.get("rms_after_um"))
    out.explanation = str(d.get("explanation", ""))
    if isinstance(d.get("candidates"), list):
        out.candidates = [c for c in d["candidates"] if isinstance(c, dict)]
    if isinstance(d.get("conclusive"), bool):
        out.conclusive = d["conclusive"]
    return out


def _num(v: object) -> float:
    try:
        return float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return math.nan


def confusion(outcomes: list[Outcome]) -> tuple[list[str], list[str], dict[tuple[str, str], int]]:
    """Rows: true effects (and 'none'); columns: verdict effects, '[]', 'other', 'failed'.

    A case counts once in the row of each of its true effects, in the column of each verdict
    effect (so two-effect cases and two-effect verdicts are visible as such).
    """
    rows = list(EFFECTS) + [NONE]
    cols = list(EFFECTS) + [NONE, "other", "failed"]
    m: dict[tuple[str, str], int] = {}
    for o in outcomes:
        for tr in (o.truth or [NONE]):
            if o.failed:
                targets = ["failed"]
            elif not o.verdict:
                targets = [NONE]
            else:
                targets = [v if v in EFFECTS else "other" for v in o.verdict]
            for c in targets:
                m[(tr, c)] = m.get((tr, c), 0) + 1
    return rows, cols, m


def _fmt(x: float) -> str:
    return "  n/a" if not math.isfinite(x) else f"{x:5.2f}"


def report(outcomes: list[Outcome], total_s: float) -> None:
    print("\nper case (truth opened only after every diagnosis was read)")
    print(f"{'case':10s} {'truth':40s} {'verdict':34s} {'ok':3s} {'before':>6s} {'after':>6s} "
          f"{'ratio':>5s} {'ident':>6s} {'diag':>6s}")
    for o in sorted(outcomes, key=lambda o: o.key):
        truth = "+".join(f"{e}:{o.levels.get(e, '')}" for e in o.truth) or "(none)"
        verdict = "FAILED" if o.failed else ("[]" if not o.verdict else ",".join(o.verdict))
        if o.conclusive is False:
            verdict += " (inconclusive)"
        ok = "yes" if o.exact else ("(+)" if o.detected and o.truth else "no")
        ratio = o.rms_after / o.rms_before if o.rms_before > 0 else math.nan
        print(f"{o.case_id:10s} {truth:40.40s} {verdict:34.34s} {ok:3s} {_fmt(o.rms_before):>6s} {_fmt(o.rms_after):>6s} "
              f"{_fmt(ratio):>5s} {o.identify_s:5.1f}s {o.diagnose_s:5.1f}s")

    rows, cols, m = confusion(outcomes)
    print("\nconfusion matrix (rows: true effect, columns: verdict)")
    print(f"{'':8s}" + "".join(f"{SHORT[c]:>7s}" for c in cols))
    for r in rows:
        if not any(m.get((r, c), 0) for c in cols):
            continue
        print(f"{SHORT[r]:8s}" + "".join(f"{(m.get((r, c), 0) or '.'):>7}" for c in cols))

    ran = [o for o in outcomes if not o.failed]
    eff = [o for o in outcomes if o.truth]
    null = [o for o in outcomes if not o.truth]
    eff_ran = [o for o in eff if not o.failed]
    null_ran = [o for o in null if not o.failed]
    print("\nsummary")
    print(f"  cases run: {len(ran)}/{len(outcomes)} (failed: {len(outcomes) - len(ran)})")
    if ran:
        print(f"  named exactly (verdict == truth): {sum(o.exact for o in ran)}/{len(ran)} = "
              f"{100 * sum(o.exact for o in ran) / len(ran):.0f} %   (target >= 90 %)")
    if eff_ran:
        det = sum(o.detected for o in eff_ran)
        print(f"  detection rate (every true effect in the verdict): {det}/{len(eff_ran)} = {100 * det / len(eff_ran):.0f} %")
        for lvl in ("clear", "subtle"):
            sub = [o for o in eff_ran if len(o.truth) == 1 and o.levels.get(o.truth[0]) == lvl]
            if sub:
                print(f"    single-effect {lvl:6s}: detected {sum(o.detected for o in sub)}/{len(sub)}, "
                      f"exact {sum(o.exact for o in sub)}/{len(sub)}")
        extra = sum(bool(set(o.verdict or []) - set(o.truth)) for o in eff_ran)
        print(f"  effect cases with an extra (wrong) effect in the verdict: {extra}/{len(eff_ran)}")
        halved = [o for o in eff_ran if o.rms_before > 0 and o.rms_after <= 0.5 * o.rms_before]
        print(f"  held-out RMS at least halved where an effect is present: {len(halved)}/{len(eff_ran)}   (target: all)")
        ratios = sorted(o.rms_after / o.rms_before for o in eff_ran if o.rms_before > 0 and math.isfinite(o.rms_after))
        if ratios:
            print(f"  after/before RMS on effect cases: median {ratios[len(ratios) // 2]:.2f}, worst {ratios[-1]:.2f}")
    if null_ran:
        fa = sum(bool(o.verdict) for o in null_ran)
        print(f"  false-alarm rate on null cases: {fa}/{len(null_ran)} = {100 * fa / len(null_ran):.0f} %   (target 0 %)")
    inconclusive = [o for o in ran if o.conclusive is False]
    if inconclusive:
        print(f"  cases the tool called inconclusive (too little data etc.): {len(inconclusive)} "
              f"({sum(not o.truth for o in inconclusive)} of them null cases, so their [] is not a confident 'no effect')")
    if ran:
        dts = [o.identify_s + o.diagnose_s for o in ran]
        print(f"  time per case (identify + diagnose): mean {sum(dts) / len(dts):.1f} s, max {max(dts):.1f} s; "
              f"whole benchmark {total_s:.0f} s")

    fitted_vs_true(outcomes)

    misses = [o for o in outcomes if not o.exact]
    if misses:
        print("\nmisses and failures (the tool's own explanation)")
        for o in sorted(misses, key=lambda o: o.key):
            truth = "+".join(o.truth) or "none"
            if o.failed:
                print(f"- {o.case_id} [{o.key}] truth {truth}: {o.error}")
            else:
                expl = " ".join(o.explanation.split())
                print(f"- {o.case_id} [{o.key}] truth {truth}, verdict {o.verdict or '[]'}: "
                      f"{expl[:600]}{'...' if len(expl) > 600 else ''}")


def _derived(effect: str, cfg: AltPlantConfig, loads_kg: list[float]) -> str:
    """The rig's setting in the terms a lumped model would fit."""
    if effect == "rate_dependence":
        return f" (slowest diffusion mode {cfg.diffusion_time_ms / 2.4048 ** 2:.3g} ms)"
    if effect == "mechanical_dynamics":
        return " (" + ", ".join(f"{cfg.resonance_hz(m):.0f} Hz at {m:g} kg" for m in loads_kg) + ")"
    if effect == "thermal_drift":
        fast, slow = cfg.thermal_time_constants_s()
        return f" (time constants {fast:.0f} s and {slow:.0f} s)"
    return ""


def fitted_vs_true(outcomes: list[Outcome]) -> None:
    """What the tool fitted for each true effect it named, beside the rig's setting."""
    lines = []
    for o in sorted(outcomes, key=lambda o: o.key):
        for effect in o.truth:
            if effect not in (o.verdict or []):
                continue
            cand = next((c for c in o.candidates if c.get("effect") == effect and c.get("accepted", True)), None)
            keys = sorted({k for lvl in EFFECT_SETTINGS[effect].values() for k in lvl})
            true = ", ".join(f"{k}={o.plant.get(k, getattr(AltPlantConfig(), k))}" for k in keys)
            true += _derived(effect, AltPlantConfig(**o.plant), o.loads_kg)
            fitted = ", ".join(f"{k}={v}" for k, v in (cand or {}).get("params", {}).items()) or "(no params in json)"
            lines.append(f"  {o.case_id} {effect}: fitted {fitted}  |  rig {true}")
    if lines:
        print("\nfitted parameters of named true effects vs the rig's settings")
        print("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help=f"a subset: {', '.join(case_gen.QUICK_KEYS)}")
    ap.add_argument("--cases", help="comma-separated case keys, e.g. creep-clear,null-0 (see cases.py)")
    ap.add_argument("--keep", metavar="DIR", help="generate into DIR and keep it (default: a temp folder, removed)")
    ap.add_argument("--seed", type=int, default=0, help="case generation seed (default 0)")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per command (default 900)")
    ap.add_argument("--cli", help="the gma-ffc command to judge, e.g. '/other/venv/bin/gma-ffc' "
                                  "(default: the one installed next to this interpreter)")
    a = ap.parse_args(argv)

    keys = list(case_gen.QUICK_KEYS) if a.quick else ([k.strip() for k in a.cases.split(",") if k.strip()] if a.cases else None)
    known = {c.key for c in case_gen.all_cases()}
    if keys and set(keys) - known:
        print(f"bench: unknown case key(s) {sorted(set(keys) - known)}; known: {', '.join(sorted(known))}",
              file=sys.stderr)
        return 2
    cli = a.cli.split() if a.cli else cli_command()
    why = diagnose_available(cli)
    if why:
        print(f"diagnose is not usable yet, nothing to judge: {why}")
        return 1

    root = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="unseen_"))
    if a.keep and root.exists() and any(root.iterdir()):
        print(f"--keep {root}: the folder exists and is not empty; give a new or empty folder", file=sys.stderr)
        return 2
    try:
        t_all = time.perf_counter()
        try:
            manifest = case_gen.generate(root, a.seed, keys)
        except ValueError as e:
            print(f"bench: {e}", file=sys.stderr)
            return 2
        print(f"generated {len(manifest['cases'])} concealed cases in {root} "
              f"({time.perf_counter() - t_all:.1f} s); running {' '.join(cli)} identify + diagnose on each")
        outcomes: list[Outcome] = []
        for k, case in enumerate(sorted(manifest["cases"], key=lambda c: c["id"]), 1):
            o = run_case(cli, root / case["id"], a.timeout)
            outcomes.append(o)
            status = o.error or ("[]" if not o.verdict else ",".join(o.verdict))
            print(f"  [{k}/{len(manifest['cases'])}] {o.case_id}: {status} "
                  f"({o.identify_s:.1f} s + {o.diagnose_s:.1f} s)", flush=True)
        # only now: the truth
        truth = {c["id"]: c for c in yaml.safe_load((root / "manifest.yaml").read_text())["cases"]}
        for o in outcomes:
            c = truth[o.case_id]
            o.key, o.truth, o.levels = c["key"], list(c["effects"]), dict(c["levels"])
            o.plant = dict(c.get("plant", {}))
            o.loads_kg = sorted({float(f["load_kg"]) for f in c["test_files"]}
                                | {float(m) for f in c["test_files"] for _, m in f["load_changes"]})
        report(outcomes, time.perf_counter() - t_all)
        results = [{"id": o.case_id, "key": o.key, "truth": o.truth, "levels": o.levels, "verdict": o.verdict,
                    "error": o.error, "rms_before_um": o.rms_before, "rms_after_um": o.rms_after,
                    "identify_s": round(o.identify_s, 2), "diagnose_s": round(o.diagnose_s, 2),
                    "conclusive": o.conclusive, "explanation": o.explanation} for o in outcomes]
        (root / "results.json").write_text(json.dumps(results, indent=1, default=str))
        if a.keep:
            print(f"\nkept: {root} (cases, manifest.yaml with the truth, results.json)")
        failed = [o for o in outcomes if o.failed]
        if failed:
            print(f"\n{len(failed)} case(s) could not be diagnosed (see above); exit 1")
            return 1
        return 0
    finally:
        if not a.keep:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
