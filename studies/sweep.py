"""Run a study's trials (method x training seed) on Ray Tune, one process per trial.

libsumo allows one simulation per process and is not thread-safe, so every trial runs in its own Ray worker
process (never in threads, never in a home-made pool). Locally Ray uses this machine's cores (``cpus``, default
all of them, each trial taking one); ``address`` joins an existing Ray cluster instead, which is how a ``full``
budget is meant to run. Tune keeps its experiment state under ``storage/name``: calling :func:`run_sweep` again
with the same folder resumes it, rerunning only the trials that had not finished or had failed. A progress bar
counts finished trials.

A trial is a plain picklable function ``trial(config) -> {metric: value}``; ``config`` holds ``method``,
``seed`` and the sweep's fixed settings. Each trial process sets torch to one thread so that concurrent
trials do not oversubscribe the cores.

Tune's state lives on the machine that ran it. A :class:`TrialLedger` keeps each finished trial's row beside the
results, one small JSON file a trial written as the trial finishes, in a folder meant to be committed: a study that
outlives a session (or a machine) resumes from it anywhere, running only the trials it lacks.
"""

from __future__ import annotations

import hashlib
import json
import os
import socket
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

TrialFn = Callable[[dict[str, Any]], Mapping[str, float]]


class SweepError(RuntimeError):
    """Some trials failed; the finished ones are kept in the sweep folder and a rerun resumes the rest."""


class SweepInterrupted(SweepError):
    """The sweep was stopped (Ctrl+C) before every trial finished; the finished ones are kept for a rerun."""


class LedgerError(ValueError):
    """A trial ledger row that ran with other settings or cannot be read; ``str()`` is one line saying what to do."""


CASE = "trial"
"""The config key of a sweep's (method, seed) when it runs only some pairs of its grid (a ledger held the rest)."""


def _trial_config(config: Mapping[str, Any]) -> dict[str, Any]:
    """A trial's config with its (method, seed) at the top level, however the sweep laid out its grid."""
    flat = {k: v for k, v in config.items() if k != CASE}
    flat.update(config.get(CASE) or {})
    return flat


def _run_trial(config: dict[str, Any], trial: TrialFn) -> dict[str, float]:
    """Inside the Ray worker: one torch thread, then the trial itself (its return value is the result)."""
    import torch

    torch.set_num_threads(1)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    result = dict(trial(_trial_config(config)))
    bad = [k for k, v in result.items() if not isinstance(v, (int, float))]
    if bad:
        raise TypeError(f"trial results must be numbers; {bad} are not")
    return result


INVOCATION_KEYS = frozenset({"methods"})
"""Sweep settings that say what one invocation runs, not how a trial runs: left out of a ledger's settings."""


@dataclass(frozen=True)
class TrialLedger:
    """Finished trials' rows, ``<method>-s<seed>.json`` in ``folder``, each with the settings it ran with.

    Meant to be committed beside a study's table: Tune's experiment state (``sweep/``) and the run folders are not,
    so without it a study interrupted on one machine starts again from nothing on the next. ``settings`` are the
    sweep's fixed settings with the machine's paths (``root``, the results folder, and the checkout) written as
    placeholders, so that the same study on another machine reads the same; a ledger row run with other settings is
    refused, never mixed into a table.
    """

    folder: Path
    settings: Mapping[str, Any]

    @classmethod
    def for_results(cls, folder: Path, settings: Mapping[str, Any], root: Path) -> TrialLedger:
        """The ledger ``folder`` of a study whose results folder is ``root``, for ``settings`` (portable form)."""
        repo = Path(__file__).resolve().parent.parent
        swaps = [(str(Path(root).resolve()), "<results>"), (str(repo), "<repo>")]
        # which methods an invocation runs does not change a trial: a later call may ask for more or fewer of them
        trial_settings = {k: v for k, v in settings.items() if k not in INVOCATION_KEYS}
        return cls(Path(folder), _portable(trial_settings, swaps))

    def path(self, method: str, seed: int) -> Path:
        return self.folder / f"{method}-s{seed}.json"

    @property
    def digest(self) -> str:
        return hashlib.sha256(json.dumps(self.settings, sort_keys=True, default=str).encode()).hexdigest()[:16]

    def read(self, methods: Sequence[str], seeds: Sequence[int]) -> dict[tuple[str, int], dict[str, Any]]:
        """The rows this ledger holds for these (method, seed) pairs. :class:`LedgerError` for a row that ran with
        other settings or cannot be read: the person decides, the table never mixes them."""
        rows: dict[tuple[str, int], dict[str, Any]] = {}
        for method in methods:
            for seed in seeds:
                path = self.path(method, seed)
                if not path.is_file():
                    continue
                try:
                    entry = json.loads(path.read_text())
                    row = {"method": method, "seed": seed, **entry["row"]}
                    theirs = entry["settings"]
                except (OSError, ValueError, KeyError, TypeError) as error:
                    raise LedgerError(
                        f"{path}: not a trial ledger row ({error}); delete it to run that trial again"
                    ) from None
                ours = json.loads(json.dumps(self.settings, default=str))
                if theirs != ours:
                    differ = sorted(k for k in {*theirs, *ours} if theirs.get(k) != ours.get(k))
                    raise LedgerError(
                        f"{path} ran with other settings ({', '.join(differ)}): give another results folder, or "
                        "delete that file to run the trial again with these settings"
                    )
                rows[(method, seed)] = row
        return rows

    def write(self, row: Mapping[str, Any]) -> None:
        """Keep one finished trial's row (atomically: an interrupted write leaves the old file or none)."""
        method, seed = str(row["method"]), int(row["seed"])
        entry = {
            "row": {k: v for k, v in row.items() if k not in ("method", "seed")},
            "settings": self.settings,
            "digest": self.digest,
        }
        self.folder.mkdir(parents=True, exist_ok=True)
        path = self.path(method, seed)
        partial = path.with_suffix(".json.partial")
        partial.write_text(json.dumps(entry, indent=1, sort_keys=True, default=str) + "\n")
        partial.replace(path)


