"""``mosaic-data view``: one episode (or an agent/demonstrator pair) as a rerun recording with a blueprint.

Frames come from LeRobot's own reader, so what you see is what a policy trained on the dataset sees (stored as
JPEG in the recording). With ``--pair``, a demonstrator episode of the same variation (same LeRobot task
string) is logged beside the agent's, both starting at time 0 on the shared ``time`` timeline.

Three ways out: ``--save`` writes an ``.rrd`` file, ``--web`` serves rerun's web viewer on localhost until
Ctrl-C (for a machine without a display, e.g. over ssh with a forwarded port), and by default the native viewer
is spawned, which needs a display: without one, or with one that does not answer (a stale ssh X forwarding), the
command stops within seconds and says so.
"""

from __future__ import annotations

import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO
from urllib.parse import quote

import numpy as np

from mosaic_data.collection.episode_matching import listed
from mosaic_data.collection.metadata import read_aligned_sidecar
from mosaic_data.collection.schema import ACTION_NAMES, CAMERA_KEY, FPS, is_lerobot_dataset, repo_id_of

OTHER_ROBOT = {"panda": "sawyer", "sawyer": "panda"}


@dataclass(frozen=True)
class WebPorts:
    """Where ``--web`` serves: rerun's web viewer (HTTP) and the gRPC server it reads the recording from."""

    web: int = 9090
    grpc: int = 9876

    def url(self) -> str:
        """The address to open in a browser: the viewer, told where the recording is served."""
        return f"http://localhost:{self.web}/?url={quote(f'rerun+http://localhost:{self.grpc}/proxy', safe='')}"


def has_display() -> bool:
    """Whether a display is named for rerun's native viewer to open a window on (Linux only: X11 or Wayland).
    Whether it answers shows only when the viewer starts: :func:`start_viewer`."""
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


SERVE_FLUSH_TIMEOUT_S = 60.0
"""How long ``--web`` waits for rerun's gRPC server to take the logged episode before it gives up with one line."""

VIEWER_PORT = 9876
"""rerun's default viewer port: a viewer the user already has open there gets the episode."""
VIEWER_START_TIMEOUT_S = 10.0
"""How long a spawned viewer may take to listen on its port. One that cannot open its window usually exits at
once, which is noticed at once; one stuck on a display that never answers is killed after this."""
VIEWER_FLUSH_TIMEOUT_S = 60.0
"""How long the viewer may take to receive the logged episode before the command gives up with one line."""
NO_WINDOW_ADVICE = "add --save episode.rrd to write a file, or --web to serve rerun's web viewer on localhost"


def start_viewer(port: int = VIEWER_PORT, timeout_s: float = VIEWER_START_TIMEOUT_S) -> None:
    """Make sure a rerun viewer listens on ``port``: the one already there, or a new one, detached so that it
    outlives the command. A new one that exits, or does not listen within ``timeout_s`` (then it is killed),
    raises a one-line ValueError that names ``--save`` and ``--web``: logging to it would wait forever."""
    if _port_answers(port):
        return
    executable = _viewer_executable()
    # The viewer's own output goes to a file without a name (it keeps it open while it runs); only the reason a
    # failed start gives is shown, in the command's one error line.
    with tempfile.TemporaryFile() as log:
        viewer = subprocess.Popen(
            [executable, f"--port={port}", "--memory-limit=75%", "--expect-data-soon"],
            stdin=subprocess.DEVNULL, stdout=log, stderr=log, env={**os.environ, "RERUN_APP_ONLY": "true"},
            start_new_session=True,  # Ctrl-C in the terminal and the command's exit leave the window open
        )
        deadline = time.monotonic() + timeout_s
        while not _port_answers(port):
            if viewer.poll() is not None:
                raise ValueError(
                    f"rerun's viewer cannot open a window on {_display()} ({_last_words(log, viewer.returncode)}): {NO_WINDOW_ADVICE}"
                )
            if time.monotonic() > deadline:
                viewer.kill()
                viewer.wait()
                raise ValueError(
                    f"rerun's viewer did not start within {timeout_s:g} s on {_display()} (does the display answer?): {NO_WINDOW_ADVICE}"
                )
            time.sleep(0.1)


def _port_answers(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.5):
            return True
    except OSError:
        return False


def _viewer_executable() -> str:
    """The viewer binary shipped with the rerun SDK in use (same version as the SDK), else ``rerun`` on PATH."""
    import rerun_cli

    bundled = Path(rerun_cli.__file__).parent / "rerun"
    found = str(bundled) if bundled.is_file() else shutil.which("rerun")
    if found is None:
        raise ValueError(f"rerun's viewer is not installed (reinstall rerun-sdk): {NO_WINDOW_ADVICE}")
    return found


def _display() -> str:
    names = [f"{name}={os.environ[name]}" for name in ("DISPLAY", "WAYLAND_DISPLAY") if os.environ.get(name)]
    return " and ".join(names) or "this machine"


