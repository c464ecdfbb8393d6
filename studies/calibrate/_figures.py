"""The calibration's figures: the reliability diagram of ĉ and the operating curve, with report.json."""

from __future__ import annotations

import json
import math
from pathlib import Path

from studies.calibrate._calibration import CalibrationReport
from studies.calibrate._curve import EXPERT_ALONE
from studies.calibrate._metrics import violation_interval


def write_figures(report: CalibrationReport, out: Path) -> list[Path]:
    """reliability.png and (with a curve) operating_curve.png, plus report.json."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    written = []
    (out / "report.json").write_text(json.dumps(report.as_dict(), indent=1, default=float))
    fig, ax = plt.subplots(figsize=(4.6, 4.2), dpi=120)
    ax.plot([0, 1], [0, 1], color="#888", lw=1, ls="--", label="perfect calibration")
    if report.reliability:
        pred, obs, _ = zip(*report.reliability, strict=True)
        ax.plot(pred, obs, "o-", color="#d62728", label="ĉ (predicted violation probability)")
        for x, y, n in report.reliability:
            ax.annotate(str(n), (x, y), textcoords="offset points", xytext=(4, -10), fontsize=7, color="#555")
    ax.set_xlabel("predicted ĉ")
    ax.set_ylabel("observed rate of a violation ahead")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_title(f"{report.sim} {report.scenario}: reliability of ĉ", fontsize=10)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(out / "reliability.png")
    plt.close(fig)
    written.append(out / "reliability.png")
    if report.curve:
        fig, ax = plt.subplots(figsize=(5.2, 4.2), dpi=120)
        colours = {"fear (SAGE)": "#d62728", "random": "#7f7f7f", "curiosity only": "#1f77b4", EXPERT_ALONE: "#000"}
        for name, points in report.curve.items():
            if name == EXPERT_ALONE and points:
                # the floor every gating tends towards as it hands the expert more of the steps: a level, not a curve
                y = points[0]["violation_rate"]
                ax.axhline(y, color=colours[name], lw=0.8, ls=":", label=f"scripted expert alone ({y:.1%})")
                continue
            xs = [p["takeover_rate"] for p in points]
            ys = [p["violation_rate"] for p in points]
            bounds = [violation_interval(p) for p in points]
            if all(math.isfinite(lo) for lo, _ in bounds):
                errors = [
                    # clipped at 0: at 0 or n of n the bound equals the rate up to rounding
                    [max(y - lo, 0.0) for y, (lo, _) in zip(ys, bounds, strict=True)],
                    [max(hi - y, 0.0) for y, (_, hi) in zip(ys, bounds, strict=True)],
                ]
                ax.errorbar(xs, ys, yerr=errors, fmt="o-", capsize=3, lw=1.2, label=name, color=colours.get(name))
            else:
                ax.plot(xs, ys, "o-", label=name, color=colours.get(name))
        ax.set_xlabel("takeover rate (share of steps under the expert)")
        ax.set_ylabel("episodes with a violation (95% Wilson interval)")
        ax.set_xlim(0, 1)
        # up to the highest interval's top, so that curves of a few percent are told apart
        tops = [violation_interval(p)[1] for points in report.curve.values() for p in points]
        top = min(1.0, 1.15 * max((t for t in tops if math.isfinite(t)), default=1.0)) + 0.02
        ax.set_ylim(-0.02 * top, top)
        ax.set_title(f"{report.sim} {report.scenario}: the gate's operating curve", fontsize=10)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(out / "operating_curve.png")
        plt.close(fig)
        written.append(out / "operating_curve.png")
    return written