def _portable(value: Any, swaps: Sequence[tuple[str, str]]) -> Any:
    """``value`` with absolute paths under the results folder or the checkout written as placeholders."""
    if isinstance(value, str):
        for prefix, placeholder in swaps:
            if value == prefix or value.startswith(prefix + os.sep):
                return placeholder + value[len(prefix) :]
        return value
    if isinstance(value, Mapping):
        return {str(k): _portable(v, swaps) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_portable(v, swaps) for v in value]
    return value


def _trial_row(config: Mapping[str, Any], metrics: Mapping[str, Any]) -> dict[str, Any] | None:
    """A finished trial's row from Tune's config and last result; None where the trial reported nothing of its
    own (it was stopped before it finished)."""
    own = {k: v for k, v in metrics.items() if k not in _TUNE_KEYS}
    if not own:
        return None
    flat = _trial_config(config)
    seconds = float(metrics.get("time_total_s") or 0.0)
    return {"method": flat["method"], "seed": flat["seed"], "trial_seconds": seconds, **own}


def _ledger_callback(ledger: TrialLedger) -> Any:
    from ray.tune import Callback

    class _Ledger(Callback):
        """Writes each trial's row into the ledger the moment it finishes, so a stop later loses none of them."""

        def on_trial_complete(self, iteration: int, trials: list[Any], trial: Any, **info: Any) -> None:
            row = _trial_row(trial.config or {}, trial.last_result or {})
            if row is not None:
                ledger.write(row)

    return _Ledger()


def _progress_callback(total: int) -> Any:
    from ray.tune import Callback
    from tqdm import tqdm

    class _Progress(Callback):
        """A progress bar over trials (finished or failed) for the person waiting on the sweep."""

        def __init__(self) -> None:
            self.bar: Any = None

        def __getstate__(self) -> dict[str, Any]:
            # Tune pickles its callbacks with the experiment state; a terminal stream does not pickle.
            return {"bar": None}

        def _tick(self) -> None:
            if self.bar is None:
                self.bar = tqdm(total=total, desc="trials", unit="trial")
            self.bar.update(1)

        def on_trial_complete(self, iteration: int, trials: list[Any], trial: Any, **info: Any) -> None:
            self._tick()

        def on_trial_error(self, iteration: int, trials: list[Any], trial: Any, **info: Any) -> None:
            self._tick()

        def on_experiment_end(self, trials: list[Any], **info: Any) -> None:
            if self.bar is not None:
                self.bar.close()

    return _Progress()


class ClusterError(ValueError):
    """The Ray cluster at ``--address`` cannot be reached or joined; ``str()`` is one line saying what to do."""


ADDRESS_TIMEOUT = 3.0
"""Seconds to wait for a TCP connection to a cluster's address before saying it cannot be reached."""


