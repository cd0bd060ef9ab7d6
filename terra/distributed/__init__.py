"""Phase 1 on a Dask cluster: perception is a map over frames, fusion an ordered reduce.

    terra map SOURCE --out BUNDLE --workers 4            # a local cluster on 127.0.0.1
    terra map SOURCE --out BUNDLE --scheduler tcp://h:8786   # a running cluster (or TERRA_DASK_SCHEDULER)

Workers read frames from the source themselves and write each image's perception into the per-frame
perception cache (terra/perception/cache.py); the client reads the frames too, waits for each frame's
task, and fuses in frame order with the cache answering every image. The bundle is the serial run's,
byte for byte. Modules: `source` (how a worker reopens the source), `cluster` (which cluster, a client
of it), `job` (what a worker needs, as JSON), `worker` (the tasks, run in worker processes), `feed` (the
client's bounded window of tasks), `phase1` (`map_on_cluster`, `perceive_on_cluster`). Dask is an
optional dependency (the `dask` extra) imported only when a cluster is asked for.
"""
