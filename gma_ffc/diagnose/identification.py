"""Are the identification recordings given to `diagnose --ident` the ones the model was made from?

`gma-ffc identify` keeps each identification file's name, size and SHA-256 in the model's
provenance (`identification_files`; `recordings` lists the names). `check` compares what the user
gave with that record and says, in words and in `diagnosis.json`, whether they match, and what a
diagnosis without them cannot do. Files that differ from the record are refused: fitting the core
again on other loops than the base's would change what "before" means. Pure: no I/O (the CLI
reads the files and hands their fingerprints in).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

from ..errors import InputError

def lost_without(voltage: bool, loads: bool) -> str:
    """What a diagnosis cannot do without the identification recordings, in the recording's words: a
    voltage drive's first-order lag is the amplifier charging the stack, not an eddy lag; and a loop
    width that follows stress, and stress_dependent_play's law, exist only where the model is an SDPI
    and the recordings' loads vary (else that effect cannot be tested, and cannot_conclude says so)."""
    lag = "a first-order lag" if voltage else "an eddy lag"
    through = f"through {lag} or a delay" + (", or with a loop width that follows stress" if loads else "")
    text = ("Without them (--ident), every fit is held near the base model's own output on its loops, known only to "
            f"within its identification error. The core cannot be identified again on measured loops ({through})")
    if loads:
        text += (". So stress_dependent_play's loop-width law is fitted to these recordings alone, not on the "
                 "identification loops at every load")
    return text


@dataclass(frozen=True)
class IdentificationCheck:
    """What was given against what the model records."""

    given: tuple[str, ...]              # names of the recordings given with --ident
    recorded: tuple[str, ...]           # names the model's provenance lists
    verified: bool                      # sizes and hashes were compared (the model records them)
    missing: tuple[str, ...] = ()       # recorded but not given
    diagnosed: tuple[str, ...] = ()     # recordings given to diagnose that bear a recorded name
    voltage: bool = False               # the model's drive is a voltage (no coil, no eddy currents)
    loads: bool = True                  # a loop width that follows stress can be tested (an SDPI, loads varying)

    @property
    def status(self) -> str:
        if not self.given:
            return "not_given"
        if not self.recorded:
            return "unchecked"
        return "match" if not self.missing else "partial"

    def words(self) -> str:
        """The note for the report and the CLI: what was given, and what that means."""
        if not self.given and self.diagnosed:
            names, one = ", ".join(self.diagnosed), len(self.diagnosed) == 1
            return (f"{names} {'bears the name of one' if one else 'bear the names'} of the model's identification "
                    f"recordings, and {'is' if one else 'are'} given to diagnose, not with --ident. On the data the base "
                    f"was fitted to, a diagnosis shows only what its class misses there. Give {names} with --ident, "
                    "and diagnose other runs.")
        if not self.given:
            known = f" ({', '.join(self.recorded)})" if self.recorded else ""
            return f"The identification recordings{known} were not given. {lost_without(self.voltage, self.loads)}."
        how = "name, size and content" if self.verified else "name"
        if self.status == "unchecked":
            return (f"{len(self.given)} identification recording(s) given; the model keeps no record of the "
                    "files it was identified on, so they could not be checked against it.")
        if self.missing:
            return (f"{len(self.given)} of the model's {len(self.recorded)} identification recordings given, "
                    f"each matching its record by {how}; not given: {', '.join(self.missing)}.")
        if len(self.recorded) == 1:
            return f"The identification recording given ({self.recorded[0]}) matches the model's record by {how}."
        return (f"All {len(self.recorded)} identification recordings given match the model's record by {how}.")

    def to_json(self) -> dict[str, Any]:
        return {"status": self.status, "given": list(self.given), "recorded": list(self.recorded),
                "verified": self.verified, "missing": list(self.missing), "diagnosed": list(self.diagnosed),
                "note": self.words()}


def recorded_files(model: Any) -> tuple[list[dict[str, Any]], list[str]]:
    """The model's record: fingerprints (name, bytes, sha256) where `identify` wrote them, and names."""
    prov = getattr(model, "provenance", None)
    prov = prov if isinstance(prov, Mapping) else {}

    def listed(key: str) -> list[Any]:       # a record edited into something else is no record
        v = prov.get(key)
        return v if isinstance(v, list) else []

    files = [f for f in listed("identification_files") if isinstance(f, Mapping) and "name" in f]
    names = [str(f["name"]) for f in files] or [str(n) for n in listed("recordings")]
    return [dict(f) for f in files], names


def check(model: Any, names: Sequence[str], fingerprints: Sequence[Mapping[str, Any]] | None = None
          ) -> IdentificationCheck:
    """Compare the recordings given (their names; the files' fingerprints when read from disk) with
    the model's record. Raises InputError for a file the record does not hold or whose content
    differs from it, naming the file and what the model was identified on."""
    files, recorded = recorded_files(model)
    given = tuple(str(n) for n in names)
    voltage = str(getattr(model, "drive_name", "current_A")).endswith("_V")
    loads = getattr(model, "stress_range_MPa", None) is not None
    if not given or not recorded:
        return IdentificationCheck(given, tuple(recorded), False, voltage=voltage, loads=loads)
    by_name = {f["name"]: f for f in files}
    verified = bool(files) and fingerprints is not None
    for k, name in enumerate(given):
        if name not in recorded:
            raise InputError(f"--ident {name}: the model was not identified on it (it was identified on "
                             f"{', '.join(recorded)}); give those recordings, or leave out --ident")
        if verified:
            fp = fingerprints[k]          # type: ignore[index]
            rec = by_name[name]
            if fp.get("bytes") != rec.get("bytes") or fp.get("sha256") != rec.get("sha256"):
                raise InputError(f"--ident {name}: its content differs from the file the model was identified on "
                                 f"({rec.get('bytes')} bytes, sha256 {str(rec.get('sha256'))[:12]}...); give the "
                                 "identification recordings the model was made from, or leave out --ident")
    missing = tuple(n for n in recorded if n not in given)
    return IdentificationCheck(given, tuple(recorded), verified, missing, voltage=voltage, loads=loads)


def split_by_record(model: Any, paths: Sequence[str], fingerprints: Sequence[Mapping[str, Any]]
                    ) -> tuple[list[int], list[int]]:
    """Of files given after --ident with nothing after them, which are the model's identification
    files (name, size and hash as recorded) and which are recordings to diagnose: (indices, indices)."""
    files, _ = recorded_files(model)
    known = {(f.get("name"), f.get("bytes"), f.get("sha256")) for f in files}
    ident = [k for k, fp in enumerate(fingerprints) if (fp.get("name"), fp.get("bytes"), fp.get("sha256")) in known]
    return ident, [k for k in range(len(paths)) if k not in ident]
