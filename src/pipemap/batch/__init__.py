"""`pipemap batch`: many inspection runs at once, one Dask task per run (docs/formats.md, `pipemap-batch/1`).

    manifest   the runs a manifest (YAML, CSV or a glob of dataset folders) lists, with their settings
    task       one run on a worker: `pipemap run`'s code path, its failure as one line
    summary    the summary table (batch.csv) read from each result folder's run.json
    engine     the cluster (local or at an address), the tasks, resuming and interruption
"""
