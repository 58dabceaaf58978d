"""What a training run writes for people: the loss log, the validation table and its figure.

* ``losses.csv``: one row every ``run.log_every`` steps with every loss term, the
  learning rate and the seconds since the run (or its resume) started;
* ``validation.csv``: one row per validation with every figure;
* ``validation.png``: the validation figures (left) and the loss terms (right).

Redraw the figure of a finished or running run with
``python -m train.report outputs/train/<date_time>``.
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

import numpy as np

LOSS_COLUMNS = ("step", "loss", "bij", "orth", "couple", "sup", "partial", "lr", "seconds")
VALIDATION_COLUMNS = (
    "step",
    "val_error",
    "val_unsup",
    "val_bij",
    "val_orth",
    "val_couple",
    "val_partial",
    "wks_error",
    "loss",
)


class LossLog:
    """Appends loss terms to ``losses.csv``; on resume, drops rows after the resumed step.

    Parameters
    ----------
    path : Path
    start_step : int
        Steps already done (rows with a larger step are from a run that was not
        checkpointed and are removed).
    """

    def __init__(self, path: Path, start_step: int = 0) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        kept = [row for row in read_rows(self.path) if int(float(row["step"])) <= start_step]
        with self.path.open("w", newline="") as handle:
            writer = csv.DictWriter(handle, LOSS_COLUMNS)
            writer.writeheader()
            writer.writerows({key: row.get(key, "") for key in LOSS_COLUMNS} for row in kept)

    def append(self, step: int, terms: dict[str, float], lr: float, seconds: float) -> None:
        """Write one row (missing terms are left empty)."""
        row = {"step": step, "lr": f"{lr:.3g}", "seconds": f"{seconds:.1f}"}
        row.update({key: f"{terms[key]:.6g}" for key in LOSS_COLUMNS if key in terms})
        with self.path.open("a", newline="") as handle:
            csv.DictWriter(handle, LOSS_COLUMNS).writerow(row)


def read_rows(path: Path) -> list[dict[str, str]]:
    """Rows of a CSV file with a header ([] if the file does not exist)."""
    if not Path(path).is_file():
        return []
    with Path(path).open(newline="") as handle:
        return list(csv.DictReader(handle))


def column(rows: list[dict[str, str]], key: str) -> np.ndarray:
    """A column as floats (nan where empty or missing)."""
    return np.array([float(row[key]) if row.get(key) not in (None, "") else math.nan for row in rows])


def write_validation_csv(history: list[dict[str, float]], out_dir: Path) -> None:
    """``validation.csv`` from the history (one dict per validation)."""
    with (Path(out_dir) / "validation.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, VALIDATION_COLUMNS)
        writer.writeheader()
        for entry in history:
            writer.writerow({key: _format(entry.get(key, math.nan)) for key in VALIDATION_COLUMNS})


def _format(value) -> str:
    return str(int(value)) if isinstance(value, int) else f"{float(value):.6f}"


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing mean over ``window`` values (shorter at the start), ignoring nan."""
    finite = np.where(np.isfinite(values), values, 0.0)
    counts = np.cumsum(np.isfinite(values).astype(float))
    sums = np.cumsum(finite)
    lagged_sums = np.concatenate([np.zeros(window), sums[:-window]]) if len(sums) > window else 0 * sums
    lagged_counts = np.concatenate([np.zeros(window), counts[:-window]]) if len(sums) > window else 0 * counts
    with np.errstate(invalid="ignore", divide="ignore"):
        return (sums - lagged_sums) / (counts - lagged_counts)


def plot_validation(ax, rows: list[dict[str, str]]) -> None:
    """Left panel: the labelled error (with WKS) and/or the label-free loss per validation."""
    steps = column(rows, "step")
    error, unsup, wks = column(rows, "val_error"), column(rows, "val_unsup"), column(rows, "wks_error")
    partial = column(rows, "val_partial")
    labelled = bool(np.isfinite(error).any())
    main = error if labelled else unsup
    ax.plot(
        steps, main, marker="o", color="tab:blue", label="NN geodesic error" if labelled else "label-free"
    )
    if np.isfinite(partial).any():  # a partial recipe: selected on its parts' error
        ax.plot(steps, partial, marker="s", color="tab:orange", label="NN error, partial copies")
        main = partial
    if np.isfinite(main).any():
        best = int(np.nanargmin(main))
        ax.plot([steps[best]], [main[best]], marker="*", markersize=14, color="tab:red")
        ax.set_title(f"validation: best {main[best]:.4f} at step {int(steps[best])} (star)", fontsize=9)
    if labelled and np.isfinite(wks).any():
        ax.axhline(float(np.nanmean(wks)), color="tab:gray", linestyle="--", label="WKS")
    ax.set_xlabel("training step")
    ax.set_ylabel("mean geodesic error (NN feature map)" if labelled else "unsupervised loss, held-out pairs")
    if labelled and np.isfinite(unsup).any():
        twin = ax.twinx()
        twin.plot(steps, unsup, marker=".", color="tab:green", alpha=0.7, label="label-free loss")
        twin.set_ylabel("unsupervised loss, held-out pairs", color="tab:green")
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(alpha=0.3)


def plot_losses(ax, rows: list[dict[str, str]]) -> None:
    """Right panel: every loss term over the steps (moving average of 50 rows), log scale."""
    steps = column(rows, "step")
    for key in ("loss", "bij", "orth", "couple", "sup"):
        values = column(rows, key)
        if np.isfinite(values).any():
            ax.plot(steps, moving_average(values, 50), label=key, linewidth=1.2)
    ax.set_yscale("log")
    ax.set_xlabel("training step")
    ax.set_title("training loss terms (moving average of 50 log rows)", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)


def write_figure(out_dir: Path) -> Path:
    """Draw ``validation.png`` from ``validation.csv`` and ``losses.csv`` of a run folder."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    plot_validation(left, read_rows(out_dir / "validation.csv"))
    losses = read_rows(out_dir / "losses.csv")
    if losses:
        plot_losses(right, losses)
    fig.tight_layout()
    fig.savefig(out_dir / "validation.png", dpi=110)
    plt.close(fig)
    return out_dir / "validation.png"


def main(argv: list[str] | None = None) -> None:
    """``python -m train.report RUN_DIR``: redraw ``validation.png`` of a run folder."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path, help="a spidermatch-train output folder")
    args = parser.parse_args(argv)
    if not (args.run_dir / "validation.csv").is_file():
        parser.error(f"{args.run_dir}: no validation.csv (not a training run, or nothing validated yet)")
    print(write_figure(args.run_dir))


if __name__ == "__main__":
    main()
