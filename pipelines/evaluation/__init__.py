"""One-shot evaluation by simulated rollouts (`mosaic-eval`) and the LeRobot environment (`--env.type=mosaic`).

Modules: plan.py (what runs, input checks), agents.py (checkpoint of any LeRobot type / untrained / expert),
demo_sources.py (where demonstrations come from), rollouts.py (one episode, seeds, which variation was achieved),
runner.py (worker processes), report.py (tables, JSON, Markdown), confusion.py (which variation the agent did:
matrices, heat maps), recording.py (rerun), cli.py (`mosaic-eval`), lerobot_env.py (`lerobot-eval --env.type=mosaic`).
"""
