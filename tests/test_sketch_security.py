"""The sketching server obeys only its user: a foreign ``Host`` (DNS rebinding) and a cross-site
``Origin`` on a state-changing request are refused, and ``POST /api/model`` opens only model files (.ckpt, .onnx,
.pt) under the folders the server was started with, never echoing what a parser made of another file. Its sketch
file holds one map's sketches (a file of another map is refused, never written into), a corrupted file or a NUL byte
is answered 4xx, and a save keeps the file's mode."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

pytest.importorskip("fastapi")
pytest.importorskip("httpx")
from fastapi.testclient import TestClient  # noqa: E402

from spade.sketching import build_app  # noqa: E402

from factories import LOCAL, L_WAYPOINTS, TINY, site_map, student_checkpoint  # noqa: E402

def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.exists() else "absent"


@pytest.fixture
def served(tmp_path: Path) -> dict:
    maps = tmp_path / "maps"
    maps.mkdir()
    out = tmp_path / "out"
    app = build_app(str(site_map(maps)), out, TINY, hosts=["192.168.7.7"])
    return {"client": TestClient(app, base_url=LOCAL), "app": app, "out": out, "maps": maps, "tmp": tmp_path}


# -- Host allow-list (DNS rebinding) -----------------------------------------------------------------------------------
@pytest.mark.parametrize("host", ["attacker.example", "attacker.example:8765", "127.0.0.1.attacker.example",
                                  "localhost.attacker.example", "testserver", ""])
def test_a_foreign_host_is_refused(served, host: str) -> None:
    client = served["client"]
    for method, url, body in (("GET", "/api/map", None), ("GET", "/", None),
                              ("POST", "/api/sketches", {"shape": "L", "waypoints": L_WAYPOINTS})):
        r = client.request(method, url, json=body, headers={"Host": host})
        assert r.status_code == 403, (host, url, r.text)
        assert "is not this server" in r.json()["error"]
    assert digest(served["out"] / "sketches.yaml") == "absent"


@pytest.mark.parametrize("host", ["127.0.0.1:8765", "localhost:8765", "[::1]:8765", "LOCALHOST", "192.168.7.7:8765"])
def test_its_own_names_and_the_bound_address_are_served(served, host: str) -> None:
    r = served["client"].get("/api/map", headers={"Host": host})
    assert r.status_code == 200, r.text


# -- same-origin check on state-changing requests ---------------------------------------------------------------------
@pytest.mark.parametrize("headers", [
    {"Origin": "http://attacker.example"}, {"Origin": "null"}, {"Origin": "http://127.0.0.1:9999"},
    {"Origin": "http://localhost:8765"},  # another origin, even on this machine
    {"Sec-Fetch-Site": "cross-site"}, {"Sec-Fetch-Site": "same-site"},
])
def test_a_cross_origin_state_change_is_refused_and_changes_nothing(served, headers: dict) -> None:
    client, out = served["client"], served["out"]
    saved = client.post("/api/sketches", json={"shape": "L", "waypoints": L_WAYPOINTS, "name": "mine"})
    assert saved.status_code == 201, saved.text
    before = digest(out / "sketches.yaml")
    for method, url, body in (("POST", "/api/sketches", {"shape": "L", "waypoints": L_WAYPOINTS}),
                              ("DELETE", "/api/sketches/mine", None), ("POST", "/api/build", {}),
                              ("POST", "/api/model", {"path": "x.ckpt"})):
        r = client.request(method, url, json=body, headers=headers)
        assert r.status_code == 403, (method, url, r.text)
        assert "refused" in r.json()["error"]
    assert digest(out / "sketches.yaml") == before and not (out / "dataset").exists()


def test_the_page_itself_and_scripts_may_change_state(served) -> None:
    client = served["client"]
    same = {"Origin": LOCAL, "Sec-Fetch-Site": "same-origin"}
    assert client.post("/api/sketches", json={"shape": "L", "waypoints": L_WAYPOINTS}, headers=same).status_code == 201
    assert client.post("/api/sketches", json={"shape": "L", "waypoints": L_WAYPOINTS}).status_code == 201  # curl
    r = client.get("/api/sketches", headers={"Origin": "http://attacker.example"})
    assert r.status_code == 200 and "access-control-allow-origin" not in r.headers  # the browser keeps it from them


def test_oversized_requests_are_refused_in_one_line_before_they_are_read(served) -> None:
    """Once, a 47 MB POST of 2.5 M waypoints ran 28 s and kept 0.7 GB. The body's length is checked before a
    byte of it is read (413), a body without a length is not read (411), a list past the waypoint cap is a 422 that
    does not echo the request; nothing is saved."""
    import json as jsonlib

    from spade.sketching.api import MAX_WAYPOINTS
    from spade.sketching.app import MAX_BODY_BYTES

    client, out = served["client"], served["out"]
    before = digest(out / "sketches.yaml") if (out / "sketches.yaml").exists() else None
    huge = jsonlib.dumps({"shape": "L", "waypoints": [[1.0, 2.0]] * 2_500_000}).encode()
    assert len(huge) > 25 * MAX_BODY_BYTES
    r = client.post("/api/sketches", content=huge, headers={"Content-Type": "application/json"})
    assert r.status_code == 413 and "at most" in r.json()["error"] and "\n" not in r.json()["error"]

    def chunks():
        yield b'{"shape": "L", '
        yield b'"waypoints": [[1.0, 2.0]]}'

    r = client.post("/api/execute", content=chunks(), headers={"Content-Type": "application/json"})
    assert r.status_code == 411 and "Content-Length" in r.json()["error"]
    many = {"shape": "L", "waypoints": [[1.0, 2.0]] * (MAX_WAYPOINTS + 1)}
    r = client.post("/api/sketches", json=many)
    assert r.status_code == 422 and f"at most {MAX_WAYPOINTS} items" in r.json()["error"], r.text
    assert len(r.text) < 2000  # the refusal does not echo the request
    after = digest(out / "sketches.yaml") if (out / "sketches.yaml").exists() else None
    assert after == before


# -- model loading ---------------------------------------------------------------------------------------------------
@pytest.fixture
def no_planner(monkeypatch) -> list:
    """Records every file the planner would have opened."""
    import spade.deploy.student_planner as planner_module

    opened: list = []

    class Recorder:
        def __init__(self, path, **kwargs) -> None:
            opened.append(Path(path))
            raise AssertionError("the planner was asked to open a file")

    monkeypatch.setattr(planner_module, "Planner", Recorder)
    return opened


def test_a_file_that_is_not_a_model_is_refused_without_opening_it(served, no_planner, tmp_path: Path) -> None:
    client = served["client"]
    secret = served["maps"] / "shadow"
    secret.write_text("root:$6$saltsalt$hash:19000:0:99999:7:::\n")
    for path in ("/etc/shadow", "/etc/passwd", str(secret), str(served["maps"] / "site.yaml"), str(served["maps"])):
        r = client.post("/api/model", json={"path": path})
        assert r.status_code == 422, r.text
        assert "is not a model file" in r.json()["error"] and "root:" not in r.text
    assert no_planner == []


def test_a_model_file_outside_the_model_folders_is_refused_without_opening_it(served, no_planner) -> None:
    client, tmp = served["client"], served["tmp"]
    elsewhere = student_checkpoint(tmp.parent / f"{tmp.name}-elsewhere" / "student.ckpt")
    link = served["maps"] / "linked.ckpt"
    link.symlink_to(elsewhere)  # a link in a model folder to a file outside is outside
    answers = {}
    for path in (elsewhere, link, served["maps"] / "missing.ckpt", Path("/root/secret.onnx")):
        r = client.post("/api/model", json={"path": str(path)})
        answers[str(path)] = r.status_code
        assert r.status_code == 404 and "no such file in the model folders" in r.json()["error"], r.text
    assert set(answers.values()) == {404}  # one answer whether it exists or not: no oracle
    assert no_planner == []


def test_a_model_named_file_that_is_no_model_is_refused_without_echoing_a_parse(served) -> None:
    client, maps = served["client"], served["maps"]
    for name, content in (("fake.onnx", b"root:$6$saltsalt$hash:19000:0:99999:7:::\n"),
                          ("fake.ckpt", b"PK\x03\x04 not really a zip"), ("fake.pt", b"\x80\x04junk")):
        (maps / name).write_bytes(content)
        r = client.post("/api/model", json={"path": str(maps / name)})
        assert r.status_code == 422, r.text
        error = r.json()["error"]
        assert error.startswith(f"model {name} cannot be read as a student checkpoint or export"), error
        for leak in ("root:", "saltsalt", "protobuf", "Protobuf", "zip", "pickle", "Error", "header"):
            assert leak not in error, (leak, error)


def test_models_load_from_the_started_folders_or_the_models_setting(tmp_path: Path) -> None:
    maps, kept, other = tmp_path / "maps", tmp_path / "kept", tmp_path / "other"
    for d in (maps, kept, other):
        d.mkdir()
    yaml_path = site_map(maps)
    in_map_folder = student_checkpoint(maps / "a.ckpt")
    in_kept = student_checkpoint(kept / "b.ckpt")
    client = TestClient(build_app(str(yaml_path), tmp_path / "out", TINY), base_url=LOCAL)
    assert client.post("/api/model", json={"path": str(in_map_folder)}).status_code == 200
    assert client.post("/api/model", json={"path": str(in_kept)}).status_code == 404
    client = TestClient(build_app(str(yaml_path), tmp_path / "out", TINY, models=[kept]), base_url=LOCAL)
    assert client.post("/api/model", json={"path": str(in_kept)}).status_code == 200
    assert client.post("/api/model", json={"path": str(in_map_folder)}).status_code == 404
    # the model named on the command line is the operator's own choice: its folder is a model folder
    started = student_checkpoint(other / "c.ckpt")
    client = TestClient(build_app(str(yaml_path), tmp_path / "out", TINY, model=started, models=[kept]),
                        base_url=LOCAL)
    assert client.get("/api/model").json()["model"]["path"] == str(started.resolve())
    assert client.post("/api/model", json={"path": str(student_checkpoint(other / "d.ckpt"))}).status_code == 200


def _sketch_client(yaml_path: Path, out: Path):
    pytest.importorskip("fastapi")
    pytest.importorskip("httpx")
    from fastapi.testclient import TestClient

    from spade.sketching import build_app
    from factories import LOCAL, TINY

    return TestClient(build_app(str(yaml_path), out, TINY), base_url=LOCAL)


def test_one_sketch_file_one_map(tmp_path: Path) -> None:
    """Two sketch servers on one ``out_dir`` with different maps both saved (``sketches.yaml`` named one
    map and held the other's sketch), and an edit of the file's ``map:`` while a server ran was ignored. The file's
    map is checked on every request: a file of another map is refused (409), never written into."""
    from spade.maps import OccupancyMap, save_ros_map
    from factories import L_WAYPOINTS

    first = site_map(tmp_path / "a")
    import numpy as np

    g = np.ones((100, 120), np.uint8)
    g[[0, -1], :] = 2
    g[:, [0, -1]] = 2
    second = save_ros_map(OccupancyMap(g, 0.1, origin=(-2.0, -1.0, 0.0), name="other"), tmp_path / "b" / "other.yaml")
    out = tmp_path / "sketches"
    a, b = _sketch_client(first, out), _sketch_client(second, out)  # neither has saved yet: both start
    r = a.post("/api/sketches", json={"shape": "L", "waypoints": L_WAYPOINTS})
    assert r.status_code == 201, r.text
    before = digest(out / "sketches.yaml")
    r = b.post("/api/sketches", json={"shape": "L", "waypoints": L_WAYPOINTS})
    assert r.status_code == 409 and "holds sketches of map" in r.json()["error"], r.text
    assert b.get("/api/sketches").status_code == 409
    assert digest(out / "sketches.yaml") == before
    with pytest.raises(ValueError, match="holds sketches of map"):
        _sketch_client(second, out)  # a second server of another map, started now: refused
    # the file's map edited while the server runs: refused, not ignored
    text = (out / "sketches.yaml").read_text()
    (out / "sketches.yaml").write_text(text.replace(str(first.resolve()), str(second.resolve())))
    r = a.post("/api/sketches", json={"shape": "L", "waypoints": L_WAYPOINTS})
    assert r.status_code == 409 and "holds sketches of map" in r.json()["error"]


def test_sketch_server_answers_4xx_for_a_nul_byte_and_a_corrupted_file(tmp_path: Path) -> None:
    """A NUL byte in a model path and a corrupted ``sketches.yaml`` answered 500."""
    yaml_path = site_map(tmp_path)
    out = tmp_path / "sk"
    client = _sketch_client(yaml_path, out)
    r = client.post("/api/model", json={"path": "stud\x00ent.onnx"})
    assert r.status_code == 400 and "NUL byte" in r.json()["error"], r.text
    out.mkdir(exist_ok=True)
    (out / "sketches.yaml").write_text("map: [unclosed\n  scenarios: {\n")
    for r in (client.get("/api/sketches"),
              client.post("/api/sketches", json={"shape": "L", "waypoints": [[0.0, 1.0], [1.5, 1.0]]})):
        assert r.status_code in (409, 422) and "error" in r.json(), r.text
    r = client.get("/api/sketches")
    assert r.status_code == 409 and "is not readable YAML" in r.json()["error"]
    (out / "sketches.yaml").write_text("map: x\nscenarios: [1, 2]\n")
    r = client.get("/api/sketches")
    assert r.status_code == 409 and "not a list of sketches" in r.json()["error"]


def test_a_sketch_save_keeps_the_files_mode(tmp_path: Path) -> None:
    """Every save rewrote ``sketches.yaml`` through ``mkstemp``, leaving it at mode 0600 whatever it was; a save now
    keeps the file's own mode, and a new file gets the umask's."""
    import os
    import stat

    from spade.sketching.storage import SketchStore

    waypoints = [[1.0, 1.0], [1.5, 1.0], [2.0, 1.5]]
    path = tmp_path / "sk" / "sketches.yaml"
    old = os.umask(0o022)
    try:
        store = SketchStore(path, "warehouse:1")
        store.append("L", waypoints)
        assert stat.S_IMODE(path.stat().st_mode) == 0o644
        path.chmod(0o664)
        store.append("L", waypoints)
        assert stat.S_IMODE(path.stat().st_mode) == 0o664
        path.chmod(0o640)
        SketchStore(path, "warehouse:1").append("L", waypoints)
        assert stat.S_IMODE(path.stat().st_mode) == 0o640
    finally:
        os.umask(old)
