"""One-shot evaluation by simulated rollouts (`mosaic-eval`) and the LeRobot environment (`--env.type=mosaic`).

Modules: plan.py (what runs, input checks), agents.py (checkpoint of any LeRobot type / untrained / expert),
seeds.py and demo_sources.py (the seed rule and where demonstrations come from, shared by both front-ends),
rollouts.py (one episode, which variation was achieved), runner.py (worker processes), report.py (tables, JSON,
Markdown), intervals.py (95% Wilson intervals of success rates), confusion.py (which variation the agent did:
matrices, heat maps), recording.py (rerun), cli.py (`mosaic-eval`),
lerobot_env.py (`lerobot-eval --env.type=mosaic`).
"""
