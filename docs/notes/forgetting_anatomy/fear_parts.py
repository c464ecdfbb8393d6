import sys, numpy as np, torch
torch.set_num_threads(1)
from core.agents import load_agent
from core.loop import Runner
import sims
d = sims.descriptor("ugv")
from core.experts import ScriptedExpert
for v in sys.argv[1:]:
    agent = load_agent(v)
    gate = agent.make_gate()
    env = d.make("ugv-fields:test:1")
    rows = []
    def rec(r, gate=gate):
        det = gate.detail
        rows.append((det.cost, det.sigma, getattr(det, "fear", np.nan), r.takeover, float(np.abs(r.action[0]))))
    try:
        run = Runner(env, agent.policy, gate, ScriptedExpert(), seed=3_000_000, deterministic=True)
        run.step_listeners.append(rec)
        for _ in range(2):
            run.run_episode()
    finally:
        env.close()
    a = np.array(rows, float)
    print(v.split("/")[-1], "steps", len(a), "cost %.3f sigma %.3f fear %.3f takeover %.2f |a0| %.2f" % tuple(np.nanmean(a, 0)))
