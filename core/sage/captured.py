"""The SAGE-SAC and D3QN updates captured once as CUDA graphs and replayed (``AgentConfig.cuda_graph``, CUDA only).

On a GPU the update of these small networks is bound by kernel launches: a stand-in SAGE-SAC update with the
project's sizes took 21.7 ms eager on an H200 at batch 256 and 2.9 ms replayed as a graph (PITFALLS.md). A graph
replays fixed kernels on fixed memory, so the update here is written against the pattern PyTorch documents for
whole-network capture:

- every input lives in a static buffer that each update fills in place: the sampled batch, the virtual states, the
  imitation batch, and the numbers the host decides (λ, c*, the fear budget) as 0-dim device tensors;
- the optimisers are Adam with ``capturable=True`` (their step counts on the device: no host sync);
- the first updates of each structure run eagerly on a side stream (warm-up: lazy state such as Adam's moments and
  the ego step's geometry is allocated outside the capture), then ``torch.cuda.graph`` records one update;
- nothing inside reads a value back to the host: α comes from log α on the device, λ's dual step runs on the device,
  and the statistics are read once after the replay (one sync per update);
- the world model's folded weights are copied in place into the graph's own buffers when the model changes.

A graph is recorded per structure (whether fear is active, whether an imitation batch exists, how many virtual
states the actor batch holds); a checkpoint load or a world model of another shape drops them (recaptured).

:class:`core.sage.sac.CapturedSACUpdate` and :class:`core.sage.d3qn.CapturedD3QNUpdate` (built on
:class:`CapturedUpdate`, here) also run their body eagerly (``eager=True``), which is how
the CPU tests hold the captured computation to the reference update (``tests/core/sage/test_captured.py``): the
body is the same code a graph records.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import torch
from torch import Tensor

from core.device import DeviceError
from core.replay import Batch
from core.sage.fear import closing_channels, contact_floors, fear_of, rollout
from core.sage.world_model import FoldedModel

WARMUP_UPDATES = 3
"""Eager updates on a side stream before a structure is captured (PyTorch's whole-network capture example)."""


def require_cuda(device: torch.device) -> None:
    """The one clear error of ``learner.cuda_graph=true`` anywhere but on CUDA."""
    if device.type != "cuda":
        raise DeviceError(
            f"learner.cuda_graph=true captures the update as a CUDA graph: it needs --device cuda (this run's device "
            f"is {device})"
        )


def _batch_tensors(batch: Batch) -> list[str]:
    """The batch's tensors (a graph replays on them; the drawn rows are the sampler's bookkeeping)."""
    return [f.name for f in dataclasses.fields(batch) if isinstance(getattr(batch, f.name), torch.Tensor)]


def static_batch(batch: Batch) -> Batch:
    return Batch(**{name: getattr(batch, name).clone() for name in _batch_tensors(batch)})


def fill_batch(static: Batch, batch: Batch) -> None:
    for name in _batch_tensors(batch):
        getattr(static, name).copy_(getattr(batch, name), non_blocking=True)


class CapturedUpdate:
    """What the SAC and D3QN captures share: structures, warm-up, capture, replay, static world model, statistics."""

    def __init__(self, learner: Any, *, eager: bool = False) -> None:
        """``learner``: a :class:`core.sage.learner.BaseLearner` (typed loosely: that module imports this one)."""
        if not eager:
            require_cuda(learner.device)
        self.learner, self.eager = learner, eager
        self.device = learner.device
        self.graphs: dict[tuple[Any, ...], torch.cuda.CUDAGraph] = {}
        self.warmed: dict[tuple[Any, ...], int] = {}
        self.inputs: dict[tuple[Any, ...], dict[str, Any]] = {}
        """Per structure: its static input buffers (what the graph reads)."""
        self.outputs: dict[tuple[Any, ...], dict[str, Tensor]] = {}
        """Per structure: the statistics the graph writes."""
        self.scalars = {name: torch.zeros((), device=self.device) for name in ("lam", "c_star", "fear_budget")}
        self.folded: FoldedModel | None = None
        self.folded_version = -1
        gate = learner.cfg.gate
        floors = contact_floors(gate)
        self.contact = None if floors is None else floors.to(self.device)
        closing = closing_channels(gate, None, floors)
        self.closing = None if closing is None else closing.to(self.device)

    def __call__(self) -> dict[str, float]:
        """One update: each method's capture (SAC's, D3QN's) fills its inputs and :meth:`run`s its own body."""
        raise NotImplementedError

    # -- the world model the graph reads --------------------------------------------------------------
    def static_folded(self) -> FoldedModel:
        """The world model's folded weights in buffers of this capture's own, refreshed in place on a new version
        (a graph keeps reading the addresses it recorded); a model of another shape drops the graphs."""
        model = self.learner.world_model
        assert model is not None
        if self.folded is not None and self.folded_version == model.version:
            return self.folded
        fresh = model.folded().to(self.device)
        if self.folded is None or not _same_shapes(self.folded, fresh):
            self.folded = dataclasses.replace(fresh, **{k: _clone(v) for k, v in _tensor_fields(fresh).items()})
            self.graphs.clear()
            self.warmed.clear()
        else:
            with torch.no_grad():
                for name, value in _tensor_fields(fresh).items():
                    _copy_into(getattr(self.folded, name), value)
            self.folded.curiosity_ref = fresh.curiosity_ref
        self.folded_version = model.version
        return self.folded

    def fear(self, obs: Tensor, action: Tensor, policy: Any) -> Tensor:
        """F(s, a) as the learner's ``learner_fear`` computes it, on the static model and device-side contact."""
        cfg = self.learner.cfg
        assert self.folded is not None
        horizon = cfg.learner_fear_horizon
        ro = rollout(self.folded, policy, obs, action, horizon, None, self.contact, self.closing, states_needed=False)
        return fear_of(self.folded, ro, cfg.gate).fear

    # -- run ------------------------------------------------------------------------------------------
    def run(self, key: tuple[Any, ...], body: Any) -> dict[str, float]:
        """The update of structure ``key`` whose inputs were just filled: eagerly (warm-up, or ``eager``), or by
        replaying its graph (captured on first use after the warm-up)."""
        if self.eager:
            return self._read(body())
        if key in self.graphs:
            self.graphs[key].replay()
            return self._read(self.outputs[key])
        if self.warmed.get(key, 0) < WARMUP_UPDATES:
            self.warmed[key] = self.warmed.get(key, 0) + 1
            side = torch.cuda.Stream(self.device)
            side.wait_stream(torch.cuda.current_stream(self.device))
            with torch.cuda.stream(side):
                stats = body()
            torch.cuda.current_stream(self.device).wait_stream(side)
            return self._read(stats)
        for optimizer in self.optimizers():
            optimizer.zero_grad(set_to_none=True)  # the graph allocates its gradients from its own pool
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph):
            self.outputs[key] = body()
        self.graphs[key] = graph
        graph.replay()  # the capture recorded the update; this runs it
        return self._read(self.outputs[key])

    def zero(self, optimizer: torch.optim.Optimizer) -> None:
        """``zero_grad`` where the update runs eagerly; inside a capture the gradients are written, not summed (they
        are None when the capture starts)."""
        if self.eager or not torch.cuda.is_current_stream_capturing():
            optimizer.zero_grad(set_to_none=True)

    def optimizers(self) -> list[torch.optim.Optimizer]:
        return [getattr(self.learner, name) for name in self.learner.declared_state().optimizers]

    def _read(self, stats: dict[str, Tensor]) -> dict[str, float]:
        """The statistics as floats (one host sync); λ written back to the learner."""
        names = list(stats)
        values = torch.stack([stats[n].detach().reshape(()).float() for n in names]).tolist()
        out = dict(zip(names, values, strict=True))
        if "lam" in out:
            self.learner.lam = out["lam"]
        return out

    def drop(self) -> None:
        """Forget every graph (a checkpoint replaced the optimisers' memory): the next updates warm up again."""
        self.graphs.clear()
        self.warmed.clear()
        self.outputs.clear()


# -- helpers ------------------------------------------------------------------------------------------------
def _tensor_fields(folded: FoldedModel) -> dict[str, Any]:
    return {
        f.name: getattr(folded, f.name)
        for f in dataclasses.fields(folded)
        if isinstance(getattr(folded, f.name), Tensor) or f.name == "hidden"
    }


def _clone(value: Any) -> Any:
    if isinstance(value, Tensor):
        return value.clone()
    return [(w.clone(), b.clone()) for w, b in value]


def _copy_into(target: Any, source: Any) -> None:
    if isinstance(target, Tensor):
        target.copy_(source)
        return
    for (tw, tb), (sw, sb) in zip(target, source, strict=True):
        tw.copy_(sw)
        tb.copy_(sb)


def _shapes(value: Any) -> Any:
    if isinstance(value, Tensor):
        return tuple(value.shape)
    return [(tuple(w.shape), tuple(b.shape)) for w, b in value]


def _same_shapes(a: FoldedModel, b: FoldedModel) -> bool:
    fa, fb = _tensor_fields(a), _tensor_fields(b)
    return all(_shapes(fa[name]) == _shapes(fb[name]) for name in fa)
