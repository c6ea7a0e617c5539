"""docs/extended-model.md cannot drift from the code that writes and reads the extended-model file.

- Every block name of every registered effect class has a section (`## \\`name\\``), in signal-path
  order, and the effects table gives each class's name, blocks, stage and position.
- Each block's table lists exactly the keys the code writes: every class's `fitted_blocks` (what
  `gma-ffc diagnose` writes), called with a stand-in fitter, `rod_load.make_block` with both ends
  held, and the identity `StaticMap().to_blocks()`. The older forms (`stress_width`, `dynamics`
  without `form`) are read only; their keys are listed here.
- The "required or optional" column agrees with the loader: a key marked required is refused when
  left out; an optional one loads without it (with its partner, for "together with `X`"); the
  static map's defaults are the code's.
- The file example loads and is what the code writes back; the refusal quoted is the loader's own.
"""

from __future__ import annotations

import copy
import re
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import yaml

from gma_ffc.effects import REGISTRY, path_order
from gma_ffc.effects import rod_load as RL
from gma_ffc.effects.dynamics import Dynamics
from gma_ffc.effects.static import STATIC_DEFAULTS, StaticMap
from gma_ffc.errors import ModelError
from gma_ffc.extended import ExtendedModel
from gma_ffc.modelio import load_model, model_from_dict

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "extended-model.md"
TEXT = DOC.read_text(encoding="utf-8")

# A stand-in for the diagnosis' fitter: the attributes `fitted_blocks` reads (a drive range of 0..3 A
# that the recordings leave on both sides, so saturation gets its wide plays).
FITTER = SimpleNamespace(drive_lo=0.0, drive_hi=3.0, drive_span=3.0, drive_margin=0.06,
                         data=[SimpleNamespace(u=np.array([-1.0, 1.5, 4.0]))],
                         play_thresholds=np.array([0.3, 0.75, 1.35]), yc_center=20.0, stress_ref=-15.0,
                         stress_top=-11.0, identification=[])

# Per effect name: the (parameter, coefficients) whose `fitted_blocks` writes every key it can.
# A new effect fails here until its blocks are documented and its entry added.
FULLEST: dict[str, tuple[Any, dict[str, float]]] = {
    "rate_dependence": (0.002, {}),
    "time_delay": (0.0005, {}),
    "static_recalibration": (None, {"offset": 0.2, "gain": 1.02, "stress_gain": 0.001, "quadratic": 2e-4,
                                    "play_0": 0.3, "play_1": -0.1, "play_2": 0.05}),
    "stress_dependent_play": (0.03, {"stress_play_0": 0.01, "stress_play_1": 0.0, "stress_play_2": -0.01}),
    "saturation": (3, {"sat_lin_lo": 0.5, "sat_quad_lo": 0.1, "sat_lin_hi": -1.0, "sat_quad_hi": -0.5,
                       "sat_play_0": 0.3, "sat_play_1": 0.2, "sat_play_2": 0.1}),
    "creep": (3.0, {"creep_gain": 0.01}),
    "mechanical_dynamics": ((150.0, 0.05, 0.3, -20.0, -12.0), {}),     # the law held at both ends
    "thermal_drift": (60.0, {"thermal_gain": 1.3, "thermal_fast_gain": 0.2}),
}

# Forms the code reads but no longer writes (files from earlier versions): (block, section's sub-heading word)
OLDER: list[tuple[str, dict[str, Any], str]] = [
    ("stress_width", {"eps": 0.3, "coef_per_MPa": -0.08}, ""),
    ("dynamics", {"f_ref_hz": 150.0, "zeta": 0.05, "beta_per_MPa": 0.3, "stress_ref_MPa": -14.0}, "Older"),
]


# ----------------------------------------------------------------------------- the doc, parsed
def _sections(text: str) -> dict[str, str]:
    """Level-2 sections by heading text (without the '## ')."""
    out: dict[str, str] = {}
    head = None
    for line in text.splitlines():
        if line.startswith("## "):
            head = line[3:].strip()
            out[head] = ""
        elif head is not None:
            out[head] += line + "\n"
    return out


