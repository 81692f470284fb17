"""Sweeps: one base mission, many combinations of its keys, run as independent missions.

    spec.py       the sweep file: base mission, grid/zip axes, seeds -> combinations
    plan.py       every combination resolved, validated (each map/plugin once) and given its id
    manifest.py   the sweep's own manifest (sweep.json): every combination, its status and run dir
    worker.py     the one task a worker runs: prepare a mission dict, run it into its run dir
    executors.py  where tasks run: local processes, or a Dask distributed cluster
    engine.py     the loop: skip completed, retry failed up to a limit, isolate failures, Ctrl-C
    summary.py    the sweep's runs for ``guadal report`` and the summary table by the swept axes

A combination's mission is exactly a mission file's content, so each run is the same, byte for
byte, as ``guadal run`` of that mission.
"""
