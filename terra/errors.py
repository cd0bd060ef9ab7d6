"""Errors a user can cause and fix. The CLI prints them as one line and exits with `exit_code`."""


class TerraError(Exception):
    """Bad input or configuration: one clear line naming the file or field and what was expected."""

    exit_code = 2


class NoPathError(TerraError):
    """A plan request whose goal cannot be reached under the given terrain constraints."""

    exit_code = 3
