"""Replay buffers: the real buffer D_actual (every executed transition, with the takeover flag Ξ and both
the policy's and the expert's actions) and the virtual buffer D_virtual (world-model rollouts).

Both are fixed-capacity numpy rings; samples come back as torch tensors. The real buffer also keeps the
indices of intervention samples (Ξ = 1) so that the imitation term can draw from them directly, however
rare they are, and the reward's bounds that c* reads: both kept as rows are written, so that an update costs no
scan of the buffer (at 200,000 rows a scan per update cost more than the update's sampling). The columns those
depend on are read-only views; rows are changed through the buffer's methods (:meth:`ReplayBuffer.label`,
:meth:`ReplayBuffer.unlabel`, :meth:`ReplayBuffer.set_rewards`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from core.motion import ScanAlignment, motion_between
from core.protocol import StepRecord


def refused_by_gate(fear: float, threshold: float) -> bool:
    """Whether a step's fear was over its τ (both finite): the gate judged the agent's proposal dangerous there."""
    return bool(np.isfinite(fear) and np.isfinite(threshold) and fear > threshold)


class SortedRows:
    """The rows of a ring where a flag is set, in increasing order, kept as the flag changes: the same array as
    ``np.flatnonzero(flag[:size])`` without reading the flag. Setting a row past the last is an append (amortised
    O(1): a ring that has not wrapped); elsewhere an insertion that moves the rows after it (O(count))."""

    def __init__(self) -> None:
        self._rows = np.empty(64, np.int64)
        self.count = 0

    def view(self) -> np.ndarray:
        """The rows, increasing (a view: valid until the next change)."""
        return self._rows[: self.count]

    def add(self, row: int) -> None:
        """Adds ``row`` (not already present)."""
        n = self.count
        if n == len(self._rows):
            grown = np.empty(2 * n, np.int64)
            grown[:n] = self._rows
            self._rows = grown
        if n == 0 or row > self._rows[n - 1]:
            self._rows[n] = row
        else:
            at = int(np.searchsorted(self._rows[:n], row))
            self._rows[at + 1 : n + 1] = self._rows[at:n].copy()
            self._rows[at] = row
        self.count = n + 1

    def remove(self, row: int) -> None:
        """Removes ``row`` (present)."""
        n = self.count
        at = int(np.searchsorted(self._rows[:n], row))
        self._rows[at : n - 1] = self._rows[at + 1 : n].copy()
        self.count = n - 1

    def change(self, row: int, was: bool, now: bool) -> None:
        if now and not was:
            self.add(row)
        elif was and not now:
            self.remove(row)


def read_only(array: np.ndarray) -> np.ndarray:
    """A view of ``array`` that refuses writes (the buffer's own methods write the array itself)."""
    view = array.view()
    view.flags.writeable = False
    return view


@dataclass
class Batch:
    """A minibatch of real transitions as float32 tensors (flags as 0/1 floats)."""

    obs: Tensor
    action: Tensor
    """The executed action a_t = (1 - Ξ) a_RL + Ξ a_expert."""
    reward: Tensor
    next_obs: Tensor
    terminated: Tensor
    violation: Tensor
    cost: Tensor
    takeover: Tensor
    a_rl: Tensor
    a_expert: Tensor
    """The expert's action (zeros where Ξ = 0)."""
    rows: np.ndarray | None = None
    """The buffer rows drawn (None: not from a buffer)."""

    def __len__(self) -> int:
        return self.obs.shape[0]


class ReplayBuffer:
    """D_actual: a ring of executed transitions with Ξ, a_RL and a_expert."""

    def __init__(self, obs_dim: int, act_dim: int, capacity: int, device: torch.device | str = "cpu") -> None:
        if capacity < 1:
            raise ValueError(f"replay capacity must be >= 1, got {capacity}")
        self.obs_dim, self.act_dim, self.capacity = obs_dim, act_dim, capacity
        self.obs = np.zeros((capacity, obs_dim), np.float32)
        self.next_obs = np.zeros((capacity, obs_dim), np.float32)
        self.action = np.zeros((capacity, act_dim), np.float32)
        self.a_rl = np.zeros((capacity, act_dim), np.float32)
        self.a_expert = np.zeros((capacity, act_dim), np.float32)
        self._reward = np.zeros(capacity, np.float32)
        self.reward = read_only(self._reward)
        """Read-only (c*'s bounds are kept as rows are written): :meth:`set_rewards` changes a stored row's."""
        self.cost = np.zeros(capacity, np.float32)
        self._terminated = np.zeros(capacity, np.float32)
        self.terminated = read_only(self._terminated)
        """Read-only, as :attr:`reward`."""
        self.violation = np.zeros(capacity, np.float32)
        self.conflict = np.zeros(capacity, np.float32)
        """The simulator's traffic conflict flag (``info["conflict"]``: a near miss, e.g. highway's time to contact
        under 3 s; 0 where the simulator reports none): a label the world model may learn besides violations."""
        self._takeover = np.zeros(capacity, bool)
        self.takeover = read_only(self._takeover)
        """Rows with an expert label to imitate: the expert drove (Ξ = 1), or it coached the agent's step
        (:attr:`coached`). Read-only: :meth:`label` and :meth:`unlabel` change it."""
        self.coached = np.zeros(capacity, bool)
        """The agent drove the row and a coach labelled it (``StepRecord.coached``): imitated, executed by the agent."""
        self._refused = np.zeros(capacity, bool)
        self.refused = read_only(self._refused)
        """The expert drove and the gate had judged the agent's own proposal a_RL dangerous there (fear over τ): a
        counterfactual failure of a_RL at that state, never executed (``AgentConfig.refused_weight``). Read-only."""
        self._takeover_rows, self._refused_rows = SortedRows(), SortedRows()
        self._magnitude: np.float32 | None = None
        """max |reward| over the stored rows (None: empty), valid while :attr:`_magnitude_known`."""
        self._bounds: tuple[np.float32, np.float32] | None = None
        """(min, max) reward over the stored live rows (None: none), valid while :attr:`_bounds_known`."""
        self._magnitude_known = self._bounds_known = True
        self.device = torch.device(device)
        """Where sampled batches go (the learner's update device; the rows themselves stay in numpy)."""
        self.size = 0
        self.pos = 0
        self.total = 0
        """Transitions ever added (the ring keeps the last ``capacity``)."""
        self.writes = 0
        """Changes to the stored rows so far (added or rewritten): what a value computed from the rows is valid for."""

    def __len__(self) -> int:
        return self.size

    def add(
        self,
        obs: np.ndarray,
        action: np.ndarray,
        reward: float,
        next_obs: np.ndarray,
        terminated: bool,
        *,
        cost: float = 0.0,
        violation: bool = False,
        conflict: float = 0.0,
        takeover: bool = False,
        a_rl: np.ndarray | None = None,
        a_expert: np.ndarray | None = None,
        refused: bool = False,
        coached: bool = False,
    ) -> None:
        obs = np.asarray(obs, np.float32).reshape(-1)
        if obs.shape[0] != self.obs_dim:
            raise ValueError(f"observation has {obs.shape[0]} values, the buffer expects {self.obs_dim}")
        i = self.pos
        if i < self.size:
            self._forget_reward(i)
        was_takeover, was_refused = bool(self._takeover[i]), bool(self._refused[i])
        self.obs[i] = obs
        self.next_obs[i] = np.asarray(next_obs, np.float32).reshape(-1)
        self.action[i] = np.asarray(action, np.float32).reshape(-1)
        self.a_rl[i] = self.action[i] if a_rl is None else np.asarray(a_rl, np.float32).reshape(-1)
        self.a_expert[i] = 0.0 if a_expert is None else np.asarray(a_expert, np.float32).reshape(-1)
        self._reward[i] = reward
        self.cost[i] = cost
        self._terminated[i] = float(terminated)
        self.violation[i] = float(violation)
        self.conflict[i] = float(conflict)
        self.coached[i] = bool(coached) and not takeover and a_expert is not None
        self._takeover[i] = (bool(takeover) and a_expert is not None) or self.coached[i]
        self._refused[i] = bool(refused) and self._takeover[i] and not self.coached[i]
        self._takeover_rows.change(i, was_takeover, bool(self._takeover[i]))
        self._refused_rows.change(i, was_refused, bool(self._refused[i]))
        self.pos = (i + 1) % self.capacity
        self.size = min(self.size + 1, self.capacity)
        self.total += 1
        self.writes += 1
        self._note_reward(i)

    # -- changing stored rows (the kept indices and bounds follow) ---------------------------------
    def label(self, row: int, a_expert: np.ndarray) -> None:
        """Makes a stored row an imitation row labelled ``a_expert`` (look-back labels)."""
        self.a_expert[row] = np.asarray(a_expert, np.float32).reshape(-1)
        self._takeover_rows.change(row, bool(self._takeover[row]), True)
        self._takeover[row] = True
        self.writes += 1

    def unlabel(self, rows: np.ndarray) -> None:
        """Stored rows are no longer imitated (held out to measure imitation); their other flags stay."""
        for row in np.unique(np.asarray(rows, np.int64)):
            self._takeover_rows.change(int(row), bool(self._takeover[row]), False)
            self._takeover[row] = False
        self.writes += 1

    def set_rewards(self, rows: int | np.ndarray, reward: float | np.ndarray, terminated: bool | None = None) -> None:
        """Rewrites stored rows' rewards (reward shaping after the fact), and their terminal flag if given."""
        self._reward[rows] = reward
        if terminated is not None:
            self._terminated[rows] = float(terminated)
        self._magnitude_known = self._bounds_known = False
        self.writes += 1

    def _forget_reward(self, row: int) -> None:
        """Before ``row`` is overwritten: the kept bounds stay valid unless it held one of them."""
        old = self._reward[row]
        if self._magnitude_known and not (self._magnitude is not None and abs(old) < self._magnitude):
            self._magnitude_known = False
        if self._bounds_known and self._terminated[row] < 0.5:
            bounds = self._bounds
            if bounds is None or not (bounds[0] < old < bounds[1]):
                self._bounds_known = False

    def _note_reward(self, row: int) -> None:
        """After ``row`` is written: the kept bounds take it in (np.minimum/maximum carry a NaN as a scan does)."""
        value = self._reward[row]
        if self._magnitude_known:
            size = abs(value)
            self._magnitude = size if self._magnitude is None else np.maximum(self._magnitude, size)
        if self._bounds_known and self._terminated[row] < 0.5:
            bounds = self._bounds
            self._bounds = (
                (value, value) if bounds is None else (np.minimum(bounds[0], value), np.maximum(bounds[1], value))
            )

    def add_record(self, record: StepRecord) -> None:
        """Store one step of the loop (violations are terminal for learning even if the sim goes on). The step is
        :attr:`refused` where the expert drove and the step's fear was over its τ: the gate judged the agent's
        proposal there, not a hold counting down or the expert's own manoeuvre."""
        self.add(
            record.obs,
            record.action,
            record.reward,
            record.next_obs,
            record.terminated or record.violation,
            cost=record.cost,
            violation=record.violation,
            conflict=float(record.info.get("conflict", 0.0)),
            takeover=record.takeover,
            a_rl=record.a_rl,
            a_expert=record.a_expert,
            refused=refused_by_gate(record.fear, record.threshold),  # add() keeps it to takeover rows
            coached=record.coached,
        )

    # -- sampling --------------------------------------------------------------------------------
    def _batch(self, idx: np.ndarray) -> Batch:
        def t(rows: np.ndarray) -> Tensor:
            tensor = torch.from_numpy(rows)
            return tensor if self.device.type == "cpu" else tensor.to(self.device, non_blocking=True)

        return Batch(
            obs=t(self.obs[idx]),
            action=t(self.action[idx]),
            reward=t(self.reward[idx]),
            next_obs=t(self.next_obs[idx]),
            terminated=t(self.terminated[idx]),
            violation=t(self.violation[idx]),
            cost=t(self.cost[idx]),
            takeover=t(self.takeover[idx].astype(np.float32)),
            a_rl=t(self.a_rl[idx]),
            a_expert=t(self.a_expert[idx]),
            rows=idx,
        )

    def sample(self, batch_size: int, rng: np.random.Generator) -> Batch:
        if self.size == 0:
            raise ValueError("cannot sample from an empty replay buffer")
        return self._batch(rng.integers(0, self.size, size=batch_size))

    def takeover_count(self) -> int:
        return self._takeover_rows.count

    def takeover_rows(self) -> np.ndarray:
        """The stored rows with an expert label (:attr:`takeover`), increasing (a view, valid until the next write)."""
        return self._takeover_rows.view()

    def sample_takeovers(self, batch_size: int, rng: np.random.Generator) -> Batch | None:
        """Intervention samples (Ξ = 1) only; None when there are none yet."""
        idx = self._takeover_rows.view()
        if len(idx) == 0:
            return None
        return self._batch(idx[rng.integers(0, len(idx), size=batch_size)])

    def refused_count(self) -> int:
        return self._refused_rows.count

    def refused_rows(self) -> np.ndarray:
        """The stored rows of :attr:`refused`, increasing (a view, valid until the next write)."""
        return self._refused_rows.view()

    def sample_refused(self, batch_size: int, rng: np.random.Generator) -> Batch | None:
        """Rows whose a_RL the gate refused (:attr:`refused`) only; None when there are none."""
        idx = self._refused_rows.view()
        if len(idx) == 0:
            return None
        return self._batch(idx[rng.integers(0, len(idx), size=batch_size)])

    def sample_prior(self, batch_size: int, rng: np.random.Generator) -> Batch | None:
        """Rows of a base policy's own drives only (a fine-tuning buffer keeps them apart); a plain buffer has none."""
        return None

    def arrays(self) -> dict[str, np.ndarray]:
        """Views of the filled part (for world-model fits)."""
        n = self.size
        return {
            "obs": self.obs[:n],
            "action": self.action[:n],
            "next_obs": self.next_obs[:n],
            "cost": np.maximum(self.cost[:n], self.violation[:n]),
            "reward": self.reward[:n],
            "terminated": self.terminated[:n],
            "violation": self.violation[:n],
            "conflict": self.conflict[:n],
        }

    def _chronology(self) -> tuple[np.ndarray, np.ndarray]:
        """Stored rows in insertion order, and whether each leads into the next one (same episode: it did not
        terminate and its next state is the next row's state)."""
        n = self.size
        order = np.arange(n) if n < self.capacity else (np.arange(n) + self.pos) % n
        continues = np.zeros(n, bool)
        if n > 1:
            prev, cur = order[:-1], order[1:]
            same = np.all(np.abs(self.next_obs[prev] - self.obs[cur]) <= 1e-6, axis=1)
            continues[:-1] = (self.terminated[prev] < 0.5) & same
        return order, continues

    def violation_soon(self, steps: int) -> np.ndarray:
        """Per stored row (in the order of :meth:`arrays`): 1 when a violation happens at this transition or
        within the next ``steps - 1`` transitions of the same episode, else 0."""
        return self.flag_soon(self.violation[: self.size] > 0.5, steps)

    def conflict_soon(self, steps: int) -> np.ndarray:
        """:meth:`violation_soon` for the simulator's traffic conflict flag (``info["conflict"]``): 1 when a
        conflict is reported at this transition or within the next ``steps - 1`` of the same episode."""
        return self.flag_soon(self.conflict[: self.size] > 0.5, steps)

    def flag_soon(self, flag: np.ndarray, steps: int) -> np.ndarray:
        """Per stored row (the order of :meth:`arrays`): 1 when ``flag`` (one bool per stored row, in storage
        order) is set at this row or within the next ``steps - 1`` rows of the same episode, else 0."""
        n = self.size
        if len(flag) != n:
            raise ValueError(f"flag_soon: {len(flag)} flags for {n} stored rows")
        if n == 0:
            return np.zeros(0, np.float32)
        order, continues = self._chronology()
        flagged = np.asarray(flag, dtype=bool)[order]
        episode = np.concatenate([[0], np.cumsum(~continues[:-1])])  # a new episode after each break
        index = np.arange(n)
        # the first flagged row at or after each row (n when none), then: same episode and close enough
        following = np.minimum.accumulate(np.where(flagged, index, n)[::-1])[::-1]
        hit = following < n
        near = hit & (following - index < max(int(steps), 1))
        near[hit] &= episode[following[hit]] == episode[hit]
        soon = np.zeros(n, np.float32)
        soon[order] = near.astype(np.float32)
        return soon

    def _chains(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The stored rows in chronological order, their positions in it, and where each row's episode chain (as far
        as the buffer holds it) began."""
        order, continues = self._chronology()
        # linked[p]: the row at chronological position p follows on from the row before it
        linked = np.zeros(self.size, bool)
        linked[1:] = continues[:-1]
        position = np.arange(self.size)
        return order, position, np.maximum.accumulate(np.where(linked, 0, position))

    def previous_deltas(self, lag: int = 1, scan: ScanAlignment | None = None) -> np.ndarray:
        """Per stored row (the order of :meth:`arrays`): (s_t - s_{t-j}) / j, j = ``lag`` or fewer where the
        episode (as far as the buffer holds it) began fewer than ``lag`` rows before, zeros at its first row: the
        motion input of the world model (``scan``: with s_{t-j}'s scan turned to s_t's heading)."""
        n = self.size
        out = np.zeros((n, self.obs_dim), np.float32)
        if n < 2:
            return out
        order, position, start = self._chains()
        back = np.minimum(position - start, max(int(lag), 1))
        has = back > 0
        cur, prev = order[position[has]], order[position[has] - back[has]]
        out[cur] = motion_between(self.obs[prev], self.obs[cur], scan) / back[has, None].astype(np.float32)
        return out

    def preceding_rows(self, back: int) -> np.ndarray:
        """Per stored row (the order of :meth:`arrays`): the stored index of the row ``back`` steps before it in the
        same episode (as far as the buffer holds it), -1 where the episode began fewer than ``back`` rows before."""
        n = self.size
        out = np.full(n, -1, np.int64)
        if n < 2 or back < 1:
            return out
        order, position, start = self._chains()
        has = position - start >= back
        out[order[position[has]]] = order[position[has] - back]
        return out

    def discounted_ahead(self, values: np.ndarray, gamma: float) -> np.ndarray:
        """Per stored row (the order of :meth:`arrays`), with ``values`` one number per stored row in that order: the
        discounted sum of the values from the row to the end of its episode as far as the buffer holds it (a chain
        cut before its end counts nothing after it). With the rewards, the recorded return to go."""
        n = self.size
        values = np.asarray(values, np.float64)
        if len(values) != n:
            raise ValueError(f"discounted_ahead: {len(values)} values for {n} stored rows")
        out = np.zeros(n, np.float64)
        if n == 0:
            return out
        order, continues = self._chronology()
        ahead = 0.0
        for p in range(n - 1, -1, -1):
            row = order[p]
            ahead = values[row] + (gamma * ahead if continues[p] else 0.0)
            out[row] = ahead
        return out

    def reward_magnitude(self) -> float:
        """The largest |reward| recorded, terminal transitions included (0 when empty)."""
        if not self._magnitude_known:
            n = self.size
            self._magnitude = np.abs(self._reward[:n]).max() if n else None
            self._magnitude_known = True
        return 0.0 if self._magnitude is None else float(self._magnitude)

    def reward_bounds(self) -> tuple[float, float] | None:
        """(min, max) reward over non-terminal transitions (terminal bonuses happen once per episode)."""
        if not self._bounds_known:
            n = self.size
            r = self._reward[:n][self._terminated[:n] < 0.5]
            self._bounds = (r.min(), r.max()) if len(r) else None
            self._bounds_known = True
        return None if self._bounds is None else (float(self._bounds[0]), float(self._bounds[1]))


class VirtualBuffer:
    """D_virtual: model-generated transitions (state, action, next state, predicted cost)."""

    def __init__(self, obs_dim: int, act_dim: int, capacity: int, device: torch.device | str = "cpu") -> None:
        self.capacity = capacity
        self.device = torch.device(device)
        """Where sampled states go (the learner's update device)."""
        self.obs = np.zeros((capacity, obs_dim), np.float32)
        self.action = np.zeros((capacity, act_dim), np.float32)
        self.next_obs = np.zeros((capacity, obs_dim), np.float32)
        self.cost = np.zeros(capacity, np.float32)
        self.size = 0
        self.pos = 0

    def __len__(self) -> int:
        return self.size

    def add_batch(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray, cost: np.ndarray) -> None:
        n = len(obs)
        if n > self.capacity:
            obs, action, next_obs, cost = (
                obs[-self.capacity :],
                action[-self.capacity :],
                next_obs[-self.capacity :],
                cost[-self.capacity :],
            )
            n = self.capacity
        idx = (self.pos + np.arange(n)) % self.capacity
        self.obs[idx], self.action[idx], self.next_obs[idx], self.cost[idx] = obs, action, next_obs, cost
        self.pos = int((self.pos + n) % self.capacity)
        self.size = min(self.size + n, self.capacity)

    def sample_obs(self, batch_size: int, rng: np.random.Generator) -> Tensor:
        if self.size == 0:
            raise ValueError("cannot sample from an empty virtual buffer")
        states = torch.from_numpy(self.obs[rng.integers(0, self.size, size=batch_size)])
        return states if self.device.type == "cpu" else states.to(self.device, non_blocking=True)
