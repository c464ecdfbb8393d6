"""A copy of a policy whose configuration says it was trained as another method (same weights, same world model).

    .venv/bin/python results/as_method.py SOURCE METHOD OUT

For diagnoses that run the fine-tuning rounds with another learner on the same starting weights
(``--set study.policy=OUT --set finetune.adapt_as_sage=false``): the learner is built from the checkpoint's
configuration, so the rounds then train as METHOD. The gate's settings and the world model are kept (METHOD's preset
switches are applied over the source's configuration, the world model kept on for the gate)."""

from __future__ import annotations

import sys
from pathlib import Path

import torch

from core.agents import FINAL_CHECKPOINT, load_checkpoint
from core.sage.config import for_method, from_dict, to_dict


def main(source: str, method: str, out: str) -> None:
    payload = load_checkpoint(source)
    cfg = for_method(method, base=from_dict(payload["agent_config"]))
    cfg.world_model = True  # the gate reads it
    payload["agent_config"] = to_dict(cfg)
    payload["meta"]["method"] = method
    payload["meta"]["extra"] = {**payload["meta"].get("extra", {}), "relabelled_from": str(source)}
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    torch.save({k: v for k, v in payload.items() if k != "file"}, folder / FINAL_CHECKPOINT)
    print(f"{folder / FINAL_CHECKPOINT}: {source} as {method}")


if __name__ == "__main__":
    main(*sys.argv[1:4])
