"""The user-error base class: input a user can correct (a bad option, a missing file, a task that cannot be used).
`gsa` prints such an error as one line and exits with its status (gsa_jax.errors.run_command). It lives here, at the
bottom of the house, so that envs/ and gsa_jax/ both import it downward (gsa_jax/errors.py re-exports it); importing
it loads nothing else (envs/__init__.py is lazy)."""


class UserError(Exception):
    """An error in what the user asked for, ending a command with `exit_status` (2: bad input, unless a command
    says otherwise, e.g. 4: disk full)."""

    exit_status = 2

    def __init__(self, *args: object, exit_status: int | None = None) -> None:
        super().__init__(*args)
        if exit_status is not None:
            self.exit_status = exit_status
