"""The one-command learning run (collect -> lerobot-train -> mosaic-eval of every checkpoint) end to end, tiny."""

import json
import subprocess
import sys


def test_policy_learning_runs_every_stage_and_writes_the_curve(tmp_path):
    output = tmp_path / "run"
    command = [sys.executable, "-m", "pipelines.bench.policy_learning", "--task", "door", "--variations", "0,2",
               "--preset", "smoke", "--workers", "1", "--output", str(output),
               "--", "--policy.n_attention_heads=2", "--policy.embed_dim=32", "--policy.head_hidden_dim=32"]
    result = subprocess.run(command, capture_output=True, text=True, timeout=900, cwd=tmp_path)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    results = json.loads((output / "results.json").read_text())
    assert [point["step"] for point in results["learning_curve"]] == [2, 4]
    final = results["final"]
    assert set(final["per_variation"]) == {"0", "2"}
    assert final["confusion"]["rows"] == [0, 2] and final["confusion"]["columns"] == [0, 1, 2, 3, "none"]
    assert sum(map(sum, final["confusion"]["counts"])) == 2  # one episode per variation
    assert (output / "learning_curve.png").stat().st_size > 10_000
    assert list((output / "eval" / "step_000004").glob("confusion_door*.png"))
    # the stages are the shipped tools, with their own logs
    assert "lerobot-train" in result.stdout and "mosaic-eval" in result.stdout
    assert (output / "train" / "checkpoints" / "000004" / "pretrained_model" / "model.safetensors").is_file()
    # runs of several policies side by side (here one): a table from the results, and a bar chart
    table = subprocess.run(
        [sys.executable, "-m", "pipelines.bench.learning_table", str(output), "--png", str(tmp_path / "bars.png")],
        capture_output=True, text=True, timeout=120, cwd=tmp_path,
    )
    assert table.returncode == 0, table.stderr[-2000:]
    assert f"| mosaic | 4 | {100 * final['success']:.0f}% |" in table.stdout
    assert (tmp_path / "bars.png").stat().st_size > 10_000
