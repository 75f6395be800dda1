"""Monte Carlo sweeps over seeds x a parameter grid (``bearingflock sweep``, docs/sweep.md).

``spec`` (what runs), ``params`` (grid parameter names), ``runs`` (one run, on a worker),
``executors`` (the :class:`concurrent.futures.Executor` seam), ``driver`` (batches out, rows
in), ``results`` (Parquet rows), ``summary`` (statistics per grid point), ``plots``, ``cli``.
"""
