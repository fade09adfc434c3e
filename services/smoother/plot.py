"""Plots of a style file in the manner of the paper's Figs 3c, 4b and 5c (matplotlib, Agg).

Raw measures are drawn light, optimised values dark:
- main-subject box components (x0, y0, x1, y1) per frame (Fig. 3c);
- one joint's x and y (default: the chest = mid-point of the shoulders; Fig. 4b);
- focused fraction b per region and the smoothed B, with the threshold theta (Fig. 5c).
"""
from __future__ import annotations

import os
from typing import Any

import numpy as np

from cinetransfer.shared.instructions import StyleFile, diag_array
from cinetransfer.shared.messages import COCO17_NAMES, FOCUS_REGIONS

BOX_NAMES = ("x0", "y0", "x1", "y1")
COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red")


def _joint_series(arr: np.ndarray | None, joint: str) -> np.ndarray | None:
    """(F, 2) series of a joint (or 'chest') from a (F, 17, 2) array."""
    if arr is None or arr.ndim != 3:
        return None
    if joint == "chest":
        ls, rs = COCO17_NAMES.index("left_shoulder"), COCO17_NAMES.index("right_shoulder")
        return 0.5 * (arr[:, ls] + arr[:, rs])
    return arr[:, COCO17_NAMES.index(joint)]


def plot_style(style: StyleFile, out_path: str | os.PathLike, *, joint: str = "chest", title: str | None = None,
               dpi: int = 110) -> None:
    """Draw the three panels into `out_path` (format from the extension: png, pdf, svg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if joint != "chest" and joint not in COCO17_NAMES:
        raise ValueError(f"joint {joint!r} is not 'chest' or a COCO-17 name")
    ins, diag = style.instructions, style.diagnostics
    K = ins.image_targets.shape[0]
    t = ins.first_frame + np.arange(K)
    fig, axes = plt.subplots(3, 1, figsize=(10, 9), sharex=True)

    ax = axes[0]
    raw_box = diag_array(diag, "raw_box")
    for k in range(4):
        if raw_box is not None:
            ax.plot(t, raw_box[:, k], ".", ms=3, color=COLORS[k], alpha=0.35)
        ax.plot(t, ins.subject_box[:, k], "-", lw=1.6, color=COLORS[k], label=BOX_NAMES[k])
    ax.set_ylabel("main-subject box\n(normalised)")
    ax.invert_yaxis()
    ax.legend(loc="upper right", ncol=4, fontsize=8)
    ax.set_title(title or f"{os.path.basename(ins.source.path) or 'style'}: raw (light) vs optimised (dark)")

    ax = axes[1]
    raw_j = _joint_series(diag_array(diag, "raw_joints"), joint)
    sm_j = _joint_series(diag_array(diag, "smoothed_joints"), joint)
    if sm_j is None:  # no diagnostics: the controlled joints of the instructions
        names = list(ins.joint_names)
        if joint == "chest" and {"left_shoulder", "right_shoulder"} <= set(names):
            sm_j = 0.5 * (ins.image_targets[:, names.index("left_shoulder")]
                          + ins.image_targets[:, names.index("right_shoulder")])
        elif joint in names:
            sm_j = ins.image_targets[:, names.index(joint)]
    for k, lab in enumerate(("x", "y")):
        if raw_j is not None:
            ax.plot(t, raw_j[:, k], ".", ms=3, color=COLORS[k], alpha=0.35)
        if sm_j is not None:
            ax.plot(t, sm_j[:, k], "-", lw=1.6, color=COLORS[k], label=f"{joint} {lab}")
    ax.set_ylabel(f"{joint}\n(normalised)")
    ax.legend(loc="upper right", fontsize=8)

    ax = axes[2]
    for k, name in enumerate(FOCUS_REGIONS):
        ax.plot(t, ins.focus_raw[:, k], ".", ms=3, color=COLORS[k], alpha=0.35)
        ax.plot(t, ins.focus_smoothed[:, k], "-", lw=1.6, color=COLORS[k], label=f"{name} B")
        on = ins.focus_in[:, k]
        if on.any():
            ax.fill_between(t, -0.02 - 0.04 * k, -0.05 - 0.04 * k, where=on, step="mid", color=COLORS[k], alpha=0.8)
    ax.axhline(ins.theta, color="k", ls="--", lw=0.8, label=f"theta = {ins.theta:g}")
    ax.set_ylim(-0.2, 1.05)
    ax.set_ylabel("focused fraction\nb (light), B (dark)")
    ax.set_xlabel("frame")
    ax.legend(loc="upper right", ncol=4, fontsize=8)
    fig.tight_layout()
    fig.savefig(out_path, dpi=dpi)
    plt.close(fig)


def summary(style: StyleFile) -> dict[str, Any]:
    """A few numbers about a style file (printed by the CLI)."""
    ins = style.instructions
    K = ins.image_targets.shape[0]
    return {"frames": K, "fps": ins.fps, "visible": float(ins.subject_visible.mean()) if K else 0.0,
            "focus_in": {r: float(ins.focus_in[:, k].mean()) if K else 0.0 for k, r in enumerate(FOCUS_REGIONS)}}
