"""Does λ act? The actor's gradient from −Q, from the fear term and from imitation, measured in fine-tuning rounds.

Runs ``sage cycles`` in this process (the arguments after ``--`` are that command's, unchanged) with a probe on
:meth:`core.sage.sac.SAC.update`: every ``--every``-th update, before the update runs, it draws its own actor batch
(real states and the virtual share, as the actor's loss does, from its own generator, under a forked torch RNG, so
the run's own sampling is untouched) and measures, at the actions a ~ π(·|s) the loss would use:

* at the action: the mean over states of |∂(−Q)/∂a| and of |∂F/∂a|, and the fear term's share at the action,
  |∂(w F)/∂a| / (|∂(−Q)/∂a| + |∂(w F)/∂a|), with w the fear weight of the run's ``fear_scale`` and of the others
  (λ for ``none``, λ·max(1, mean|Q|) for ``q``: :func:`core.sage.sac.actor_fear_weight`);
* at the actor's parameters: the gradient norm of each term of the loss (−Q, w F, α log π, the imitation term) as
  the run weighs it (the imitation term acts on other states, so only the parameters compare it with the rest).

Writes ``fear_scale.json`` (every measurement and a summary per round) into the cycles run folder and prints the
summary. Example (the adaptation probe's command, docs/notes/adaptation_probe.md):

    python -m experiments.fear_scale --every 10 -- --sim ugv --scenario 3 --cycles 3 --episodes-per-cycle 5 \\
        --alone-episodes 10 --policy policies/ugv-default --seed 0 --out runs/fearscale/none-s0
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from core.sage.config import AgentConfig
from core.sage.sac import SAC, actor_fear_weight

SCALES: tuple[str, ...] = ("none", "q")
"""The ``fear_scale`` settings the probe evaluates on every batch (the run trains with one of them)."""


def _norms(grad: torch.Tensor) -> torch.Tensor:
    return grad.reshape(len(grad), -1).norm(dim=1)


def _parameter_norm(loss: torch.Tensor, params: Sequence[torch.Tensor]) -> float:
    grads = torch.autograd.grad(loss, params, retain_graph=True, allow_unused=True)
    return float(torch.sqrt(sum((g.pow(2).sum() for g in grads if g is not None), torch.tensor(0.0))))


def actor_gradients(sac: SAC, states: torch.Tensor, imitation: Any | None) -> dict[str, float]:
    """The actor's gradient per term on ``states`` (and the imitation batch), see the module docstring."""
    cfg: AgentConfig = sac.cfg
    params = [p for p in sac.actor.parameters() if p.requires_grad]
    sac.critic.requires_grad_(False)
    try:
        action, log_prob = sac.actor.sample(states)
        leaf = action.detach().requires_grad_(True)
        q_leaf = sac.critic(states, leaf).min(0).values
        grad_q = _norms(torch.autograd.grad(q_leaf.sum(), leaf)[0])
        q_scale = q_leaf.detach().abs().mean().clamp_min(1.0)
        row: dict[str, float] = {
            "lam": float(sac.lam),
            "q_mean": float(q_leaf.detach().mean()),
            "q_scale": float(q_scale),
            "grad_q_action": float(grad_q.mean()),
        }
        fear_on = sac.fear_active()
        if fear_on:
            fear_leaf = sac.learner_fear(states, leaf)
            grad_f = _norms(torch.autograd.grad(fear_leaf.sum(), leaf)[0])
            row.update(fear_mean=float(fear_leaf.detach().mean()), grad_fear_action=float(grad_f.mean()))
            for scale in SCALES:
                weighted = float(actor_fear_weight(sac.lam, q_scale, scale)) * row["grad_fear_action"]
                row[f"fear_share_action_{scale}"] = weighted / max(weighted + row["grad_q_action"], 1e-12)
        # the parameters: each term of the loss as this run weighs it
        q = sac.critic(states, action).min(0).values
        row["grad_q_params"] = _parameter_norm(-q.mean(), params)
        row["grad_entropy_params"] = _parameter_norm((sac.alpha * log_prob).mean(), params)
        if fear_on:
            weight = actor_fear_weight(sac.lam, q.detach().abs().mean().clamp_min(1.0), cfg.fear_scale)
            row["grad_fear_params"] = _parameter_norm(weight * sac.learner_fear(states, action).mean(), params)
        if imitation is not None:
            with torch.no_grad():
                from core.sage.sac import advantage_weights

                q_expert = sac.critic(imitation.obs, imitation.a_expert).min(0).values
                q_agent = sac.critic(imitation.obs, imitation.a_rl).min(0).values
                omega = advantage_weights(q_expert, q_agent, q_scale, cfg.advantage_temperature, cfg.advantage_clip)
            error = (sac.actor.deterministic(imitation.obs) - imitation.a_expert).pow(2).sum(-1)
            row["grad_bc_params"] = _parameter_norm(cfg.bc_weight * q_scale * (omega * error).mean(), params)
    finally:
        sac.critic.requires_grad_(True)
    return row


