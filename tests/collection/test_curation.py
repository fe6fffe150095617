"""Curation after collection: LeRobot's own edits (the real ``lerobot-edit-dataset``), broken sidecars, pushing
offline, without a network and as a dry run, and lists that say when they are cut.

The edits run on copies of the shared tiny collection (door, 4 variations, 1 episode each, both robots). The
hub is never reached: offline mode is huggingface_hub's own, a missing network is an httpx transport that
refuses to connect, and an upload replaces only the HfApi calls that would reach the hub.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from tests.helpers.cli_errors import one_line_error

from mosaic_data.collection.episode_matching import CurrentEpisode, align_sidecar, listed
from mosaic_data.collection.metadata import (
    SidecarError,
    build_sidecar,
    load_sidecar,
    read_aligned_sidecar,
    read_sidecar,
    sidecar_format_problem,
    write_sidecar,
)


def _lerobot_edit_dataset(root: Path, *options: str, home: Path) -> None:
    """The real ``lerobot-edit-dataset`` console script, in place on ``root`` (LeRobot keeps ``<root>_old``)."""
    script = Path(sys.executable).parent / "lerobot-edit-dataset"
    env = {**os.environ, "HF_LEROBOT_HOME": str(home), "HF_HUB_OFFLINE": "1"}
    command = [str(script), "--repo_id", f"mosaic/{root.name}", "--root", str(root), "--new_root", str(root), *options]
    result = subprocess.run(command, env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]


@pytest.fixture(scope="module")
def edited_output(door_output, tmp_path_factory):
    """Output dir with door_sawyer as collected, door_panda with episode 1 (variation 1) deleted by LeRobot in
    place (no sidecar: LeRobot leaves it in door_panda_old), and door_rest_panda: a copy keeping only that
    episode, with the original sidecar copied in (what the missing-sidecar error tells a user to do)."""
    output = tmp_path_factory.mktemp("edited")
    for name in ("door_panda", "door_sawyer"):
        shutil.copytree(door_output / "mosaic" / name, output / "mosaic" / name)
    rest = output / "mosaic" / "door_rest_panda"
    shutil.copytree(door_output / "mosaic" / "door_panda", rest)
    home = output / "lerobot_home"
    _lerobot_edit_dataset(output / "mosaic" / "door_panda", "--operation.type", "delete_episodes",
                          "--operation.episode_indices", "[1]", home=home)
    _lerobot_edit_dataset(rest, "--operation.type", "delete_episodes", "--operation.episode_indices", "[0, 2, 3]", home=home)
    shutil.copy(rest.with_name("door_rest_panda_old") / "meta" / "mosaic.json", rest / "meta" / "mosaic.json")
    shutil.rmtree(rest.with_name("door_rest_panda_old"))
    assert not (output / "mosaic" / "door_panda" / "meta" / "mosaic.json").exists()  # what LeRobot does
    return output



def _files(root: Path) -> dict[str, bytes]:
    return {str(path.relative_to(root)): path.read_bytes() for path in sorted(root.rglob("*")) if path.is_file()}


# ---------------------------------------------------------------------- item 1: LeRobot's own edits


def test_sidecar_follows_lerobot_delete_episodes(edited_output):
    """The records follow the renumbered episodes (by their data digest); the deleted one is kept as removed."""
    root = edited_output / "mosaic" / "door_panda"
    aligned = read_aligned_sidecar(root)
    assert aligned.from_backup and aligned.path == root.with_name("door_panda_old") / "meta" / "mosaic.json"
    records = aligned.sidecar["episodes"]
    assert [(r["episode_index"], r["variation"]) for r in records] == [(0, 0), (1, 2), (2, 3)]
    assert [r["variation"] for r in aligned.sidecar["removed_episodes"]] == [1]
    assert aligned.unrecorded == [] and aligned.changed_data == [] and aligned.loosely_matched == []
    rest = read_aligned_sidecar(edited_output / "mosaic" / "door_rest_panda")
    assert not rest.from_backup and [(r["episode_index"], r["variation"]) for r in rest.sidecar["episodes"]] == [(0, 1)]


def test_validate_accepts_lerobot_edited_dataset_with_warnings(edited_output, cli, capsys):
    assert cli("validate", "mosaic/door_panda", "--output-dir", str(edited_output)) == 0
    captured = capsys.readouterr()
    assert "OK (3 episodes" in captured.out
    assert "mosaic-data: warning:" in captured.err and "LeRobot's backup" in captured.err
    assert "1 episode of meta/mosaic.json is no longer in the dataset" in captured.err
    assert cli("validate", "mosaic/door_rest_panda", "--output-dir", str(edited_output)) == 0
    captured = capsys.readouterr()
    assert "OK (1 episode," in captured.out and "3 episodes of meta/mosaic.json are no longer" in captured.err


def test_episodes_without_record_are_a_warning(door_output, tmp_path, cli, capsys):
    root = tmp_path / "door_panda"
    shutil.copytree(door_output / "mosaic" / "door_panda", root)
    sidecar = read_sidecar(root)
    sidecar["episodes"] = sidecar["episodes"][:-1]
    write_sidecar(root, sidecar)
    assert cli("validate", str(root)) == 0
    assert "1 episode has no sidecar record (their seeds are unknown): episodes [3]" in capsys.readouterr().err


def test_view_merge_push_accept_lerobot_edited_datasets(edited_output, tmp_path, monkeypatch, cli, capsys):
    import huggingface_hub
    import huggingface_hub._upload_pipeline as upload_pipeline
    from huggingface_hub import HfApi

    # view: episode 1 is variation 2 now; its pair is the sawyer episode of variation 2
    rrd = tmp_path / "pair.rrd"
    assert cli("view", "mosaic/door_panda", "--output-dir", str(edited_output), "--episode", "1", "--pair", "--save", str(rrd)) == 0
    assert "panda episode 1, sawyer episode 2 of 'push the right door" in capsys.readouterr().out and rrd.stat().st_size > 0

    # merge: the two edited halves give back every variation; the removed records keep the counts whole
    assert cli("merge", "mosaic/door_panda", "mosaic/door_rest_panda", "--repo-id", "mosaic/door_again_panda",
               "--output-dir", str(edited_output)) == 0
    assert "4 episodes" in capsys.readouterr().out
    merged = edited_output / "mosaic" / "door_again_panda"
    assert [(r["episode_index"], r["variation"]) for r in read_sidecar(merged)["episodes"]] == [(0, 0), (1, 2), (2, 3), (3, 1)]
    assert cli("validate", str(merged)) == 0, capsys.readouterr().err

    # push: the hub gets a sidecar of exactly the 3 episodes it gets (written into the dataset first)
    calls: dict[str, list] = {"create_repo": [], "uploaded": {}}

    def pipelined_upload(api, *, repo_id, add_operations, **kwargs):
        for operation in add_operations:
            calls["uploaded"][operation.path_in_repo] = Path(operation.path_or_fileobj).read_bytes()

    def create_commit(self, repo_id, operations, **kwargs):
        for operation in operations:
            content = operation.path_or_fileobj
            calls["uploaded"][operation.path_in_repo] = content if isinstance(content, bytes) else Path(content).read_bytes()

    monkeypatch.setattr(HfApi, "create_repo", lambda self, repo_id, **kw: calls["create_repo"].append(repo_id))
    monkeypatch.setattr(HfApi, "create_commit", create_commit)
    monkeypatch.setattr(upload_pipeline, "pipelined_upload", pipelined_upload)
    monkeypatch.setattr(huggingface_hub.repocard.RepoCard, "validate", lambda self, repo_type=None: None)
    monkeypatch.setattr(HfApi, "create_tag", lambda self, repo_id, **kw: None)
    monkeypatch.setattr(HfApi, "delete_tag", lambda self, repo_id, **kw: None)
    assert cli("push", "mosaic/door_panda", "--output-dir", str(edited_output), "--repo-id", "someone/door_edited") == 0
    assert "wrote" in capsys.readouterr().err
    pushed = json.loads(calls["uploaded"]["meta/mosaic.json"])
    assert [(r["episode_index"], r["variation"]) for r in pushed["episodes"]] == [(0, 0), (1, 2), (2, 3)]
    assert [r["variation"] for r in pushed["removed_episodes"]] == [1]
    assert "3 successful episodes" in calls["uploaded"]["README.md"].decode()
    assert read_sidecar(edited_output / "mosaic" / "door_panda") == pushed


def test_changed_actions_are_still_a_problem(door_output, tmp_path):
    """Matching by data digest must not hide data that changed after collection."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from mosaic_data.collection.validate import validate_dataset

    root = tmp_path / "door_panda"
    shutil.copytree(door_output / "mosaic" / "door_panda", root)
    path = next((root / "data").rglob("*.parquet"))
    table = pq.read_table(path)
    frames = table.to_pandas()
    row = frames.index[frames["episode_index"] == 2][5]
    frames.at[row, "action"] = frames.at[row, "action"] + 0.001  # a small change: no jump, same length
    pq.write_table(pa.Table.from_pandas(frames, schema=table.schema, preserve_index=False), path)
    _, problems = validate_dataset(root)
    assert any("episodes [2]: their actions differ from the ones collected" in p for p in problems), problems


