"""Where does a learned engine's column run too far or too short? Its front against the MPM's,
frame by frame.

`scripts/final_evaluation.sh` keeps every column case it rolls out (OUT/columns/predicted/CASE)
and the MPM's run of the same scene sits in the MPM cache (cases.csv's `mpm_key`). This reads
both for a few cases of one or more evaluation folders and draws the front (largest soil x, m;
the paper's L_f) and the 99th percentile of the soil's x against frame, MPM beside each file, so
a run that stops late (the toe keeps going), one that is slow from the start, and a few
stragglers ahead of the toe look different. It prints, per case, the final fronts and how many
predicted points end beyond the MPM's front. Nothing is run: the folders must hold the cases.

    PYTHONPATH=src .venv/bin/python experiments/neural_mpm_column_fronts.py runs/final-nmpm-p9 runs/final-c38562 \
        --cases column_a2_phi45_c25,column_a1_phi33.75_c40,column_a1_phi0_c40 --out docs/figures/nmpm_column_fronts.png
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from runout.mpm.cache import DEFAULT_CACHE  # noqa: E402
from runout.trajectory import load_trajectory  # noqa: E402


def _fronts(traj) -> tuple[np.ndarray, np.ndarray]:
    """Largest and 99th-percentile soil x per frame (m)."""
    x = traj.positions[:, traj.soil, 0]
    return x.max(axis=1), np.quantile(x, 0.99, axis=1)


def _mpm_folder(cache: Path, key: str) -> Path:
    found = sorted(cache.glob(f"*{key}"))
    if not found:
        raise SystemExit(f"MPM cache {cache}: no run ends in the key {key} (run the evaluation first).")
    return found[0]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folders", nargs="+", type=Path, help="final_evaluation.sh output folders (each with columns/cases.csv)")
    p.add_argument("--cases", required=True, help="comma-separated case names of cases.csv")
    p.add_argument("--cache", type=Path, default=Path(DEFAULT_CACHE), help="the MPM cache (default: runout's)")
    p.add_argument("--out", type=Path, required=True, help="PNG to write")
    args = p.parse_args()
    cases = args.cases.split(",")
    fig, axes = plt.subplots(1, len(cases), figsize=(5.2 * len(cases), 4.2), squeeze=False)
    for ax, case in zip(axes[0], cases):
        mpm_done = False
        for k, folder in enumerate(args.folders):
            rows = {r["case"]: r for r in csv.DictReader(open(folder / "columns" / "cases.csv"))}
            if case not in rows:
                raise SystemExit(f"{folder / 'columns' / 'cases.csv'}: no case {case}.")
            row = rows[case]
            pred = load_trajectory(folder / "columns" / "predicted" / case)
            if not mpm_done:
                mpm = load_trajectory(_mpm_folder(args.cache, row["mpm_key"]))
                m_max, m_q99 = _fronts(mpm)
                ax.plot(m_max, "k-", lw=2, label="MPM front")
                ax.plot(m_q99, "k:", lw=1.5, label="MPM 99th pct")
                mpm_done = True
            f_max, f_q99 = _fronts(pred)
            colour = f"C{k}"
            ax.plot(f_max, "-", color=colour, label=f"{folder.name} front ({float(row['ape_percent']):.1f} %)")
            ax.plot(f_q99, ":", color=colour, label=f"{folder.name} 99th pct")
            beyond = int((pred.positions[-1, pred.soil, 0] > m_max[-1]).sum())
            print(f"{case} {folder.name}: front {f_max[-1]:.1f} m (MPM {m_max[-1]:.1f}), 99th pct {f_q99[-1]:.1f} "
                  f"(MPM {m_q99[-1]:.1f}), {beyond} of {int(pred.soil.sum())} points beyond the MPM's front")
        ax.set_title(case.replace("column_", ""))
        ax.set_xlabel("frame")
        ax.set_ylabel("x (m)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
