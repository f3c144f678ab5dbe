"""The terminal output of the commands: the one owner of rich consoles, their tables and the progress bar.

* :func:`make_console` builds every ``rich.console.Console`` of ``prt_torch``, ``train`` and ``export`` (an
  architecture test holds that no other module constructs one): log lines carry no source location
  (``log_path=False``), and output that goes to a file or a pipe is laid out :data:`NON_TTY_WIDTH` columns
  wide (unless ``COLUMNS`` says otherwise) instead of rich's 80, its printed lines unwrapped.
* :func:`fitted_table` is a table whose every column is as wide as its longest cell or header word, so
  headers wrap at spaces (never cut to ``diff...``) and numbers are never wrapped or cut; borders are light
  (``prt eval``'s ten columns fit 80 columns).
* :func:`progress_bar` lays out the columns every caller shows: ``[spinner] label [bar n/N] fields...
  [elapsed] [remaining]``, so a bake, a simulation, an evaluation, playback and training look alike. The bar
  is the only part that shrinks in a narrow terminal (then it goes, then the times); counts and fields are
  never cut. Where the console is not a terminal (a file, a pipe, ``TERM=dumb``) there is no live display:
  the same row, without bar and spinner, is printed once per :data:`PLAIN_STEPS`-th of the total (a task
  without a total: when its description changes, at most once per :data:`PLAIN_SECONDS`).

rich is imported when a console, table or bar is built.
"""

from __future__ import annotations

import functools
import math
import os
import sys
from collections.abc import Sequence
from typing import Any

#: the layout width of a console that writes to a file or a pipe (``COLUMNS`` unset)
NON_TTY_WIDTH = 100
#: at most this many columns for the bar itself (it shrinks first, down to :data:`MIN_BAR_WIDTH`, then goes)
BAR_WIDTH = 40
MIN_BAR_WIDTH = 4
#: a non-terminal progress bar prints its row at 0, 1/N, 2/N, ... N/N of the total
PLAIN_STEPS = 10
#: ... and a task without a total its row when its description changes, at most once per this many seconds
PLAIN_SECONDS = 10.0


def make_console(*, stderr: bool = False, width: int | None = None, **kwargs: Any) -> Any:
    """A ``rich.console.Console`` (``stderr``: to standard error; ``kwargs`` go to ``Console``: ``file``,
    ``force_terminal``, ...) without source locations in its log lines. ``width`` None: the terminal's width,
    ``COLUMNS`` when set, else, when the output is not a terminal, :data:`NON_TTY_WIDTH` for tables and no
    wrapping of printed text (``soft_wrap``)."""
    from rich.console import Console

    if width is None and not os.environ.get("COLUMNS", "").strip().isdigit():
        tty = kwargs.get("force_terminal")
        if tty is None:
            stream = kwargs.get("file") or (sys.stderr if stderr else sys.stdout)
            try:
                tty = bool(stream.isatty())
            except (AttributeError, ValueError, OSError):  # a closed or stream-like object without isatty
                tty = False
        if not tty:
            width = NON_TTY_WIDTH
            kwargs.setdefault("soft_wrap", True)  # a printed line stays one line (a path is never broken)
    return Console(stderr=stderr, width=width, log_path=False, **kwargs)


def fitted_table(headers: Sequence[str], rows: Sequence[Sequence[str]], *, title: str | None = None,
                 left: int = 1) -> Any:
    """A ``rich.table.Table`` of ``rows`` (cells as text, ``len(headers)`` per row) whose column ``j`` is
    ``max(longest word of headers[j], longest cells[:, j])`` wide: a header wraps at its spaces, a cell is
    never wrapped or cut. The first ``left`` columns are left-justified, the rest right-justified (numbers)."""
    from rich import box
    from rich.cells import cell_len
    from rich.table import Table

    t = Table(title=title, box=box.SIMPLE_HEAD, padding=(0, 0))
    for j, h in enumerate(headers):
        w = max([cell_len(word) for word in h.split()] + [cell_len(r[j]) for r in rows] + [1])
        t.add_column(h, justify="left" if j < left else "right", width=w, no_wrap=False, overflow="fold")
    for r in rows:
        t.add_row(*r)
    return t


