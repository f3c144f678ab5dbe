"""The one rich progress bar of the commands (rank 0; rich is imported when a bar is built).

:func:`progress_bar` lays out the columns every caller shows: ``[spinner] label [bar n/N] fields... [elapsed]
[remaining]``, so a bake, a simulation, an evaluation, playback and training look alike.
"""

from __future__ import annotations

from typing import Any


def progress_bar(label: str = "{task.description}", fields: tuple[str, ...] = (), *, counted: bool = True,
                 spinner: bool = False, elapsed: bool = True, remaining: bool = False, **kwargs: Any) -> Any:
    """A ``rich.progress.Progress`` (not started) with columns: a spinner (``spinner``), ``label`` (a rich format
    of the task, e.g. ``"{task.description}"``), the bar and ``n/N`` (``counted``), a text column for each of
    ``fields`` (formats such as ``"{task.fields[rate]}"``), the elapsed (``elapsed``) and remaining
    (``remaining``) time. ``kwargs`` go to ``Progress`` (``console``, ``transient``)."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        SpinnerColumn,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns: list[Any] = [SpinnerColumn()] if spinner else []
    columns.append(TextColumn(label))
    if counted:
        columns += [BarColumn(), MofNCompleteColumn()]
    columns += [TextColumn(f) for f in fields]
    if elapsed:
        columns.append(TimeElapsedColumn())
    if remaining:
        columns.append(TimeRemainingColumn())
    return Progress(*columns, **kwargs)
