"""User-facing errors: one clear message naming the file or parameter and what is wrong."""


class IGSError(Exception):
    """An error the user can fix (bad input, missing file). The CLI prints only its message."""


class Cancelled(Exception):
    """Raised when the user cancels (SIGINT/SIGTERM); the last checkpoint is kept, unless ``resumable``
    is False: the cancelled work keeps nothing, and the same command starts it over (an edit's bake)."""

    def __init__(self, *args: object, resumable: bool = True):
        super().__init__(*args)
        self.resumable = resumable