# ---------------------------------------------------------------------- item 2: broken sidecars


@pytest.mark.parametrize(
    ("broken", "words"),
    [
        (lambda sidecar: [], ["holds a list, not an object"]),
        (lambda sidecar: {**sidecar, "sources": [{k: v for k, v in sidecar["sources"][0].items() if k != "settings"}]},
         ["source 0 has no collection settings"]),
        (lambda sidecar: {k: v for k, v in sidecar.items() if k != "sources"}, ["has no 'sources'"]),
        (lambda sidecar: {**sidecar, "tasks": []}, ["its 'tasks' is not an object"]),
        (lambda sidecar: {**sidecar, "format_version": "x"}, ["its 'format_version' is \"x\", expected 1"]),
    ],
    ids=["empty-list", "no-settings", "no-sources", "tasks-a-list", "format-version-x"],
)
def test_broken_sidecar_is_one_line_naming_file_and_fix(door_output, tmp_path, cli, capsys, broken, words):
    root = tmp_path / "door_panda"
    shutil.copytree(door_output / "mosaic" / "door_panda", root)
    path = root / "meta" / "mosaic.json"
    path.write_text(json.dumps(broken(json.loads(path.read_text()))))
    assert cli("validate", str(root)) == 1
    err = capsys.readouterr().err
    problem_lines = [line for line in err.splitlines() if "mosaic.json" in line]
    assert len(problem_lines) == 1 and "Traceback" not in err, err
    for word in [str(path), "not a MOSAIC sidecar", "collect the dataset again", *words]:
        assert word in problem_lines[0], err
    assert cli("push", str(root), "--repo-id", "someone/door", "--dry-run") == 2
    one_line_error(capsys, str(path), "not a MOSAIC sidecar", *words)
    assert cli("view", str(root), "--save", str(tmp_path / "x.rrd")) == 2
    one_line_error(capsys, str(path), "not a MOSAIC sidecar")


