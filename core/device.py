"""Where the learner's update runs: ``auto``, ``cpu`` or ``cuda``, resolved in one place (:func:`resolve_device`).

The learner's trained networks, their optimisers, the batches it samples and a copy of the world model's folded
weights (the fear terms of its update) live on the device; what acts in the loop (the policy the environment
and the SAGE gate read, one state at a time) and the world model's fit stay on the CPU, where one small forward
costs microseconds and a GPU only adds a transfer. Checkpoints are written device-free (every tensor on the CPU)
and read with ``map_location="cpu"``, so a run trained on a GPU loads on a machine without one and the other way
round. ``auto`` is CUDA when torch sees a GPU, else the CPU: a CPU-only machine behaves as before.
"""

from __future__ import annotations

from typing import Any

import torch

DEVICE_CHOICES = ("auto", "cpu", "cuda")
"""What ``--device`` accepts."""


class DeviceError(ValueError):
    """A device that this machine or this torch cannot give (one line for the command line)."""


def cuda_available() -> bool:
    """Whether torch sees a usable CUDA device (False on a CPU-only torch)."""
    return bool(torch.cuda.is_available())


def resolve_device(name: str | torch.device | None) -> torch.device:
    """``auto`` (or None): CUDA when present, else the CPU; ``cpu``; ``cuda`` / ``cuda:N`` (a DeviceError where torch
    has no CUDA, naming the fix)."""
    if isinstance(name, torch.device):
        name = str(name)
    choice = "auto" if name is None else str(name).strip().lower()
    if choice == "auto":
        return torch.device("cuda" if cuda_available() else "cpu")
    if choice == "cpu":
        return torch.device("cpu")
    if choice == "cuda" or choice.startswith("cuda:"):
        if not cuda_available():
            build = "a CPU-only torch" if torch.version.cuda is None else f"torch built for CUDA {torch.version.cuda}"
            raise DeviceError(
                f"--device {choice}: no CUDA device is available ({build}); use --device cpu, or install a CUDA torch "
                "(docs/setup.md)"
            )
        try:
            device = torch.device(choice)
        except RuntimeError as exc:
            raise DeviceError(f"--device {choice}: {exc}") from None
        if device.index is not None and device.index >= torch.cuda.device_count():
            raise DeviceError(f"--device {choice}: this machine has {torch.cuda.device_count()} CUDA device(s)")
        return device
    raise DeviceError(f"--device {name!r}: choose one of {', '.join(DEVICE_CHOICES)}")


def device_name(device: torch.device) -> str:
    """What a report says ran the update: the card's name on CUDA, the processor's model on the CPU."""
    if device.type == "cuda":
        return str(torch.cuda.get_device_name(device))
    return processor_name()


def processor_name() -> str:
    """The CPU's model name (``/proc/cpuinfo``; the platform's processor string elsewhere)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as info:
            for line in info:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    import platform

    return platform.processor() or platform.machine() or "unknown processor"


def to_cpu(value: Any) -> Any:
    """A state (nested dicts, lists and tensors) with every tensor on the CPU: what a checkpoint saves."""
    if isinstance(value, torch.Tensor):
        return value.detach().cpu() if value.device.type != "cpu" else value
    if isinstance(value, dict):
        return type(value)((k, to_cpu(v)) for k, v in value.items())
    if isinstance(value, list):
        return [to_cpu(v) for v in value]
    if isinstance(value, tuple):
        return tuple(to_cpu(v) for v in value)
    return value
