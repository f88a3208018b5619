"""Draw the solver-6 campaign's 16-scene measures against the CPU-hours spent.

    python scripts/plot_campaign.py docs/figures/campaign6_evaluations.csv docs/figures/campaign6_evaluations.png

The CSV holds one row per file measured with `runout evaluate heldout FILE --data data/ft8
--split valid` (16 held-out scenes rolled out from rest over 480 frames, against solver 6):
its fine-tune step, the campaign's CPU-hours when the file was written (base stage included;
a file written mid-chunk gets its share of the chunk by steps), the mean position error (m),
the front error (fraction of the MPM's travel), the extent runout error (fraction) and the
mean displacement (m). The picture puts them beside the bars the campaign is judged by:
standing still (nothing moves), the recipe issue's targets and the MPM's own displacement.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from runout.errors import InputError

COLUMNS = ("file", "finetune_step", "campaign_cpu_h", "position_error_m", "front_error", "extent_runout_error", "displacement_m")
STANDING_STILL_M = 20.30  # mean position error on the 16 scenes if nothing moved
POSITION_TARGET_M = 10.15  # the recipe issue's bar: half of standing still
FRONT_TARGET = 0.25  # the recipe issue's bar: fronts within 25 % of their travel
MPM_DISPLACEMENT_M = 33.2  # the MPM's mean displacement on the 16 scenes


def read_rows(path: Path) -> list[dict]:
    if not path.is_file():
        raise InputError(f"{path}: no such file.")
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        missing = [c for c in COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise InputError(f"{path}: the column '{missing[0]}' is missing; the columns are {', '.join(COLUMNS)}.")
        rows = []
        for line, row in enumerate(reader, start=2):
            for c in COLUMNS[1:]:
                try:
                    row[c] = float(row[c])
                except ValueError:
                    raise InputError(f"{path}, line {line}: the field '{c}' is '{row[c]}', not a number.") from None
            rows.append(row)
    if not rows:
        raise InputError(f"{path}: no rows; at least one measured file is needed.")
    return sorted(rows, key=lambda r: r["campaign_cpu_h"])


def plot(rows: list[dict], out: Path) -> Path:
    hours = [r["campaign_cpu_h"] for r in rows]
    shipped = [r for r in rows if "shipped" in r["file"]]
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    panels = (
        ("position_error_m", 1.0, "mean position error (m)", ((STANDING_STILL_M, "standing still"), (POSITION_TARGET_M, "recipe target"))),
        ("front_error", 100.0, "front error (% of the MPM's travel)", ((100 * FRONT_TARGET, "recipe target"),)),
        ("displacement_m", 1.0, "mean displacement (m)", ((MPM_DISPLACEMENT_M, "MPM"),)),
    )
    for ax, (key, scale, label, lines) in zip(axes, panels):
        ax.plot(hours, [scale * r[key] for r in rows], "o-", color="tab:blue", label="file of the run")
        for r in shipped:
            ax.plot(r["campaign_cpu_h"], scale * r[key], "*", color="tab:red", markersize=14, label="shipped")
        for value, name in lines:
            ax.axhline(value, color="grey", linestyle="--", linewidth=1)
            ax.text(hours[0], value, f" {name}", va="bottom", color="grey", fontsize=8)
        ax.set_xlabel("campaign CPU-hours (base stage included)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    fig.suptitle("Solver-6 fine-tune: 16 held-out scenes rolled out from rest (480 frames) against the MPM")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("csv", type=Path, help="measures, one row per file (columns: " + ", ".join(COLUMNS) + ")")
    parser.add_argument("out", type=Path, help="PNG to write")
    args = parser.parse_args(argv)
    try:
        print(plot(read_rows(args.csv), args.out))
    except InputError as e:
        print(e, file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
