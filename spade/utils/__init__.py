"""Small helpers used across floors (data, training, deployment, experiments, benchmarks).

Nothing here imports another ``spade`` package (but :mod:`spade.paths`, on the same floor), so every floor can
use it:

- :mod:`spade.utils.timing` - median / min wall time of a callable, the machine a timing depends on;
- :mod:`spade.utils.processes` - whether a process id is still alive (and is still the same process);
- :mod:`spade.utils.config` - composing the project's Hydra configs from code (:func:`compose_config`);
- :mod:`spade.utils.errors` - :class:`ConfigError` and the entry points' one-line report of user errors;
- :mod:`spade.utils.hashing` - a file's sha256, read in chunks.
"""
