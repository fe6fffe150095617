"""Data safety of collect and merge: repo ids that are folders, resumable --overwrite, duplicated episodes, killed
merges, a full disk, and error lines that say everything. Real collections, real merges, real kills; the full
disk is a real small tmpfs in a private mount namespace (skipped where the kernel does not allow one)."""

from __future__ import annotations

import io
import json
import shutil
import signal
import subprocess
import sys
import time
from contextlib import redirect_stdout
from pathlib import Path

import pytest
from tests.helpers.cli_errors import one_line_error

from mosaic_data.collection.metadata import read_sidecar
from mosaic_data.collection.plan import episode_seed
from mosaic_data.collection.validate import validate_dataset



@pytest.fixture(scope="module")
def size(image_size) -> str:
    """The shared collection's image size as ``--image-size`` takes it."""
    return f"{image_size[0]}x{image_size[1]}"



def _tree(folder: Path) -> dict[str, int]:
    """Every file under ``folder`` with its size: what "nothing was touched" is checked against."""
    return {str(p.relative_to(folder)): p.stat().st_size for p in sorted(folder.rglob("*")) if p.is_file()}


def _collect_quietly(cli, *args: str) -> tuple[int, str]:
    stdout = io.StringIO()
    with redirect_stdout(stdout):
        status = cli("collect", "--task", "door", "--robot", "panda", "--episodes", "1", "--quiet", *args)
    return status, stdout.getvalue()


@pytest.fixture(scope="module")
def other_panda(tmp_path_factory, cli, size) -> Path:
    """A real door/panda collection that merges with the shared one: same image size, other episodes (seed 7).
    Asked with 3 workers for its single shard, so its report tells how many workers really ran."""
    output = tmp_path_factory.mktemp("other")
    status, stdout = _collect_quietly(cli, "--variations", "0", "--seed", "7", "--workers", "3",
                                      "--image-size", size, "--output-dir", str(output))
    assert status == 0
    (output / "collect_stdout.txt").write_text(stdout)
    return output / "mosaic" / "door_panda"


@pytest.fixture(scope="module")
def small_panda(tmp_path_factory, cli) -> Path:
    """A real door/panda collection at another image size (48x88)."""
    output = tmp_path_factory.mktemp("small")
    status, _ = _collect_quietly(cli, "--variations", "1", "--seed", "3", "--workers", "1",
                                 "--image-size", "48x88", "--output-dir", str(output))
    assert status == 0
    return output / "mosaic" / "door_panda"


@pytest.fixture
def shared_folder(tmp_path, door_output, other_panda) -> Path:
    """An output folder holding two datasets and a file of the user's: what a bad --repo-id could destroy."""
    output = tmp_path / "shared"
    shutil.copytree(door_output / "mosaic" / "door_panda", output / "mosaic" / "door_panda")
    shutil.copytree(other_panda, output / "mosaic" / "other_panda")
    (output / "notes.txt").write_text("the user's own file")
    return output


# ---------------------------------------------------------------------- 1. repo ids and --overwrite
@pytest.mark.parametrize("repo_id", ["mosaic/door_panda", "you/mosaic_door_panda", "a/b.c-d_e"])
def test_check_repo_id_accepts_namespace_and_name(repo_id):
    from mosaic_data.collection.schema import check_repo_id

    assert check_repo_id(repo_id) == repo_id


@pytest.mark.parametrize("repo_id", ["", "mosaic", "mosaic/", "/mosaic", "../escape", "mosaic/../x", "mosaic/..",
                                     "/tmp/abs/x", "a/b/c", "mosaic/.hidden", "mosaic/door panda", "ns/a--b"])
def test_check_repo_id_refuses_anything_else_naming_the_flag(repo_id):
    from mosaic_data.collection.schema import check_repo_id

    with pytest.raises(ValueError, match="^--demo-repo-id .* is not a repo id: give namespace/name"):
        check_repo_id(repo_id, flag="--demo-repo-id")


