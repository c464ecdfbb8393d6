"""The replay buffer's reads per learner update: the kept indices and reward bounds against the scans they replaced.

    .venv/bin/python -m bench.bench_replay [--rows 20000,200000] [--rounds 7] [--updates 300] [--write docs/speed.md]

Every SAGE-SAC update samples a batch (a fine-tuning round's buffer: fixed shares of the base's drives and the
session's rows), a batch of takeover rows for the imitation term, and reads the reward's bounds and magnitude for c*;
between updates the loop adds a row. Until this bench's change each of those reads scanned the whole buffer
(``np.flatnonzero`` over the flags, a mask over the rewards); now the buffer keeps the indices and bounds as rows are
written (``core.replay.SortedRows``). Both buffers are filled alike (a tenth terminal, 5% takeovers, the first half of
the rows the base's), then take turns update by update, each update's reads timed alone on this process's CPU clock;
per round the median of each and kept/scanned. Both must draw the same rows (checked first).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from core.prior import SharedReplayBuffer
from core.replay import Batch


class ScannedBuffer(SharedReplayBuffer):
    """The reads as they were: a scan of the buffer per call."""

    def sample_takeovers(self, batch_size: int, rng: np.random.Generator) -> Batch | None:
        idx = np.flatnonzero(self.takeover[: self.size])
        return None if len(idx) == 0 else self._batch(idx[rng.integers(0, len(idx), size=batch_size)])

    def reward_magnitude(self) -> float:
        n = self.size
        return float(np.abs(self.reward[:n]).max()) if n else 0.0

    def reward_bounds(self) -> tuple[float, float] | None:
        n = self.size
        live = self.terminated[:n] < 0.5
        if not live.any():
            return None
        r = self.reward[:n][live]
        return float(r.min()), float(r.max())

    def sample(self, batch_size: int, rng: np.random.Generator) -> Batch:
        prior = np.flatnonzero(self.prior[: self.size])
        own = np.flatnonzero(~self.prior[: self.size])
        n_prior = round(self.prior_share * batch_size)
        drawn_prior = prior[rng.integers(0, len(prior), size=n_prior)]
        return self._batch(np.concatenate([drawn_prior, own[rng.integers(0, len(own), size=batch_size - n_prior)]]))


OBS, ACT, BATCH = 58, 2, 256


def fill(buffer: SharedReplayBuffer, rows: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    obs = rng.random((rows, OBS), dtype=np.float32)
    reward = rng.normal(size=rows).astype(np.float32)
    terminal, takeover = rng.random(rows) < 0.1, rng.random(rows) < 0.05
    expert = np.ones(ACT, np.float32)
    for i in range(rows):
        buffer.adding_prior = i < rows // 2
        buffer.add(
            obs[i], obs[i, :ACT], float(reward[i]), obs[i], bool(terminal[i]),
            takeover=bool(takeover[i]), a_expert=expert if takeover[i] else None,
        )  # fmt: skip
    buffer.adding_prior = False


def reads(buffer: SharedReplayBuffer, rng: np.random.Generator, row: np.ndarray) -> tuple[float, np.ndarray]:
    """One update's reads and the row added after it; the time of the reads alone (CPU clock)."""
    start = time.process_time()
    batch = buffer.sample(BATCH, rng)
    takeovers = buffer.sample_takeovers(BATCH, rng)
    buffer.reward_bounds(), buffer.reward_magnitude()
    spent = time.process_time() - start
    buffer.add(row, row[:ACT], 0.5, row, False)
    assert takeovers is not None
    return spent, batch.obs[:, 0].numpy() + takeovers.obs[:, 0].numpy()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rows", default="20000,200000", help="buffer sizes (capacity = rows + updates)")
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--updates", type=int, default=300)
    parser.add_argument("--write", type=Path, help="write the table into this markdown file's generated block")
    args = parser.parse_args()
    from bench.bench_sac import _commit, _loadavg, write_block
    from core.device import processor_name

    lines = ["| rows | kept reads, ms per update | scanned reads, ms per update | kept / scanned (rounds' range) |"]
    lines.append("|---|---|---|---|")
    print(lines[0], lines[1], sep="\n")
    for rows in (int(r) for r in args.rows.split(",")):
        capacity = rows + args.rounds * args.updates + 1
        kept, scanned = SharedReplayBuffer(OBS, ACT, capacity, 0.5), ScannedBuffer(OBS, ACT, capacity, 0.5)
        fill(kept, rows, 0)
        fill(scanned, rows, 0)
        new_rows = np.random.default_rng(1).random((args.rounds * args.updates, OBS), dtype=np.float32)
        kept_rng, scanned_rng = np.random.default_rng(2), np.random.default_rng(2)
        kept_ms, scanned_ms, ratios = [], [], []
        for r in range(args.rounds):
            times_kept, times_scanned = [], []
            for u in range(args.updates):
                row = new_rows[r * args.updates + u]
                t_kept, drawn_kept = reads(kept, kept_rng, row)
                t_scanned, drawn_scanned = reads(scanned, scanned_rng, row)
                if r == 0 and u < 10 and not np.array_equal(drawn_kept, drawn_scanned):
                    raise SystemExit("the kept and the scanned buffers drew different rows")
                times_kept.append(t_kept)
                times_scanned.append(t_scanned)
            kept_ms.append(1e3 * statistics.mean(times_kept))
            scanned_ms.append(1e3 * statistics.mean(times_scanned))
            ratios.append(kept_ms[-1] / scanned_ms[-1])
        lines.append(
            f"| {rows:,} | {statistics.median(kept_ms):.3f} | {statistics.median(scanned_ms):.3f} | "
            f"{statistics.median(ratios):.3f} ({min(ratios):.3f}-{max(ratios):.3f}) |"
        )
        print(lines[-1], flush=True)
    load = ", ".join(f"{x:.2f}" for x in _loadavg())
    note = (
        f"`python -m bench.bench_replay {' '.join(sys.argv[1:])}` at commit {_commit()}, one thread of "
        f"{processor_name()}; batch {BATCH}, {OBS} channels, CPU clock; per size the median over {args.rounds} rounds "
        f"of {args.updates} updates of each buffer's mean reads per update, the two taking turns update by update; "
        f"load average {load} at the end; {time.strftime('%Y-%m-%d', time.gmtime())}."
    )
    print(note)
    if args.write:
        write_block(args.write, "\n".join([note, "", *lines]), TABLE_START, TABLE_END)
        print(f"wrote {args.write}")


TABLE_START = "<!-- bench_replay: start (generated by bench/bench_replay.py --write; do not edit) -->"
TABLE_END = "<!-- bench_replay: end -->"


if __name__ == "__main__":
    main()
