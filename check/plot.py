"""The check's picture for people: the board with its measured pairs coloured by error, and the numbers."""

from __future__ import annotations

import numpy as np

from measure import Frame

from check.result import CheckResult


def _text(rep: dict, title: str) -> str:
    f = rep["figures"]

    def n(x, fmt="{:.1f}"):
        return "-" if x is None else fmt.format(x)

    import textwrap

    lines = [
        *textwrap.wrap(title, 58),
        f"status: {rep['status'].upper()}",
        "",
        f"board {f['board']['squares']} x {f['board']['square_mm']:g} mm at {n(f['distance_m'], '{:.2f}')} m, "
        f"tilt {n(f['tilt_deg'])} deg",
        f"{f['pairs']} pairs on {f['frames_with_board']}/{f['frames']} frames",
        f"mean A {f['mean_accuracy']:.2f}   median A {f['median_accuracy']:.2f}",
        f"bias {f['bias_pct']:+.2f} % (long pairs, ±{1.96 * f['bias_se_pct']:.2f})",
        f"spread {f['spread_pct']:.2f} %   95 % of long pairs within ±{f['expected_pm_pct']:.2f} %",
        f"good {100 * f['good_share']:.0f} %   truth inside interval {100 * f['interval_coverage']:.0f} %",
        f"fill rate {n(None if f['fill_rate'] is None else 100 * f['fill_rate'], '{:.0f}')} %   "
        f"plane-fit RMS {n(f['plane_rms_mm'])} mm (robust {n(f['plane_noise_mm'])} mm)",
        f"stereo depth vs pose {n(f['depth_vs_pose_pct'], '{:+.2f}')} %",
    ]
    if f["frame_spread_pct"] is not None:
        lines.append(f"frame-to-frame spread {f['frame_spread_pct']:.2f} % ({f['frame_spread_mm']:.2f} mm)")
    lines.append("")
    lines.append("per length: n, mean A, bias %")
    for label, v in f["per_length"].items():
        lines.append(f"  {label:12s} {v['n']:4d}  {v['mean_accuracy']:6.2f}  {v['bias_pct']:+.2f}")
    return "\n".join(lines)


def _findings_text(rep: dict, width: int = 95) -> str:
    import textwrap

    if not rep["findings"]:
        return "Nothing to act on."
    out = []
    for f in rep["findings"]:
        out.append(textwrap.fill(f"[{f['severity']}] measured: {f['measured']}", width))
        if f["cause"]:
            out.append(textwrap.fill(f"likely cause: {f['cause']}", width, initial_indent="    ", subsequent_indent="    "))
        if f["action"]:
            out.append(textwrap.fill(f"do: {f['action']}", width, initial_indent="    ", subsequent_indent="    "))
    return "\n".join(out)


def render_check_png(frame: Frame, result: CheckResult, rep: dict, title: str = "depthruler check") -> bytes:
    """The check's picture as PNG bytes (1500 x 840 px): the board of the first frame that showed it with
    its pairs coloured by signed error (% of the true length), the error against the true length (mm)
    of every pair, the numbers and the findings of ``rep`` (:func:`check.run.report`)."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.colors import TwoSlopeNorm

    first = result.views[0].frame
    pairs = [p for p in result.pairs if p.frame == first] or list(result.pairs)
    err = np.array([p.error_pct for p in pairs])
    vmax = max(1.0, float(np.percentile(np.abs(err), 95)))
    det = result.detections[0]
    x0, y0 = det.corners.min(axis=0)
    x1, y1 = det.corners.max(axis=0)
    pad = 0.25 * max(x1 - x0, y1 - y0)
    h, w = frame.image.shape[:2]
    xa, xb = int(max(0, x0 - pad)), int(min(w, x1 + pad))
    ya, yb = int(max(0, y0 - pad)), int(min(h, y1 + pad))
    fig = plt.figure(figsize=(15, 8.4), dpi=100)
    ax = fig.add_axes((0.01, 0.30, 0.55, 0.66))
    ax.imshow(frame.image[ya:yb, xa:xb, ::-1], extent=(xa - 0.5, xb - 0.5, yb - 0.5, ya - 0.5))
    order = np.argsort(np.abs(err))  # the worst pairs on top
    segs = [[pairs[i].p1_px, pairs[i].p2_px] for i in order]
    lc = LineCollection(segs, cmap="coolwarm", norm=TwoSlopeNorm(0.0, -vmax, vmax), linewidths=1.6, alpha=0.9)
    lc.set_array(err[order])
    ax.add_collection(lc)
    ax.plot(det.corners[:, 0], det.corners[:, 1], "o", ms=3, color="yellow", mec="black", mew=0.5)
    ax.set_xlim(xa - 0.5, xb - 0.5)
    ax.set_ylim(yb - 0.5, ya - 0.5)
    ax.set_xticks([])
    ax.set_yticks([])
    cb = fig.colorbar(lc, ax=ax, fraction=0.04, pad=0.01)
    cb.set_label("signed error, % of the true length (red = reads long)")
    ax.set_title(f"frame {first}: {len(pairs)} corner pairs measured as clicked at the corners")
    tx = fig.add_axes((0.60, 0.30, 0.39, 0.66))
    tx.axis("off")
    tx.text(0, 1, _text(rep, title), va="top", family="monospace", fontsize=10)
    sc = fig.add_axes((0.05, 0.05, 0.22, 0.2))
    allp = result.pairs
    sc.scatter([1000 * p.pair.length_m for p in allp], [p.error_pct for p in allp], s=6, c="#1f77b4", alpha=0.5)
    sc.axhline(0, color="k", lw=0.8)
    sc.axhline(rep["figures"]["bias_pct"], color="r", lw=1, ls="--")
    sc.set_xlabel("true length (mm)")
    sc.set_ylabel("error (%)")
    lim = max(1.0, float(np.percentile(np.abs([p.error_pct for p in allp]), 98)) * 1.2)
    sc.set_ylim(-lim, lim)
    fx = fig.add_axes((0.31, 0.0, 0.68, 0.27))
    fx.axis("off")
    text = _findings_text(rep)
    n_lines = text.count("\n") + 1
    fx.text(0, 0.95, text, va="top", family="monospace", fontsize=8.5 if n_lines <= 15 else max(5.0, 8.5 * 15 / n_lines))
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()