def _small_sidecar() -> dict:
    """A well-formed sidecar of one episode, as ``mosaic-data collect`` writes it (no dataset behind it)."""
    settings = {"variations": [0], "episodes_per_variation": 1, "image_height": 56, "image_width": 96, "fps": 20}
    source = {"repo_id": "mosaic/door_panda", "task": "door", "robot": "panda", "settings": settings}
    record = {"episode_index": 0, "task": "door", "robot": "panda", "variation": 0, "seed": 0, "attempts": 1, "length": 9}
    return build_sidecar("mosaic/door_panda", [source], [record])


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"tasks": []}, "its 'tasks' is not an object"),
        ({"episodes": {}}, "its 'episodes' is not a list"),
        ({"format_version": "x"}, "its 'format_version' is \"x\", expected 1"),
        ({"format_version": 2}, "its 'format_version' is 2, expected 1"),
        ({"format_version": True}, "its 'format_version' is true, expected 1"),
        ({"format_version": None}, "its 'format_version' is null, expected 1"),
    ],
)
def test_sidecar_layout_and_version_are_checked_in_plain_words(tmp_path, change, words):
    assert sidecar_format_problem(_small_sidecar()) is None
    path = tmp_path / "mosaic.json"
    path.write_text(json.dumps(_small_sidecar() | change))
    with pytest.raises(SidecarError) as raised:
        load_sidecar(path)
    assert words in str(raised.value) and "not a MOSAIC sidecar" in str(raised.value)
    assert "\n" not in str(raised.value)


def test_a_sidecar_without_a_format_version_is_refused(tmp_path):
    sidecar = {key: value for key, value in _small_sidecar().items() if key != "format_version"}
    assert sidecar_format_problem(sidecar) == "it has no 'format_version', expected 1"


def test_missing_sidecar_says_how_to_bring_it_back(door_output, tmp_path, cli, capsys):
    root = tmp_path / "door_panda"
    shutil.copytree(door_output / "mosaic" / "door_panda", root)
    (root / "meta" / "mosaic.json").unlink()
    assert cli("push", str(root), "--repo-id", "someone/door", "--dry-run") == 2
    one_line_error(capsys, "no meta/mosaic.json", "lerobot-edit-dataset", f"into {root / 'meta'}/")


# ---------------------------------------------------------------------- item 3: offline, no network, dry run


@pytest.fixture
def panda_copy(door_output, tmp_path):
    root = tmp_path / "door_panda"
    shutil.copytree(door_output / "mosaic" / "door_panda", root)
    return root


