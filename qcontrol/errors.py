"""Exception types the command line turns into exit statuses."""

from __future__ import annotations


class QcontrolInputError(ValueError):
    """Bad user input (scenario, model, command line). The CLI prints it as one line, exit 2."""


class KeyNotForKind(QcontrolInputError):
    """A key of a kinded table (``[reference]``, ``[controller]``) that the chosen kind does not
    take; ``key`` is its dotted path. The scenario loader adds the command-line fix when the kind
    or the key came from ``--set``."""

    def __init__(self, message: str, key: str) -> None:
        super().__init__(message)
        self.key = key


class OverrideError(QcontrolInputError):
    """A bad value (or key) that came from an override rather than the file: the message names the
    override as given (``--set controller.delta=abc: must be a number ...``), not the file.
    ``item`` is the override entry as the loader received it, so a command that made the entry
    from another option (``--grid``, ``--duration``) can name that option instead
    (:meth:`named`)."""

    def __init__(self, label: str, detail: str, item: object = None) -> None:
        super().__init__(f"{label}: {detail}")
        self.label = label
        self.detail = detail
        self.item = item

    def named(self, label: str) -> OverrideError:
        """The same problem, named as the option ``label`` (e.g. ``--grid controller.delta=abc``)."""
        return OverrideError(label, self.detail, self.item)


class QcontrolOutputError(OSError):
    """An output could not be written (no space left, an I/O error, no permission) while or after
    a run: the previous file at that name is intact. The CLI prints it as one line, exit 3."""


class QcontrolLawFailure(RuntimeError):
    """A control law written in Python failed during runs whose results were written anyway (its
    runs stopped there, their summaries say why): the message is the first failure's one line. The
    CLI prints it, exit 4."""


class Terminated(KeyboardInterrupt):
    """The process was asked to stop (SIGTERM): handled like Ctrl-C (every output path cleans up
    its temporaries, keeps partial data under its partial name), exit status 143."""


def shown(value: object) -> str:
    """A path or value as a message shows it on one line: as it is when printable, else quoted
    with its control characters escaped (a newline in a name would split the message)."""
    text = str(value)
    return text if text.isprintable() else repr(text)


def brief(text: str, limit: int = 40) -> str:
    """``text`` (:func:`shown`) for a one-line message, cut after ``limit // 2`` characters when it is
    longer than ``limit`` (a 400-digit literal is not echoed back whole)."""
    text = shown(text)
    if len(text) <= limit:
        return text
    return f"{text[: limit // 2]}... ({len(text)} characters)"
