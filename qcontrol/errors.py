"""Exception types the command line turns into exit statuses."""


class QcontrolInputError(ValueError):
    """Bad user input (scenario, model, command line). The CLI prints it as one line, exit 2."""


class KeyNotForKind(QcontrolInputError):
    """A key of a kinded table (``[reference]``, ``[controller]``) that the chosen kind does not
    take; ``key`` is its dotted path. The scenario loader adds the command-line fix when the kind
    or the key came from ``--set``."""

    def __init__(self, message: str, key: str) -> None:
        super().__init__(message)
        self.key = key


class QcontrolOutputError(OSError):
    """An output could not be written (no space left, an I/O error, no permission) while or after
    a run: the previous file at that name is intact. The CLI prints it as one line, exit 3."""


class Terminated(KeyboardInterrupt):
    """The process was asked to stop (SIGTERM): handled like Ctrl-C (every output path cleans up
    its temporaries, keeps partial data under its partial name), exit status 143."""


def shown(value: object) -> str:
    """A path or value as a message shows it on one line: as it is when printable, else quoted
    with its control characters escaped (a newline in a name would split the message)."""
    text = str(value)
    return text if text.isprintable() else repr(text)