SECTIONS = _sections(TEXT)
BLOCK_HEADING = re.compile(r"^`(\w+)`")


def _block_sections() -> dict[str, str]:
    return {m.group(1): body for head, body in SECTIONS.items() if (m := BLOCK_HEADING.match(head))}


def _tables(body: str) -> list[tuple[str, dict[str, list[str]]]]:
    """Each key table of a section: (the sub-heading above it, {key: its cells after the key})."""
    out: list[tuple[str, dict[str, list[str]]]] = []
    sub, rows = "", None
    for line in body.splitlines() + [""]:
        if line.startswith("### "):
            sub = line[4:]
        if line.startswith("| `"):
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if rows is None:
                rows = {}
                out.append((sub, rows))
            rows[cells[0].strip("`")] = cells[1:]
        elif not line.startswith("|"):
            rows = None
    return out


def _table(block: str, sub: str = "") -> dict[str, list[str]]:
    """The key table of a block's section (under the sub-heading containing `sub`, else its first)."""
    body = _block_sections().get(block)
    assert body is not None, f"docs/extended-model.md has no section '## `{block}`'"
    tables = [rows for head, rows in _tables(body) if sub in head]
    assert tables, f"docs/extended-model.md: section '{block}' has no key table" + (f" under '{sub}'" if sub else "")
    for rows in tables:
        assert all(len(cells) == 3 for cells in rows.values()), \
            f"section '{block}': every row must be key | unit | meaning | required or optional"
    return tables[0]


def _sub_of(block_name: str, block: dict[str, Any]) -> str:
    return "rod_load" if block_name == "dynamics" and RL.is_rod_load(block) else ""


def written_blocks(strict: bool = True) -> dict[str, dict[str, Any]]:
    """Every block as the code writes it, with every key it can write (`strict`: an effect missing
    from FULLEST fails; else it is left out, for parametrising at collection)."""
    out: dict[str, dict[str, Any]] = {}
    for cls in REGISTRY.values():
        if not strict and cls.name not in FULLEST:
            continue
        assert cls.name in FULLEST, (f"effect {cls.name!r} ({cls.keys}) is new: document its blocks in "
                                     "docs/extended-model.md and add its fullest fit to FULLEST here")
        p, coef = FULLEST[cls.name]
        blocks = cls.fitted_blocks(FITTER, p, coef)    # type: ignore[arg-type]
        assert set(blocks) <= set(cls.keys), (cls.name, sorted(blocks))
        out.update(blocks)
    return out


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def base() -> Any:
    return load_model(ROOT / "config" / "models" / "sim_sdpi.yaml")


def _file(base_dict: dict[str, Any], blocks: dict[str, Any]) -> dict[str, Any]:
    return {"format": "gma-ffc-model", "version": 1, "kind": "extended", "effects": [], "blocks": blocks,
            "base": copy.deepcopy(base_dict)}


def _loads(d: dict[str, Any]) -> bool:
    try:
        model_from_dict(d, "extended_model.yaml")
    except ModelError:
        return False
    return True


# ----------------------------------------------------------------------------- tests
def test_every_block_name_has_a_section():
    have = _block_sections()
    missing = [f"{cls.name}: {key}" for cls in REGISTRY.values() for key in cls.keys if key not in have]
    assert not missing, f"docs/extended-model.md has no '## `name`' section for {missing}"


def test_the_block_sections_follow_the_signal_path():
    order = [head for head in (BLOCK_HEADING.match(h) for h in SECTIONS) if head]
    at = {m.group(1): i for i, m in enumerate(order)}
    positions = [min(at[k] for k in cls.keys) for cls in path_order()]
    assert positions == sorted(positions), "block sections must come in signal-path order (each class's position)"


def test_the_effects_table_names_each_class_its_blocks_stage_and_position():
    rows = {cells[0].strip("`"): cells for line in SECTIONS["Effects and their blocks"].splitlines()
            if line.startswith("| `") for cells in [[c.strip() for c in line.strip().strip("|").split("|")]]}
    for cls in REGISTRY.values():
        assert cls.name in rows, f"effects table: no row for {cls.name}"
        _, blocks, stage, position = rows[cls.name]
        assert set(re.findall(r"`(\w+)`", blocks)) == set(cls.keys), (cls.name, blocks)
        assert (stage, position) == (cls.stage, str(cls.position)), (cls.name, stage, position)


