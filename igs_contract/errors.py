"""The one error the contract's readers raise."""


class ContractError(ValueError):
    """A file that does not follow the contract; the message names the file and what is wrong.

    Each side turns it into its own user-facing error (the backend's IGSError, the add-on's UserError).
    """
