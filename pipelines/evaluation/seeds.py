"""The seed rule of one-shot evaluation, in one place for both front-ends (``mosaic-eval`` and ``lerobot-eval
--env.type=mosaic``), so that the same ``--seed`` gives the same instances, demonstrations and numbers in both.

LeRobot's evaluation loop decides the episode seed: it resets the environment of every variation with
``--seed + episode`` and knows nothing of variations or demonstrations. Everything else follows from that seed
and the variation, here (constants and the rule in :mod:`mosaic_data.constants`): ``mosaic-eval`` computes the
same episode seed from its ``--seed`` and hands it to :func:`episode_seeds` as the environment does.
No torch, LeRobot or simulator: ``mosaic-eval``'s plan and the LeRobot plugin import it at no cost.
"""

from __future__ import annotations

from dataclasses import dataclass

from mosaic_data.constants import DEMO_RETRY_STRIDE, DEMO_SEED_OFFSET, SEED_STRIDE_VARIATION

SEED_RULE = (
    f"episode seed s = seed + episode (as lerobot-eval resets its environments); agent instance = "
    f"s + {SEED_STRIDE_VARIATION} * variation; demonstrator = s + {SEED_STRIDE_VARIATION} * variation + "
    f"{DEMO_SEED_OFFSET} (+{DEMO_RETRY_STRIDE}, +{2 * DEMO_RETRY_STRIDE}, ... if its expert fails)"
)
"""The rule in words, for results.json's settings and the documentation."""


@dataclass(frozen=True)
class EpisodeSeeds:
    """The seeds of one evaluation episode."""

    episode: int  # s: what LeRobot's evaluation passes to ``env.reset``
    agent: int  # the agent's instance
    demo: int  # the demonstrator's first instance; the expert's retries add DEMO_RETRY_STRIDE each


def episode_seed(base_seed: int, episode: int) -> int:
    """The seed LeRobot's ``eval_policy`` resets episode ``episode`` with (its ``start_seed`` + episode index)."""
    return base_seed + episode


def episode_seeds(seed: int, variation: int) -> EpisodeSeeds:
    """The agent's and the demonstrator's instance seeds of the episode reset with ``seed`` on ``variation``:
    variations get disjoint ranges, and the demonstration always shows another instance than the agent's."""
    agent = seed + SEED_STRIDE_VARIATION * variation
    return EpisodeSeeds(episode=seed, agent=agent, demo=agent + DEMO_SEED_OFFSET)
