"""Console scripts (``[project.scripts]`` in pyproject.toml): ``spade-train ARGS`` is ``python -m spade.train ARGS``.

Each script runs its entry point's module as ``__main__``, exactly as ``python -m`` does, so that what an entry
point does before Hydra parses the command line (``spade-plan MAP.yaml start=X,Y,YAW`` rewritten to
``map=... start=[...]``, ``spade-annotate preset=X``, ``spade-sketch model=...``) and its exit statuses (a user
error: one ``error:`` line, exit 2) are the same under both names.
"""

from __future__ import annotations

import runpy
from collections.abc import Callable


def _module(name: str) -> Callable[[], None]:
    """A console script that runs module ``name`` as ``python -m name`` does (``sys.argv[0]`` set to its file)."""

    def script() -> None:
        runpy.run_module(name, run_name="__main__", alter_sys=True)

    script.__name__ = script.__qualname__ = name.rsplit(".", 1)[-1]
    script.__doc__ = f"``python -m {name}`` under its console-script name."
    return script


train = _module("spade.train")
evaluate = _module("spade.evaluate")
annotate = _module("spade.annotate")
report = _module("spade.report")
plan = _module("spade.plan")
export = _module("spade.export")
sketch = _module("spade.sketch")
bench = _module("spade.bench")
critic = _module("spade.critic")
gpu_check = _module("spade.gpu_check")
closed_loop = _module("spade.closed_loop")
