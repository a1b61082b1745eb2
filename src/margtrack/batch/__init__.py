"""Many recordings at once: ``margtrack batch`` on an embedded or an existing Dask cluster.

- :mod:`~margtrack.batch.inputs`: files, folders and globs to recordings, unique output names;
- :mod:`~margtrack.batch.cluster`: where jobs run (in-process, LocalCluster, a scheduler);
- :mod:`~margtrack.batch.state`: the records that make a rerun skip finished outputs;
- :mod:`~margtrack.batch.run`: the batch itself (:func:`run_batch`);
- :mod:`~margtrack.batch.summary`: ``summary.csv`` and ``summary.parquet``.
"""

from __future__ import annotations

from margtrack.batch.cluster import Pool, open_pool
from margtrack.batch.run import BatchConfig, BatchResult, execute, plan_batch, run_batch

__all__ = ["BatchConfig", "BatchResult", "Pool", "execute", "open_pool", "plan_batch",
           "run_batch"]