def check_cluster_address(address: str, timeout: float = ADDRESS_TIMEOUT) -> tuple[str, int]:
    """``address`` (``HOST:PORT``, the head's GCS port that ``ray start --head`` printed) as host and port, after a
    TCP connection to it succeeded. Otherwise :class:`ClusterError` at once: ``ray.init`` would retry an address
    where nothing answers for about 14 minutes before failing with a double traceback."""
    target = address.strip().removeprefix("ray://")  # a Ray Client address is checked the same way
    host, sep, port_text = target.rpartition(":")
    host = host.strip("[]")  # an IPv6 address in brackets
    if not sep or not host or not port_text.isdigit() or not 0 < int(port_text) < 65536:
        raise ClusterError(
            f"--address {address!r} is not HOST:PORT: give the address `ray start --head` printed, e.g. 10.0.0.5:6379"
        )
    port = int(port_text)
    advice = f"start one there with `ray start --head --port {port}`, or give the address its head printed"
    try:
        with socket.create_connection((host, port), timeout=timeout) as connection:
            # the head's GCS is a gRPC server: it answers an HTTP/2 preface with a SETTINGS frame. A port that
            # accepts and says nothing (another service, a proxy) would have ray.init retry for minutes
            connection.sendall(HTTP2_PREFACE + HTTP2_EMPTY_SETTINGS)
            frame = _read_exactly(connection, 9)
    except OSError as exc:
        reason = "timed out" if isinstance(exc, TimeoutError) else (exc.strerror or type(exc).__name__).lower()
        raise ClusterError(
            f"no Ray cluster answers at {host}:{port} ({reason} after {timeout:g} s): {advice}"
        ) from None
    if len(frame) < 9 or frame[3] != HTTP2_SETTINGS:
        raise ClusterError(f"what answers at {host}:{port} is not a Ray cluster (it does not speak gRPC): {advice}")
    return host, port


HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n"
HTTP2_EMPTY_SETTINGS = b"\x00\x00\x00\x04\x00\x00\x00\x00\x00"
HTTP2_SETTINGS = 0x04
"""The frame type a gRPC server sends first."""


def _read_exactly(connection: socket.socket, size: int) -> bytes:
    """Up to ``size`` bytes (fewer when the peer closes), within the connection's timeout."""
    data = b""
    while len(data) < size:
        chunk = connection.recv(size - len(data))
        if not chunk:
            break
        data += chunk
    return data


def token_auth_for_cluster() -> bool:
    """Ask Ray for token authentication when a token is at hand and no mode was chosen: with ``~/.ray/auth_token``
    present, ``ray start --head`` starts a token-auth cluster, and ``ray.init(address=...)`` is then refused
    (InvalidAuthToken) unless ``RAY_AUTH_MODE=token`` is set. True when it was set here."""
    if os.environ.get("RAY_AUTH_MODE"):
        return False
    path = os.environ.get("RAY_AUTH_TOKEN_PATH")
    token_file = Path(path).expanduser() if path else Path.home() / ".ray" / "auth_token"
    if not (os.environ.get("RAY_AUTH_TOKEN") or token_file.is_file()):
        return False
    os.environ["RAY_AUTH_MODE"] = "token"
    try:  # Ray reads its settings once, when imported: read them again, as Ray itself does when it sets the mode
        from ray._raylet import Config  # type: ignore[attr-defined]  # Ray's _raylet.pyi leaves out Config

        Config.initialize("")
    except (ImportError, AttributeError):  # pragma: no cover - another Ray version: the mode set before import
        pass
    return True


def ensure_ray(address: str | None = None, cpus: int | None = None) -> None:
    """Start local Ray with ``cpus`` cores (default: all), or join the cluster at ``address``
    (:class:`ClusterError`, one line, when it cannot be reached or joined)."""
    import ray

    if ray.is_initialized():
        return
    if address is not None:
        if address != "auto":  # "auto": the cluster this machine's `ray start` runs, which Ray finds itself
            check_cluster_address(address)
        token_auth_for_cluster()
        try:
            ray.init(address=address, include_dashboard=False, log_to_driver=False)
        except Exception as exc:  # Ray's own errors run to many lines; the first says what went wrong
            first = next((line for line in str(exc).splitlines() if line.strip()), type(exc).__name__)
            raise ClusterError(f"cannot join the Ray cluster at {address}: {type(exc).__name__}: {first}") from None
    else:
        # Ray lowers its workers' priority by 15 by default: on a machine that runs anything else beside the study
        # (another study, the tests), its trials then get a small share of the cores and the study stalls
        # (measured: one trial 8 min of CPU in 72 min of wall beside three nice-5 jobs). The trials are the study's
        # work: they run at the priority the study was started with (`nice -n 10 sage study ...` stays that).
        os.environ.setdefault("RAY_worker_niceness", "0")
        ray.init(num_cpus=cpus or os.cpu_count() or 1, include_dashboard=False, log_to_driver=False)


