"""What a refused command leaves: its one ``error: ...; <fix>`` line, the files it must not have touched, the
runs a store holds; the refusals of ``spade.critic``."""

from __future__ import annotations

import hashlib
import time
from pathlib import Path


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def tree(root: Path) -> dict[str, str]:
    """Every file under ``root`` with its hash: what must come out of a refused command unchanged."""
    return {str(p.relative_to(root)): digest(p) for p in sorted(root.rglob("*")) if p.is_file()}


def one_error_line(err: str) -> str:
    """The single ``error:`` line a refused command prints (and nothing that looks like a traceback)."""
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("error: ")]
    assert len(errors) == 1, err
    assert "; " in errors[0], errors[0]  # "<what is wrong>; <the fix>"
    return errors[0]


UNREACHABLE = "http://127.0.0.1:9/"  # the discard port: nothing answers


def store_runs(uri_path: Path) -> int:
    """The number of runs an SQLite MLflow store holds (0 when there is no store)."""
    import sqlite3

    if not uri_path.exists():
        return 0
    db = sqlite3.connect(uri_path)
    try:
        return int(db.execute("SELECT COUNT(*) FROM runs").fetchone()[0])
    except sqlite3.OperationalError:
        return 0
    finally:
        db.close()


def assert_critic_refuses(run_main, tmp_path: Path, base: list[str], cases: dict[tuple[str, ...], str]) -> None:  # noqa: ANN001
    """Each of ``cases`` (overrides -> the text its one ``error:`` line holds) refused by ``spade.critic`` with exit
    status 2 within 30 s, before any output folder or store is made."""
    for overrides, expected in cases.items():
        start = time.monotonic()
        code, err = run_main("spade.critic", [*base, *overrides])
        assert code == 2, (overrides, err)
        assert expected in one_error_line(err), (overrides, err)
        assert time.monotonic() - start < 30
    assert not (tmp_path / "out").exists() and not (tmp_path / "home" / "logs" / "mlflow.db").exists()
