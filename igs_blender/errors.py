"""The error the add-on shows the user as one readable report."""


class UserError(Exception):
    """Something the user can fix (a missing workspace, a malformed file); the message says what and where."""
