"""One-shot evaluation by simulated rollouts (`mosaic-eval`) and the LeRobot environment (`--env.type=mosaic`).

Modules: plan.py (what runs, input checks), agents.py (checkpoint / untrained / expert), demo_sources.py
(where demonstrations come from), rollouts.py (one episode, seeds), runner.py (worker processes),
report.py (tables, JSON, Markdown), recording.py (rerun), cli.py (`mosaic-eval`), lerobot_env.py
(`lerobot-eval --env.type=mosaic`).
"""
