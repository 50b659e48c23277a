"""Parameter sweeps over many bags, in parallel (``fto-sweep``).

- :mod:`.grid`: reading ``--set NAME=V1,V2,...`` and expanding the grid;
- :mod:`.engine`: where tasks run (this process, local worker processes, a Dask cluster);
- :mod:`.tasks`: one run as a worker executes it (a replay whose failure is a value);
- :mod:`.results`: rows, ``results.csv``, the best settings, the summary;
- :mod:`.plots`: error against each parameter, the Pareto front;
- :mod:`.cli`: the command line.
"""