def test_each_table_lists_exactly_the_keys_the_code_writes():
    written = written_blocks()
    # the same keys from the code's other writers: the identity map, the dynamics block held at both ends
    assert set(StaticMap().to_blocks()["static"]) == set(written["static"])
    held = RL.make_block(150.0, 0.05, 0.3, -11.0, held=(-20.0, -12.0))
    assert set(held) == set(written["dynamics"]) and set(RL.HELD_KEYS) <= set(held)
    for name, block in written.items():
        documented = set(_table(name, _sub_of(name, block)))
        assert documented == set(block), (f"'{name}' table: missing {sorted(set(block) - documented)}, "
                                          f"not written by the code {sorted(documented - set(block))}")
    for name, block, sub in OLDER:
        assert set(_table(name, sub)) == set(block), (name, sub)


def _required_cases() -> list[tuple[str, dict[str, Any], str]]:
    return [(name, block, _sub_of(name, block)) for name, block in written_blocks(strict=False).items()] + OLDER


@pytest.mark.parametrize("name,block,sub", _required_cases(), ids=lambda v: v if isinstance(v, str) else "")
def test_required_or_optional_agrees_with_the_loader(base, name, block, sub):
    base_dict = base.to_dict()
    assert _loads(_file(base_dict, {name: block})), f"the full '{name}' block must load"
    for key, (_unit, _meaning, need) in _table(name, sub).items():
        without = {k: v for k, v in block.items() if k != key}
        if need.startswith("required"):
            assert not _loads(_file(base_dict, {name: without})), f"{name}.{key} is documented required but loads without it"
            continue
        assert need.startswith("optional"), f"{name}.{key}: say 'required' or 'optional', not {need!r}"
        partner = re.search(r"together with `(\w+)`", need)
        if partner:
            assert not _loads(_file(base_dict, {name: without})), f"{name}.{key} alone is refused: say so"
            without.pop(partner.group(1))
        assert _loads(_file(base_dict, {name: without})), f"{name}.{key} is documented optional but is refused without it"


def test_documented_defaults_are_the_codes():
    for key, (_u, _m, need) in _table("static").items():
        m = re.search(r"default `([^`]+)`", need)
        assert m and float(m.group(1)) == STATIC_DEFAULTS[key], (key, need)
    older = Dynamics({"f_ref_hz": 150.0, "zeta": 0.05})
    for key, attr in (("beta_per_MPa", "beta"), ("stress_ref_MPa", "stress_ref")):
        m = re.search(r"default `([^`]+)`", _table("dynamics", "Older")[key][2])
        assert m and float(m.group(1)) == getattr(older, attr), key


def _example() -> dict[str, Any]:
    found = [yaml.safe_load(b) for b in re.findall(r"```yaml\n(.*?)```", TEXT, re.S) if b.startswith("format:")]
    assert len(found) == 1, "docs/extended-model.md needs one yaml example of the file"
    return found[0]


def test_the_example_loads_and_is_what_the_code_writes(base):
    ex = _example()
    d = {**ex, "base": base.to_dict()}
    model = model_from_dict(d, "extended_model.yaml")
    assert isinstance(model, ExtendedModel)
    back = model.to_dict()
    for key in ("format", "version", "kind", "effects", "inverted", "blocks"):
        assert back[key] == ex[key], f"the example's '{key}' is not what the code writes: {back[key]!r}"


def test_the_top_level_table_agrees_with_the_loader(base):
    full = ExtendedModel(base, {"creep": {"gain": 0.01, "tau_s": 3.0}}, ["creep"]).to_dict()
    rows = {cells[0].strip("`"): cells for line in SECTIONS["Top-level keys"].splitlines()
            if line.startswith("| `") for cells in [[c.strip() for c in line.strip().strip("|").split("|")]]}
    assert set(rows) == set(full), f"top-level table: {sorted(rows)} but the file has {sorted(full)}"
    for key, cells in rows.items():
        loads = _loads({k: v for k, v in full.items() if k != key})
        assert loads == cells[3].startswith("optional"), f"top-level {key}: documented {cells[3]!r}"


