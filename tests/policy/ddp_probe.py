"""lerobot-train with a recorder, for the multi-process test (test_multi_process_training.py).

Run as ``accelerate launch ... tests/policy/ddp_probe.py <lerobot-train arguments>``: every process runs LeRobot's
own ``lerobot_train.main()`` unchanged; the recorder only wraps three of the toolkit's functions to note, per
rank, what the rank trained on and paired, and writes them to ``$MOSAIC_DDP_PROBE_DIR/rank<r>.json`` with the
rank's final policy state (``rank<r>.safetensors``) when training ends:

- every batch the rank's policy was asked to pair: the dataset ``index`` of each sample, its task string, and the
  variation / instance of the demonstrator frames it got (read back from the frame colours of the test datasets);
- the demonstrator sampler's RNG seed material and its decode threads;
- a digest of torch's global RNG state after every training forward (augmentations and contrastive positives
  draw from it);
- the loss weights of every batch;
- the policy's ``update()`` calls.
"""

import hashlib
import json
import os
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).parents[2]))  # the repository root, for tests.helpers

from safetensors.torch import save_file

from mosaic_policy.common.demo_conditioned_policy import DemoConditionedPolicy
from mosaic_policy.common.demo_conditioning import DemoConditioning
from tests.helpers.policy import read_variation_rank

RANK = int(os.environ.get("RANK", "0"))
OUT = Path(os.environ["MOSAIC_DDP_PROBE_DIR"])
record: dict = {"rank": RANK, "batches": [], "rng_digests": [], "updates": 0}
policies: list = []

_demo_frames = DemoConditioning.demo_frames


def demo_frames(self, batch):
    frames = _demo_frames(self, batch)
    pairs = [read_variation_rank((f[0] * 255).round().to(torch.uint8)) for f in frames]
    record["batches"].append(
        {"index": [int(i) for i in batch["index"].reshape(-1).tolist()], "task": list(batch["task"]), "demo": pairs}
    )
    sampler = self.sampler
    record["sampler"] = {"seed_entropy": str(sampler.rng.bit_generator.seed_seq.entropy),
                         "spawn_key": list(sampler.rng.bit_generator.seed_seq.spawn_key),
                         "threads": sampler.threads, "process_index": getattr(sampler, "process_index", None)}
    return frames


_sample_weights = DemoConditioning.sample_weights


def sample_weights(self, batch, n_samples, device, *args, **kwargs):
    weights = _sample_weights(self, batch, n_samples, device, *args, **kwargs)
    record.setdefault("weights", []).append([float(w) for w in weights])
    return weights


_forward = DemoConditionedPolicy.forward


def forward(self, batch, reduction="mean"):
    if not policies:
        policies.append(self)
        if hasattr(self, "update"):  # count lerobot-train's update() calls, the policy's own method unchanged
            original = self.update

            def update():
                original()
                record["updates"] += 1

            self.update = update
    out = _forward(self, batch, reduction)
    record["rng_digests"].append(hashlib.sha1(torch.get_rng_state().numpy().tobytes()).hexdigest())
    return out


DemoConditioning.demo_frames = demo_frames
DemoConditioning.sample_weights = sample_weights
DemoConditionedPolicy.forward = forward

if __name__ == "__main__":
    from lerobot.scripts.lerobot_train import main

    main()
    OUT.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().cpu().contiguous() for k, v in policies[0].state_dict().items()}
    save_file(state, str(OUT / f"rank{RANK}.safetensors"))
    (OUT / f"rank{RANK}.json").write_text(json.dumps(record))
