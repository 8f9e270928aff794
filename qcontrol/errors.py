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