class Probe:
    """Patches :meth:`SAC.update` and ``Finetuner.round`` to measure every ``every``-th update of each round."""

    def __init__(self, every: int, seed: int = 12345) -> None:
        self.every, self.rng = every, np.random.default_rng(seed)
        self.rows: list[dict[str, float | str]] = []  # the measurements, each with its round and the run's fear_scale
        self.round, self.count = 0, 0

    def measure(self, sac: SAC) -> None:
        cfg = sac.cfg
        batch = sac.buffer.sample(cfg.batch_size, self.rng)
        states = batch.obs
        if sac.virtual is not None and len(sac.virtual) > 0 and cfg.virtual_ratio > 0:
            n_virtual = round(cfg.virtual_ratio * len(batch))
            states = torch.cat([batch.obs[: len(batch) - n_virtual], sac.virtual.sample_obs(n_virtual, self.rng)])
        imitation = sac.buffer.sample_takeovers(cfg.bc_batch_size, self.rng) if cfg.imitation else None
        with torch.random.fork_rng(devices=[]):
            row = actor_gradients(sac, states, imitation)
        self.rows.append({"round": self.round, "update": self.count, "fear_scale": cfg.fear_scale, **row})

    def install(self) -> None:
        from core.finetune import Finetuner, RoundResult

        original_update, original_round = SAC.update, Finetuner.round
        probe = self

        # the replacements' first parameter is named self, as the methods' is (a caller may name it)
        def update(self: SAC) -> dict[str, float]:
            if probe.count % probe.every == 0:
                probe.measure(self)
            probe.count += 1
            return original_update(self)

        def round_(self: Finetuner, *args: Any, **kwargs: Any) -> RoundResult:
            probe.round += 1
            probe.count = 0
            return original_round(self, *args, **kwargs)

        SAC.update = update  # type: ignore[method-assign]
        Finetuner.round = round_  # type: ignore[method-assign]

    def summary(self) -> list[dict[str, Any]]:
        """Per round: medians of the measurements (and their count)."""
        out = []
        for k in sorted({int(r["round"]) for r in self.rows}):
            rows = [r for r in self.rows if r["round"] == k]
            keys = [key for key in rows[0] if key not in ("round", "update", "fear_scale")]
            medians = {key: statistics.median(float(r[key]) for r in rows if key in r) for key in keys}
            out.append({"round": k, "measurements": len(rows), "fear_scale": rows[0]["fear_scale"], **medians})
        return out


def format_summary(summary: list[dict[str, Any]]) -> str:
    """A markdown table of the per-round medians."""
    columns = [
        ("round", "round"), ("fear_scale", "run's fear_scale"), ("measurements", "n"), ("lam", "λ"),
        ("q_scale", "mean|Q|"), ("fear_mean", "F"), ("grad_q_action", "|∂Q/∂a|"), ("grad_fear_action", "|∂F/∂a|"),
        ("fear_share_action_none", "fear share at a, none"), ("fear_share_action_q", "fear share at a, q"),
        ("grad_q_params", "‖∇θ(−Q)‖"), ("grad_fear_params", "‖∇θ(wF)‖"), ("grad_bc_params", "‖∇θ BC‖"),
        ("grad_entropy_params", "‖∇θ α log π‖"),
    ]  # fmt: skip
    lines = ["| " + " | ".join(title for _, title in columns) + " |", "|" + "---|" * len(columns)]
    for row in summary:
        cells = []
        for key, _ in columns:
            value = row.get(key)
            cells.append("—" if value is None else (f"{value:.3g}" if isinstance(value, float) else str(value)))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _arm(run: dict[str, Any]) -> tuple[str, str]:
    """(the run's fear_scale, its label: the fear_scale and any other learner setting of the rounds)."""
    settings = dict(o.split("=", 1) for o in run["config"]["finetune"]["overrides"] if "=" in o)
    scale = settings.pop("fear_scale", settings.pop("learner.fear_scale", "none"))
    return scale, ", ".join([scale, *(f"{k}={v}" for k, v in settings.items())])


