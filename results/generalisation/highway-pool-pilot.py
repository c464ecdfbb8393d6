# Twenty-third session: the offline pilot of docs/notes/generalisation.md ("three world models pooled on highway's unseen
# ranking"): AUROC of the per-step mean fear of the cached models. Run from the repository root:
#   PYTHONPATH=. .venv/bin/python results/generalisation/highway-pool-pilot.py
import json, numpy as np
from core.metrics import auroc
from studies.generalisation import labels_within
def load(name):
    d = json.load(open(f"results/generalisation/{name}.json"))
    ks = sorted(k for k in d if k.startswith("signals"))
    parts = [d[k] for k in ks]
    ep = np.concatenate([np.asarray(p["episode"]) + 1000000 * i for i, p in enumerate(parts)])
    vio = np.concatenate([np.asarray(p["violation"], bool) for p in parts])
    fear = np.concatenate([np.asarray(p["fear"], float) for p in parts])
    return ep, vio, fear
ep0, v0, f0 = load("highway-approach-committed")
ep1, v1, f1 = load("highway-approach-s0")
ep2, v2, f2 = load("highway-approach-s1")
assert (ep0 == ep1).all() and (v0 == v1).all() and (ep0 == ep2).all() and (v0 == v2).all()
lab = labels_within(v0, ep0, 10)
print("steps", len(lab), "positives", lab.sum())
for name, f in [("committed", f0), ("s0", f1), ("s1", f2), ("s0+s1", (f1 + f2) / 2), ("all three", (f0 + f1 + f2) / 3)]:
    print(f"{name:10s} {auroc(f, lab):.4f}")
