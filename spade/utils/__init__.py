"""Dependency-free helpers used across floors (data, training, deployment, experiments, benchmarks).

Nothing here imports another ``spade`` package, so the lowest floor can use it:

- :mod:`spade.utils.timing` - median / min wall time of a callable, the machine a timing depends on;
- :mod:`spade.utils.processes` - whether a process id is still alive (and is still the same process).
"""