def test_push_offline_is_one_line_and_changes_nothing(panda_copy, monkeypatch, cli, capsys):
    from huggingface_hub import constants

    monkeypatch.setattr(constants, "HF_HUB_OFFLINE", True)
    before = _files(panda_copy)
    assert cli("push", str(panda_copy), "--repo-id", "someone/door_panda") == 2
    one_line_error(capsys, "HF_HUB_OFFLINE=1", "network", "--dry-run")
    assert _files(panda_copy) == before


def test_push_without_network_is_one_line(panda_copy, monkeypatch, cli, capsys):
    import httpx
    from huggingface_hub import constants
    from huggingface_hub.utils import _http

    requests: list[str] = []

    def refuse(request: httpx.Request) -> httpx.Response:
        requests.append(str(request.url))
        raise httpx.ConnectError("[Errno -3] Temporary failure in name resolution", request=request)

    monkeypatch.setattr(constants, "HF_HUB_OFFLINE", False)
    monkeypatch.setattr(constants, "HF_HUB_DISABLE_TELEMETRY", True, raising=False)
    _http.set_client_factory(lambda: httpx.Client(transport=httpx.MockTransport(refuse)))
    try:
        assert cli("push", str(panda_copy), "--repo-id", "someone/door_panda") == 2
    finally:
        _http.set_client_factory(_http.default_client_factory)
    one_line_error(capsys, "cannot be reached", "name resolution", "network connection", "--dry-run")
    assert requests and all("huggingface.co" in url for url in requests)


def test_push_dry_run_writes_card_and_uploads_nothing(panda_copy, monkeypatch, cli, capsys):
    import httpx
    from huggingface_hub.utils import _http

    requests: list[str] = []

    def record(request: httpx.Request) -> httpx.Response:
        requests.append(str(request.url))
        raise httpx.ConnectError("no request may leave a dry run", request=request)

    _http.set_client_factory(lambda: httpx.Client(transport=httpx.MockTransport(record)))
    before = _files(panda_copy)
    try:
        assert cli("push", str(panda_copy), "--repo-id", "someone/door_panda", "--private", "--dry-run") == 0
    finally:
        _http.set_client_factory(_http.default_client_factory)
    out = capsys.readouterr().out
    card = panda_copy / "README.md"
    assert requests == []
    assert "nothing uploaded" in out and str(card) in out and "private repository" in out
    text = card.read_text()
    assert "push the left door open, away from the robot" in text and 'LeRobotDataset("someone/door_panda")' in text
    assert text.startswith("---\n") and "- mosaic" in text
    after = _files(panda_copy)
    assert after.pop("README.md") and after == before


# ---------------------------------------------------------------------- item 4: messages


def test_cut_lists_end_with_dots_and_the_count():
    assert listed([1, 2, 3]) == "[1, 2, 3]"
    assert listed(range(12)) == "[0, 1, 2, 3, 4, ...] (12 in all)"
    sidecar = {
        "tasks": {"door": {"variations": [{"index": 0, "description": "open it"}]}},
        "robots": ["panda"],
        "sources": [],
        "episodes": [{"episode_index": 0, "task": "door", "robot": "panda", "variation": 0, "seed": 7, "attempts": 1,
                      "length": 10, "data_digest": "d0"}],
    }
    current = [CurrentEpisode(index, 10, "open it", 0, f"d{index}") for index in range(8)]
    aligned = align_sidecar(sidecar, current, Path("meta/mosaic.json"))
    assert aligned.unrecorded == [1, 2, 3, 4, 5, 6, 7]
    assert "7 episodes have no sidecar record (their seeds are unknown): episodes [1, 2, 3, 4, 5, ...] (7 in all)" in aligned.warnings(Path("x"))


def test_push_not_logged_in_is_one_line(panda_copy, monkeypatch, cli, capsys):
    import httpx
    from huggingface_hub import constants
    from huggingface_hub.utils import _http

    monkeypatch.setattr(constants, "HF_HUB_OFFLINE", False)
    unauthorized = httpx.MockTransport(lambda request: httpx.Response(401, json={"error": "Invalid username or password."}))
    _http.set_client_factory(lambda: httpx.Client(transport=unauthorized))
    before = _files(panda_copy)
    try:
        assert cli("push", str(panda_copy), "--repo-id", "someone/door_panda") == 2
    finally:
        _http.set_client_factory(_http.default_client_factory)
    one_line_error(capsys, "refused", "401", "hf auth login", "--dry-run")
    assert _files(panda_copy) == before
