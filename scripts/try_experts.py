import time, sys, numpy as np, imageio.v2 as imageio
from mosaic_data.tasks import make_task_env
from mosaic_data.experts import make_expert
task=sys.argv[1]; robots=sys.argv[2].split(","); seeds=range(int(sys.argv[3])); video=len(sys.argv)>4
for robot in robots:
  for v in range(len(make_task_env.__globals__['get_task_class'](task).variations)):
    env = make_task_env(task, v, robot)
    succ=[]; lens=[]
    for seed in seeds:
        env.reset_to_seed(seed); ex=make_expert(env); frames=[]
        for t in range(env.horizon):
            a=ex.act(); env.step(a)
            if video and seed==0: frames.append(env.render_agentview())
            if env.check_success(): break
        succ.append(env.check_success()); lens.append(t+1)
        if not succ[-1]: print("  fail", robot, v, seed, ex.phase_name, [round(env.opening_angle(d),2) for d in ("left","right")] if task=="door" else "")
        if frames: imageio.mimsave(f"/tmp/{task}_{robot}_{v}.mp4", frames, fps=20)
    print(task, robot, v, np.mean(succ), np.mean(lens), flush=True)
