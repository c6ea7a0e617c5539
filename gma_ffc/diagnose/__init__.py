"""The discrepancy tool behind `gma-ffc diagnose` (issue 5).

    from gma_ffc.diagnose.engine import diagnose
    dg = diagnose(model, recordings)          # Diagnosis: verdict, located, candidates, extended model
    from gma_ffc.diagnose.report import write_outputs
    write_outputs(dg, "diagnosis/")           # diagnosis.json, report.html, extended_model.yaml

Modules: `data` (recordings as arrays, the held-out split, noise floor), `locate` (where the
residual is), `kernels` (numba blocks), `extended` (the extended model, a first-class model
kind), `fitting` (least squares and parameter search on held-out blocks), `catalog` (the
physical extensions), `engine` (selection and the verdict), `report` (JSON, HTML, YAML).
"""