def compare(folders: list[Path]) -> str:
    """Per run folder (cycles.json and fear_scale.json): the outcomes per cycle and, per round, the medians of λ, of
    the actor batch's fear F and of the fear share at the action under the run's own ``fear_scale``;
    then per arm, sums over its seeds of the last cycle's alone successes and of the supervised collisions."""
    head = (
        "| rounds' settings | seed | alone UGV 3 (of 10) | alone unseen (of 10) | takeover (supervised) "
        "| supervised collisions (of 5) | λ by round | F by round | fear share at a by round |\n"
        "|---|---|---|---|---|---|---|---|---|"
    )
    lines = [head]
    totals: dict[str, dict[str, int]] = {}
    for folder in folders:
        run = json.loads((folder / "cycles.json").read_text())
        probe = json.loads((folder / "fear_scale.json").read_text())["summary"]
        (scale, arm), seed, cycles = _arm(run), run["config"]["seed"], run["cycles"]
        share = f"fear_share_action_{scale}"
        alone = [round(10 * c["alone_success"]) for c in cycles]
        unseen = [round(10 * c["unseen_success"]) for c in cycles]
        hits = [round(c["collision"] * c["episodes"]) for c in cycles]
        lams = ", ".join(f"{r['lam']:.2f}" for r in probe)
        fears = ", ".join(f"{r['fear_mean']:.3f}" for r in probe)
        lines.append(
            f"| {arm} | {seed} | {' → '.join(map(str, alone))} | {' → '.join(map(str, unseen))} | "
            + " → ".join(f"{100 * c['takeover_rate']:.1f}%" for c in cycles)
            + f" | {', '.join(map(str, hits))} | {lams} | {fears} | "
            + ", ".join(f"{100 * r[share]:.1f}%" for r in probe)
            + " |"
        )
        total = totals.setdefault(arm, {"seeds": 0, "alone": 0, "unseen": 0, "collisions": 0})
        total["seeds"] += 1
        total["alone"] += alone[-1]
        total["unseen"] += unseen[-1]
        total["collisions"] += sum(hits)
    lines += ["", "| settings | seeds | last cycle alone UGV 3 | last cycle alone unseen | supervised collisions |"]
    lines.append("|---|---|---|---|---|")
    for arm, t in totals.items():
        n = 10 * t["seeds"]
        lines.append(
            f"| {arm} | {t['seeds']} | {t['alone']}/{n} | {t['unseen']}/{n} | {t['collisions']}/{5 * t['seeds'] * 3} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--every", type=int, default=10, help="Measure every this-many updates of a round.")
    parser.add_argument("--compare", type=Path, nargs="+", help="Only tabulate these finished run folders.")
    parser.add_argument("cycles", nargs=argparse.REMAINDER, help="-- then the arguments of `sage cycles`.")
    args = parser.parse_args(argv)
    if args.compare:
        print(compare(args.compare))
        return
    cycles_args = [a for a in args.cycles if a != "--"]
    if "--out" not in cycles_args:
        parser.error("give the cycles run an --out folder (fear_scale.json is written into it)")
    out = Path(cycles_args[cycles_args.index("--out") + 1])
    torch.set_num_threads(1)
    probe = Probe(args.every)
    probe.install()
    from app.cli import app

    try:
        app(["cycles", *cycles_args], standalone_mode=False)
    finally:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
        summary = probe.summary()
        payload: dict[str, Any] = {
            "command": " ".join(["python -m experiments.fear_scale", *sys.argv[1:]]),
            "commit": commit,
        }
        payload.update(summary=summary, rows=probe.rows)
        if out.is_dir():
            (out / "fear_scale.json").write_text(json.dumps(payload, indent=1) + "\n")
        print(format_summary(summary))


if __name__ == "__main__":
    main()