def progress_bar(label: str = "{task.description}", fields: tuple[str, ...] = (), *, counted: bool = True,
                 spinner: bool = False, elapsed: bool = True, remaining: bool = False, **kwargs: Any) -> Any:
    """A ``rich.progress.Progress`` (not started) with columns: a spinner (``spinner``), ``label`` (a rich format
    of the task, e.g. ``"{task.description}"``), the bar and ``n/N`` (``counted``), a text column for each of
    ``fields`` (formats such as ``"{task.fields[rate]}"``), the elapsed (``elapsed``) and remaining
    (``remaining``) time. ``kwargs`` go to ``Progress`` (``transient``; ``console``, default
    ``make_console(stderr=True)``). Not on a terminal: plain rows instead of a live bar (module docstring)."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        SpinnerColumn,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )
    from rich.table import Column

    def fixed() -> Any:
        return Column(no_wrap=True)

    columns: list[Any] = [SpinnerColumn(table_column=fixed())] if spinner else []
    columns.append(TextColumn(label, table_column=fixed()))
    if counted:
        columns += [BarColumn(bar_width=None, table_column=Column(no_wrap=False, max_width=BAR_WIDTH)),
                    MofNCompleteColumn(table_column=fixed())]
    columns += [TextColumn(f, table_column=fixed()) for f in fields]
    if elapsed:
        columns.append(TimeElapsedColumn(table_column=fixed()))
    if remaining:
        columns.append(TimeRemainingColumn(table_column=fixed()))
    con = kwargs.pop("console", None) or make_console(stderr=True)
    return _fitted_progress()(*columns, console=con, **kwargs)


@functools.cache
def _fitted_progress() -> type:
    """The ``Progress`` subclass of :func:`progress_bar` (built once, when rich is first needed)."""
    from rich.measure import Measurement
    from rich.progress import BarColumn, Progress, SpinnerColumn, Task, TaskID, TimeElapsedColumn, TimeRemainingColumn
    from rich.table import Table

    class FittedProgress(Progress):
        """``Progress`` whose row drops the bar, then the times, rather than cut a count; plain rows when the
        console is not a terminal."""

        def __init__(self, *columns: Any, console: Any, **kwargs: Any) -> None:
            self.plain = not console.is_terminal or console.is_dumb_terminal
            super().__init__(*columns, console=console, disable=self.plain, **kwargs)
            self._shown: dict[TaskID, tuple[object, float]] = {}

        def _table(self, tasks: list[Task], drop: tuple[type, ...]) -> Table:
            saved = self.columns
            self.columns = tuple(c for c in saved if not isinstance(c, drop))
            try:
                return super().make_tasks_table(tasks)
            finally:
                self.columns = saved

        def _needed(self, tasks: list[Task], drop: tuple[type, ...]) -> int:
            """Columns the row needs with the ``drop`` columns left out (the bar at its narrowest)."""
            kept = [c for c in self.columns if not isinstance(c, drop)]
            opts = self.console.options
            total = max(len(kept) - 1, 0)  # one space between columns
            for c in kept:
                if isinstance(c, BarColumn):
                    total += MIN_BAR_WIDTH
                    continue
                cells = [c.format(task=t) if isinstance(c, str) else c(t) for t in tasks]
                total += max((Measurement.get(self.console, opts, x).maximum for x in cells), default=0)
            return total

        def make_tasks_table(self, tasks: Any) -> Table:
            tasks = [t for t in tasks if t.visible]
            if not tasks or not hasattr(self, "live"):  # rich renders once while building its Live
                return super().make_tasks_table(tasks)
            width = self.console.width
            for drop in ((), (BarColumn,), (BarColumn, TimeElapsedColumn, TimeRemainingColumn)):
                if self._needed(tasks, drop) <= width:
                    break
            return self._table(tasks, drop)

        def add_task(self, *args: Any, **kwargs: Any) -> TaskID:
            task_id = super().add_task(*args, **kwargs)
            self._note(task_id)
            return task_id

        def update(self, task_id: TaskID, *args: Any, **kwargs: Any) -> None:
            super().update(task_id, *args, **kwargs)
            self._note(task_id)

        def advance(self, task_id: TaskID, advance: float = 1) -> None:
            super().advance(task_id, advance)
            self._note(task_id)

        def _note(self, task_id: TaskID) -> None:
            """Not a terminal: print the task's row when it crosses a step (or its description changes)."""
            if not self.plain:
                return
            with self._lock:
                task, now = self._tasks[task_id], self.get_time()
                step: object = (min(int(PLAIN_STEPS * task.completed / task.total), PLAIN_STEPS)
                                if task.total else task.description)
                last, when = self._shown.get(task_id, (None, -math.inf))
                if step == last or not task.visible or (not task.total and now - when < PLAIN_SECONDS):
                    return
                self._shown[task_id] = (step, now)
            self.console.print(self._table([task], (BarColumn, SpinnerColumn)))

    return FittedProgress
