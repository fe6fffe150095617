"""`mosaic-data view` on the shared tiny collection: no display, the web viewer, --save paths, the pair blueprint."""

from __future__ import annotations

import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request

import pytest

from tests.helpers.collection import ctrl_c_reaches_it


def _view_command(door_output, *args: str) -> list[str]:
    return [sys.executable, "-m", "mosaic_data.cli", "view", "mosaic/door_panda", "--output-dir", str(door_output), *args]


def _without_display() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_view_without_a_display_stops_at_once_and_names_save_and_web(door_output):
    # rerun's viewer cannot open a window: the command stops at once instead of waiting for it.
    start = time.monotonic()
    result = subprocess.run(
        _view_command(door_output, "--pair"), env=_without_display(), capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 2, result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith("mosaic-data: error:")]
    assert len(errors) == 1 and "no display" in errors[0] and "--save" in errors[0] and "--web" in errors[0]
    assert time.monotonic() - start < 60


RERUN_VIEWER_PORT = 9876
"""Where the viewer is spawned (rerun's default): one already listening there would get the episode."""


def _x_server_answers(display: int) -> bool:
    """Whether an X server listens on ``:display`` (its Unix socket, or TCP port 6000 + display)."""
    unix = f"/tmp/.X11-unix/X{display}"
    for family, address in ((socket.AF_UNIX, unix), (socket.AF_INET, ("127.0.0.1", 6000 + display))):
        if family == socket.AF_UNIX and not os.path.exists(unix):
            continue
        with socket.socket(family, socket.SOCK_STREAM) as probe:
            probe.settimeout(1)
            if probe.connect_ex(address) == 0:
                return True
    return False


def test_view_with_a_display_that_does_not_answer_stops_and_names_save_and_web(door_output):
    # A stale ssh X forwarding: DISPLAY is set, no X server answers; rerun's viewer exits and nothing listens.
    display = 97
    if _x_server_answers(display):
        pytest.skip(f"an X server answers on :{display}")
    with socket.socket() as probe:
        if probe.connect_ex(("127.0.0.1", RERUN_VIEWER_PORT)) == 0:
            pytest.skip(f"a rerun viewer (or something else) listens on port {RERUN_VIEWER_PORT}: the episode would go there")
    env = {**_without_display(), "DISPLAY": f":{display}"}
    start = time.monotonic()
    try:
        result = subprocess.run(_view_command(door_output), env=env, capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        pytest.fail("mosaic-data view waited for a viewer that cannot open a window")
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith("mosaic-data: error:")]
    assert len(errors) == 1 and f"DISPLAY=:{display}" in errors[0] and "--save" in errors[0] and "--web" in errors[0], result.stderr
    assert time.monotonic() - start < 60


def test_a_viewer_that_never_listens_is_killed_after_the_timeout(tmp_path, monkeypatch):
    from mosaic_data.collection import view

    pid_file = tmp_path / "viewer.pid"
    hanging = tmp_path / "hanging_viewer"
    hanging.write_text(f"#!/bin/sh\necho $$ > {pid_file}\nexec sleep 60\n")
    hanging.chmod(0o755)
    monkeypatch.setattr(view, "_viewer_executable", lambda: str(hanging))
    with pytest.raises(ValueError, match=r"viewer did not start within 1 s .*--save .*--web"):
        view.start_viewer(port=_free_port(), timeout_s=1)
    with pytest.raises(ProcessLookupError):
        os.kill(int(pid_file.read_text()), 0)


