"""Scale-out: a command's units of work (shards, benchmark runs, evaluation flights) on local worker processes or as
Ray tasks on a cluster.

:func:`~edge_explorer.cluster.units.map_units` is the one entry point; :mod:`~edge_explorer.cluster.local_pool`
runs units in a ``concurrent.futures`` process pool and :mod:`~edge_explorer.cluster.ray_tasks` as Ray tasks.
Ray is an optional extra (``pip install 'edge-explorer[cluster]'``) and is imported only when ``--ray`` is given.
Network training scales with torch's own DDP under ``torchrun`` instead (:mod:`edge_explorer.learn.ddp`).
"""