def _run_task(fn: Callable[..., Any], kwargs: Mapping[str, Any]) -> Any:
    """Inside a Ray worker: one torch thread, as in a trial, then ``fn(**kwargs)``."""
    import torch

    torch.set_num_threads(1)
    return fn(**kwargs)


def run_tasks(
    fn: Callable[..., Any],
    calls: Sequence[Mapping[str, Any]],
    labels: Sequence[str] | None = None,
    address: str | None = None,
    cpus: int | None = None,
) -> list[Any]:
    """``fn(**kwargs)`` for each of ``calls`` as Ray tasks, at once where the cores allow; results in order.
    ``labels`` name the calls in errors (default: their positions).

    For the work a study does before its sweep (e.g. training one expert per route). Each task takes one core and
    a fresh worker process that exits afterwards (``max_calls=1``): libsumo allows one simulation per process, and
    a reused worker would already hold one. Raises :class:`SweepError` naming the failed calls after all the
    others have finished; what they wrote (cached experts) stays for a rerun.
    """
    import ray

    names = list(labels) if labels is not None else [f"call {i}" for i in range(len(calls))]
    if len(names) != len(calls):
        raise ValueError(f"{len(names)} labels for {len(calls)} calls")
    ensure_ray(address, cpus)
    task = ray.remote(num_cpus=1, max_calls=1, max_retries=0)(_run_task)
    refs = [task.remote(fn, dict(kwargs)) for kwargs in calls]
    results: list[Any] = []
    failed: list[str] = []
    for name, ref in zip(names, refs, strict=True):
        try:
            results.append(ray.get(ref))
        except Exception as error:  # every failure is reported together below, after the others finish
            results.append(None)
            cause = getattr(error, "cause", None) or error  # Ray wraps it with the worker's traceback
            failed.append(f"{name}: {type(cause).__name__}: {cause}")
    if failed:
        raise SweepError(f"{len(failed)} of {len(calls)} tasks failed (rerun to resume): " + "; ".join(failed))
    return results


def trial_gpu_share(device: str, concurrent: int | None) -> float:
    """What part of a GPU each trial asks Ray for: none on the CPU; on CUDA one GPU shared by the trials that run
    at once (``concurrent``; default: one per core), so that Ray packs them on it rather than queueing them."""
    if not device.startswith("cuda"):
        return 0.0
    import os

    return 1.0 / max(1, concurrent or os.cpu_count() or 1)


def run_sweep(
    trial: TrialFn,
    methods: Sequence[str],
    seeds: Sequence[int],
    storage: Path,
    name: str,
    settings: Mapping[str, Any] | None = None,
    address: str | None = None,
    cpus: int | None = None,
    max_concurrent: int | None = None,
    gpu_share: float = 0.0,
    ledger: TrialLedger | None = None,
) -> list[dict[str, Any]]:
    """Run ``trial`` for every (method, seed), resuming ``storage/name`` if it exists; one row per trial.
    ``gpu_share``: the part of a GPU each trial asks Ray for (:func:`trial_gpu_share`; 0: none, CPU trials).

    Each row holds ``method``, ``seed``, ``trial_seconds`` (the trial's own run time, also for trials restored from
    an earlier run) and the trial's metrics, sorted by method then seed. ``settings``
    are passed to every trial unchanged (budget, study options). ``max_concurrent`` caps simultaneous
    trials (default: as many as the cores allow). ``ledger``: where finished trials' rows are kept as they finish
    and read back first: only the pairs it lacks run (none: no Ray at all). Raises :class:`SweepError` naming the
    failed trials after all others have finished, :class:`SweepInterrupted` when stopped before the end.
    """
    if not methods or not seeds:
        raise ValueError("a sweep needs at least one method and one seed")
    if len(set(seeds)) != len(seeds) or len(set(methods)) != len(methods):
        raise ValueError(f"duplicate methods or seeds: {list(methods)}, {list(seeds)}")
    pairs = [(m, s) for m in methods for s in seeds]
    kept = ledger.read(methods, seeds) if ledger is not None else {}
    pending = [pair for pair in pairs if pair not in kept]
    found = dict(kept)
    if pending:
        ran = _run_pending(
            trial, pairs, pending, Path(storage), name, settings, address, cpus, max_concurrent, gpu_share, ledger
        )
        found.update(ran)
    return sorted(found.values(), key=lambda r: (list(methods).index(r["method"]), r["seed"]))


def _stored_pairs(tuner: Any) -> set[tuple[Any, Any]]:
    """The (method, seed) pairs a restored Tune experiment holds, run or not (none if it cannot say)."""
    try:
        grid = tuner.get_results()
    except Exception:  # an experiment state Ray cannot read back: treated as holding nothing
        return set()
    pairs = set()
    for result in grid:
        config = _trial_config(result.config or {})
        pairs.add((config.get("method"), config.get("seed")))
    return pairs


