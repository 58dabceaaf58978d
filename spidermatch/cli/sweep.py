"""The end of a Hydra sweep (``-m``): which jobs failed, and an exit code that says so.

Hydra runs each job of a sweep and exits 0 whatever they returned, so a sweep whose every job
was refused looked like a success to a script. Each job records its exit code in its folder
(``.hydra/exit_code``, :func:`record_job_code`); :class:`SweepReport`, a Hydra callback that runs
where the sweep was started (whatever the launcher), reads them when the sweep ends, logs one line
per failed job and a summary, and leaves the first failed job's exit code in :data:`sweep_code`
for the command to exit with.
"""

from __future__ import annotations

import logging
from pathlib import Path

from hydra.experimental.callback import Callback

logger = logging.getLogger("spidermatch.match")

CODE_FILE = "exit_code"
"""Name of the file in a job's ``.hydra/`` folder that holds its exit code."""

UNRECORDED = 1
"""Exit code of a job that left no record (killed, or refused before its folder was held)."""

sweep_code = 0
"""Exit code of the last sweep in this process: 0, or the first failed job's."""


def record_job_code(output_dir: Path, code: int) -> None:
    """Write a sweep job's exit code into its ``.hydra/`` folder (there only if the job held the folder)."""
    folder = output_dir / ".hydra"
    if folder.is_dir():
        try:
            (folder / CODE_FILE).write_text(f"{int(code)}\n")
        except OSError as error:  # the job's own outputs say what failed; the summary counts it unknown
            logger.warning("%s: the job's exit code cannot be recorded (%s)", folder, error.strerror)


def recorded_code(job_dir: Path) -> int | None:
    """The exit code a sweep job recorded in its ``.hydra/`` folder (None: not recorded)."""
    try:
        return int((job_dir / ".hydra" / CODE_FILE).read_text().strip())
    except (OSError, ValueError):
        return None


def natural_key(relative: Path) -> list:
    """Sort key that puts sweep job folders 2 before 10."""
    return [int(part) if part.isdigit() else part for part in relative.parts]


def job_codes(sweep_dir: Path) -> list[tuple[str, int]]:
    """(job folder relative to ``sweep_dir``, exit code) of every job that held its folder, in name order."""
    jobs = sorted(
        (marker.parent.relative_to(sweep_dir) for marker in Path(sweep_dir).rglob(".hydra")), key=natural_key
    )
    codes = (recorded_code(Path(sweep_dir) / job) for job in jobs)
    return [(str(job), UNRECORDED if code is None else code) for job, code in zip(jobs, codes)]


def report_sweep(sweep_dir: Path) -> int:
    """Log the sweep's failed jobs and a summary line; return 0 or the first failed job's exit code."""
    jobs = job_codes(sweep_dir)
    failed = [(name, code) for name, code in jobs if code != 0]
    for name, code in failed:
        logger.error("sweep job %s failed (exit %d): %s", name, code, Path(sweep_dir) / name)
    if not jobs:
        logger.error("sweep in %s: no job recorded an outcome", sweep_dir)
        return UNRECORDED
    line = f"sweep in {sweep_dir}: {len(jobs) - len(failed)} of {len(jobs)} jobs succeeded"
    if failed:
        logger.error("%s; failed: %s", line, ", ".join(f"{name} (exit {code})" for name, code in failed))
        return failed[0][1]
    logger.info("%s", line)
    return 0


class SweepReport(Callback):
    """Hydra callback: :func:`report_sweep` when a sweep ends (``conf/match.yaml``, ``conf/eval.yaml``)."""

    def on_multirun_end(self, config, **kwargs) -> None:
        """Report the sweep in ``hydra.sweep.dir`` and keep its exit code."""
        global sweep_code
        sweep_code = report_sweep(Path(str(config.hydra.sweep.dir)))
