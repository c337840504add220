"""The cache machinery, below the engine and the studies that use it: a content-addressed store
of every computed result (:mod:`ibt.cache.store`: keys, code versions, atomic entries), its
plain-data payload codecs (:mod:`ibt.cache.payloads`: JSON and npz, never pickles), upkeep
(:mod:`ibt.cache.upkeep`: statuses, pruning, verification), migrations
(:mod:`ibt.cache.migrations`), their command line (:mod:`ibt.cache.admin`) and the guard that
keeps each kind's code version honest (:mod:`ibt.cache.guard`). Module paths are not part of a
key, so where this code lives does not move any entry."""
