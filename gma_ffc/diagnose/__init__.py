"""The discrepancy tool behind `gma-ffc diagnose` (issues 5 and 9).

    from gma_ffc.diagnose.selection import EffectSelector
    sel = EffectSelector().fit(model, recordings)   # outcome_, verdict_, candidates_, extended_model_
    from gma_ffc.diagnose.engine import diagnose
    dg = diagnose(model, recordings)                # the same as a Diagnosis (what the CLI and report use)
    from gma_ffc.diagnose.report import write_outputs
    write_outputs(dg, "diagnosis/")                 # diagnosis.json, report.html, extended_model.yaml

Modules: `data` (recordings as arrays, the held-out split, noise floor), `checks` (overlap and
enough loops, before any fit), `locate` (where the residual is), `fitting` (`Spec`, least
squares and parameter search on held-out blocks), `selection` (`EffectSelector`: the forward
selection and the verdict), `explain` (the words), `results` (`Diagnosis`, `Candidate`),
`engine` (`diagnose`, the one-call wrapper), `report` (JSON, HTML, YAML). The effects
themselves and the extended model live under the models (`gma_ffc.effects`, `gma_ffc.extended`):
this package imports them, never the other way round.
"""