def test_view_web_serves_rerun_web_viewer_until_interrupted(door_output, tmp_path):
    web_port, grpc_port = _free_port(), _free_port()
    while grpc_port == web_port:  # the kernel may hand the same free port out twice in a row
        grpc_port = _free_port()
    errors = (tmp_path / "stderr.txt").open("w")
    process = subprocess.Popen(
        _view_command(door_output, "--pair", "--web", "--web-port", str(web_port), "--grpc-port", str(grpc_port)),
        env=_without_display(), stdout=subprocess.PIPE, stderr=errors, text=True, preexec_fn=ctrl_c_reaches_it,
    )
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: [lines.put(line) for line in process.stdout], daemon=True).start()
    try:
        deadline = time.monotonic() + 180
        url = None
        while url is None and time.monotonic() < deadline and process.poll() is None:
            try:
                line = lines.get(timeout=1)
            except queue.Empty:
                continue
            url = next((word for word in line.split() if word.startswith("http://")), None)
        assert url is not None, f"no URL printed (exit status {process.poll()}): {(tmp_path / 'stderr.txt').read_text()[-2000:]}"
        assert url.startswith(f"http://localhost:{web_port}/") and f"localhost%3A{grpc_port}" in url
        with urllib.request.urlopen(url, timeout=30) as response:
            assert response.status == 200 and b"rerun" in response.read().lower()
        with socket.create_connection(("127.0.0.1", grpc_port), timeout=10):
            pass  # the recording's gRPC server answers too
        assert process.poll() is None, "it keeps serving"
        process.send_signal(signal.SIGINT)
        try:
            status = process.wait(timeout=180)  # a loaded 2-core machine may take minutes to shut the servers down
        except subprocess.TimeoutExpired:
            status = None
        assert status == 0, f"exit status {status} after Ctrl-C: {(tmp_path / 'stderr.txt').read_text()[-2000:]}"
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()


@pytest.mark.parametrize(
    "make_path, message",
    [
        (lambda tmp: tmp, "is a folder: give a file in it, e.g. --save {tmp}/door_panda_episode_1_pair.rrd"),
        (lambda tmp: tmp / "pair.png", "--save must name a .rrd file"),
        (lambda tmp: tmp / "notes.txt" / "pair.rrd", "notes.txt is a file, not a folder"),
    ],
    ids=["existing-folder", "wrong-suffix", "under-a-file"],
)
def test_view_save_refuses_bad_paths_in_one_line(door_output, tmp_path, capsys, cli, make_path, message):
    (tmp_path / "notes.txt").write_text("not a folder")
    path = make_path(tmp_path)
    status = cli("view", "mosaic/door_panda", "--output-dir", str(door_output), "--episode", "1", "--pair", "--save", str(path))
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1, err
    assert message.format(tmp=tmp_path) in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"], "nothing written"


def _text_views_and_documents(rrd):
    """(origin of every text-document view in the blueprint, entity paths holding a text document)."""
    from rerun.experimental import RrdReader

    reader = RrdReader(rrd)
    (blueprint,) = reader.blueprints()
    views: dict[str, dict] = {}
    for chunk in reader.stream(store=blueprint):
        columns = chunk.to_record_batch().to_pydict()
        for key in ("ViewBlueprint:class_identifier", "ViewBlueprint:space_origin", "ViewContents:query"):
            if key in columns:
                view = chunk.entity_path.removesuffix("/ViewContents")
                views.setdefault(view, {})[key] = columns[key][-1][0]
    text_origins = []
    for fields in views.values():
        if fields.get("ViewBlueprint:class_identifier") == "TextDocument":
            assert fields.get("ViewContents:query", "$origin/**") == "$origin/**", "a view that shows its origin's subtree"
            text_origins.append(fields["ViewBlueprint:space_origin"])
    documents = sorted(
        {name.split(":")[0] for name in reader.store().schema().column_names() if name.endswith("TextDocument:text")}
    )
    return text_origins, documents


def test_pair_recording_gives_each_text_document_its_own_view(door_output, tmp_path, cli):
    # One view over /description holding both robots' documents would show neither: rerun says "Can only show one
    # text document at a time; was given 2".
    rrd = tmp_path / "pair.rrd"
    assert cli("view", "mosaic/door_panda", "--output-dir", str(door_output), "--episode", "1", "--pair", "--save", str(rrd)) == 0
    origins, documents = _text_views_and_documents(rrd)
    assert documents == ["/description/panda", "/description/sawyer"], documents
    for origin in origins:
        shown = [d for d in documents if d == origin or d.startswith(origin.rstrip("/") + "/")]
        assert len(shown) == 1, f"the text view at {origin} would get {shown}"
    assert {d for d in documents if any(d == o or d.startswith(o.rstrip("/") + "/") for o in origins)} == set(documents)


def test_view_web_refuses_one_port_for_both_servers(door_output):
    result = subprocess.run(
        _view_command(door_output, "--web", "--web-port", "9555", "--grpc-port", "9555"),
        env=_without_display(), capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 2
    assert result.stderr.strip() == "mosaic-data: error: --web-port and --grpc-port are both 9555: the two servers need two ports"
