"""Collection pipeline: expert episodes into LeRobot v3 datasets, and the tools around them.

One module per job: :mod:`.schema` (features, repo ids, where datasets live), :mod:`.plan` (jobs, shards,
seeds), :mod:`.worker` (one shard in a worker process), :mod:`.collect` (orchestration, resume),
:mod:`.merge` (LeRobot aggregation), :mod:`.metadata` (the ``meta/mosaic.json`` sidecar),
:mod:`.validate`, :mod:`.view` (rerun) and :mod:`.hub` (dataset card, push).
"""


class CollectionError(RuntimeError):
    """A collection that cannot finish (an expert gave up, a worker died): not a bad input, exit status 1."""