def test_the_refusal_quoted_is_the_loaders(base):
    d = {**_example(), "base": base.to_dict()}
    d["blocks"]["dynamics"]["zeta"] = -0.05
    with pytest.raises(ModelError) as exc:
        model_from_dict(d, "extended_model.yaml")
    assert "dynamics.zeta" in str(exc.value)
    assert str(exc.value) in TEXT, f"the doc should quote the loader's own words: {exc.value}"


def test_each_blocks_declared_keys_are_the_keys_documented_for_it():
    """`block_keys` (what the loader accepts) is the union of a block's tables: the forms written and read."""
    owners = {key: cls for cls in REGISTRY.values() for key in cls.keys}
    for name, body in _block_sections().items():
        documented = {key for _, rows in _tables(body) for key in rows}
        assert set(owners[name].block_keys[name]) == documented, (name, sorted(documented))


@pytest.mark.parametrize("block, key, value, says", [
    ("dynamics", "law_held_belwo_MPa", -20.0, "unknown key 'dynamics.law_held_belwo_MPa' (did you mean "
                                              "'dynamics.law_held_below_MPa'?): rename it"),
    ("static", "gian", 1.1, "unknown key 'static.gian' (did you mean 'static.gain'?)"),
    ("creep", "colour", "red", "unknown key 'creep.colour': the creep block reads only gain, tau_s; remove it"),
])
def test_a_key_no_block_reads_is_refused_not_ignored(base, block, key, value, says):
    """A misspelt optional key used to be ignored: the model ran on its default (the law not held,
    the gain 1), and nothing said so."""
    d = {**_example(), "base": base.to_dict()}
    d["blocks"][block][key] = value
    with pytest.raises(ModelError) as exc:
        model_from_dict(d, "extended_model.yaml")
    assert says in str(exc.value)


@pytest.mark.parametrize("block, says", [
    ({"f_ref_hz": 150.0, "zeta": 0.05, "beta_per_MPa": "0.3"}, "dynamics.beta_per_MPa must be a finite number"),
    ({"f_ref_hz": 150.0, "zeta": 0.05, "stress_ref_MPa": float("nan")}, "dynamics.stress_ref_MPa must be a finite"),
    ({"form": "rodload", "f_ref_hz": 150.0, "zeta": 0.05}, "dynamics.form must be 'rod_load'"),
])
def test_a_damaged_dynamics_block_is_refused_by_name(base, block, says):
    """The older form's beta read as text was a ValueError ('internal error'); a misspelt form
    quietly loaded as the older filter."""
    with pytest.raises(ModelError, match=re.escape(says)):
        model_from_dict(_file(base.to_dict(), {"dynamics": block}), "extended_model.yaml")


def test_a_saturation_range_upside_down_is_refused(base):
    block = {"lo": 3.0, "hi": 0.0, "lin_lo": 0.1, "quad_lo": 0.0, "lin_hi": -0.1, "quad_hi": 0.0}
    with pytest.raises(ModelError, match=re.escape("saturation.lo (3) must not be above saturation.hi (0)")):
        model_from_dict(_file(base.to_dict(), {"saturation": block}), "extended_model.yaml")


def test_simulate_refuses_a_misspelt_key_in_one_line(base, tmp_path, capsys):
    from gma_ffc.cli import main
    from gma_ffc.recordings import Recording, write_recording

    d = {**_example(), "base": base.to_dict()}
    d["blocks"]["dynamics"]["law_held_belwo_MPa"] = -20.0
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(d))
    t = np.arange(200) / 1000.0
    write_recording(tmp_path / "drive.csv", Recording({"time_s": t, "current_A": 1.0 + 0.5 * np.sin(20 * t),
                                                       "stress_MPa": np.full(t.size, -15.0)}))
    out = tmp_path / "sim.csv"
    assert main(["simulate", "--model", str(tmp_path / "m.yaml"), str(tmp_path / "drive.csv"), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "did you mean 'dynamics.law_held_below_MPa'" in err and not out.exists()
