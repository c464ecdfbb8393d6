"""The route-shift figure panels: what is drawn (lines, the switch), read from the returned figures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from studies import route_shift_figures as figures
from studies.route_shift import StudyRun, read_run
from studies.route_shift_figures import write_figures


def synthetic_run(method: str, c1: int = 12, c2: int = 6, fear: bool = True) -> StudyRun:
    """Succeeds throughout C1, fails (collides) in the first half of C2, recovers after."""
    rows = []
    for i in range(c1 + c2):
        in_c2 = i >= c1
        dip = in_c2 and i < c1 + c2 // 2
        row = {
            "episode": i,
            "success": 0.0 if dip else 1.0,
            "collision": 1.0 if dip else 0.0,
            "red_light": 1.0 if i == c1 else 0.0,
            "takeover_rate": 0.5 if dip else 0.1,
            "mean_fear": (0.6 if dip else 0.2) if fear else None,
            "mean_curiosity": 3.0 if in_c2 else 1.0,
        }
        rows.append(row)
    return StudyRun(Path(f"/runs/{method}"), figures_label(method), method, rows, c1)


def figures_label(method: str) -> str:
    from studies.route_shift import method_label

    return method_label(method)


def switch_lines(ax) -> list:
    return [line for line in ax.get_lines() if line.get_gid() == figures.SWITCH_GID]


def test_rates_overlay_every_run_and_mark_the_switch() -> None:
    runs = [synthetic_run("sage"), synthetic_run("sac", fear=False)]
    fig = figures.route_shift_rates(runs, window=3)
    assert [ax.get_title() for ax in fig.axes] == ["Success rate", "Collision rate", "Red-light violation rate"]
    for ax in fig.axes:
        curves = [line for line in ax.get_lines() if line.get_gid() != figures.SWITCH_GID]
        assert [line.get_label() for line in curves] == ["SAGE-RL", "RL (SAC)"]
        (switch,) = switch_lines(ax)
        assert switch.get_xdata()[0] == pytest.approx(12.5)  # between episode 12 (last C1) and 13 (first C2)
    success = fig.axes[0].get_lines()[0]
    x, y = success.get_xdata(), success.get_ydata()
    assert list(x[:2]) == [1, 2] and len(x) == 18
    assert y[11] == pytest.approx(100.0)  # C1 all successes
    assert y[14] == pytest.approx(0.0)  # three C2 failures in the window of 3
    assert y[17] == pytest.approx(100.0)  # recovered
    collision = fig.axes[1].get_lines()[0].get_ydata()
    assert np.allclose(collision, 100.0 - y)


def test_runs_of_different_schedules_are_not_overlaid() -> None:
    with pytest.raises(ValueError, match="different numbers of episodes"):
        figures.route_shift_rates([synthetic_run("sage", c1=12), synthetic_run("sac", c1=10)])


def test_signals_show_takeovers_fear_and_curiosity_with_the_switch() -> None:
    run = synthetic_run("sage")
    fig = figures.sage_signals(run, window=2)
    assert [ax.get_title() for ax in fig.axes] == ["Takeover frequency", "Mean fear", "Mean curiosity"]
    takeover_raw = fig.axes[0].get_lines()[0].get_ydata()
    assert takeover_raw[0] == pytest.approx(10.0) and takeover_raw[12] == pytest.approx(50.0)  # percent
    fear_mean = fig.axes[1].get_lines()[1].get_ydata()
    assert fear_mean[13] == pytest.approx(0.6) and fear_mean[5] == pytest.approx(0.2)
    assert all(len(switch_lines(ax)) == 1 for ax in fig.axes)
    assert figures.has_signals(run) and not figures.has_signals(synthetic_run("sac", fear=False))


def test_default_window_is_a_tenth_of_the_run_within_bounds() -> None:
    assert [figures.default_window(n) for n in (10, 90, 300, 1500)] == [3, 9, 30, 50]


def test_write_figures_gives_rates_for_all_and_signals_for_runs_with_fear(tmp_path: Path) -> None:
    runs = [synthetic_run("sage"), synthetic_run("sac", fear=False)]
    paths = write_figures(runs, tmp_path)
    assert [p.name for p in paths] == ["route_shift_rates.png", "route_shift_signals_sage.png"]
    for path in paths:
        data = path.read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000


def test_read_run_refuses_folders_that_are_not_route_shift_runs(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"metrics\.jsonl"):
        read_run(tmp_path)
    (tmp_path / "metrics.jsonl").write_text('{"phase": "train", "route": 1}\n{"phase": "train", "route": 1}\n')
    with pytest.raises(ValueError, match="not a route-shift run"):
        read_run(tmp_path)
    (tmp_path / "metrics.jsonl").write_text('{"phase": "train", "route": 1}\nnot json\n')
    with pytest.raises(ValueError, match=r"metrics.jsonl:2"):
        read_run(tmp_path)
    # without study.json the switch is where the route changes
    (tmp_path / "metrics.jsonl").write_text(
        '{"phase": "demo", "route": 1}\n' + "".join(f'{{"phase": "train", "route": {r}}}\n' for r in (1, 1, 2))
    )
    run = read_run(tmp_path)
    assert run.switch == 2 and len(run.rows) == 3