def _run_pending(
    trial: TrialFn,
    pairs: Sequence[tuple[str, int]],
    pending: Sequence[tuple[str, int]],
    storage: Path,
    name: str,
    settings: Mapping[str, Any] | None,
    address: str | None,
    cpus: int | None,
    max_concurrent: int | None,
    gpu_share: float,
    ledger: TrialLedger | None,
) -> dict[tuple[str, int], dict[str, Any]]:
    """Tune over the ``pending`` pairs (or the experiment state in ``storage/name``, resumed): their rows."""
    from ray import tune

    ensure_ray(address, cpus)
    storage = storage.resolve()
    storage.mkdir(parents=True, exist_ok=True)
    resources = {"cpu": 1, **({"gpu": gpu_share} if gpu_share > 0 else {})}
    trainable = tune.with_resources(tune.with_parameters(_run_trial, trial=trial), resources)
    path = storage / name
    callbacks = [_progress_callback(len(pending)), *([_ledger_callback(ledger)] if ledger is not None else [])]
    run_config = tune.RunConfig(storage_path=str(storage), name=name, callbacks=callbacks, verbose=0)
    tuner = None
    if tune.Tuner.can_restore(str(path)):
        tuner = tune.Tuner.restore(str(path), trainable, resume_errored=False, restart_errored=True, param_space=None)
        if not set(pending) <= _stored_pairs(tuner):
            # laid out for other pairs (another --methods or --seeds): resumed, it would never run the ones asked
            # for now. Kept aside; the trials it finished are in the ledger (without one, they run again)
            aside = path.with_name(f"{name}.before-{time.strftime('%Y%m%dT%H%M%S')}")
            path.rename(aside)
            print(f"sweep: the stored experiment {path} lacks trials asked for now; moved to {aside}", file=sys.stderr)
            tuner = None
    if tuner is None:
        methods = list(dict.fromkeys(m for m, _ in pending))
        seeds = list(dict.fromkeys(s for _, s in pending))
        if len(methods) * len(seeds) == len(pending):  # a whole grid: laid out as every earlier sweep was
            grid = {"method": tune.grid_search(methods), "seed": tune.grid_search(seeds)}
        else:  # the pairs a ledger lacks
            grid = {CASE: tune.grid_search([{"method": m, "seed": s} for m, s in pending])}
        tuner = tune.Tuner(
            trainable,
            param_space={**dict(settings or {}), **grid},
            tune_config=tune.TuneConfig(max_concurrent_trials=max_concurrent or 0),
            run_config=run_config,
        )
    try:
        results = tuner.fit()
    except KeyboardInterrupt:  # a second Ctrl+C: Tune's own stop was cut short
        where = ledger.folder if ledger is not None else path
        raise SweepInterrupted(f"stopped; the trials that had finished are kept in {where}: rerun to resume") from None
    rows: dict[tuple[str, int], dict[str, Any]] = {}
    failed: list[str] = []
    unfinished = 0
    for i in range(len(results)):  # a ResultGrid has __len__ and __getitem__, no __iter__
        result = results[i]
        config = _trial_config(result.config or {})
        if (config.get("method"), config.get("seed")) not in pairs:
            continue
        if result.error is not None:
            failed.append(f"{config.get('method')} seed {config.get('seed')}: {result.error!r}")
            continue
        row = _trial_row(result.config or {}, result.metrics or {})
        if row is None:
            unfinished += 1
            continue
        if ledger is not None:
            ledger.write(row)  # also the trials a resumed Tune state had finished before the ledger existed
        rows[(row["method"], row["seed"])] = row
    if failed:
        raise SweepError(f"{len(failed)} of {len(pairs)} trials failed (rerun to resume): " + "; ".join(failed))
    if unfinished:
        where = ledger.folder if ledger is not None else path
        raise SweepInterrupted(
            f"stopped with {unfinished} of {len(pairs)} trials unfinished; the finished ones are kept in {where}: "
            "rerun the same command to resume"
        )
    return rows


_TUNE_KEYS = {
    "timestamp", "checkpoint_dir_name", "done", "training_iteration", "trial_id", "date", "time_this_iter_s",
    "time_total_s", "pid", "hostname", "node_ip", "config", "time_since_restore", "iterations_since_restore",
    "experiment_tag",
}  # fmt: skip
"""What Tune adds to every result; everything else is the trial's own metrics."""


def _metric_keys(result: Any) -> set[str]:
    return {k for k in (result.metrics or {}) if k not in _TUNE_KEYS}