@pytest.mark.parametrize("repo_id", ["mosaic", "", "../escape", "mosaic/../escape", "ABSOLUTE"])
def test_merge_overwrite_with_a_bad_repo_id_touches_nothing(shared_folder, tmp_path, cli, capsys, repo_id):
    if repo_id == "ABSOLUTE":
        repo_id = str(tmp_path / "elsewhere" / "merged")
    before = _tree(tmp_path)
    status = cli("merge", "mosaic/door_panda", "mosaic/other_panda", "--repo-id", repo_id, "--overwrite",
                 "--output-dir", str(shared_folder))
    assert status == 2
    one_line_error(capsys, "--repo-id", "is not a repo id", "namespace/name")
    assert _tree(tmp_path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shared"]


def test_merge_overwrite_replaces_only_a_dataset_folder(shared_folder, cli, capsys):
    keep = shared_folder / "mosaic" / "keep"
    (keep / "mine").mkdir(parents=True)
    (keep / "mine" / "results.csv").write_text("1,2,3\n")
    before = _tree(shared_folder)
    status = cli("merge", "mosaic/door_panda", "mosaic/other_panda", "--repo-id", "mosaic/keep", "--overwrite",
                 "--output-dir", str(shared_folder))
    assert status == 2
    one_line_error(capsys, str(keep), "not a LeRobot dataset", "--overwrite replaces only a dataset folder")
    assert _tree(shared_folder) == before

    # A LeRobot dataset there is replaced, as --overwrite says.
    assert cli("merge", "mosaic/door_panda", "mosaic/other_panda", "--repo-id", "mosaic/merged",
               "--output-dir", str(shared_folder)) == 0
    assert cli("merge", "mosaic/door_panda", "mosaic/other_panda", "--repo-id", "mosaic/merged", "--overwrite",
               "--output-dir", str(shared_folder)) == 0
    assert len(read_sidecar(shared_folder / "mosaic" / "merged")["episodes"]) == 5


def test_collect_overwrite_never_replaces_a_folder_of_other_things(tmp_path, cli, capsys):
    folder = tmp_path / "mosaic" / "door_panda"
    folder.mkdir(parents=True)
    (folder / "thesis.tex").write_text("months of work")
    status = cli("collect", "--task", "door", "--robot", "panda", "--variations", "0", "--episodes", "1", "--overwrite",
                 "--workers", "1", "--image-size", "48x88", "--quiet", "--output-dir", str(tmp_path))
    assert status == 2
    one_line_error(capsys, str(folder), "not a LeRobot dataset")
    assert (folder / "thesis.tex").read_text() == "months of work"
    assert sorted(p.name for p in (tmp_path / "mosaic").iterdir()) == ["door_panda"]


# ---------------------------------------------------------------------- 5. an interrupted --overwrite resumes


def _committed_shards(staging: Path) -> list[str]:
    shards = staging / "shards"
    return sorted(p.name for p in shards.iterdir() if ".tmp-" not in p.name) if shards.is_dir() else []


def test_interrupted_overwrite_resumes_with_the_same_command(tmp_path, other_panda, cli, capsys, size):
    resume_args = ["collect", "--task", "door", "--robot", "panda", "--variations", "2,3", "--episodes", "1", "--seed", "5",
                   "--workers", "1", "--image-size", size, "--quiet", "--overwrite"]
    output = tmp_path / "out"
    root = output / "mosaic" / "door_panda"
    staging = output / "mosaic" / ".door_panda.collecting"
    shutil.copytree(other_panda, root)  # the finished dataset the --overwrite run replaces
    old = read_sidecar(root)
    command = [sys.executable, "-m", "mosaic_data.cli", *resume_args, "--output-dir", str(output)]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 300
    while not _committed_shards(staging) and time.monotonic() < deadline and process.poll() is None:
        time.sleep(0.2)
    assert process.poll() is None, process.stderr.read().decode()[-2000:]
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert _committed_shards(staging) == ["v002_e00000-00001"]
    assert read_sidecar(root) == old  # the old dataset stays until the new one is complete

    # Without --overwrite the old dataset is not replaced, and the error says how to resume.
    assert cli(*[a for a in resume_args if a != "--overwrite"], "--output-dir", str(output)) == 2
    one_line_error(capsys, "--overwrite", "resumes the unfinished --overwrite run", str(staging))

    # The same command again resumes: the committed shard is kept, only the other episode is collected.
    assert cli(*resume_args, "--output-dir", str(output)) == 0
    assert "collected 1 episodes" in capsys.readouterr().out
    assert not staging.exists()
    _, problems = validate_dataset(root)
    assert problems == []
    records = read_sidecar(root)["episodes"]
    assert [r["variation"] for r in records] == [2, 3]
    assert [r["seed"] for r in records] == [episode_seed(5, r["variation"], 0, r["attempts"] - 1) for r in records]


def test_overwrite_discards_an_unfinished_run_of_other_settings(tmp_path, cli, capsys):
    output = tmp_path / "out"
    staging = output / "mosaic" / ".door_panda.collecting"
    (staging / "shards" / "v000_e00000-00001" / "meta").mkdir(parents=True)
    (staging / "plan.json").write_text(json.dumps({"repo_id": "mosaic/door_panda", "settings": {"base_seed": 99}}))
    args = ["collect", "--task", "door", "--robot", "panda", "--variations", "0", "--episodes", "1",
            "--workers", "1", "--image-size", "48x88", "--quiet", "--output-dir", str(output)]
    assert cli(*args) == 2
    one_line_error(capsys, "other settings", "--overwrite")
    assert cli(*args, "--overwrite") == 0
    assert "collected 1 episodes" in capsys.readouterr().out
    assert not staging.exists() and read_sidecar(output / "mosaic" / "door_panda")["episodes"][0]["variation"] == 0


# ---------------------------------------------------------------------- 6. the same episodes twice
def test_merge_refuses_collections_with_the_same_episodes(door_output, tmp_path, cli, capsys):
    copy = tmp_path / "copy" / "door_panda"
    shutil.copytree(door_output / "mosaic" / "door_panda", copy)
    output = tmp_path / "out"
    original = door_output / "mosaic" / "door_panda"
    status = cli("merge", str(original), str(copy), "--repo-id", "mosaic/twice", "--output-dir", str(output))
    assert status == 2
    one_line_error(capsys, str(original), str(copy), "the same 4 episode(s)", "variation 0 seed 0",
                    "merge each collection once")
    assert not output.exists()


# ---------------------------------------------------------------------- 7. a killed merge's leftovers
def _dead_pid() -> int:
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


def test_killed_merge_leftovers_are_cleaned_by_the_next_merge(door_output, other_panda, tmp_path, cli):
    output = tmp_path / "out"
    (output / "mosaic").mkdir(parents=True)
    sources = [str(door_output / "mosaic" / "door_panda"), str(other_panda)]
    command = [sys.executable, "-m", "mosaic_data.cli", "merge", *sources, "--repo-id", "mosaic/both", "--output-dir", str(output)]
    for _attempt in range(5):  # the merge itself takes a fraction of a second: catch it while it builds
        process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        while process.poll() is None and not list((output / "mosaic").glob(".both.merging-*")):
            time.sleep(0.002)
        process.kill()
        process.wait()
        leftovers = list((output / "mosaic").glob(".both.merging-*"))
        if leftovers:
            break
        shutil.rmtree(output / "mosaic" / "both", ignore_errors=True)  # it finished first: try again
    else:
        pytest.fail("could not kill the merge while it was building")
    assert leftovers == [output / "mosaic" / f".both.merging-{process.pid}"]

    assert cli("merge", *sources, "--repo-id", "mosaic/both", "--output-dir", str(output)) == 0
    assert sorted(p.name for p in (output / "mosaic").iterdir()) == ["both"]
    summary, problems = validate_dataset(output / "mosaic" / "both")
    assert problems == [] and summary.startswith("5 episodes")


def test_merge_killed_between_its_renames_gets_the_old_dataset_back(door_output, other_panda, tmp_path, cli, capsys):
    """The one state a merge killed between ``rename(root, retired)`` and ``rename(built, root)`` leaves: the old
    dataset under ``.NAME.replaced-PID`` and nothing at NAME (set up by moving a real dataset there)."""
    output = tmp_path / "out"
    (output / "mosaic").mkdir(parents=True)
    retired = output / "mosaic" / f".both.replaced-{_dead_pid()}"
    shutil.copytree(other_panda, retired)
    old = read_sidecar(retired)
    sources = [str(door_output / "mosaic" / "door_panda"), str(other_panda)]
    assert cli("merge", *sources, "--repo-id", "mosaic/both", "--output-dir", str(output)) == 2
    one_line_error(capsys, "already exists", "--overwrite")
    assert sorted(p.name for p in (output / "mosaic").iterdir()) == ["both"]
    assert read_sidecar(output / "mosaic" / "both") == old


# ---------------------------------------------------------------------- a full disk
def _small_disk_or_skip(mountpoint: Path) -> None:
    mountpoint.mkdir(parents=True, exist_ok=True)
    probe = subprocess.run(["unshare", "-rm", "mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mountpoint)],
                           capture_output=True, text=True) if shutil.which("unshare") else None
    if probe is None or probe.returncode != 0:
        pytest.skip(f"no private mount namespace for a small tmpfs here: {probe.stderr.strip() if probe else 'no unshare'}")


def _run_on_small_disk(mountpoint: Path, size_kb: int, script: str, result: Path) -> dict:
    """Run the Python ``script`` with a ``size_kb`` tmpfs at ``mountpoint`` (gone afterwards); it writes ``result``."""
    program = mountpoint.parent / "on_small_disk.py"
    program.write_text(script)
    shell = f"mount -t tmpfs -o size={size_kb}k tmpfs {mountpoint} && exec {sys.executable} {program}"
    completed = subprocess.run(["unshare", "-rm", "sh", "-c", shell], capture_output=True, text=True, timeout=600)
    assert completed.returncode == 0 and result.is_file(), completed.stderr[-3000:]
    return json.loads(result.read_text())


INNER_HELPERS = '''
import json, subprocess, sys
from pathlib import Path

def cli(*args):
    done = subprocess.run([sys.executable, "-m", "mosaic_data.cli", *args], capture_output=True, text=True)
    lines = [l for l in done.stderr.splitlines() if l.startswith("mosaic-data")]
    return {"rc": done.returncode, "errors": lines, "stdout": done.stdout, "tail": done.stderr[-2000:]}

def tree(folder):
    return sorted(str(p.relative_to(folder)) for p in Path(folder).rglob("*"))
'''


def test_disk_full_during_merge_loses_nothing(door_output, other_panda, tmp_path):
    disk = tmp_path / "disk"
    _small_disk_or_skip(disk)
    sources = [door_output / "mosaic" / "door_panda", other_panda]
    source_trees = [_tree(source) for source in sources]
    sizes_kb = [sum(_tree(source).values()) // 1024 for source in sources]
    size_kb = sizes_kb[1] + 64 + sum(sizes_kb) // 3  # the old dataset fits, the merged one does not
    result = tmp_path / "result.json"
    script = INNER_HELPERS + f'''
from mosaic_data.collection.metadata import read_sidecar
from mosaic_data.collection.validate import validate_dataset
import shutil
disk = Path({str(disk)!r})
shutil.copytree({str(other_panda)!r}, disk / "mosaic" / "both")  # the dataset --overwrite would replace
before = read_sidecar(disk / "mosaic" / "both")
run = cli("merge", {str(sources[0])!r}, {str(sources[1])!r}, "--repo-id", "mosaic/both", "--overwrite", "--output-dir", str(disk))
run["tree"] = tree(disk / "mosaic")
run["unchanged"] = read_sidecar(disk / "mosaic" / "both") == before
run["problems"] = validate_dataset(disk / "mosaic" / "both")[1]
Path({str(result)!r}).write_text(json.dumps(run))
'''
    run = _run_on_small_disk(disk, size_kb, script, result)
    assert run["rc"] == 1, run
    assert len(run["errors"]) == 1 and "Traceback" not in run["tail"], run["tail"]
    error = run["errors"][0]
    assert error.startswith("mosaic-data: error: no space left on the disk holding") and str(disk / "mosaic") in error
    assert "nothing was lost" in error and "free some space" in error
    assert not [name for name in run["tree"] if name.startswith(".")], run["tree"]  # the partial build is gone
    assert run["unchanged"] and run["problems"] == []
    assert [_tree(source) for source in sources] == source_trees


def test_disk_full_during_collects_final_merge_keeps_the_shards(tmp_path, size):
    disk = tmp_path / "disk"
    _small_disk_or_skip(disk)
    result = tmp_path / "result.json"
    args = ["collect", "--task", "door", "--robot", "panda", "--variations", "0", "--episodes", "1", "--seed", "7",
            "--workers", "1", "--image-size", size, "--quiet", "--output-dir", str(disk)]
    script = INNER_HELPERS + f'''
import subprocess
disk = Path({str(disk)!r})
full = cli(*{args!r})
full["tree"] = tree(disk / "mosaic")
subprocess.run(["mount", "-o", "remount,size=8m", "tmpfs", str(disk)], check=True)  # space freed
again = cli(*{args!r})
from mosaic_data.collection.validate import validate_dataset
again["tree"] = tree(disk / "mosaic")
again["problems"] = validate_dataset(disk / "mosaic" / "door_panda")[1]
Path({str(result)!r}).write_text(json.dumps({{"full": full, "again": again}}))
'''
    # About 170 KB for the one shard: it fits in 300 KB, the merged dataset beside it does not.
    runs = _run_on_small_disk(disk, 300, script, result)
    full, again = runs["full"], runs["again"]
    assert full["rc"] == 1 and len(full["errors"]) == 1 and "Traceback" not in full["tail"], full["tail"]
    assert "no space left on the disk holding" in full["errors"][0] and "nothing was lost" in full["errors"][0]
    assert "the finished shards stay in" in full["errors"][0]
    assert ".door_panda.collecting/shards/v000_e00000-00001/meta/info.json" in full["tree"]
    assert not [name for name in full["tree"] if ".merging-" in name or name.startswith("door_panda")]
    assert again["rc"] == 0, again["tail"]
    assert "collected 1 episodes" not in again["stdout"]  # the kept shard was merged, not collected again
    assert again["tree"][0] == "door_panda" and again["problems"] == []


# ---------------------------------------------------------------------- messages
def test_merge_names_the_feature_and_both_shapes_in_full(door_output, small_panda, tmp_path, cli, capsys, image_size):
    output = tmp_path / "out"
    status = cli("merge", str(door_output / "mosaic" / "door_panda"), str(small_panda), "--repo-id", "mosaic/sizes",
                 "--output-dir", str(output))
    assert status == 2
    height, width = image_size
    one_line_error(capsys, str(small_panda), "feature 'observation.images.agentview' is video [48, 88, 3]",
                    f"expected video [{height}, {width}, 3]", "--image-size")
    assert not output.exists()


def test_collect_says_a_feature_is_missing(small_panda, tmp_path, cli, capsys):
    root = tmp_path / "mosaic" / "door_panda"
    shutil.copytree(small_panda, root)
    info = json.loads((root / "meta" / "info.json").read_text())
    del info["features"]["action"]  # a LeRobot dataset of another schema: no action
    (root / "meta" / "info.json").write_text(json.dumps(info))
    assert cli("collect", "--task", "door", "--robot", "panda", "--image-size", "48x88", "--output-dir", str(tmp_path)) == 2
    one_line_error(capsys, "another schema", "feature 'action' is missing, expected float32 [7]")


def test_resolve_dataset_names_a_folder_once_and_the_callers_flag(tmp_path, cli, capsys):
    from mosaic_data.collection.schema import resolve_dataset

    missing = tmp_path / "nothing_here"
    assert cli("validate", str(missing)) == 2
    error = one_line_error(capsys, "no LeRobot dataset", "with --output-dir")
    assert error.count(f"{missing}/meta/info.json") == 1
    with pytest.raises(ValueError) as raised:
        resolve_dataset("mosaic/door_panda", tmp_path, where_hint="under $HF_LEROBOT_HOME")
    assert str(raised.value).endswith("a repo id such as mosaic/door_panda under $HF_LEROBOT_HOME")
    assert "--output-dir" not in str(raised.value)


def test_collect_reports_the_workers_that_ran(other_panda):
    stdout = (other_panda.parent.parent / "collect_stdout.txt").read_text()
    assert "with 1 worker(s)" in stdout, stdout  # 3 asked, 1 shard