def _last_words(log: BinaryIO, status: int) -> str:
    """The reason in the viewer's last line (``Error: ...: Failed to open connection to X server``), or its status."""
    log.seek(0)
    text = re.sub(r"\x1b\[[0-9;]*m", "", log.read().decode(errors="replace"))  # its log lines are coloured
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    reason = lines[-1].rsplit(": ", 1)[-1] if lines else ""
    return reason if reason else f"it exited with status {status}"


def check_port_free(port: int, option: str) -> None:
    """Raise a one-line ValueError if ``port`` cannot be served on (rerun only logs an error, then serves nothing)."""
    if not 1 <= port <= 65535:
        raise ValueError(f"{option} must be a port number in 1..65535, got {port}")
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server does: a closed port is free
        try:
            probe.bind(("0.0.0.0", port))
        except OSError as error:
            raise ValueError(f"port {port} is not free ({error.strerror}): choose another with {option}") from None


def default_save_name(root: Path, episode: int, pair: bool) -> str:
    """File name suggested when ``--save`` names a folder."""
    return f"{root.name}_episode_{episode}{'_pair' if pair else ''}.rrd"


def view_episode(
    root: Path,
    episode: int,
    pair: bool = False,
    pair_root: Path | None = None,
    save: Path | None = None,
    web: WebPorts | None = None,
    announce: Callable[[str], None] = lambda line: print(line, flush=True),
) -> str:
    """Log the episode (and its pair) to rerun: save an ``.rrd``, serve the web viewer, or spawn the viewer.

    With ``web`` this blocks, serving, until Ctrl-C (the servers live as long as the recording stream);
    ``announce`` gets the line with the URL first. Returns what was shown (or served).
    """
    import rerun as rr

    from mosaic_data.recording_files import rerun_file

    sidecar = _sidecar(root)
    record = _episode_record(sidecar, episode, root)
    shown = [(record["robot"], root, record)]
    if pair:
        pair_root = pair_root or _sibling_of_other_robot(root, record["robot"])
        pair_sidecar = _sidecar(pair_root)
        partner = _same_variation_episode(pair_sidecar, record)
        if partner is None:
            raise ValueError(f"{pair_root} has no episode of {record['task']} variation {record['variation']} to pair with")
        shown.append((partner["robot"], pair_root, partner))
    application_id, recording_id = "mosaic_dataset", f"{repo_id_of(root)}/episode_{episode}"
    blueprint = _blueprint([role for role, _, _ in shown])
    names = ", ".join(f"{role} episode {r['episode_index']}" for role, _, r in shown)
    shown_what = f"{names} of '{_description(sidecar, record)}'"

    def log_all(recording) -> None:
        for role, dataset_root, episode_record in shown:
            _log_episode(recording, role, dataset_root, episode_record, sidecar_of=_sidecar(dataset_root))

    if save is not None:
        with rerun_file(save, application_id, blueprint, recording_id=recording_id) as recording:
            log_all(recording)
        return f"{shown_what} saved to {save} (open with: rerun {save})"
    recording = rr.RecordingStream(application_id, recording_id=recording_id)
    if web is not None:
        check_port_free(web.web, "--web-port")
        check_port_free(web.grpc, "--grpc-port")
        # The blueprint is sent after the server is up, not as serve_grpc's default_blueprint: serve_grpc waits for
        # rerun's server thread while holding the GIL, and that thread, dropping the blueprint's NumPy-backed arrow
        # buffers, waits for the GIL (seen with py-spy: a hang that left the web port unbound on a loaded machine).
        recording.serve_grpc(grpc_port=web.grpc)
        recording.send_blueprint(blueprint, make_active=True, make_default=True)
        rr.serve_web_viewer(web_port=web.web, open_browser=False, connect_to=f"rerun+http://localhost:{web.grpc}/proxy")
        log_all(recording)
        try:  # an unbounded flush would wait forever for a server that did not come up
            recording.flush(timeout_sec=SERVE_FLUSH_TIMEOUT_S)
        except Exception as error:  # rerun raises a plain RuntimeError (or its own error type) on the timeout
            recording.disconnect()
            raise ValueError(
                f"rerun's server on --grpc-port {web.grpc} did not take the recording within "
                f"{SERVE_FLUSH_TIMEOUT_S:.0f} s ({_first_line(error)}): "
                "choose other ports with --web-port/--grpc-port, or write a file with --save"
            ) from None
        announce(f"{shown_what} served at {web.url()} (open it in a browser; Ctrl-C to stop)")
        try:
            while True:
                time.sleep(3600)
        except KeyboardInterrupt:
            pass
        # No disconnect: everything was flushed before serving began, and `mosaic-data view --web` ends the process
        # right after this returns, so there is nothing left to send. Disconnecting tears rerun's servers down
        # one by one; on loaded CI machines the exit after Ctrl-C has taken minutes, and this is one step less.
        return "stopped serving"
    start_viewer()
    recording.connect_grpc(f"rerun+http://127.0.0.1:{VIEWER_PORT}/proxy", default_blueprint=blueprint)
    log_all(recording)
    try:  # a viewer that dies while receiving must not leave the command waiting
        recording.flush(timeout_sec=VIEWER_FLUSH_TIMEOUT_S)
    except Exception as error:  # rerun raises a plain RuntimeError (or its own error type) on the timeout
        recording.disconnect()
        raise ValueError(f"rerun's viewer did not take the recording within {VIEWER_FLUSH_TIMEOUT_S:.0f} s ({_first_line(error)}): {NO_WINDOW_ADVICE}") from None
    return f"{shown_what} sent to the rerun viewer"


