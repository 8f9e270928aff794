"""Exception types the command line turns into exit statuses."""


class QcontrolInputError(ValueError):
    """Bad user input (scenario, model, command line). The CLI prints it as one line, exit 2."""