def _first_line(error: BaseException) -> str:
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__


def _sidecar(root: Path) -> dict:
    """The sidecar matched to the current LeRobot episodes (also after lerobot-edit-dataset renumbered them)."""
    if not is_lerobot_dataset(root):
        raise ValueError(f"{root} is not a LeRobot dataset (no meta/info.json)")
    return read_aligned_sidecar(root).sidecar


def _episode_record(sidecar: dict, episode: int, root: Path) -> dict:
    records = {record["episode_index"]: record for record in sidecar["episodes"]}
    if episode not in records:
        raise ValueError(f"--episode {episode} is not an episode of {root} with a sidecar record: choose one of {listed(sorted(records))}")
    return records[episode]


def _sibling_of_other_robot(root: Path, robot: str) -> Path:
    suffix = f"_{robot}"
    if not root.name.endswith(suffix):
        raise ValueError(f"cannot guess the other robot's dataset for {root}: give it with --pair-with")
    sibling = root.with_name(root.name[: -len(suffix)] + f"_{OTHER_ROBOT[robot]}")
    if not is_lerobot_dataset(sibling):
        raise ValueError(f"--pair needs the {OTHER_ROBOT[robot]} dataset {sibling}: collect it, or give another with --pair-with")
    return sibling


def _same_variation_episode(sidecar: dict, record: dict) -> dict | None:
    """The other robot's episode of the same variation, same slot if there is one (else the first)."""
    candidates = [r for r in sidecar["episodes"] if r["task"] == record["task"] and r["variation"] == record["variation"]]
    same_slot = [r for r in candidates if r["slot"] == record["slot"]]
    return (same_slot or candidates or [None])[0]


def _description(sidecar: dict, record: dict) -> str:
    return sidecar["tasks"][record["task"]]["variations"][record["variation"]]["description"]


def _blueprint(roles: list[str]):
    """One column per role, its episode description on top.

    Each text view gets one document: rerun shows a single text document per view, and a shared ``episode``
    view over ``/description`` (both roles' documents) showed "Can only show one text document at a time".
    """
    import rerun.blueprint as rrb

    columns = [
        rrb.Vertical(
            rrb.TextDocumentView(origin=f"/description/{role}", name=f"{role}: episode"),
            rrb.Spatial2DView(origin=f"/{role}/camera", name=f"{role}: agentview"),
            rrb.TimeSeriesView(origin=f"/{role}/action", name=f"{role}: action (target pose, gripper)"),
            rrb.TimeSeriesView(origin=f"/{role}/state", name=f"{role}: state"),
            rrb.TimeSeriesView(origin=f"/{role}/success", name=f"{role}: success"),
            row_shares=[2, 4, 2, 2, 1],
        )
        for role in roles
    ]
    return rrb.Blueprint(rrb.Horizontal(*columns), rrb.TimePanel(timeline="time"), collapse_panels=True)


def _log_episode(recording, role: str, root: Path, record: dict, sidecar_of: dict) -> None:
    import rerun as rr
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from mosaic_data.recording_files import jpeg_bytes

    dataset = LeRobotDataset(repo_id_of(root), root=root, episodes=[record["episode_index"]])
    recording.log(
        f"/description/{role}",
        rr.TextDocument(
            f"{role}: {record['task']} variation {record['variation']}: {_description(sidecar_of, record)}\n"
            f"episode {record['episode_index']}, seed {record['seed']}, {record['length']} frames, "
            f"{record['attempts'] - 1} expert retries"
        ),
        static=True,
    )
    for name in ACTION_NAMES:
        recording.log(f"/{role}/action/{name}", rr.SeriesLines(names=name), static=True)
    for step in range(len(dataset)):
        frame = dataset[step]
        recording.set_time("frame", sequence=step)
        recording.set_time("time", duration=step / FPS)
        image = (frame[CAMERA_KEY].permute(1, 2, 0).numpy() * 255.0).round().astype(np.uint8)
        recording.log(f"/{role}/camera", rr.EncodedImage(contents=jpeg_bytes(image), media_type="image/jpeg"))
        for name, value in zip(ACTION_NAMES, frame["action"].tolist()):
            recording.log(f"/{role}/action/{name}", rr.Scalars(value))
        state = frame["observation.state"].tolist()
        for name, value in zip(["x", "y", "z"], state[:3]):
            recording.log(f"/{role}/state/{name}", rr.Scalars(value))
        recording.log(f"/{role}/state/gripper_opening", rr.Scalars(state[-1]))
        recording.log(f"/{role}/success", rr.Scalars(float(bool(frame["next.success"]))))
